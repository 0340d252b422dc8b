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
    assert_ne!(a.mesh.texture, c.mesh.texture);
    for seed in 0..12u64 {
        let s = small(seed);
        let p = &s.mesh.mesh.positions;
        let (lo, hi) = s.mesh.mesh.bounds().unwrap();
        assert!((lo.y + 0.9).abs() < 1e-4 && (hi.y - 0.9).abs() < 1e-4, "seed {seed}: {lo} {hi}");
        let xz: Vec<Vec2> = p.iter().map(|q| Vec2::new(q.x, q.z)).collect();
        let (c, r) = min_enclosing_circle(&xz);
        assert!(c.length() < 1e-3, "seed {seed}: circle centre {c}");
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
    assert_eq!(back.texture, s.mesh.texture);
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
