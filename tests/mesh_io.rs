//! Mesh files: OBJ+MTL and glTF/GLB reading, GLB writing, scan normalisation, and clear errors on bad input.

use std::path::Path;

use glam::{Vec2, Vec3};
use r2human::geometry::mesh::TriMesh;
use r2human::io::mesh_io::*;
use r2human::synth::scan::load_scan;
use r2human::synth::SynthError;

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn checker_png(dir: &Path, name: &str) -> image::RgbImage {
    let img = image::RgbImage::from_fn(4, 4, |x, y| {
        if (x + y) % 2 == 0 {
            image::Rgb([255, 0, 0])
        } else {
            image::Rgb([0, 0, 255])
        }
    });
    img.save(dir.join(name)).unwrap();
    img
}

/// A textured quad pyramid-ish OBJ: a quad face, a triangle with negative indices, a UV seam.
const OBJ: &str =
    "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 2 0\nv 0 2 0\nv 0.5 1 1\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 0.5\n\
usemtl skin\nf 1/1 2/2 3/3 4/4\nf -4/2 -3/3 -1/5\nf 1/5 2/2 5/5\n";

#[test]
fn obj_with_mtl_texture_reads_with_flipped_uvs_and_split_seams() {
    let dir = tempfile::tempdir().unwrap();
    let tex = checker_png(dir.path(), "tex file.png");
    write(dir.path(), "m.mtl", "newmtl skin\nKd 0.5 0.5 0.5\nmap_Kd -s 1 1 1 tex file.png\n");
    let p = write(dir.path(), "a.obj", OBJ);
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.mesh.triangles.len(), 4); // quad -> 2, plus 2 triangles
    assert_eq!(m.texture.as_ref().unwrap(), &tex);
    assert_eq!(m.mesh.uvs.len(), m.mesh.positions.len());
    // Vertex 1 (0,0,0) is used with vt 1 and vt 5: split into two vertices.
    let at_origin = m.mesh.positions.iter().filter(|p| **p == Vec3::ZERO).count();
    assert_eq!(at_origin, 2);
    // OBJ v=1 becomes glTF v=0 (top row).
    let i = m.mesh.positions.iter().position(|p| *p == Vec3::new(1.0, 2.0, 0.0)).unwrap();
    assert_eq!(m.mesh.uvs[i], Vec2::new(1.0, 0.0));
    // Quad winding kept: the first triangle faces +z.
    let t = m.mesh.triangles[0].map(|k| m.mesh.positions[k as usize]);
    assert!((t[1] - t[0]).cross(t[2] - t[0]).z > 0.0);
    // Texture lookup is bilinear in linear light: the centre of texel (0,0) is pure red.
    let c = sample_texture(m.texture.as_ref().unwrap(), Vec2::new(0.125, 0.125));
    assert!((c - Vec3::X).length() < 1e-5, "{c}");
}

#[test]
fn obj_without_texture_uses_vertex_colours_or_kd() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "c.obj", "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n");
    let m = read_obj(&p).unwrap();
    assert!(m.texture.is_none() && m.mesh.uvs.is_empty());
    assert_eq!(m.mesh.colors, vec![Vec3::X, Vec3::Y, Vec3::Z]);
    write(dir.path(), "k.mtl", "newmtl a\nKd 0.2 0.4 0.6\n");
    let p = write(dir.path(), "k.obj", "mtllib k.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let m = read_obj(&p).unwrap();
    assert!(m.mesh.colors.iter().all(|c| (*c - Vec3::new(0.2, 0.4, 0.6)).length() < 1e-6));
}

fn err_names_file(e: &dyn std::fmt::Display, file: &str) {
    let s = e.to_string();
    assert!(s.contains(file), "error {s:?} does not name {file}");
}

#[test]
fn bad_obj_inputs_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Missing texture.
    write(d, "m.mtl", "newmtl skin\nmap_Kd missing.png\n");
    let p = write(d, "a.obj", OBJ);
    let e = read_mesh(&p).unwrap_err();
    assert!(matches!(e, MeshIoError::Texture { .. }), "{e}");
    err_names_file(&e, "missing.png");
    // Missing MTL.
    let p = write(d, "b.obj", &OBJ.replace("m.mtl", "nope.mtl"));
    err_names_file(&read_mesh(&p).unwrap_err(), "nope.mtl");
    // Empty, NaN, out-of-range index, garbage number, truncated face.
    let e = read_mesh(&write(d, "empty.obj", "# nothing\nv 0 0 0\n")).unwrap_err();
    assert!(matches!(e, MeshIoError::Empty { .. }));
    err_names_file(&e, "empty.obj");
    let e = read_mesh(&write(d, "nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")).unwrap_err();
    assert!(matches!(e, MeshIoError::NonFinite { index: 1, .. }), "{e}");
    err_names_file(&e, "nan.obj");
    let e = read_mesh(&write(d, "idx.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")).unwrap_err();
    assert!(matches!(e, MeshIoError::Obj { line: 4, .. }), "{e}");
    let e = read_mesh(&write(d, "num.obj", "v 0 0 zero\n")).unwrap_err();
    assert!(matches!(e, MeshIoError::Obj { line: 1, .. }), "{e}");
    let e = read_mesh(&write(d, "trunc.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n")).unwrap_err();
    err_names_file(&e, "trunc.obj");
    // Unknown extension and missing file.
    assert!(matches!(read_mesh(&d.join("x.ply")).unwrap_err(), MeshIoError::UnsupportedFormat { .. }));
    err_names_file(&read_mesh(&d.join("gone.obj")).unwrap_err(), "gone.obj");
}

fn textured_cube() -> TexturedMesh {
    let mut mesh = TriMesh::cuboid(Vec3::new(-0.3, -0.9, -0.2), Vec3::new(0.3, 0.9, 0.2));
    mesh.uvs = mesh.positions.iter().map(|p| Vec2::new(p.x + 0.5, 0.5 - p.y * 0.5)).collect();
    let tex = image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([(x * 30) as u8, (y * 30) as u8, 200]));
    TexturedMesh { mesh, texture: Some(tex) }
}

#[test]
fn glb_round_trip_and_corrupt_glb_errors() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("cube.glb");
    let cube = textured_cube();
    write_glb(&p, &cube).unwrap();
    let back = read_mesh(&p).unwrap();
    assert_eq!(back.mesh.positions, cube.mesh.positions);
    assert_eq!(back.mesh.triangles, cube.mesh.triangles);
    assert_eq!(back.mesh.uvs, cube.mesh.uvs);
    assert_eq!(back.texture, cube.texture);
    // Colour-only meshes round-trip through COLOR_0.
    let mut col = TexturedMesh { mesh: TriMesh::uv_sphere(Vec3::ZERO, 0.5, 6, 8), texture: None };
    col.mesh.colors = col.mesh.positions.iter().map(|p| (*p + Vec3::splat(0.5)).clamp(Vec3::ZERO, Vec3::ONE)).collect();
    let pc = dir.path().join("col.glb");
    write_glb(&pc, &col).unwrap();
    let back = read_gltf(&pc).unwrap();
    assert!(back.mesh.colors.iter().zip(&col.mesh.colors).all(|(a, b)| a.distance(*b) < 1e-6));
    // Truncated and garbage files.
    let bytes = std::fs::read(&p).unwrap();
    for (name, data) in [("trunc.glb", &bytes[..bytes.len() / 2]), ("junk.glb", &b"glTF\x02\0\0\0garbage"[..])] {
        let q = dir.path().join(name);
        std::fs::write(&q, data).unwrap();
        let e = read_mesh(&q).unwrap_err();
        assert!(matches!(e, MeshIoError::Gltf { .. }), "{e}");
        err_names_file(&e, name);
    }
    // Writing an empty mesh is refused and leaves no file.
    let pe = dir.path().join("empty.glb");
    assert!(write_glb(&pe, &TexturedMesh::default()).is_err());
    assert!(!pe.exists());
}

#[test]
fn gltf_with_missing_external_texture_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let gltf = r#"{"asset": {"version": "2.0"}, "images": [{"uri": "albedo.png"}], "textures": [{"source": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}], "meshes": [], "nodes": [], "scenes": [{"nodes": []}]}"#;
    let p = write(dir.path(), "s.gltf", gltf);
    let e = read_mesh(&p).unwrap_err();
    assert!(matches!(e, MeshIoError::Texture { .. }), "{e}");
    err_names_file(&e, "albedo.png");
    // With the texture present but no triangles, the mesh is empty.
    checker_png(dir.path(), "albedo.png");
    assert!(matches!(read_mesh(&p).unwrap_err(), MeshIoError::Empty { .. }));
}

#[test]
fn scans_are_normalised_and_implausible_ones_rejected() {
    let dir = tempfile::tempdir().unwrap();
    // A 170-unit-tall box standing on y = 0, off-centre: normalised to height 1.8, centred.
    let mut m = textured_cube();
    for p in &mut m.mesh.positions {
        *p = Vec3::new(p.x * 100.0 + 40.0, (p.y + 0.9) * 94.4, p.z * 100.0 - 7.0);
    }
    let p = dir.path().join("scan.glb");
    write_glb(&p, &m).unwrap();
    let s = load_scan(&p).unwrap();
    let (lo, hi) = s.mesh.mesh.bounds().unwrap();
    assert!((lo.y + 0.9).abs() < 1e-5 && (hi.y - 0.9).abs() < 1e-5);
    assert!((lo.x + hi.x).abs() < 1e-4 && (lo.z + hi.z).abs() < 1e-4);
    assert!(s.mesh.texture.is_some());
    // A floor plane far wider than the person: does not fit the body cube.
    let floor =
        "v -50 0 -50\nv 50 0 -50\nv 50 0 50\nv -50 0 50\nv 0 0 0\nv 1 0 0\nv 0 17 0\nf 1 3 2\nf 1 4 3\nf 5 6 7\n";
    let e = load_scan(&write(dir.path(), "floor.obj", floor)).unwrap_err();
    assert!(matches!(e, SynthError::Scan { .. }), "{e}");
    err_names_file(&e, "floor.obj");
    // Absurd coordinates and flat meshes.
    let e = load_scan(&write(dir.path(), "far.obj", "v 0 0 0\nv 1e9 0 0\nv 0 1 0\nf 1 2 3\n")).unwrap_err();
    err_names_file(&e, "far.obj");
    let e = load_scan(&write(dir.path(), "flat.obj", "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n")).unwrap_err();
    err_names_file(&e, "flat.obj");
}
