//! The photos an example runs on: the paths on its command line, else every photo bundled in assets/photos.

use std::path::{Path, PathBuf};

/// The command line's paths, or (none given) every PNG and JPEG in assets/photos, sorted.
pub fn from_args_or_bundled() -> anyhow::Result<Vec<PathBuf>> {
    let photos: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    if !photos.is_empty() {
        return Ok(photos);
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/photos");
    let mut photos: Vec<PathBuf> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png" || x == "jpg"))
        .collect();
    photos.sort();
    Ok(photos)
}
