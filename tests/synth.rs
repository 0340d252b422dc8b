//! Synthetic subjects: body extraction, morphs, skinning, determinism, normalisation and GLB output.
//! Needs the registry data from `scripts/setup.d/synth.sh`.

use std::collections::HashMap;

use glam::{Quat, Vec2, Vec3};
use r2human::io::mesh_io::{read_gltf, write_glb};
use r2human::synth::base::{BaseMesh, BODY_VERTEX_COUNT};
use r2human::synth::normalize::min_enclosing_circle;
use r2human::synth::rig::Rig;
use r2human::synth::*;

fn assets() -> &'static SynthAssets {
    SynthAssets::shared().expect("synth data missing: run `bash scripts/setup.d/synth.sh`")
}

fn height(p: &[Vec3]) -> f32 {
    let (lo, hi) = p.iter().fold((f32::MAX, f32::MIN), |(a, b), q| (a.min(q.y), b.max(q.y)));
    hi - lo
}

#[test]
fn body_is_watertight_consistent_and_split_only_at_seams() {
    let base = BaseMesh::load().unwrap();
    // Triangles mapped back to base-mesh vertices: every undirected edge shared by exactly two triangles, every
    // directed edge used once (consistent winding), Euler characteristic 2.
    let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
    for t in &base.triangles {
        let v = t.map(|i| base.source_vertex[i as usize]);
        for k in 0..3 {
            *directed.entry((v[k], v[(k + 1) % 3])).or_default() += 1;
        }
    }
    assert!(directed.values().all(|&c| c == 1), "a directed edge repeats");
    let boundary = directed.keys().filter(|&&(a, b)| !directed.contains_key(&(b, a))).count();
    assert_eq!(boundary, 0, "boundary edges");
    let edges = directed.len() / 2;
    let chi = BODY_VERTEX_COUNT as i64 - edges as i64 + base.triangles.len() as i64;
    assert_eq!(chi, 2);
    // Seams: every base vertex appears, some more than once, and duplicates differ in UV.
    let mut seen = vec![0u32; BODY_VERTEX_COUNT];
    base.source_vertex.iter().for_each(|&v| seen[v as usize] += 1);
    assert!(seen.iter().all(|&c| c >= 1));
    let split = seen.iter().filter(|&&c| c > 1).count();
    assert!((1000..1300).contains(&split), "{split} seam vertices (the notes count 1,122)");
    assert!(base.uvs.iter().all(|uv| (0.0..=1.0).contains(&uv.x) && (0.0..=1.0).contains(&uv.y)));
    // Outward: positive signed volume in decimetres (the notes measure 54.9).
    let mesh = r2human::geometry::mesh::TriMesh::new(base.body_positions(&base.full_positions), base.triangles.clone());
    let vol = mesh.signed_volume();
    assert!((vol - 54.9).abs() < 0.5, "{vol}");
}

#[test]
fn zero_weight_morphs_are_identity_and_scale_is_decimetres() {
    let a = assets();
    let rest = a.base.full_positions.clone();
    let mut p = rest.clone();
    for name in a.morphs.targets.keys().take(40) {
        a.morphs.apply(name, 0.0, &mut p).unwrap();
    }
    assert_eq!(p, rest);
    // +w then -w returns to the rest shape (linear blend).
    a.morphs.apply("caucasian-female-old", 0.7, &mut p).unwrap();
    assert_ne!(p, rest);
    a.morphs.apply("caucasian-female-old", -0.7, &mut p).unwrap();
    assert!(p.iter().zip(&rest).all(|(x, y)| x.distance(*y) < 1e-4));
    // Fixed-point scale: a 1-year-old is 0.55-0.95 m tall, a young adult 1.5-1.9 m (decimetre units).
    let body = |m: &MacroParams| {
        let mut f = rest.clone();
        a.morphs.apply_macros(m, &mut f).unwrap();
        height(&f[..BODY_VERTEX_COUNT])
    };
    let baby = body(&MacroParams { age: 0.0, ..Default::default() });
    let adult = body(&MacroParams::default());
    assert!((5.5..9.5).contains(&baby), "baby {baby} dm");
    assert!((15.0..19.0).contains(&adult), "adult {adult} dm");
    let tall = body(&MacroParams { height: 1.0, ..Default::default() });
    let short = body(&MacroParams { height: 0.0, ..Default::default() });
    assert!(tall > adult + 1.0 && short < adult - 1.0, "{short} {adult} {tall}");
    let male = body(&MacroParams { gender: 1.0, ..Default::default() });
    let female = body(&MacroParams { gender: 0.0, ..Default::default() });
    assert!(male > female, "{male} {female}");
}

#[test]
fn rig_joints_sit_where_the_rig_says() {
    let a = assets();
    let heads = a.rig.heads(&a.base.full_positions);
    // The rig's default positions were fitted on a default-shaped body, so agreement is to a few centimetres; a
    // wrong axis convention would be off by decimetres.
    for name in ["upperarm01.L", "lowerarm01.R", "upperleg01.L", "lowerleg01.R", "head", "spine03", "foot.L"] {
        let b = a.rig.bone(name).unwrap();
        let d = heads[b].distance(a.rig.bones[b].default_head);
        assert!(d < 0.6, "{name}: {:?} vs {:?}", heads[b], a.rig.bones[b].default_head);
    }
    assert!(a.rig.bones.iter().enumerate().all(|(i, b)| b.parent.is_none_or(|p| p < i)));
}

#[test]
fn lbs_identity_and_rigid_root_rotation() {
    let a = assets();
    let full = &a.base.full_positions;
    let heads = a.rig.heads(full);
    let tails = a.rig.tails(full);
    let rot = PoseParams::rest().rotations(&a.rig, &heads, &tails);
    assert!(rot.is_empty());
    let body = &full[..BODY_VERTEX_COUNT];
    let t = a.rig.skinning_transforms(&heads, &rot);
    // Identity transforms: each vertex is its weighted sum with weights summing to one (float rounding only).
    let same = a.rig.skin(body, &t);
    let worst = same.iter().zip(body).map(|(x, y)| x.distance(*y)).fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "identity pose moved a vertex by {worst}");
    // Rotating the root rotates every vertex rigidly about the root head (weights sum to one).
    let root = a.rig.bones.iter().position(|b| b.parent.is_none()).unwrap();
    let q = Quat::from_rotation_y(0.7) * Quat::from_rotation_x(-0.3);
    let t = a.rig.skinning_transforms(&heads, &HashMap::from([(root, q)]));
    let moved = a.rig.skin(body, &t);
    let h = heads[root];
    for (m, p) in moved.iter().zip(body).step_by(97) {
        assert!(m.distance(h + q * (*p - h)) < 1e-4);
    }
    // A bent elbow moves the hand but not the other arm or the feet.
    let mut pose = PoseParams::rest();
    pose.arms[0].elbow = 90.0;
    let rot = pose.rotations(&a.rig, &heads, &tails);
    let posed = a.rig.skin(body, &a.rig.skinning_transforms(&heads, &rot));
    let hand = a.base.group_centroid("joint-l-hand", full).unwrap();
    let near = |p: Vec3, c: Vec3| p.distance(c) < 0.5;
    let (mut hand_moved, mut other_moved) = (0.0f32, 0.0f32);
    for (q, p) in posed.iter().zip(body) {
        if near(*p, hand) {
            hand_moved = hand_moved.max(q.distance(*p));
        }
        if p.x < -1.0 || p.y < -5.0 {
            other_moved = other_moved.max(q.distance(*p));
        }
    }
    assert!(hand_moved > 1.0, "hand moved {hand_moved} dm");
    assert!(other_moved < 1e-5, "{other_moved}");
}

fn small(seed: u64) -> Subject {
    generate(assets(), &SubjectParams::sample(seed), 128).unwrap()
}

#[test]
fn subjects_are_reproducible_normalised_and_in_the_cube() {
    let a = small(7);
    let b = small(7);
    assert_eq!(a.params, b.params);
    assert_eq!(a.mesh, b.mesh);
    let c = small(8);
    assert_ne!(a.params, c.params);
    assert_ne!(a.mesh.mesh.positions, c.mesh.mesh.positions);
    assert_ne!(a.mesh.first_texture(), c.mesh.first_texture());
    for seed in 0..12u64 {
        let s = small(seed);
        let p = &s.mesh.mesh.positions;
        let (lo, hi) = s.mesh.mesh.bounds().unwrap();
        assert!((lo.y + 0.9).abs() < 1e-4 && (hi.y - 0.9).abs() < 1e-4, "seed {seed}: {lo} {hi}");
        let xz: Vec<Vec2> = p.iter().map(|q| Vec2::new(q.x, q.z)).collect();
        let (c, r) = min_enclosing_circle(&xz);
        // x: the enclosing circle's centre (the reference's normalisation); z: the occupied volume's centroid (the
        // body cube's depth convention), inside the cube.
        assert!(c.x.abs() < 1e-3, "seed {seed}: circle centre {c}");
        let (centroid, z_lo, z_hi) = r2human::geometry::depth_centre::mesh_depth_extent(&s.mesh.mesh).unwrap();
        assert!(centroid.abs() < 1e-3, "seed {seed}: volume centroid at z = {centroid}");
        assert!(z_lo >= -1.0 && z_hi <= 1.0, "seed {seed}: z from {z_lo} to {z_hi}");
        assert!(r <= 1.0 && lo.x >= -1.0 && hi.x <= 1.0, "seed {seed}: radius {r}");
        assert!(s.mesh.mesh.validate().is_ok() && s.mesh.mesh.normals.iter().all(|n| n.is_finite()));
        // Subjects face the source camera (+z): the nose region is in front.
        assert!(hi.z > 0.0 && lo.z < 0.0);
    }
}

#[test]
fn some_poses_fold_an_arm_across_the_body() {
    let n = (0..40u64).filter(|&s| SubjectParams::sample(s).pose.arm_across).count();
    assert!((5..30).contains(&n), "{n} of 40");
}

#[test]
fn glb_round_trip_keeps_geometry_uvs_and_texture() {
    let s = small(3);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("subject.glb");
    write_glb(&path, &s.mesh).unwrap();
    let back = read_gltf(&path).unwrap();
    assert_eq!(back.mesh.triangles, s.mesh.mesh.triangles);
    assert_eq!(back.mesh.positions, s.mesh.mesh.positions);
    assert_eq!(back.mesh.uvs, s.mesh.mesh.uvs);
    assert_eq!(back.first_texture(), s.mesh.first_texture());
    assert_eq!(back.materials.len(), 1);
    // The document itself is valid glTF for the reference loader.
    let (doc, _, images) = gltf::import(&path).unwrap();
    assert_eq!(images.len(), 1);
    let prim = doc.meshes().next().unwrap().primitives().next().unwrap();
    assert!(prim.get(&gltf::Semantic::TexCoords(0)).is_some() && prim.get(&gltf::Semantic::Normals).is_some());
    assert!(doc.extensions_used().any(|e| e == "KHR_materials_unlit"));
}

#[test]
fn missing_registry_data_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let err = SynthAssets::load(dir.path()).unwrap_err().to_string();
    assert!(err.contains("targets.npz") && err.contains("setup.d/synth.sh"), "{err}");
}

#[test]
fn rig_rejects_unknown_bones_and_bad_indices() {
    let base = BaseMesh::load().unwrap();
    let p = std::path::Path::new("rig.json");
    let rig = r#"{"root": {"head": {"strategy": "VERTEX", "vertex_index": 99999, "default_position": [0,0,0]},
                 "tail": {"strategy": "VERTEX", "vertex_index": 1, "default_position": [0,0,0]}, "parent": ""}}"#;
    assert!(Rig::from_json(rig, r#"{"weights": {}}"#, &base, p, p).is_err());
    let rig = rig.replace("99999", "0");
    assert!(Rig::from_json(&rig, r#"{"weights": {"nope": [[0, 1.0]]}}"#, &base, p, p).is_err());
}

mod dataset {
    use super::*;
    use r2human::eval::dataset::{write_dataset, DatasetOptions};
    use r2human::eval::EvalError;
    use r2human::geometry::camera::Camera;
    use r2human::io::npy::{NpyArray, NpyData};
    use std::path::Path;

    fn opts(out: &Path, subjects: usize) -> DatasetOptions {
        DatasetOptions {
            subjects,
            seed: 11,
            out: out.to_path_buf(),
            views: 2,
            size: 64,
            fof_n: 8,
            texture_size: 128,
            progress: false,
            framing: Default::default(),
            body_fof: false,
        }
    }

    fn f32s(p: &Path) -> (Vec<usize>, Vec<f32>) {
        let a = NpyArray::read(p).unwrap();
        match a.data {
            NpyData::F32(v) => (a.shape, v),
            other => panic!("{p:?}: not f32: {other:?}"),
        }
    }

    fn no_partial_files(dir: &Path) {
        for e in std::fs::read_dir(dir).unwrap() {
            let name = e.unwrap().file_name().to_string_lossy().into_owned();
            assert!(!name.starts_with('.'), "leftover {name}");
        }
    }

    #[test]
    fn dataset_layout_conventions_and_cross_view_consistency() {
        let dir = tempfile::tempdir().unwrap();
        let summary = write_dataset(&opts(dir.path(), 2)).unwrap();
        assert_eq!(summary.written, vec!["subject_0000", "subject_0001"]);
        no_partial_files(dir.path());
        let manifest: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("dataset.json")).unwrap()).unwrap();
        assert_eq!(manifest["format"], "r2human-dataset");
        assert_eq!(manifest["resolution"], 64);
        assert_eq!(manifest["fof_n"], 8);
        assert_eq!(manifest["views_per_subject"], 2);
        let s = dir.path().join("subject_0001");
        let (shape, depth) = f32s(&s.join("source_depth.npy"));
        assert_eq!(shape, vec![64, 64]);
        let (shape, normal) = f32s(&s.join("source_normal.npy"));
        assert_eq!(shape, vec![64, 64, 3]);
        let (shape, fof) = f32s(&s.join("fof.npy"));
        assert_eq!(shape, vec![64, 64, 8]);
        let rgba = image::open(s.join("source_rgba.png")).unwrap().to_rgba8();
        let mut covered = 0;
        let mut fof_agree = 0;
        for i in 0..64 * 64 {
            let a = rgba.as_raw()[4 * i + 3];
            let bg = depth[i] == -1.0;
            assert_eq!(a == 0, bg, "alpha and depth disagree at {i}");
            let n = Vec3::from_slice(&normal[3 * i..3 * i + 3]);
            if bg {
                assert_eq!(n, Vec3::ZERO);
            } else {
                covered += 1;
                assert!((n.length() - 1.0).abs() < 1e-4 && (-1.0..=1.0).contains(&depth[i]));
            }
            // c_0 is the occupied length along the ray: positive exactly where the source view sees the body.
            fof_agree += ((fof[8 * i] > 1e-4) != bg) as usize;
        }
        assert!(covered > 200, "{covered} covered pixels");
        assert!(fof_agree >= 64 * 64 - 8, "FOF and mask disagree on {} pixels", 64 * 64 - fof_agree);
        // A surface point seen in a target view and in the source view has the same colour in both.
        let cam_json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(s.join("views/view_01/camera.json")).unwrap()).unwrap();
        let cam = Camera::orbit(
            cam_json["yaw_deg"].as_f64().unwrap() as f32,
            cam_json["pitch_deg"].as_f64().unwrap() as f32,
            64,
            64,
        );
        let m = glam::Mat4::from(cam.view_from_world);
        for r in 0..4 {
            let row: Vec<f32> =
                cam_json["view_from_world"][r].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
            assert!((glam::Vec4::from_slice(&row) - m.row(r)).abs().max_element() < 1e-6);
        }
        let (_, vdepth) = f32s(&s.join("views/view_01/depth.npy"));
        let vrgba = image::open(s.join("views/view_01/rgba.png")).unwrap().to_rgba8();
        let src = Camera::source(64);
        let mut diffs = Vec::new();
        for row in 0..64 {
            for col in 0..64 {
                let i = row * 64 + col;
                if vdepth[i] == -1.0 {
                    continue;
                }
                let w = cam.unproject(col as f32 + 0.5, row as f32 + 0.5, vdepth[i]);
                let p = src.project(w).unwrap();
                let (c, r) = (p.x.floor() as usize, p.y.floor() as usize);
                if c >= 64 || r >= 64 {
                    continue;
                }
                let j = r * 64 + c;
                if depth[j] == -1.0 || (depth[j] - p.z).abs() > 0.01 {
                    continue; // occluded in the source
                }
                let a = vrgba.get_pixel(col as u32, row as u32);
                let b = rgba.get_pixel(c as u32, r as u32);
                diffs.push((0..3).map(|k| (a[k] as i32 - b[k] as i32).abs()).max().unwrap());
            }
        }
        diffs.sort();
        assert!(diffs.len() > 20, "{} shared points", diffs.len());
        let median = diffs[diffs.len() / 2];
        assert!(median <= 12, "median colour difference {median} of 255 across views");
    }

    #[test]
    fn dataset_is_reproducible_and_failures_leave_nothing() {
        let a = tempfile::tempdir().unwrap();
        let b = tempfile::tempdir().unwrap();
        write_dataset(&DatasetOptions { views: 1, ..opts(a.path(), 1) }).unwrap();
        // In b, subject_0000's destination is a file that cannot be replaced by a folder: that subject fails,
        // the other is written, and no temporary folder is left behind.
        std::fs::write(b.path().join("subject_0000"), b"in the way").unwrap();
        std::fs::create_dir(b.path().join("subject_0000.keep")).unwrap();
        let summary = write_dataset(&DatasetOptions { views: 1, ..opts(b.path(), 2) }).unwrap();
        assert_eq!(summary.written, vec!["subject_0001"]);
        assert_eq!(summary.failed.len(), 1);
        assert!(summary.failed[0].1.contains("subject_0000"), "{:?}", summary.failed);
        no_partial_files(b.path());
        for f in ["source_rgba.png", "fof.npy", "mesh.glb", "subject.json", "views/view_00/rgba.png"] {
            assert!(a.path().join("subject_0000").join(f).is_file(), "{f}");
        }
        // Same seed, same bytes.
        let c = tempfile::tempdir().unwrap();
        write_dataset(&DatasetOptions { views: 1, ..opts(c.path(), 1) }).unwrap();
        for f in ["source_rgba.png", "fof.npy", "views/view_00/depth.npy", "mesh.glb"] {
            let x = std::fs::read(a.path().join("subject_0000").join(f)).unwrap();
            let y = std::fs::read(c.path().join("subject_0000").join(f)).unwrap();
            assert!(x == y, "{f} differs between runs");
        }
        assert!(matches!(write_dataset(&opts(a.path(), 0)), Err(EvalError::InvalidOptions(_))));
        assert!(matches!(
            write_dataset(&DatasetOptions { size: 4, ..opts(a.path(), 1) }),
            Err(EvalError::InvalidOptions(_))
        ));
    }
}

mod eval_run {
    use r2human::eval::runner::{run_eval, EvalOptions};

    #[test]
    fn eval_writes_reports_and_ranks_methods_sensibly() {
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("broken.obj");
        std::fs::write(&bad, "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        let opts = EvalOptions {
            subjects: 1,
            seed: 5,
            out: dir.path().join("eval"),
            scans: vec![bad.clone()],
            size: 64,
            yaws: vec![0.0, 30.0, 90.0, 180.0],
            texture_size: 128,
            save_views: true,
            ..EvalOptions::default()
        };
        let rep = run_eval(&opts).unwrap();
        // The broken scan is reported by name, the synthetic subject still evaluated.
        assert_eq!(rep.failed.len(), 1);
        assert!(rep.failed[0].1.contains("broken.obj"), "{:?}", rep.failed);
        let get = |m: &str, g: &str| rep.rows.iter().find(|r| r.method == m && r.group == g).unwrap().clone();
        for r in &rep.rows {
            assert!(
                r.scores.ssim.is_finite() && r.scores.mask_iou.is_finite() && r.scores.depth_l1.is_finite(),
                "{r:?}"
            );
            assert!((0.0..=1.0).contains(&r.scores.mask_iou) && r.ms_per_view >= 0.0);
        }
        // Seen from the side, a flat billboard covers far less of the person than oracle geometry.
        let bb = get("billboard", "divergent");
        let oracle = get("geometric+gt-fof", "divergent");
        assert!(oracle.scores.mask_iou > bb.scores.mask_iou + 0.2, "{oracle:?} vs {bb:?}");
        assert!(oracle.scores.depth_l1 < bb.scores.depth_l1, "{oracle:?} vs {bb:?}");
        // Close to the input every method sees roughly the person's silhouette.
        assert!(get("billboard", "close").scores.mask_iou > 0.5);
        let csv = std::fs::read_to_string(opts.out.join("report.csv")).unwrap();
        assert!(csv.starts_with("method,group,psnr,ssim,"));
        assert!(csv.contains("ms_per_view,ms_per_input"));
        assert!(csv.lines().next().unwrap().ends_with(",peak_mib,psnr_frame,ssim_frame,inputs,framing"));
        // The paper's whole-frame metrics: the background both agree on counts, so they exceed the union's.
        for r in &rep.rows {
            assert_eq!((r.inputs.as_str(), r.framing.as_str()), ("synthetic/full", "full"));
            assert!(
                r.scores.psnr_frame > r.scores.psnr
                    && r.scores.ssim_frame > r.scores.ssim
                    && r.scores.ssim_frame <= 1.0,
                "{r:?}"
            );
        }
        // Memory per method (exact values belong to tests/eval_memory.rs: tests here run in parallel threads).
        for r in &rep.rows {
            assert!(r.peak_mib.is_none_or(|m| m.is_finite() && m >= 0.0), "{r:?}");
        }
        assert_eq!(csv.lines().count(), 1 + rep.rows.len());
        assert!(std::fs::read_to_string(opts.out.join("report.md")).unwrap().contains("| billboard | close |"));
        let png = image::open(opts.out.join("error_vs_time.png")).unwrap();
        assert_eq!((png.width(), png.height()), (800, 500));
        // Saved views: seen from the input camera, the billboard is the input itself (no half-pixel shift).
        let views = opts.out.join("views").join("subject_0000");
        let gt = image::open(views.join("yaw000_ground_truth.png")).unwrap().to_rgb8();
        let bb = image::open(views.join("yaw000_billboard.png")).unwrap().to_rgb8();
        let differing = gt.pixels().zip(bb.pixels()).filter(|(a, b)| a != b).count();
        assert!(differing * 200 < gt.len() / 3, "{differing} of {} pixels differ", gt.len() / 3);
        assert!(views.join("yaw180_geometric_gt-fof.png").exists());
    }
}

mod clothes {
    use super::*;
    use r2human::geometry::camera::Camera;
    use r2human::geometry::fof::Fof;
    use r2human::synth::framing::{crop, Framing};
    use r2human::synth::garment::{self, BagKind, HairKind, LowerKind, UpperKind};

    /// Signed distance of `q` from the body surface near it (positive outside): along the normal of the nearest
    /// body vertex.
    fn outside(s: &Subject, q: Vec3) -> f32 {
        let body_n = s.garments.first().map_or(s.mesh.mesh.positions.len(), |g| g.vertices.start);
        let (p, n) = (&s.mesh.mesh.positions, &s.mesh.mesh.normals);
        let b = (0..body_n).min_by(|&a, &b| p[a].distance_squared(q).total_cmp(&p[b].distance_squared(q))).unwrap();
        (q - p[b]).dot(n[b])
    }

    fn dressed(seed: u64, upper: UpperKind, lower: LowerKind) -> SubjectParams {
        let mut p = SubjectParams::sample(seed);
        p.outfit.upper = upper;
        p.outfit.lower = lower;
        p
    }

    #[test]
    fn a_posed_arm_moves_its_sleeve_and_nothing_else() {
        let a = assets();
        let params = dressed(4, UpperKind::LongSleeve, LowerKind::Skirt);
        let sleeves = |pose: &PoseParams| {
            let posed = pose_body(a, &params.shape, pose).unwrap();
            let body = garment::BodyRest {
                positions: &posed.rest[..BODY_VERTEX_COUNT],
                parts: &a.parts,
                rig: &a.rig,
                heads: &posed.heads,
            };
            let g = garment::build(&body, &params.outfit, [0.1; 3], [0.2; 3], [0.9; 3]);
            let p = garment::pose_garments(&g, &posed.transforms, &posed.body, &a.parts);
            let wrist = a.rig.bone("wrist.L").unwrap();
            let posed_wrist = posed.transforms[wrist].transform_point3(posed.heads[wrist]);
            let get = |label: &str| p[g.iter().position(|x| x.label == label).unwrap()].clone();
            (get("sleeve.L"), get("sleeve.R"), posed_wrist)
        };
        let rest = PoseParams::rest();
        let mut bent = PoseParams::rest();
        bent.arms[0].elbow = 90.0;
        let (l0, r0, w0) = sleeves(&rest);
        let (l1, r1, w1) = sleeves(&bent);
        // The cuff (last rows) follows the wrist: it moves by decimetres and keeps its distance to the wrist.
        let cuff0 = l0[l0.len() - 25..].iter().sum::<Vec3>() / 25.0;
        let cuff1 = l1[l1.len() - 25..].iter().sum::<Vec3>() / 25.0;
        assert!(cuff0.distance(cuff1) > 1.0, "cuff moved {} dm", cuff0.distance(cuff1));
        assert!(
            (cuff0.distance(w0) - cuff1.distance(w1)).abs() < 0.1,
            "{} vs {}",
            cuff0.distance(w0),
            cuff1.distance(w1)
        );
        // The other sleeve does not move.
        let still = r0.iter().zip(&r1).map(|(x, y)| x.distance(*y)).fold(0.0f32, f32::max);
        assert!(still < 1e-4, "right sleeve moved {still} dm");
    }

    #[test]
    fn garments_stand_off_the_body_and_some_are_open() {
        let (mut open, mut closed) = (0, 0);
        for seed in 0..6u64 {
            let s = small(seed);
            for g in &s.garments {
                if g.closed {
                    closed += 1;
                } else {
                    open += 1;
                }
                if !["top", "dress", "skirt", "hips", "leg.L", "leg.R"].contains(&g.label.as_str()) {
                    continue;
                }
                let d: Vec<f32> =
                    g.vertices.clone().step_by(7).map(|v| outside(&s, s.mesh.mesh.positions[v])).collect();
                let inside = d.iter().filter(|&&x| x < -0.002).count() as f32 / d.len() as f32;
                let mut sorted = d.clone();
                sorted.sort_by(f32::total_cmp);
                let median = sorted[sorted.len() / 2];
                // Folds at the hems and the waist may dip in; the cloth itself stands off the skin.
                assert!(inside < 0.2, "seed {seed} {}: {inside} of the vertices inside the body", g.label);
                assert!(median > 0.004, "seed {seed} {}: median distance {median}", g.label);
            }
        }
        assert!(open >= 6 && closed >= 6, "{open} open, {closed} closed pieces");
        // Open pieces have free edges; closed ones none (edges keyed by position: UV seams duplicate vertices).
        let s = small(0);
        let key = |p: Vec3| (p * 1e5).round().as_ivec3().to_array();
        for g in &s.garments {
            let mut edges: HashMap<([i32; 3], [i32; 3]), i32> = HashMap::new();
            for t in s.mesh.mesh.triangles.iter().filter(|t| g.vertices.contains(&(t[0] as usize))) {
                for k in 0..3 {
                    let (a, b) = (
                        key(s.mesh.mesh.positions[t[k] as usize]),
                        key(s.mesh.mesh.positions[t[(k + 1) % 3] as usize]),
                    );
                    if a != b {
                        *edges.entry((a.min(b), a.max(b))).or_default() += 1;
                    }
                }
            }
            let free = edges.values().filter(|&&c| c == 1).count();
            assert_eq!(free == 0, g.closed, "{}: {free} free edges", g.label);
        }
    }

    #[test]
    fn clothed_fof_contains_the_skirt_between_the_legs() {
        let a = assets();
        let mut params = dressed(2, UpperKind::Tee, LowerKind::Skirt);
        params.pose = PoseParams::rest();
        params.outfit.lower_hem = -4.5;
        params.outfit.flare = 1.0;
        (params.outfit.bag, params.outfit.hair) = (BagKind::None, HairKind::Short);
        let s = generate(a, &params, 64).unwrap();
        let skirt = s.garments.iter().find(|g| g.label == "skirt").unwrap();
        let body_only = r2human::geometry::mesh::TriMesh::new(
            s.mesh.mesh.positions[..s.garments[0].vertices.start].to_vec(),
            s.mesh.mesh.triangles.iter().filter(|t| (t[0] as usize) < s.garments[0].vertices.start).copied().collect(),
        );
        let res = 128;
        let clothed = Fof::from_mesh(&s.mesh.mesh, res, 32).unwrap();
        let naked = Fof::from_mesh(&body_only, res, 32).unwrap();
        // Just above the skirt's hem, on the body's axis: between the legs, inside the skirt.
        let hem_y = s.mesh.mesh.positions[skirt.vertices.clone()].iter().map(|p| p.y).fold(f32::MAX, f32::min);
        let row = ((1.0 - (hem_y + 0.08)) * res as f32 / 2.0) as usize;
        let col = res / 2;
        let mut occ = vec![0.0f32; 128];
        clothed.decode_column(col, row, 128, &mut occ);
        let inside_skirt = occ.iter().filter(|&&o| o >= 0.5).count();
        naked.decode_column(col, row, 128, &mut occ);
        let inside_body = occ.iter().filter(|&&o| o >= 0.5).count();
        assert!(inside_skirt > 20 && inside_body == 0, "skirt {inside_skirt} vs body {inside_body} of 128 samples");
        // The source view sees the garments: more pixels than the body alone, none fewer.
        let cam = Camera::source(res);
        let (c, b) = (
            r2human::geometry::raster::rasterize(&s.mesh.mesh, &cam),
            r2human::geometry::raster::rasterize(&body_only, &cam),
        );
        assert!(b.mask.iter().zip(&c.mask).all(|(&b, &c)| !b || c));
        assert!(c.mask.iter().filter(|&&m| m).count() > b.mask.iter().filter(|&&m| m).count() * 11 / 10);
    }

    #[test]
    fn framings_cut_where_they_should_in_the_pipeline_frame() {
        let a = assets();
        let mut seen = Vec::new();
        for seed in 0..5u64 {
            let full = small(seed);
            for framing in [Framing::ThreeQuarter, Framing::Upper] {
                let c = crop(&full, framing, &a.rig).unwrap();
                assert_eq!(c.crop.requested, framing);
                seen.push(c.crop.framing);
                if c.crop.framing == Framing::Full {
                    continue; // no crop fitted the cube: the full subject, recorded as such
                }
                let y = |name: &str| full.joints[a.rig.bone(name).unwrap()].y;
                let (hip, knee, shoulder) = (
                    y("upperleg01.L").min(y("upperleg01.R")),
                    y("lowerleg01.L").max(y("lowerleg01.R")),
                    y("upperarm01.L"),
                );
                match c.crop.framing {
                    Framing::ThreeQuarter => assert!(c.crop.cut_y < hip && c.crop.cut_y > knee, "{:?}", c.crop),
                    _ => assert!(c.crop.cut_y > hip && c.crop.cut_y < shoulder, "{:?}", c.crop),
                }
                // Nothing below the cut; inside the cube; 1.8 high or 1.96 wide, centred like a photo.
                let (lo, hi) = c.mesh.mesh.bounds().unwrap();
                assert!(lo.min_element() >= -1.0 && hi.max_element() <= 1.0, "{lo} {hi}");
                let (h, w) = (hi.y - lo.y, hi.x - lo.x);
                assert!((h - 1.8).abs() < 1e-3 || (w - 1.96).abs() < 1e-3, "{h} x {w}");
                assert!((lo.y + hi.y).abs() < 1e-3 && (lo.x + hi.x).abs() < 1e-3);
                // The pipeline normalises the cropped source image into (nearly) the same frame.
                let gt = r2human::eval::ground_truth::render_ground_truth(&c.mesh, &Camera::source(256));
                let rgb = gt.to_linear_rgba().map(|p| p.truncate());
                let mask = r2human::buffer::Image {
                    width: 256,
                    height: 256,
                    data: gt.mask.iter().map(|&m| m as u8 as f32).collect(),
                };
                let n = r2human::pipeline::input::normalise(&rgb, &mask, 256).unwrap();
                assert!((n.transform.scale - 1.0).abs() < 0.012, "scale {}", n.transform.scale);
                assert!(n.transform.offset.abs().max_element() < 1.6, "offset {}", n.transform.offset);
                // Reproducible.
                assert_eq!(crop(&full, framing, &a.rig).unwrap().mesh, c.mesh);
            }
        }
        assert!(seen.contains(&Framing::ThreeQuarter) && seen.contains(&Framing::Upper), "{seen:?}");
    }
}
