//! A contact sheet of scans as `r2human eval --scan` sees them (after orientation and normalisation): one row per
//! scan, its ground truth at yaw 0, 90 and 180 degrees (textured and shaded), to check that a character is upright,
//! faces the source camera at yaw 0, is whole and carries its textures before any number about it is read.
//!
//! ```text
//! cargo run --release --example scan_sheet -- OUT.png [--up y|z] [--facing +z|-z|+x|-x] [--size PX] SCAN...
//! ```

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use r2human::synth::scan::{load_scan_with, ScanOrientation};

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let out =
        PathBuf::from(args.next().context("usage: scan_sheet OUT.png [--up A] [--facing F] [--size PX] SCAN...")?);
    let (mut orientation, mut size, mut scans) = (ScanOrientation::default(), 384usize, Vec::new());
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--up" => orientation.up = Some(value()?.parse()?),
            "--facing" => orientation.facing = Some(value()?.parse()?),
            "--size" => size = value()?.parse().context("--size: a pixel count")?,
            _ => scans.push(PathBuf::from(a)),
        }
    }
    if scans.is_empty() || !(16..=2048).contains(&size) {
        bail!("give at least one scan, and --size within 16..=2048");
    }
    let mut meshes = Vec::new();
    for path in &scans {
        let scan = load_scan_with(path, &orientation).with_context(|| path.display().to_string())?;
        println!(
            "{}: up {:?}, facing {:?}, fitted {}, {} triangles",
            path.display(),
            scan.up,
            scan.facing,
            scan.fitted,
            scan.mesh.mesh.triangles.len()
        );
        meshes.push(scan.mesh);
    }
    let refs: Vec<_> = meshes.iter().collect();
    r2human::eval::ground_truth::write_contact_sheet(&out, &refs, &[0.0, 90.0, 180.0], size)?;
    println!("wrote {}", out.display());
    Ok(())
}
