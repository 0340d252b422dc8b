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
    assert_eq!(m.first_texture().unwrap(), &tex);
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
    let c = sample_texture(m.first_texture().unwrap(), Vec2::new(0.125, 0.125));
    assert!((c - Vec3::X).length() < 1e-5, "{c}");
}

#[test]
fn obj_without_texture_uses_vertex_colours_or_kd() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "c.obj", "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nf 1 2 3\n");
    let m = read_obj(&p).unwrap();
    assert!(m.first_texture().is_none() && m.mesh.uvs.is_empty() && m.materials.is_empty());
    assert_eq!(m.mesh.colors, vec![Vec3::X, Vec3::Y, Vec3::Z]);
    // Vertex colours are sRGB, in [0, 1] or [0, 255]: mid grey 0.5 (or 128) is linear 0.214.
    for (name, level) in [("half.obj", "0.5"), ("byte.obj", "128")] {
        let text = format!("v 0 0 0 {level} {level} {level}\nv 1 0 0 0 0 0\nv 0 1 0 0 0 0\nf 1 2 3\n");
        let m = read_obj(&write(dir.path(), name, &text)).unwrap();
        let want = r2human::buffer::srgb_to_linear(if level == "128" { 128.0 / 255.0 } else { 0.5 });
        assert!((m.mesh.colors[0] - Vec3::splat(want)).length() < 1e-5, "{name}: {}", m.mesh.colors[0]);
        assert!((want - 0.214).abs() < 0.003);
    }
    write(dir.path(), "k.mtl", "newmtl a\nKd 0.2 0.4 0.6\n");
    let p = write(dir.path(), "k.obj", "mtllib k.mtl\nusemtl a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let m = read_obj(&p).unwrap();
    assert_eq!(m.materials.len(), 1);
    assert!((m.albedo(0, None, None) - Vec3::new(0.2, 0.4, 0.6)).length() < 1e-6);
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
    assert!(matches!(e, MeshIoError::Texture { source: TextureError::NotFound, .. }), "{e}");
    err_names_file(&e, "missing.png");
    assert!(e.to_string().ends_with("cannot be used: file not found"), "{e}");
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
    assert!(matches!(read_mesh(&d.join("x.stl")).unwrap_err(), MeshIoError::UnsupportedFormat { .. }));
    err_names_file(&read_mesh(&d.join("gone.obj")).unwrap_err(), "gone.obj");
}

fn textured_cube() -> TexturedMesh {
    let mut mesh = TriMesh::cuboid(Vec3::new(-0.3, -0.9, -0.2), Vec3::new(0.3, 0.9, 0.2));
    mesh.uvs = mesh.positions.iter().map(|p| Vec2::new(p.x + 0.5, 0.5 - p.y * 0.5)).collect();
    let tex = image::RgbImage::from_fn(8, 8, |x, y| image::Rgb([(x * 30) as u8, (y * 30) as u8, 200]));
    TexturedMesh::textured(mesh, tex)
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
    assert_eq!(back.first_texture(), cube.first_texture());
    // Colour-only meshes round-trip through COLOR_0.
    let mut col = TexturedMesh::untextured(TriMesh::uv_sphere(Vec3::ZERO, 0.5, 6, 8));
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

/// A GLB header and chunks from parts: (declared total length, [(declared chunk length, tag, data)]).
fn glb_raw(total: u32, chunks: &[(u32, &[u8; 4], &[u8])]) -> Vec<u8> {
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total.to_le_bytes());
    for (len, tag, data) in chunks {
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(*tag);
        out.extend_from_slice(data);
    }
    out
}

#[test]
fn glb_container_is_checked_before_any_length_is_trusted() {
    let json: &[u8] = br#"{"asset":{"version":"2.0"}}     "#; // 27 + 5 spaces of padding
    let bin: &[u8] = &[1, 2, 3, 4, 5, 6, 7, 8];
    // Well formed: header 12 + JSON 8+32 + BIN 8+8 = 68 bytes.
    let good = glb_raw(68, &[(32, b"JSON", json), (8, b"BIN\0", bin)]);
    assert_eq!(good.len(), 68);
    let c = glb_chunks(&good).unwrap();
    assert_eq!((c.json, c.bin, c.trailing), (json, Some(bin), 0));
    // The writer's container is the same bytes; it pads a chunk to 4 bytes (JSON with spaces, BIN with zeros).
    assert_eq!(glb_container(json, Some(bin)).unwrap(), good);
    let padded = glb_container(&json[..27], Some(&bin[..5])).unwrap();
    assert_eq!(padded.len(), 12 + 8 + 28 + 8 + 8);
    let c = glb_chunks(&padded).unwrap();
    assert_eq!((c.json, c.bin), (&json[..28], Some(&[1, 2, 3, 4, 5, 0, 0, 0][..])));
    // An extension's chunk after BIN is skipped; trailing bytes past the declared length are counted, not read.
    let mut ext = glb_raw(80, &[(32, b"JSON", json), (8, b"BIN\0", bin), (4, b"XYZW", &[9; 4])]);
    ext.extend_from_slice(&[0xEE; 3]);
    let c = glb_chunks(&ext).unwrap();
    assert_eq!((c.json, c.bin, c.trailing), (json, Some(bin), 3));
    // Every broken container is an error saying what is wrong (none may panic: lengths below 12 made gltf
    // 1.4.1 subtract with overflow).
    let cases: Vec<(Vec<u8>, &str)> = vec![
        (b"glTF\x02\0\0".to_vec(), "shorter than the 12-byte GLB header"),
        (glb_raw(0, &[(32, b"JSON", json)]), "total length of 0 bytes"),
        (glb_raw(11, &[(32, b"JSON", json)]), "total length of 11 bytes"),
        (glb_raw(69, &[(32, b"JSON", json), (8, b"BIN\0", bin)]), "the file has 68: it is truncated"),
        (glb_raw(u32::MAX, &[(32, b"JSON", json)]), "truncated"),
        (glb_raw(52, &[(33, b"JSON", json)]), "chunk 0 (\"JSON\") at offset 12 declares 33 bytes but only 32"),
        (glb_raw(52, &[(u32::MAX, b"JSON", json)]), "declares 4294967295 bytes"),
        (glb_raw(68, &[(32, b"JSON", json), (u32::MAX - 3, b"BIN\0", bin)]), "chunk 1 (\"BIN\\x00\")"),
        (glb_raw(56, &[(32, b"JSON", json), (0, b"BIN\0", &[])]), "4 bytes at offset 52 are too few"),
        (glb_raw(28, &[(8, b"BIN\0", bin)]), "the first chunk is \"BIN\\x00\", not JSON"),
        (glb_raw(76, &[(32, b"JSON", json), (0, b"ABCD", &[]), (8, b"BIN\0", bin)]), "must directly follow JSON"),
        (glb_raw(76, &[(32, b"JSON", json), (0, b"JSON", &[]), (8, b"BIN\0", bin)]), "a second JSON chunk"),
    ];
    let mut v1 = good.clone();
    v1[4] = 1;
    let cases = cases.into_iter().chain([(v1, "GLB version 1")]);
    let dir = tempfile::tempdir().unwrap();
    for (i, (data, expected)) in cases.enumerate() {
        let e = glb_chunks(&data).unwrap_err().to_string();
        assert!(e.contains(expected), "case {i}: {e:?} does not say {expected:?}");
        // Through the reader: a glTF error naming the file.
        let p = dir.path().join(format!("case{i}.glb"));
        std::fs::write(&p, &data).unwrap();
        let e = read_mesh(&p).unwrap_err();
        assert!(matches!(e, MeshIoError::Gltf { source: GltfError::Container(_), .. }), "case {i}: {e}");
        err_names_file(&e, &format!("case{i}.glb"));
        // The cause chain keeps the container's own error under the file's.
        let cause = std::error::Error::source(&e).expect("a cause").to_string();
        assert!(cause.contains(expected), "case {i}: {cause:?}");
    }
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
    assert!(s.mesh.first_texture().is_some() && !s.fitted);
    // Absurd coordinates and flat meshes.
    let e = load_scan(&write(dir.path(), "far.obj", "v 0 0 0\nv 1e9 0 0\nv 0 1 0\nf 1 2 3\n")).unwrap_err();
    err_names_file(&e, "far.obj");
    // Flat on the floor when Y is up (with Z up the same triangle stands: detection picks that).
    let flat = write(dir.path(), "flat.obj", "v 0 0 0\nv 1 0 0\nv 0 0 1\nf 1 2 3\n");
    let e = load_scan_with(&flat, &ScanOrientation { up: Some(UpAxis::Y), facing: None }).unwrap_err();
    err_names_file(&e, "flat.obj");
    assert_eq!(load_scan(&flat).unwrap().up, UpAxis::Z);
    let e = load_scan(&write(dir.path(), "point.obj", "v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n")).unwrap_err();
    err_names_file(&e, "point.obj");
}

// ------------------------------------------------------------------------------------------------------------
// Scans as users bring them: several materials and texture formats, vertex colours, PLY, T-pose, Z up.
// ------------------------------------------------------------------------------------------------------------

use r2human::eval::ground_truth::render_ground_truth;
use r2human::geometry::camera::Camera;
use r2human::synth::scan::{load_scan_with, Facing, ScanOrientation, UpAxis, FIT_RADIUS};

/// A 2x2 texture of one sRGB colour, saved in the format its extension names.
fn solid(dir: &Path, name: &str, rgb: [u8; 3]) {
    image::RgbImage::from_pixel(2, 2, image::Rgb(rgb)).save(dir.join(name)).unwrap();
}

/// Linear colour of an sRGB byte triple.
fn lin(rgb: [u8; 3]) -> Vec3 {
    Vec3::from(rgb.map(|v| r2human::buffer::srgb_to_linear(v as f32 / 255.0)))
}

/// Albedo at the source-camera pixel over body-cube point (x, y).
fn albedo_at(m: &TexturedMesh, x: f32, y: f32) -> Vec3 {
    let size = 64;
    let gt = render_ground_truth(m, &Camera::source(size));
    let (col, row) = (((x + 1.0) * 32.0) as usize, ((1.0 - y) * 32.0) as usize);
    assert!(gt.mask[row * size + col], "nothing at ({x}, {y})");
    gt.albedo[row * size + col]
}

/// Four quads side by side facing +z, x in [-1, -0.5], [-0.5, 0], [0, 0.5], [0.5, 1], each with its own material:
/// BMP, TGA, WebP textures and a plain Kd.
const MULTI_OBJ: &str = "mtllib multi.mtl
v -0.9 -0.5 0\nv -0.6 -0.5 0\nv -0.6 0.5 0\nv -0.9 0.5 0
v -0.4 -0.5 0\nv -0.1 -0.5 0\nv -0.1 0.5 0\nv -0.4 0.5 0
v 0.1 -0.5 0\nv 0.4 -0.5 0\nv 0.4 0.5 0\nv 0.1 0.5 0
v 0.6 -0.5 0\nv 0.9 -0.5 0\nv 0.9 0.5 0\nv 0.6 0.5 0
vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1
usemtl bmp\nf 1/1 2/2 3/3 4/4
usemtl tga\nf 5/1 6/2 7/3 8/4
usemtl webp\nf 9/1 10/2 11/3 12/4
usemtl plain\nf 13/1 14/2 15/3 16/4
";

const RED: [u8; 3] = [230, 20, 10];
const GREEN: [u8; 3] = [15, 200, 40];
const YELLOW: [u8; 3] = [250, 220, 0];

fn multi_material_obj(dir: &Path) -> std::path::PathBuf {
    solid(dir, "skin.bmp", RED);
    solid(dir, "cloth.tga", GREEN);
    solid(dir, "hair.webp", YELLOW);
    // Windows paths and odd case, as scans from other machines carry them.
    write(
        dir,
        "multi.mtl",
        "newmtl bmp\nKd 0.8 0.8 0.8\nmap_Kd skin.bmp\nnewmtl tga\nmap_Kd C:\\Users\\artist\\cloth.tga\n\
         newmtl webp\nmap_kd HAIR.webp\nnewmtl plain\nKd 0.1 0.2 0.9\n",
    );
    write(dir, "multi.obj", MULTI_OBJ)
}

#[test]
fn multi_material_obj_with_bmp_tga_webp_textures() {
    let dir = tempfile::tempdir().unwrap();
    let m = read_mesh(&multi_material_obj(dir.path())).unwrap();
    assert_eq!(m.materials.len(), 4);
    assert_eq!(m.triangle_materials, vec![0, 0, 1, 1, 2, 2, 3, 3]);
    assert!(m.materials[..3].iter().all(|mat| mat.texture.is_some() && mat.base_color == Vec3::ONE));
    assert_eq!(m.materials[3].base_color, Vec3::new(0.1, 0.2, 0.9));
    // Each quad shows its own material in the ground truth.
    for (x, want) in [(-0.75, lin(RED)), (-0.25, lin(GREEN)), (0.25, lin(YELLOW)), (0.75, Vec3::new(0.1, 0.2, 0.9))] {
        let got = albedo_at(&m, x, 0.0);
        assert!((got - want).length() < 2e-3, "x {x}: {got} vs {want}");
    }
    // A missing texture among several is named.
    std::fs::remove_file(dir.path().join("cloth.tga")).unwrap();
    let e = read_mesh(&dir.path().join("multi.obj")).unwrap_err();
    err_names_file(&e, "cloth.tga");
}

#[test]
fn multi_material_glb_round_trip_keeps_every_material() {
    let dir = tempfile::tempdir().unwrap();
    let m = read_mesh(&multi_material_obj(dir.path())).unwrap();
    let p = dir.path().join("multi.glb");
    write_glb(&p, &m).unwrap();
    // One primitive per material, three embedded images, readable by the reference loader.
    let (doc, _, images) = gltf::import(&p).unwrap();
    assert_eq!(doc.meshes().next().unwrap().primitives().count(), 4);
    assert_eq!((doc.materials().count(), images.len()), (4, 3));
    let back = read_gltf(&p).unwrap();
    assert_eq!(back.materials.len(), 4);
    assert_eq!(back.triangle_materials, m.triangle_materials);
    let cam = Camera::orbit(20.0, 0.0, 64, 64);
    assert_eq!(render_ground_truth(&back, &cam), render_ground_truth(&m, &cam));
    // glTF base colour factors and COLOR_0 multiply the texture.
    let mut tinted = m.clone();
    tinted.materials[0].base_color = Vec3::new(0.5, 1.0, 1.0);
    tinted.mesh.colors = vec![Vec3::new(1.0, 0.5, 1.0); tinted.mesh.positions.len()];
    let q = dir.path().join("tinted.glb");
    write_glb(&q, &tinted).unwrap();
    let back = read_mesh(&q).unwrap();
    let got = albedo_at(&back, -0.75, 0.0);
    let want = lin(RED) * Vec3::new(0.5, 0.5, 1.0);
    assert!((got - want).length() < 2e-3, "{got} vs {want}");
}

#[test]
fn gltf_with_external_bmp_and_tga_textures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    solid(d, "a.bmp", RED);
    solid(d, "b.tga", GREEN);
    // Two triangles, one per material, in one .gltf with an external buffer.
    let pos: [[f32; 3]; 6] =
        [[-0.8, -0.5, 0.0], [-0.1, -0.5, 0.0], [-0.8, 0.5, 0.0], [0.1, -0.5, 0.0], [0.8, -0.5, 0.0], [0.8, 0.5, 0.0]];
    let uv: [[f32; 2]; 6] = [[0.0, 1.0], [1.0, 1.0], [0.0, 0.0], [0.0, 1.0], [1.0, 1.0], [1.0, 0.0]];
    let mut bin: Vec<u8> = pos.iter().flatten().flat_map(|v| v.to_le_bytes()).collect();
    bin.extend(uv.iter().flatten().flat_map(|v| v.to_le_bytes()));
    std::fs::write(d.join("buf.bin"), &bin).unwrap();
    let gltf = r#"{"asset": {"version": "2.0"}, "buffers": [{"uri": "buf.bin", "byteLength": 120}],
      "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 72}, {"buffer": 0, "byteOffset": 72, "byteLength": 48}],
      "accessors": [
        {"bufferView": 0, "byteOffset": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [-0.8,-0.5,0], "max": [-0.1,0.5,0]},
        {"bufferView": 0, "byteOffset": 36, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0.1,-0.5,0], "max": [0.8,0.5,0]},
        {"bufferView": 1, "byteOffset": 0, "componentType": 5126, "count": 3, "type": "VEC2"},
        {"bufferView": 1, "byteOffset": 24, "componentType": 5126, "count": 3, "type": "VEC2"}],
      "images": [{"uri": "a.bmp"}, {"uri": "b.tga"}], "textures": [{"source": 0}, {"source": 1}],
      "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
                    {"pbrMetallicRoughness": {"baseColorTexture": {"index": 1}}}],
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 2}, "material": 0},
                                 {"attributes": {"POSITION": 1, "TEXCOORD_0": 3}, "material": 1}]}],
      "nodes": [{"mesh": 0}], "scenes": [{"nodes": [0]}], "scene": 0}"#;
    let p = write(d, "two.gltf", gltf);
    let m = read_mesh(&p).unwrap();
    assert_eq!(m.materials.len(), 2);
    assert!((albedo_at(&m, -0.6, -0.3) - lin(RED)).length() < 2e-3);
    assert!((albedo_at(&m, 0.6, -0.3) - lin(GREEN)).length() < 2e-3);
}

/// A quad facing +z at x, y in [-0.5, 0.5] as a PLY: colours per vertex (uchar), in ASCII.
const PLY_ASCII: &str = "ply
format ascii 1.0
comment made by a test
element vertex 4
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element face 1
property list uchar int vertex_indices
end_header
-0.5 -0.5 0 230 20 10
0.5 -0.5 0 230 20 10
0.5 0.5 0 230 20 10
-0.5 0.5 0 230 20 10
4 0 1 2 3
";

#[test]
fn ply_ascii_and_binary_with_vertex_colours_and_textures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let m = read_mesh(&write(d, "quad.ply", PLY_ASCII)).unwrap();
    assert_eq!(m.mesh.triangles.len(), 2);
    assert!((albedo_at(&m, 0.0, 0.0) - lin(RED)).length() < 1e-4);
    // Binary little endian, double positions, float colours, an extra element, MeshLab's per-face texcoords and
    // a TextureFile comment.
    solid(d, "tex.tga", GREEN);
    let mut b = b"ply\nformat binary_little_endian 1.0\ncomment TextureFile tex.tga\nelement vertex 3\n\
property double x\nproperty double y\nproperty double z\nproperty float red\nproperty float green\nproperty float blue\n\
element face 1\nproperty list uchar uint vertex_indices\nproperty list uchar float texcoord\n\
element edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n"
        .to_vec();
    for p in [[-0.5f64, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]] {
        p.iter().for_each(|v| b.extend(v.to_le_bytes()));
        [1.0f32, 1.0, 1.0].iter().for_each(|v| b.extend(v.to_le_bytes()));
    }
    b.push(3);
    [0u32, 1, 2].iter().for_each(|v| b.extend(v.to_le_bytes()));
    b.push(6);
    [0.0f32, 0.0, 1.0, 0.0, 0.5, 1.0].iter().for_each(|v| b.extend(v.to_le_bytes()));
    [0i32, 1].iter().for_each(|v| b.extend(v.to_le_bytes()));
    let p = d.join("bin.ply");
    std::fs::write(&p, &b).unwrap();
    let m = read_mesh(&p).unwrap();
    assert_eq!((m.mesh.triangles.len(), m.materials.len()), (1, 1));
    assert!((albedo_at(&m, 0.0, -0.2) - lin(GREEN)).length() < 2e-3);
    // Truncated data, a point cloud and a bad index are errors naming the file.
    let q = d.join("trunc.ply");
    std::fs::write(&q, &b[..b.len() - 30]).unwrap();
    err_names_file(&read_mesh(&q).unwrap_err(), "trunc.ply");
    let cloud =
        PLY_ASCII.replace("element face 1\nproperty list uchar int vertex_indices\n", "").replace("4 0 1 2 3\n", "");
    let e = read_mesh(&write(d, "cloud.ply", &cloud)).unwrap_err();
    assert!(e.to_string().contains("point cloud"), "{e}");
    err_names_file(&e, "cloud.ply");
    let e = read_mesh(&write(d, "idx.ply", &PLY_ASCII.replace("4 0 1 2 3", "4 0 1 2 9"))).unwrap_err();
    assert!(matches!(e, MeshIoError::Ply { .. }), "{e}");
    err_names_file(&e, "idx.ply");
    let e = read_mesh(&write(d, "junk.ply", "ply\nformat ascii 1.0\nelement vertex -3\nend_header\n")).unwrap_err();
    err_names_file(&e, "junk.ply");
}

/// An OBJ of cuboids (each `(min, max)`).
fn boxes_obj(boxes: &[(Vec3, Vec3)]) -> String {
    let mut s = String::new();
    for (k, (lo, hi)) in boxes.iter().enumerate() {
        let m = TriMesh::cuboid(*lo, *hi);
        for p in &m.positions {
            s.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        }
        for t in &m.triangles {
            let o = 8 * k as u32 + 1;
            s.push_str(&format!("f {} {} {}\n", t[0] + o, t[1] + o, t[2] + o));
        }
    }
    s
}

#[test]
fn t_pose_scan_is_fitted_and_a_floor_still_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Torso 0.4 wide, 1.7 tall; arms out to 2.4 across at shoulder height: too wide for the cube at height 1.8.
    let t_pose = boxes_obj(&[
        (Vec3::new(-0.2, 0.0, -0.12), Vec3::new(0.2, 1.7, 0.12)),
        (Vec3::new(-1.2, 1.35, -0.05), Vec3::new(1.2, 1.45, 0.05)),
    ]);
    let s = load_scan_with(&write(dir.path(), "tpose.obj", &t_pose), &ScanOrientation::default()).unwrap();
    assert!(s.fitted);
    assert_eq!((s.up, s.facing), (UpAxis::Y, Facing::PlusZ));
    let (lo, hi) = s.mesh.mesh.bounds().unwrap();
    // The minimal enclosing circle of the arm tips (x = +-1.2, z = +-0.05) becomes the fit radius.
    let r = (1.2f32 * 1.2 + 0.05 * 0.05).sqrt();
    let widest = s.mesh.mesh.positions.iter().map(|p| p.x.hypot(p.z)).fold(0.0f32, f32::max);
    assert!((widest - FIT_RADIUS).abs() < 1e-4 && (hi.x + lo.x).abs() < 1e-4, "{lo} {hi}");
    // Height scaled by the same factor: 1.7 * 0.98 / r.
    assert!(((hi.y - lo.y) - 1.7 * FIT_RADIUS / r).abs() < 1e-4, "{lo} {hi}");
    // A floor far wider than the person is still refused, naming the file. (The person, an ellipsoid 17 tall,
    // has far more vertices than the floor, as in real scans: detection keeps Y up.)
    let mut floor = boxes_obj(&[(Vec3::new(-50.0, -0.1, -50.0), Vec3::new(50.0, 0.0, 50.0))]);
    let body = TriMesh::uv_sphere(Vec3::ZERO, 1.0, 16, 16);
    for p in &body.positions {
        floor.push_str(&format!("v {} {} {}\n", 0.2 * p.x, 8.5 * (p.y + 1.0), 0.12 * p.z));
    }
    for t in &body.triangles {
        floor.push_str(&format!("f {} {} {}\n", t[0] + 9, t[1] + 9, t[2] + 9));
    }
    let e = load_scan_with(&write(dir.path(), "floor.obj", &floor), &ScanOrientation::default()).unwrap_err();
    assert!(matches!(e, SynthError::Scan { .. }), "{e}");
    err_names_file(&e, "floor.obj");
}

#[test]
fn z_up_scan_is_detected_or_told_and_turned_to_face_the_camera() {
    let dir = tempfile::tempdir().unwrap();
    // Blender convention: +Z up, the person faces -Y. Body 0.4 wide (x), 0.25 deep (y), 1.7 tall (z); toes and
    // a nose toward -Y.
    let z_up = boxes_obj(&[
        (Vec3::new(-0.2, -0.12, 0.0), Vec3::new(0.2, 0.12, 1.7)),
        (Vec3::new(-0.15, -0.3, 0.0), Vec3::new(0.15, 0.0, 0.04)),
        (Vec3::new(-0.03, -0.2, 1.5), Vec3::new(0.03, -0.1, 1.55)),
    ]);
    let p = write(dir.path(), "zup.obj", &z_up);
    let s = load_scan_with(&p, &ScanOrientation::default()).unwrap();
    assert_eq!((s.up, s.facing), (UpAxis::Z, Facing::PlusZ), "Blender's -Y front becomes +z");
    let (lo, hi) = s.mesh.mesh.bounds().unwrap();
    assert!((hi.y - lo.y - 1.8).abs() < 1e-3 && !s.fitted, "{lo} {hi}");
    // The nose (the only vertices at 88-91 % of the height) is in front of the body, on the camera side.
    let z_of = |band: std::ops::Range<f32>| {
        let z: Vec<f32> = s.mesh.mesh.positions.iter().filter(|q| band.contains(&q.y)).map(|q| q.z).collect();
        z.iter().sum::<f32>() / z.len() as f32
    };
    let (nose, body) = (z_of(0.6..0.75), z_of(0.85..1.0));
    assert!(nose > body + 0.1, "nose z {nose}, body {body}");
    // Flags override detection: facing -z turns the person around.
    let turned = load_scan_with(&p, &ScanOrientation { up: Some(UpAxis::Z), facing: Some(Facing::MinusZ) }).unwrap();
    let (lo2, _) = turned.mesh.mesh.bounds().unwrap();
    assert!((lo2.z + hi.z).abs() < 1e-3, "turned around: {lo2} vs {hi}");
    // Read as Y-up, the same file lies on its back: 1.7 deep, 0.24 tall, far too wide at height 1.8.
    let e = load_scan_with(&p, &ScanOrientation { up: Some(UpAxis::Y), facing: Some(Facing::PlusZ) }).unwrap_err();
    assert!(e.to_string().contains("--up"), "{e}");
}

/// A multi-material Z-up person written as `dir/<name>.obj` (+ `p.mtl`, `body.tga`): body and head in two
/// materials (a texture and a colour), arms out at `arm_height`.
fn cuboid_person(dir: &Path, name: &str, arm_height: f32) -> std::path::PathBuf {
    solid(dir, "body.tga", GREEN);
    write(dir, "p.mtl", "newmtl body\nmap_Kd body.tga\nnewmtl head\nKd 0.9 0.6 0.5\n");
    let mut obj = String::from("mtllib p.mtl\nvt 0.5 0.5\nusemtl body\n");
    let mut k = 0;
    for (part, (lo, hi)) in [
        ("body", (Vec3::new(-0.2, -0.12, 0.0), Vec3::new(0.2, 0.12, 1.45))),
        ("body", (Vec3::new(-0.9, -0.05, arm_height), Vec3::new(0.9, 0.05, arm_height + 0.1))),
        ("head", (Vec3::new(-0.1, -0.1, 1.45), Vec3::new(0.1, 0.1, 1.7))),
    ] {
        let m = TriMesh::cuboid(lo, hi);
        obj.push_str(&format!("usemtl {part}\n"));
        for p in &m.positions {
            obj.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        }
        for t in &m.triangles {
            obj.push_str(&format!("f {}/1 {}/1 {}/1\n", t[0] + k + 1, t[1] + k + 1, t[2] + k + 1));
        }
        k += 8;
    }
    write(dir, &format!("{name}.obj"), &obj)
}

#[test]
fn eval_scan_alone_reports_the_scan_rows() {
    use r2human::eval::runner::{run_eval_with, EvalOptions, NeuralEvalOptions};
    let dir = tempfile::tempdir().unwrap();
    let scan = cuboid_person(dir.path(), "person", 1.3);
    let opts = EvalOptions {
        subjects: 0,
        out: dir.path().join("eval"),
        scans: vec![scan],
        size: 64,
        yaws: vec![30.0, 90.0, 180.0],
        ..EvalOptions::default()
    };
    let rep = run_eval_with(&opts, &NeuralEvalOptions { skip: true, ..Default::default() }).unwrap();
    assert!(rep.failed.is_empty(), "{:?}", rep.failed);
    assert!(!rep.rows.is_empty() && rep.rows.iter().all(|r| r.inputs == "person"), "{:?}", rep.rows);
    let get = |m: &str| rep.rows.iter().find(|r| r.method == m && r.group == "divergent").unwrap();
    assert!(get("geometric+gt-fof").scores.mask_iou > get("billboard").scores.mask_iou + 0.2);
    let md = std::fs::read_to_string(opts.out.join("report.md")).unwrap();
    assert!(md.contains("## Scan: person") && !md.contains("## Synthetic"), "{md}");
    // One scan: no summary over scans.
    assert!(!md.contains("Scans together") && !opts.out.join("scans.csv").exists());
}

#[test]
fn eval_of_several_scans_summarises_them_with_a_held_out_split() {
    use r2human::eval::runner::{run_eval_with, EvalOptions, NeuralEvalOptions};
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (cuboid_person(dir.path(), "bob", 1.3), cuboid_person(dir.path(), "ann", 1.0));
    let opts = EvalOptions {
        subjects: 0,
        out: dir.path().join("eval"),
        scans: vec![a, b],
        size: 48,
        yaws: vec![30.0, 180.0],
        ..EvalOptions::default()
    };
    let rep = run_eval_with(&opts, &NeuralEvalOptions { skip: true, ..Default::default() }).unwrap();
    assert!(rep.failed.is_empty(), "{:?}", rep.failed);
    // Each scan has its own inflation volumetric IoU; the overall mean is theirs.
    let iou = |s: &str| rep.set_geometry_iou.iter().find(|x| x.0 == s && x.1 == "inflation").unwrap().2;
    let overall = rep.geometry_iou.iter().find(|x| x.0 == "inflation").unwrap().1;
    assert!((overall - (iou("ann") + iou("bob")) / 2.0).abs() < 1e-5, "{overall} {:?}", rep.set_geometry_iou);
    let md = std::fs::read_to_string(opts.out.join("report.md")).unwrap();
    assert!(md.contains("## Scans together (2 characters)") && md.contains("Dev (1): ann. Held out (1): bob."), "{md}");
    let csv = std::fs::read_to_string(opts.out.join("scans.csv")).unwrap();
    let line = csv.lines().find(|l| l.starts_with("\"bob\",held-out,geometric+inflation,")).unwrap();
    assert!(line.contains(&format!("{:.4}", iou("bob"))), "{line}");
    let summary = std::fs::read_to_string(opts.out.join("scans_summary.csv")).unwrap();
    let all = summary.lines().find(|l| l.starts_with("all,geometric+inflation,2,")).unwrap();
    assert!(all.contains(&format!("{:.4}", overall)), "{all}");
}
