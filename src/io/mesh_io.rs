//! Textured meshes on disk: glTF 2.0 binary (`.glb`) writing, and reading of textured glTF/GLB and Wavefront
//! OBJ + MTL (`map_Kd`) scans such as THuman2.0 and 2K2K.
//!
//! Every error names the offending file. Reading does not normalise (see `synth::scan` for that); it checks that
//! the mesh is non-empty, finite and references only existing vertices.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use glam::{Mat4, Vec2, Vec3};
use serde_json::json;

use crate::buffer::{linear_to_srgb, srgb8_to_linear, srgb_to_linear};
use crate::geometry::mesh::{MeshError, TriMesh};
use crate::io::image_io::{check_plausible, check_webp_frames, HeaderError};

/// Errors reading or writing mesh files. Each names the file concerned.
#[derive(Debug, thiserror::Error)]
pub enum MeshIoError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file extension is not one of `.obj`, `.gltf`, `.glb`, `.ply`.
    #[error("{path}: unsupported mesh format (expected .obj, .gltf, .glb or .ply)")]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
    },
    /// Malformed or unsupported PLY.
    #[error("{path}: invalid PLY: {message}")]
    Ply {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// Malformed OBJ or MTL text.
    #[error("{path}:{line}: {message}")]
    Obj {
        /// The OBJ or MTL file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// The glTF/GLB file is corrupt, truncated or uses something this reader does not support.
    #[error("{path}: invalid glTF: {source}")]
    Gltf {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: GltfError,
    },
    /// A texture the mesh references is missing or cannot be decoded.
    #[error("{path}: texture {texture:?} cannot be used: {source}")]
    Texture {
        /// The mesh (or material) file that references the texture.
        path: PathBuf,
        /// The texture as referenced.
        texture: String,
        /// What is wrong.
        source: TextureError,
    },
    /// The mesh has no triangles.
    #[error("{path}: the mesh has no triangles")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// A vertex coordinate is NaN or infinite.
    #[error("{path}: vertex {index} is not finite ({value:?})")]
    NonFinite {
        /// The file.
        path: PathBuf,
        /// 0-based vertex index.
        index: usize,
        /// The offending position.
        value: [f32; 3],
    },
    /// The mesh to encode is inconsistent (a non-finite vertex, an index past the vertices…).
    #[error("{path}: cannot encode: {source}")]
    InvalidMesh {
        /// The destination file.
        path: PathBuf,
        /// What is wrong with the mesh.
        source: MeshError,
    },
    /// The encoded glTF does not fit a GLB container.
    #[error("{path}: cannot encode: {source}")]
    Container {
        /// The destination file.
        path: PathBuf,
        /// What does not fit.
        source: GlbError,
    },
    /// The mesh cannot be encoded (e.g. more vertices than 32-bit indices allow, or a bad texture).
    #[error("{path}: cannot encode: {message}")]
    Encode {
        /// The destination file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
}

/// Why a texture a mesh references cannot be used ([`MeshIoError::Texture`]'s cause).
#[derive(Debug, thiserror::Error)]
pub enum TextureError {
    /// No file by that name (nor its bare name, nor another case of it) next to the mesh.
    #[error("file not found")]
    NotFound,
    /// The file exists but cannot be read.
    #[error("{0}")]
    Read(#[source] std::io::Error),
    /// A glTF texture names an image the file does not have.
    #[error("does not exist")]
    NoSuchImage,
    /// A glTF `data:` URI without the comma that starts its payload.
    #[error("a data: URI without a comma")]
    DataUriWithoutComma,
    /// A glTF `data:` URI whose base64 payload does not decode.
    #[error("data: URI: {0}")]
    DataUriBase64(#[source] base64::DecodeError),
    /// An embedded glTF image whose buffer view lies outside its buffer.
    #[error("its buffer view is past the end of the buffer")]
    ViewPastBuffer,
    /// The header claims a size its bytes cannot hold (checked before anything is decoded).
    #[error("{0}")]
    Header(#[source] HeaderError),
    /// The `image` crate cannot read or decode it (unknown format, corrupt data, a side over
    /// [`MAX_TEXTURE_SIDE`]).
    #[error("{0}")]
    Decode(#[source] Box<image::ImageError>),
}

/// What is wrong with a glTF or GLB file ([`MeshIoError::Gltf`]'s cause).
#[derive(Debug, thiserror::Error)]
pub enum GltfError {
    /// The GLB container around the document is broken ([`glb_chunks`]).
    #[error("{0}")]
    Container(#[source] GlbError),
    /// The document is not glTF JSON.
    #[error("JSON: {0}")]
    Json(#[source] gltf::json::Error),
    /// The `gltf` crate's validation refused the document. (`gltf` and `image` errors are boxed: they are large,
    /// and every `Result` that carries a `MeshIoError` pays for its largest variant.)
    #[error("{0}")]
    Invalid(#[source] Box<gltf::Error>),
    /// A buffer cannot be loaded (missing file, bad `data:` URI, too short).
    #[error("buffers: {0}")]
    Buffers(#[source] Box<gltf::Error>),
    /// A primitive uses an accessor the file does not have.
    #[error("mesh {mesh} primitive {primitive} uses accessor {accessor} but there are {count}")]
    MissingAccessor {
        /// Mesh index.
        mesh: usize,
        /// Primitive index within the mesh.
        primitive: usize,
        /// The accessor index used.
        accessor: usize,
        /// How many accessors there are.
        count: usize,
    },
    /// An image stored in a buffer view without its `mimeType`.
    #[error("image {0} is in a buffer view but has no mimeType")]
    ImageWithoutMimeType(usize),
    /// An image with neither a `uri` nor a `bufferView`.
    #[error("image {0} has neither a uri nor a bufferView")]
    ImageWithoutSource(usize),
    /// An accessor this reader cannot read safely.
    #[error("accessor {index} ({what}) {problem}")]
    Accessor {
        /// Accessor index.
        index: usize,
        /// What the primitive uses it for (`Positions`, `indices`…).
        what: String,
        /// What is wrong with it.
        problem: AccessorProblem,
    },
    /// A node reached twice while walking the scene (a cycle or a shared child).
    #[error("node {0} appears twice in the node hierarchy (a cycle)")]
    NodeTwice(usize),
    /// A node hierarchy deeper than the reader walks.
    #[error("the node hierarchy is deeper than 256 levels")]
    TooDeep,
    /// A triangle index past its primitive's vertices.
    #[error("primitive index {index} past its {count} vertices")]
    IndexPastVertices {
        /// The index.
        index: u32,
        /// The primitive's vertex count.
        count: usize,
    },
    /// The merged mesh is inconsistent (materials, UVs or colours do not match its vertices).
    #[error("{0}")]
    Mesh(#[source] MeshError),
}

/// What is wrong with one glTF accessor ([`GltfError::Accessor`]).
#[derive(Debug, thiserror::Error)]
pub enum AccessorProblem {
    /// A component type or shape the `gltf` reader does not handle.
    #[error("is {0:?} {1:?}, which this reader does not take")]
    Kind(gltf::accessor::DataType, gltf::accessor::Dimensions),
    /// Elements overlap: the view's stride is shorter than an element.
    #[error("has a byte stride of {stride}, less than its {size}-byte elements")]
    Stride {
        /// The buffer view's byte stride.
        stride: usize,
        /// The element size in bytes.
        size: usize,
    },
    /// The elements end past the buffer view (or the view past its buffer).
    #[error("reads {count} elements past the end of buffer view {view}")]
    PastView {
        /// Elements read.
        count: usize,
        /// Buffer view index.
        view: usize,
    },
    /// `count` is 0 (glTF requires at least 1).
    #[error("has a count of 0 (glTF requires at least 1)")]
    ZeroCount,
    /// A sparse accessor with no elements.
    #[error("is sparse with no elements")]
    EmptySparse,
}

/// What is wrong with a GLB container ([`glb_chunks`]) or why one cannot be written ([`glb_container`]). Each
/// message gives the offsets involved.
#[derive(Debug, thiserror::Error)]
pub enum GlbError {
    /// Fewer bytes than the header.
    #[error("GLB: the file is {0} bytes, shorter than the 12-byte GLB header")]
    Short(usize),
    /// The magic is not `glTF`.
    #[error("GLB: the file starts with {}, not the magic \"glTF\"", show_tag(.0))]
    Magic([u8; 4]),
    /// A container version other than 2.
    #[error("GLB version {0}; only version 2 is supported")]
    Version(u32),
    /// The declared total length cannot hold a header and one chunk header.
    #[error("GLB: the header declares a total length of {0} bytes, less than the 20 of a header and one chunk header")]
    DeclaredTooShort(usize),
    /// The declared total length is past the end of the data.
    #[error("GLB: the header declares a total length of {declared} bytes but the file has {len}: it is truncated")]
    Truncated {
        /// Declared total length.
        declared: usize,
        /// Actual length.
        len: usize,
    },
    /// Bytes left before the declared end that cannot hold a chunk header.
    #[error("GLB: {left} bytes at offset {at} are too few for a chunk header (8)")]
    ChunkHeader {
        /// Bytes left.
        left: usize,
        /// Their offset.
        at: usize,
    },
    /// A chunk longer than what remains before the declared end.
    #[error(
        "GLB: chunk {index} ({}) at offset {at} declares {length} bytes but only {remain} remain before the declared \
         end ({declared})",
        show_tag(tag)
    )]
    ChunkTooLong {
        /// Chunk position.
        index: usize,
        /// Chunk type.
        tag: [u8; 4],
        /// Chunk header offset.
        at: usize,
        /// Declared chunk length.
        length: usize,
        /// Bytes remaining after the chunk header.
        remain: usize,
        /// Declared total length.
        declared: usize,
    },
    /// The first chunk is not JSON.
    #[error("GLB: the first chunk is {}, not JSON", show_tag(.0))]
    FirstNotJson([u8; 4]),
    /// A second JSON chunk.
    #[error("GLB: a second JSON chunk (chunk {index}, offset {at})")]
    SecondJson {
        /// Chunk position.
        index: usize,
        /// Its offset.
        at: usize,
    },
    /// A BIN chunk anywhere but right after JSON.
    #[error("GLB: a BIN chunk at position {index} (offset {at}); it must directly follow JSON")]
    MisplacedBin {
        /// Chunk position.
        index: usize,
        /// Its offset.
        at: usize,
    },
    /// No JSON chunk at all.
    #[error("GLB: no JSON chunk")]
    NoJson,
    /// A container to write that would be 4 GiB or more (GLB lengths are 32-bit).
    #[error("file larger than 4 GiB")]
    TooLarge,
}

/// Albedo of a surface with neither a material nor vertex colours (linear grey).
pub const DEFAULT_ALBEDO: f32 = 0.7;

/// Largest texture side accepted from a mesh file (bounded memory on hostile files).
pub const MAX_TEXTURE_SIDE: u32 = 16384;

/// How a triangle's base colour (albedo) is made, the glTF way: `base_color` times the interpolated vertex colour
/// (when the mesh has [`TriMesh::colors`]) times the texture at the interpolated UV (when the material has a
/// texture and the mesh has [`TriMesh::uvs`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Name from the file (for messages), may be empty.
    pub name: String,
    /// Linear RGB base-colour factor.
    pub base_color: Vec3,
    /// Base-colour texture, 8-bit sRGB (row 0 at the top, sampled at glTF UVs); shared between the materials of
    /// a file that use the same image.
    pub texture: Option<Arc<image::RgbImage>>,
}

impl Material {
    /// A material of one colour (linear RGB).
    pub fn color(name: &str, base_color: Vec3) -> Self {
        Self { name: name.to_string(), base_color, texture: None }
    }

    /// A textured material (base colour factor 1).
    pub fn textured(name: &str, texture: Arc<image::RgbImage>) -> Self {
        Self { name: name.to_string(), base_color: Vec3::ONE, texture: Some(texture) }
    }
}

/// A triangle mesh with its appearance: any number of [`Material`]s, one per triangle
/// ([`TexturedMesh::triangle_materials`]), optional per-vertex UVs ([`TriMesh::uvs`], glTF convention) and
/// per-vertex colours ([`TriMesh::colors`], linear RGB). [`TexturedMesh::albedo`] is the one rule every consumer
/// (ground truth, GLB writing) applies.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TexturedMesh {
    /// Geometry, normals, UVs and optional colours.
    pub mesh: TriMesh,
    /// Materials; empty: the albedo is the vertex colour, or [`DEFAULT_ALBEDO`] grey without one.
    pub materials: Vec<Material>,
    /// Material index of each triangle; empty when every triangle uses material 0 (the single-material fast
    /// path: no per-pixel triangle lookup).
    pub triangle_materials: Vec<u32>,
}

impl TexturedMesh {
    /// One textured material on every triangle (the mesh needs one UV per vertex to sample it).
    pub fn textured(mesh: TriMesh, texture: image::RgbImage) -> Self {
        Self { mesh, materials: vec![Material::textured("albedo", Arc::new(texture))], triangle_materials: Vec::new() }
    }

    /// No material: vertex colours when present, else grey.
    pub fn untextured(mesh: TriMesh) -> Self {
        Self { mesh, materials: Vec::new(), triangle_materials: Vec::new() }
    }

    /// Whether triangles can differ in material (the per-pixel lookup needs the triangle; see
    /// [`crate::geometry::raster::rasterize_with_triangles`]).
    pub fn has_several_materials(&self) -> bool {
        self.materials.len() > 1 && !self.triangle_materials.is_empty()
    }

    /// The material of triangle `t` (`None` without materials).
    pub fn material_of(&self, t: usize) -> Option<&Material> {
        let m = self.triangle_materials.get(t).map_or(0, |&m| m as usize);
        self.materials.get(m)
    }

    /// The texture of the first textured material (the single-texture case; `None` without one).
    pub fn first_texture(&self) -> Option<&image::RgbImage> {
        self.materials.iter().find_map(|m| m.texture.as_deref())
    }

    /// Linear RGB albedo on triangle `t` at the interpolated `uv` and vertex colour (`None` when the mesh has none):
    /// the rule of [`Material`], or the vertex colour (grey without one) for a mesh without materials.
    pub fn albedo(&self, t: usize, uv: Option<Vec2>, vertex_color: Option<Vec3>) -> Vec3 {
        let Some(m) = self.material_of(t) else {
            return vertex_color.unwrap_or(Vec3::splat(DEFAULT_ALBEDO));
        };
        let mut c = m.base_color * vertex_color.unwrap_or(Vec3::ONE);
        if let (Some(tex), Some(uv)) = (&m.texture, uv) {
            c *= sample_texture(tex, uv);
        }
        c
    }

    /// Checks what [`TriMesh::validate`] checks plus the appearance: one material index per triangle (or none),
    /// each naming an existing material, and UVs/colours either absent or one per vertex.
    pub fn validate(&self) -> Result<(), MeshError> {
        self.mesh.validate()?;
        let (triangles, vertices) = (self.mesh.triangles.len(), self.mesh.positions.len());
        if !self.triangle_materials.is_empty() && self.triangle_materials.len() != triangles {
            return Err(MeshError::MaterialCount { indices: self.triangle_materials.len(), triangles });
        }
        if let Some(&index) = self.triangle_materials.iter().find(|&&m| m as usize >= self.materials.len()) {
            return Err(MeshError::MaterialIndex { index, materials: self.materials.len() });
        }
        for (what, len) in [("UVs", self.mesh.uvs.len()), ("colours", self.mesh.colors.len())] {
            if len != 0 && len != vertices {
                return Err(MeshError::AttributeCount { what, len, vertices });
            }
        }
        Ok(())
    }
}

/// Bilinear lookup of an sRGB texture at a glTF UV (origin top-left, repeat wrapping) returning linear RGB.
pub fn sample_texture(tex: &image::RgbImage, uv: Vec2) -> Vec3 {
    let (w, h) = (tex.width() as i64, tex.height() as i64);
    if w == 0 || h == 0 || !uv.is_finite() {
        return Vec3::splat(0.5);
    }
    let x = uv.x.rem_euclid(1.0) * w as f32 - 0.5;
    let y = uv.y.rem_euclid(1.0) * h as f32 - 0.5;
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let texel = |xi: i64, yi: i64| {
        let p = tex.get_pixel(xi.rem_euclid(w) as u32, yi.rem_euclid(h) as u32);
        Vec3::new(srgb8_to_linear(p[0]), srgb8_to_linear(p[1]), srgb8_to_linear(p[2]))
    };
    let (xi, yi) = (x0 as i64, y0 as i64);
    let top = texel(xi, yi).lerp(texel(xi + 1, yi), fx);
    let bottom = texel(xi, yi + 1).lerp(texel(xi + 1, yi + 1), fx);
    top.lerp(bottom, fy)
}

/// Decodes a texture file (PNG, JPEG, BMP, TGA, WebP, GIF; format from the content, then the extension), at
/// most [`MAX_TEXTURE_SIDE`] a side. A name that does not exist is looked up as its bare file name in `dir`,
/// then case-insensitively there (scans often carry absolute paths of the machine that made them, or a
/// different case). `referrer` (the mesh or MTL file) labels errors.
pub fn load_texture(dir: &Path, name: &str, referrer: &Path) -> Result<Arc<image::RgbImage>, MeshIoError> {
    let err = |texture: &Path, source: TextureError| MeshIoError::Texture {
        path: referrer.to_path_buf(),
        texture: texture.display().to_string(),
        source,
    };
    let given = dir.join(name.replace('\\', "/"));
    let path = resolve_texture(dir, &given).ok_or_else(|| err(&given, TextureError::NotFound))?;
    let bytes = std::fs::read(&path).map_err(|e| err(&path, TextureError::Read(e)))?;
    decode_texture(&bytes, image::ImageFormat::from_path(&path).ok()).map(Arc::new).map_err(|e| err(&path, e))
}

/// Decodes an encoded texture (format from the content, else `hint`: TGA has no signature), at most
/// [`MAX_TEXTURE_SIDE`] a side, to 8-bit RGB.
fn decode_texture(bytes: &[u8], hint: Option<image::ImageFormat>) -> Result<image::RgbImage, TextureError> {
    let mut reader =
        image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(TextureError::Read)?;
    if let (None, Some(format)) = (reader.format(), hint) {
        reader.set_format(format);
    }
    // A header claiming more pixels than the bytes can hold is refused before any pixel buffer exists.
    let format = reader.format();
    let mut header = image::ImageReader::new(std::io::Cursor::new(bytes));
    if let Some(f) = format {
        header.set_format(f);
    }
    let (w, h) = header.into_dimensions().map_err(|e| TextureError::Decode(Box::new(e)))?;
    check_plausible(format, w, h, bytes.len() as u64).map_err(TextureError::Header)?;
    check_webp_frames(bytes).map_err(TextureError::Header)?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_TEXTURE_SIDE);
    limits.max_image_height = Some(MAX_TEXTURE_SIDE);
    reader.limits(limits);
    Ok(reader.decode().map_err(|e| TextureError::Decode(Box::new(e)))?.to_rgb8())
}

fn resolve_texture(dir: &Path, given: &Path) -> Option<PathBuf> {
    if given.is_file() {
        return Some(given.to_path_buf());
    }
    let base = given.file_name()?.to_str()?.rsplit(['/', '\\']).next()?.to_string();
    let bare = dir.join(&base);
    if bare.is_file() {
        return Some(bare);
    }
    let lower = base.to_lowercase();
    std::fs::read_dir(dir)
        .ok()?
        .flatten()
        .map(|e| e.path())
        .find(|p| p.is_file() && p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.to_lowercase() == lower))
}

/// Reads a textured mesh, choosing the reader by extension (`.obj`, `.gltf`, `.glb`, `.ply`, case-insensitive).
pub fn read_mesh(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("obj") => read_obj(path),
        Some("gltf") | Some("glb") => read_gltf(path),
        Some("ply") => super::ply::read_ply(path),
        _ => Err(MeshIoError::UnsupportedFormat { path: path.to_path_buf() }),
    }
}

/// Checks the common invariants of a freshly read mesh: triangles present, finite vertices, indices in range,
/// consistent materials.
pub(crate) fn check_mesh(path: &Path, textured: &TexturedMesh) -> Result<(), MeshIoError> {
    let mesh = &textured.mesh;
    if mesh.is_empty() {
        return Err(MeshIoError::Empty { path: path.to_path_buf() });
    }
    if let Some(index) = mesh.positions.iter().position(|p| !p.is_finite()) {
        let p = mesh.positions[index];
        return Err(MeshIoError::NonFinite { path: path.to_path_buf(), index, value: p.to_array() });
    }
    textured.validate().map_err(|e| MeshIoError::Gltf { path: path.to_path_buf(), source: GltfError::Mesh(e) })
}

// ------------------------------------------------------------------------------------------------------------
// OBJ + MTL
// ------------------------------------------------------------------------------------------------------------

#[derive(Default, Clone)]
struct ObjMaterial {
    kd: Option<Vec3>,
    map_kd: Option<String>,
    /// The MTL file that defined it (textures are relative to it).
    mtl: PathBuf,
}

/// Reads a Wavefront OBJ with its MTL materials. Polygons are fan-triangulated, negative indices resolved, UVs
/// (OBJ convention, v up) flipped to glTF's (v down) with seam vertices split. Every material used by the faces
/// becomes a [`Material`]: its `map_Kd` texture (relative to the MTL file; any number of textures, in any format
/// [`load_texture`] reads) replaces `Kd` (exporters write `Kd 0.8` next to textures), otherwise `Kd` is its colour.
/// Per-vertex colours (`v x y z r g b`, sRGB in `[0, 1]`, or `[0, 255]` when any exceeds 1) become
/// [`TriMesh::colors`] (linear) and replace `Kd`; on a textured material they multiply the texture. Faces before
/// any `usemtl` (or naming an unknown material) are grey, or their vertex colour.
pub fn read_obj(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let bytes = std::fs::read(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    let text = String::from_utf8_lossy(&bytes);
    let dir = path.parent().unwrap_or(Path::new("."));
    let obj_err = |line: usize, message: String| MeshIoError::Obj { path: path.to_path_buf(), line, message };

    let mut positions: Vec<Vec3> = Vec::new();
    let mut vcolors: Vec<Vec3> = Vec::new();
    let mut texcoords: Vec<Vec2> = Vec::new();
    let mut materials: HashMap<String, ObjMaterial> = HashMap::new();
    // Material names in order of first use by a face; triangles index into it (None: no usemtl yet).
    let mut used: Vec<Option<String>> = Vec::new();
    // Index of each name in `used` (a linear search per `usemtl` would be quadratic in hostile files).
    let mut used_index: HashMap<Option<String>, usize> = HashMap::new();
    let mut mtl_files: Vec<PathBuf> = Vec::new();
    let mut current: Option<usize> = None;
    let mut current_name: Option<String> = None;
    // Per triangle: corners as (position index, texcoord index or u32::MAX), and its index into `used`.
    let mut corners: Vec<[(u32, u32); 3]> = Vec::new();
    let mut tri_used: Vec<u32> = Vec::new();

    let parse_f = |tok: Option<&str>, line: usize, what: &str| -> Result<f32, MeshIoError> {
        let tok = tok.ok_or_else(|| obj_err(line, format!("{what}: missing coordinate")))?;
        tok.parse::<f32>().map_err(|_| obj_err(line, format!("{what}: {tok:?} is not a number")))
    };

    for (lineno, raw) in text.lines().enumerate() {
        let line = lineno + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let (key, rest) = l.split_once(char::is_whitespace).unwrap_or((l, ""));
        let rest = rest.trim();
        match key {
            "v" => {
                let mut it = rest.split_whitespace();
                let x = parse_f(it.next(), line, "v")?;
                let y = parse_f(it.next(), line, "v")?;
                let z = parse_f(it.next(), line, "v")?;
                positions.push(Vec3::new(x, y, z));
                let c: Vec<f32> = it.take(3).filter_map(|t| t.parse().ok()).collect();
                if c.len() == 3 && c.iter().all(|v| v.is_finite()) {
                    vcolors.resize(positions.len() - 1, Vec3::ONE);
                    vcolors.push(Vec3::new(c[0], c[1], c[2]));
                }
            }
            "vt" => {
                let mut it = rest.split_whitespace();
                let u = parse_f(it.next(), line, "vt")?;
                let v =
                    it.next().map(|t| t.parse::<f32>()).transpose().map_err(|_| obj_err(line, "vt: bad v".into()))?;
                texcoords.push(Vec2::new(u, 1.0 - v.unwrap_or(0.0)));
            }
            "f" => {
                let mut poly: Vec<(u32, u32)> = Vec::with_capacity(4);
                for tok in rest.split_whitespace() {
                    let mut parts = tok.split('/');
                    let resolve = |s: &str, n: usize, what: &str| -> Result<u32, MeshIoError> {
                        let i: i64 = s.parse().map_err(|_| obj_err(line, format!("f: bad {what} index {s:?}")))?;
                        let idx = if i > 0 { i - 1 } else { n as i64 + i };
                        if i == 0 || idx < 0 || idx >= n as i64 {
                            return Err(obj_err(line, format!("f: {what} index {i} out of range (have {n})")));
                        }
                        Ok(idx as u32)
                    };
                    let vi = resolve(parts.next().unwrap_or(""), positions.len(), "vertex")?;
                    let ti = match parts.next() {
                        Some(s) if !s.is_empty() => resolve(s, texcoords.len(), "texcoord")?,
                        _ => u32::MAX,
                    };
                    poly.push((vi, ti));
                }
                if poly.len() < 3 {
                    return Err(obj_err(line, format!("f: a face needs 3 vertices, got {}", poly.len())));
                }
                let m = *current.get_or_insert_with(|| {
                    used.push(current_name.clone());
                    used_index.insert(current_name.clone(), used.len() - 1);
                    used.len() - 1
                });
                for k in 1..poly.len() - 1 {
                    corners.push([poly[0], poly[k], poly[k + 1]]);
                    tri_used.push(m as u32);
                }
            }
            "mtllib" => {
                for name in split_file_list(rest) {
                    let mtl_path = dir.join(name.replace('\\', "/"));
                    if mtl_files.contains(&mtl_path) {
                        continue; // already read (only existing files get here, so the list stays short)
                    }
                    parse_mtl(&mtl_path, &mut materials).map_err(|e| match e {
                        // A missing or unreadable library: say which OBJ line asked for it.
                        MeshIoError::Io { path: mtl, source } => {
                            obj_err(line, format!("mtllib: cannot read {}: {source}", mtl.display()))
                        }
                        other => other,
                    })?;
                    mtl_files.push(mtl_path);
                }
            }
            "usemtl" => {
                current_name = Some(rest.to_string());
                current = used_index.get(&current_name).copied();
            }
            _ => {}
        }
    }

    // Vertex colours are sRGB display values; some writers use 0..255.
    if vcolors.iter().any(|c| c.max_element() > 1.0) {
        vcolors.iter_mut().for_each(|c| *c /= 255.0);
    }
    vcolors.iter_mut().for_each(|c| *c = c.clamp(Vec3::ZERO, Vec3::ONE).to_array().map(srgb_to_linear).into());
    let has_vcolors = !vcolors.is_empty();
    vcolors.resize(if has_vcolors { positions.len() } else { 0 }, Vec3::ONE);

    // One material per used name; textures decoded once each.
    let mut textures: HashMap<PathBuf, Arc<image::RgbImage>> = HashMap::new();
    let mut out_materials = Vec::with_capacity(used.len());
    let mut textured = Vec::with_capacity(used.len());
    for name in &used {
        let def = name.as_ref().and_then(|n| materials.get(n));
        let grey = if has_vcolors { Vec3::ONE } else { Vec3::splat(DEFAULT_ALBEDO) };
        let label = name.clone().unwrap_or_default();
        let material = match def {
            Some(ObjMaterial { map_kd: Some(map), mtl, .. }) if !texcoords.is_empty() => {
                let mtl_dir = mtl.parent().unwrap_or(dir);
                let key = mtl_dir.join(map);
                let tex = match textures.get(&key) {
                    Some(t) => Arc::clone(t),
                    None => {
                        let t = load_texture(mtl_dir, map, mtl)?;
                        textures.insert(key, Arc::clone(&t));
                        t
                    }
                };
                Material::textured(&label, tex)
            }
            Some(ObjMaterial { kd: Some(kd), .. }) if !has_vcolors => Material::color(&label, *kd),
            _ => Material::color(&label, grey),
        };
        textured.push(material.texture.is_some());
        out_materials.push(material);
    }
    // A referenced texture that is missing is an error even when the file has no UVs to use it.
    for name in used.iter().flatten() {
        if let Some(ObjMaterial { map_kd: Some(map), mtl, .. }) = materials.get(name) {
            let mtl_dir = mtl.parent().unwrap_or(dir);
            if resolve_texture(mtl_dir, &mtl_dir.join(map.replace('\\', "/"))).is_none() {
                return Err(MeshIoError::Texture {
                    path: mtl.clone(),
                    texture: mtl_dir.join(map).display().to_string(),
                    source: TextureError::NotFound,
                });
            }
        }
    }
    let any_textured = textured.iter().any(|&t| t);
    // No face names a material the MTL files define: appearance from the vertex colours (or grey) alone.
    let no_materials = used.iter().all(|u| u.as_ref().and_then(|n| materials.get(n)).is_none());

    // Split vertices per (position, texcoord) pair on textured triangles so UVs are per vertex.
    let mut remap: HashMap<(u32, u32), u32> = HashMap::new();
    let mut out_pos = Vec::new();
    let mut out_uv = Vec::new();
    let mut out_col = Vec::new();
    let mut triangles = Vec::with_capacity(corners.len());
    for (tri, &m) in corners.iter().zip(&tri_used) {
        let tex = textured[m as usize];
        let mut idx = [0u32; 3];
        for (k, &(vi, ti)) in tri.iter().enumerate() {
            let key = if tex { (vi, ti) } else { (vi, u32::MAX) };
            idx[k] = *remap.entry(key).or_insert_with(|| {
                out_pos.push(positions[vi as usize]);
                if any_textured {
                    out_uv.push(texcoords.get(ti as usize).copied().unwrap_or(Vec2::ZERO));
                }
                if has_vcolors {
                    out_col.push(vcolors[vi as usize]);
                }
                (out_pos.len() - 1) as u32
            });
        }
        triangles.push(idx);
    }
    let mut mesh = TriMesh::new(out_pos, triangles);
    mesh.uvs = out_uv;
    mesh.colors = out_col;
    let several = out_materials.len() > 1;
    let out = TexturedMesh {
        mesh,
        materials: if no_materials { Vec::new() } else { out_materials },
        triangle_materials: if several && !no_materials { tri_used } else { Vec::new() },
    };
    check_mesh(path, &out)?;
    Ok(out)
}

/// File names on an `mtllib` line: whitespace separated unless the whole rest names one file with spaces.
fn split_file_list(rest: &str) -> Vec<String> {
    if rest.to_ascii_lowercase().matches(".mtl").count() <= 1 {
        vec![rest.to_string()]
    } else {
        rest.split_whitespace().map(str::to_string).collect()
    }
}

fn parse_mtl(path: &Path, materials: &mut HashMap<String, ObjMaterial>) -> Result<(), MeshIoError> {
    let bytes = std::fs::read(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    let text = String::from_utf8_lossy(&bytes);
    let mut current: Option<String> = None;
    for (lineno, raw) in text.lines().enumerate() {
        let l = raw.trim();
        let (key, rest) = l.split_once(char::is_whitespace).unwrap_or((l, ""));
        let rest = rest.trim();
        match key {
            "newmtl" => {
                current = Some(rest.to_string());
                materials.insert(rest.to_string(), ObjMaterial { mtl: path.to_path_buf(), ..Default::default() });
            }
            k if k.eq_ignore_ascii_case("Kd") || k.eq_ignore_ascii_case("map_Kd") => {
                let Some(name) = &current else {
                    return Err(MeshIoError::Obj {
                        path: path.to_path_buf(),
                        line: lineno + 1,
                        message: format!("{key} before any newmtl"),
                    });
                };
                let m = materials.entry(name.clone()).or_default();
                if key.eq_ignore_ascii_case("Kd") {
                    let c: Vec<f32> = rest
                        .split_whitespace()
                        .filter_map(|t| t.parse().ok())
                        .filter(|v: &f32| v.is_finite())
                        .collect();
                    if c.len() >= 3 {
                        m.kd = Some(Vec3::new(c[0], c[1], c[2]).max(Vec3::ZERO));
                    }
                } else {
                    m.map_kd = Some(strip_map_options(rest));
                }
            }
            _ => {}
        }
    }
    Ok(())
}

/// The file name of a `map_Kd` statement, skipping options such as `-s 1 1 1`, `-bm 0.5` or `-clamp on`. The
/// last token is always kept as (part of) the name.
fn strip_map_options(rest: &str) -> String {
    let toks: Vec<&str> = rest.split_whitespace().collect();
    let mut i = 0;
    while i + 1 < toks.len() && toks[i].starts_with('-') {
        i += 1;
        while i + 1 < toks.len() && (toks[i].parse::<f32>().is_ok() || matches!(toks[i], "on" | "off")) {
            i += 1;
        }
    }
    toks[i.min(toks.len().saturating_sub(1))..].join(" ")
}

// ------------------------------------------------------------------------------------------------------------
// glTF / GLB
// ------------------------------------------------------------------------------------------------------------

/// Reads a glTF 2.0 file (`.gltf` with its buffers/images, or `.glb`): every triangle primitive of the default
/// scene, with node transforms applied, merged into one mesh. Each glTF material used becomes a [`Material`]
/// (base colour factor and base-colour texture, any number of them; UVs from the texture's `TEXCOORD_n`);
/// `COLOR_0` becomes [`TriMesh::colors`] (1 where a primitive has none), multiplying the material as glTF
/// specifies. Primitives without a material get glTF's default (white).
pub fn read_gltf(path: &Path) -> Result<TexturedMesh, MeshIoError> {
    let gerr = |source: GltfError| MeshIoError::Gltf { path: path.to_path_buf(), source };
    let bytes = std::fs::read(path).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })?;
    // The GLB container is split here, not by `gltf` (its reader panics on a declared length below 12 bytes and
    // refuses chunk types the specification says to skip).
    let (json, blob) = if bytes.starts_with(b"glTF") {
        let chunks = glb_chunks(&bytes).map_err(|e| gerr(GltfError::Container(e)))?;
        if chunks.trailing > 0 {
            tracing::warn!("{}: {} bytes after the GLB's declared length ignored", path.display(), chunks.trailing);
        }
        (chunks.json, chunks.bin.map(<[u8]>::to_vec))
    } else {
        (&bytes[..], None)
    };
    let root = gltf::json::Root::from_slice(json).map_err(|e| gerr(GltfError::Json(e)))?;
    check_gltf_references(&root).map_err(gerr)?;
    let document = gltf::Document::from_json(root).map_err(|e| gerr(GltfError::Invalid(Box::new(e))))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    // Name a missing external texture or buffer before the importer fails with a generic message.
    for image in document.images() {
        if let gltf::image::Source::Uri { uri, .. } = image.source() {
            if !uri.starts_with("data:") && !dir.join(percent_decode(uri)).is_file() {
                return Err(MeshIoError::Texture {
                    path: path.to_path_buf(),
                    texture: uri.to_string(),
                    source: TextureError::NotFound,
                });
            }
        }
    }
    let buffers =
        gltf::import_buffers(&document, Some(dir), blob).map_err(|e| gerr(GltfError::Buffers(Box::new(e))))?;

    struct Prim {
        base: u32,
        n: usize,
        uv: Option<Vec<Vec2>>,
        colors: Option<Vec<Vec3>>,
        material: u32,
    }
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    let mut triangle_materials: Vec<u32> = Vec::new();
    let mut prims: Vec<Prim> = Vec::new();
    // (glTF material index, whether its texture is sampled) -> our material; images decoded once each.
    let mut material_ids: HashMap<(Option<usize>, bool), u32> = HashMap::new();
    let mut materials: Vec<Material> = Vec::new();
    let mut images: HashMap<usize, Arc<image::RgbImage>> = HashMap::new();

    let scene = document.default_scene().or_else(|| document.scenes().next());
    let mut stack: Vec<(gltf::Node, Mat4, usize)> = match &scene {
        Some(s) => s.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect(),
        None => document.nodes().map(|n| (n, Mat4::IDENTITY, 0)).collect(),
    };
    // The node hierarchy must be a forest (glTF 2.0, 3.5.3): a node reached twice is a cycle or a shared child,
    // which would loop forever or multiply the geometry exponentially (a chain of nodes each listing the next
    // twice).
    let mut visited = vec![false; document.nodes().len()];
    while let Some((node, parent, depth)) = stack.pop() {
        match visited.get_mut(node.index()) {
            Some(seen) if !*seen => *seen = true,
            _ => return Err(gerr(GltfError::NodeTwice(node.index()))),
        }
        if depth > 256 {
            return Err(gerr(GltfError::TooDeep));
        }
        let world = parent * Mat4::from_cols_array_2d(&node.transform().matrix());
        for child in node.children() {
            stack.push((child, world, depth + 1));
        }
        let Some(mesh) = node.mesh() else { continue };
        for prim in mesh.primitives() {
            if prim.mode() != gltf::mesh::Mode::Triangles {
                continue;
            }
            check_primitive_accessors(&prim).map_err(gerr)?;
            let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
            let Some(pos) = reader.read_positions() else { continue };
            let base = positions.len() as u32;
            let local: Vec<Vec3> = pos.map(|p| world.transform_point3(Vec3::from(p))).collect();
            let n = local.len();
            let material = prim.material();
            let pbr = material.pbr_metallic_roughness();
            let tex = pbr.base_color_texture();
            let prim_uv: Option<Vec<Vec2>> = tex
                .as_ref()
                .and_then(|t| reader.read_tex_coords(t.tex_coord()))
                .map(|tc| tc.into_f32().map(Vec2::from).collect::<Vec<_>>())
                .filter(|uv| uv.len() == n);
            let sampled = tex.is_some() && prim_uv.is_some();
            let key = (material.index(), sampled);
            let id = match material_ids.get(&key) {
                Some(&id) => id,
                None => {
                    let factor = Vec3::from_slice(&pbr.base_color_factor()[..3]);
                    let factor = if factor.is_finite() { factor.max(Vec3::ZERO) } else { Vec3::ONE };
                    let texture = match (&tex, sampled) {
                        (Some(t), true) => {
                            let i = t.texture().source().index();
                            Some(match images.get(&i) {
                                Some(img) => Arc::clone(img),
                                None => {
                                    let img = Arc::new(decode_gltf_image(&document, i, dir, &buffers, path)?);
                                    images.insert(i, Arc::clone(&img));
                                    img
                                }
                            })
                        }
                        _ => None,
                    };
                    let name = material.name().unwrap_or("").to_string();
                    materials.push(Material { name, base_color: factor, texture });
                    material_ids.insert(key, materials.len() as u32 - 1);
                    materials.len() as u32 - 1
                }
            };
            let colors: Option<Vec<Vec3>> = reader
                .read_colors(0)
                .map(|c| c.into_rgb_f32().map(|c| Vec3::from(c).clamp(Vec3::ZERO, Vec3::ONE)).collect::<Vec<_>>())
                .filter(|c| c.len() == n);
            positions.extend(local);
            let flip = world.determinant() < 0.0;
            let mut push = |a: u32, b: u32, c: u32| {
                if a.max(b).max(c) as usize >= n {
                    return Err(gerr(GltfError::IndexPastVertices { index: a.max(b).max(c), count: n }));
                }
                triangles.push(if flip { [base + a, base + c, base + b] } else { [base + a, base + b, base + c] });
                triangle_materials.push(id);
                Ok(())
            };
            match reader.read_indices() {
                Some(ind) => {
                    let ind: Vec<u32> = ind.into_u32().collect();
                    for t in ind.chunks_exact(3) {
                        push(t[0], t[1], t[2])?;
                    }
                }
                None => {
                    for t in 0..(n / 3) as u32 {
                        push(3 * t, 3 * t + 1, 3 * t + 2)?;
                    }
                }
            }
            prims.push(Prim { base, n, uv: prim_uv.filter(|_| sampled), colors, material: id });
        }
    }
    let nv = positions.len();
    let mut mesh = TriMesh::new(positions, triangles);
    if prims.iter().any(|p| p.uv.is_some()) {
        mesh.uvs = vec![Vec2::ZERO; nv];
        for p in &prims {
            if let Some(uv) = &p.uv {
                mesh.uvs[p.base as usize..p.base as usize + p.n].copy_from_slice(uv);
            }
        }
    }
    if prims.iter().any(|p| p.colors.is_some()) {
        mesh.colors = vec![Vec3::ONE; nv];
        for p in &prims {
            if let Some(c) = &p.colors {
                mesh.colors[p.base as usize..p.base as usize + p.n].copy_from_slice(c);
            }
        }
    }
    debug_assert!(prims.iter().all(|p| (p.material as usize) < materials.len()));
    let several = materials.len() > 1;
    let out =
        TexturedMesh { mesh, materials, triangle_materials: if several { triangle_materials } else { Vec::new() } };
    check_mesh(path, &out)?;
    Ok(out)
}

/// Decodes glTF image `i` (embedded or external) to 8-bit sRGB RGB.
fn decode_gltf_image(
    document: &gltf::Document,
    i: usize,
    dir: &Path,
    buffers: &[gltf::buffer::Data],
    path: &Path,
) -> Result<image::RgbImage, MeshIoError> {
    let terr =
        |source: TextureError| MeshIoError::Texture { path: path.to_path_buf(), texture: format!("image {i}"), source };
    let image = document.images().nth(i).ok_or_else(|| terr(TextureError::NoSuchImage))?;
    // Every source goes through `decode_texture` (every format it reads, bounded size, header checked against the
    // bytes): external files, buffer views and `data:` URIs (decoded here: the glTF importer's decoder has none of
    // these checks).
    match image.source() {
        gltf::image::Source::Uri { uri, mime_type } => match uri.strip_prefix("data:") {
            None => load_texture(dir, &percent_decode(uri), path).map(|t| (*t).clone()),
            Some(data) => {
                let (header, payload) = data.split_once(',').ok_or_else(|| terr(TextureError::DataUriWithoutComma))?;
                let bytes = if header.ends_with(";base64") {
                    base64::decode(payload).map_err(|e| terr(TextureError::DataUriBase64(e)))?
                } else {
                    percent_decode(payload).into_bytes()
                };
                let mime = mime_type.or_else(|| header.split(';').next());
                decode_texture(&bytes, mime.and_then(image::ImageFormat::from_mime_type)).map_err(terr)
            }
        },
        gltf::image::Source::View { view, mime_type } => {
            let data = buffers.get(view.buffer().index()).map(|d| &d.0[..]).unwrap_or(&[]);
            let bytes = data.get(view.offset()..view.offset().saturating_add(view.length()));
            let bytes = bytes.ok_or_else(|| terr(TextureError::ViewPastBuffer))?;
            decode_texture(bytes, image::ImageFormat::from_mime_type(mime_type)).map_err(terr)
        }
    }
}

/// The chunks of a binary glTF (`.glb`) container, as [`glb_chunks`] finds them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GlbChunks<'a> {
    /// The JSON chunk's data (the glTF document).
    pub json: &'a [u8],
    /// The BIN chunk's data (buffer 0 without a `uri`), when the file has one.
    pub bin: Option<&'a [u8]>,
    /// Bytes after the header's declared total length (ignored).
    pub trailing: usize,
}

/// Size of the GLB header (magic, version, total length) and of a chunk header (length, type).
const GLB_HEADER: usize = 12;
const GLB_CHUNK_HEADER: usize = 8;

/// Splits a GLB container (glTF 2.0, section 4.4) into its chunks, checking the container before anything
/// trusts its lengths: the `glTF` magic, version 2, a declared total length that covers a header and a chunk
/// header and is not past the end of the data, every chunk's length within the declared length, a JSON chunk
/// first, at most one BIN chunk and only right after it. Chunks of other types are skipped, as the
/// specification requires. The error says what is wrong, with the offsets involved.
pub fn glb_chunks(bytes: &[u8]) -> Result<GlbChunks<'_>, GlbError> {
    let word = |at: usize| bytes.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
    if bytes.len() < GLB_HEADER {
        return Err(GlbError::Short(bytes.len()));
    }
    if !bytes.starts_with(b"glTF") {
        return Err(GlbError::Magic(tag_at(bytes, 0)));
    }
    let version = word(4).unwrap_or(0);
    if version != 2 {
        return Err(GlbError::Version(version));
    }
    let declared = word(8).unwrap_or(0) as usize;
    if declared < GLB_HEADER + GLB_CHUNK_HEADER {
        return Err(GlbError::DeclaredTooShort(declared));
    }
    if declared > bytes.len() {
        return Err(GlbError::Truncated { declared, len: bytes.len() });
    }
    let mut json = None;
    let mut bin = None;
    let mut at = GLB_HEADER;
    let mut index = 0;
    while at < declared {
        let left = declared - at;
        if left < GLB_CHUNK_HEADER {
            return Err(GlbError::ChunkHeader { left, at });
        }
        let length = word(at).unwrap_or(0) as usize;
        let tag = tag_at(bytes, at + 4);
        let data_at = at + GLB_CHUNK_HEADER;
        if length > declared - data_at {
            return Err(GlbError::ChunkTooLong { index, tag, at, length, remain: declared - data_at, declared });
        }
        let data = &bytes[data_at..data_at + length];
        match (&tag, index) {
            (b"JSON", 0) => json = Some(data),
            (_, 0) => return Err(GlbError::FirstNotJson(tag)),
            (b"JSON", _) => return Err(GlbError::SecondJson { index, at }),
            (b"BIN\0", 1) => bin = Some(data),
            (b"BIN\0", _) => return Err(GlbError::MisplacedBin { index, at }),
            _ => {} // an extension's chunk: skipped
        }
        at = data_at + length;
        index += 1;
    }
    let json = json.ok_or(GlbError::NoJson)?;
    Ok(GlbChunks { json, bin, trailing: bytes.len() - declared })
}

/// A 4-byte GLB tag for messages, quoted (printable ASCII as is, other bytes escaped: `"BIN\x00"`).
fn show_tag(tag: &[u8; 4]) -> String {
    format!("\"{}\"", tag.escape_ascii())
}

/// The 4 bytes at `at` (the caller has checked they exist).
fn tag_at(bytes: &[u8], at: usize) -> [u8; 4] {
    [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]
}

/// A GLB container around a JSON chunk and an optional BIN chunk, each padded to 4 bytes (JSON with spaces, BIN
/// with zeros) as the specification requires.
pub fn glb_container(json: &[u8], bin: Option<&[u8]>) -> Result<Vec<u8>, GlbError> {
    let padded = |n: usize| n.div_ceil(4) * 4;
    let total = GLB_HEADER
        + GLB_CHUNK_HEADER
        + padded(json.len())
        + bin.map(|b| GLB_CHUNK_HEADER + padded(b.len())).unwrap_or(0);
    let total32 = u32::try_from(total).map_err(|_| GlbError::TooLarge)?;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&total32.to_le_bytes());
    for (data, tag, pad) in [(Some(json), b"JSON", b' '), (bin, b"BIN\0", 0)] {
        let Some(data) = data else { continue };
        out.extend_from_slice(&(padded(data.len()) as u32).to_le_bytes());
        out.extend_from_slice(tag);
        out.extend_from_slice(data);
        out.resize(out.len() + padded(data.len()) - data.len(), pad);
    }
    Ok(out)
}

/// Checks what `gltf` 1.4's validation does not but its reader relies on (each of these made it panic in
/// `tests/fuzz.rs`; the inputs are in `tests/corpus/glb`, `tests/corpus/gltf`): before validation, that every
/// primitive's accessors exist (validation indexes them) and that images say where their bytes are.
fn check_gltf_references(root: &gltf::json::Root) -> Result<(), GltfError> {
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for index in prim.attributes.values().chain(prim.indices.iter()) {
                if index.value() >= root.accessors.len() {
                    return Err(GltfError::MissingAccessor {
                        mesh: m,
                        primitive: p,
                        accessor: index.value(),
                        count: root.accessors.len(),
                    });
                }
            }
        }
    }
    for (i, image) in root.images.iter().enumerate() {
        match (&image.buffer_view, &image.mime_type, &image.uri) {
            (Some(_), None, _) => return Err(GltfError::ImageWithoutMimeType(i)),
            (None, _, None) => return Err(GltfError::ImageWithoutSource(i)),
            _ => {}
        }
    }
    Ok(())
}

/// After validation: the accessors this reader reads (positions, the first UVs and colours, indices) have the
/// component types and shapes the `gltf` reader handles (others reach an `unreachable!`) and lie inside their
/// buffer views (so the number of elements read is bounded by the file's size).
fn check_primitive_accessors(prim: &gltf::Primitive<'_>) -> Result<(), GltfError> {
    use gltf::accessor::{DataType as T, Dimensions as D};
    use gltf::Semantic;
    for (semantic, acc) in prim.attributes() {
        let allowed: &[(T, D)] = match semantic {
            Semantic::Positions => &[(T::F32, D::Vec3)],
            Semantic::TexCoords(_) => &[(T::F32, D::Vec2), (T::U8, D::Vec2), (T::U16, D::Vec2)],
            Semantic::Colors(_) => &[
                (T::F32, D::Vec3),
                (T::U8, D::Vec3),
                (T::U16, D::Vec3),
                (T::F32, D::Vec4),
                (T::U8, D::Vec4),
                (T::U16, D::Vec4),
            ],
            _ => continue,
        };
        check_accessor(&acc, &format!("{semantic:?}"), allowed)?;
    }
    if let Some(acc) = prim.indices() {
        check_accessor(&acc, "indices", &[(T::U8, D::Scalar), (T::U16, D::Scalar), (T::U32, D::Scalar)])?;
    }
    Ok(())
}

fn check_accessor(
    acc: &gltf::Accessor<'_>,
    what: &str,
    allowed: &[(gltf::accessor::DataType, gltf::accessor::Dimensions)],
) -> Result<(), GltfError> {
    let problem = accessor_problem(acc, allowed);
    problem.map_or(Ok(()), |problem| Err(GltfError::Accessor { index: acc.index(), what: what.to_string(), problem }))
}

/// What [`check_accessor`] finds wrong with `acc`, if anything.
fn accessor_problem(
    acc: &gltf::Accessor<'_>,
    allowed: &[(gltf::accessor::DataType, gltf::accessor::Dimensions)],
) -> Option<AccessorProblem> {
    let kind = (acc.data_type(), acc.dimensions());
    if !allowed.contains(&kind) {
        return Some(AccessorProblem::Kind(kind.0, kind.1));
    }
    // The byte range of `count` elements of `size` bytes at `stride` from `offset` must fit the view.
    let fits = |view: &gltf::buffer::View<'_>, offset: usize, count: usize, size: usize| {
        let stride = view.stride().unwrap_or(size);
        if stride < size {
            return Some(AccessorProblem::Stride { stride, size });
        }
        let end = match count {
            0 => Some(offset),
            n => stride.checked_mul(n - 1).and_then(|s| s.checked_add(offset)).and_then(|e| e.checked_add(size)),
        };
        let view_end = view.offset().checked_add(view.length());
        match (end, view_end) {
            (Some(e), Some(v)) if e <= view.length() && v <= view.buffer().length() => None,
            _ => Some(AccessorProblem::PastView { count, view: view.index() }),
        }
    };
    // glTF requires count >= 1; gltf 1.4.1's reader computes `count - 1` (found by the fuzz harness, input in
    // tests/corpus/glb/accessor-count-zero.glb.bin).
    if acc.count() == 0 {
        return Some(AccessorProblem::ZeroCount);
    }
    if let Some(problem) = acc.view().and_then(|view| fits(&view, acc.offset(), acc.count(), acc.size())) {
        return Some(problem);
    }
    let sparse = acc.sparse()?;
    if sparse.count() == 0 {
        return Some(AccessorProblem::EmptySparse);
    }
    let indices = sparse.indices();
    fits(&indices.view(), indices.offset(), sparse.count(), indices.index_type().size())
        .or_else(|| fits(&sparse.values().view(), sparse.values().offset(), sparse.count(), acc.size()))
}

fn percent_decode(uri: &str) -> String {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' && i + 2 < b.len() {
            if let Ok(v) = u8::from_str_radix(&uri[i + 1..i + 3], 16) {
                out.push(v);
                i += 3;
                continue;
            }
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Encodes a mesh as glTF 2.0 binary: positions, normals, `TEXCOORD_0` (when a material is textured), `COLOR_0`
/// (when the mesh has vertex colours), `u32` indices, one primitive per material (sharing the vertex attributes)
/// with its base colour factor and its texture embedded as PNG (each image once), all unlit
/// (`KHR_materials_unlit`, so viewers show the albedo as the ground truth sees it). A mesh without materials gets
/// one of [`DEFAULT_ALBEDO`] grey when it has no vertex colours, white otherwise, so reading it back gives the same
/// albedo. `name` labels the file in errors.
pub fn glb_bytes(mesh: &TexturedMesh, name: &Path) -> Result<Vec<u8>, MeshIoError> {
    let enc = |message: String| MeshIoError::Encode { path: name.to_path_buf(), message };
    let m = &mesh.mesh;
    let nv = m.positions.len();
    if m.is_empty() {
        return Err(MeshIoError::Empty { path: name.to_path_buf() });
    }
    mesh.validate().map_err(|source| MeshIoError::InvalidMesh { path: name.to_path_buf(), source })?;
    if u32::try_from(nv).is_err() {
        return Err(enc("too many vertices for 32-bit indices".into()));
    }
    let normals: Vec<Vec3> = if m.normals.len() == nv {
        m.normals.clone()
    } else {
        let mut c = m.clone();
        c.compute_normals();
        c.normals
    };
    let colored = m.colors.len() == nv;
    let default_material;
    let materials: &[Material] = if mesh.materials.is_empty() {
        let grey = if colored { Vec3::ONE } else { Vec3::splat(DEFAULT_ALBEDO) };
        default_material = [Material::color("albedo", grey)];
        &default_material
    } else {
        &mesh.materials
    };
    let textured = m.uvs.len() == nv && materials.iter().any(|mat| mat.texture.is_some());

    let mut bin: Vec<u8> = Vec::new();
    let mut views = Vec::new();
    let mut accessors = Vec::new();
    let mut push_view = |bin: &mut Vec<u8>, data: &[u8], target: Option<u32>| -> usize {
        while bin.len() % 4 != 0 {
            bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": data.len()});
        if let Some(t) = target {
            v["target"] = json!(t);
        }
        bin.extend_from_slice(data);
        views.push(v);
        views.len() - 1
    };
    let f32_bytes = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();

    let (lo, hi) = m.bounds().unwrap_or((Vec3::ZERO, Vec3::ZERO));
    let flat: Vec<f32> = m.positions.iter().flat_map(|p| p.to_array()).collect();
    let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
    accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC3",
        "min": lo.to_array(), "max": hi.to_array()}));
    let flat: Vec<f32> = normals.iter().flat_map(|p| p.to_array()).collect();
    let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
    accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC3"}));
    let mut attributes = json!({"POSITION": 0, "NORMAL": 1});
    if textured {
        let flat: Vec<f32> = m.uvs.iter().flat_map(|p| p.to_array()).collect();
        let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
        accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC2"}));
        attributes["TEXCOORD_0"] = json!(accessors.len() - 1);
    }
    if colored {
        let flat: Vec<f32> = m.colors.iter().flat_map(|c| c.clamp(Vec3::ZERO, Vec3::ONE).to_array()).collect();
        let v = push_view(&mut bin, &f32_bytes(&flat), Some(34962));
        accessors.push(json!({"bufferView": v, "componentType": 5126, "count": nv, "type": "VEC3"}));
        attributes["COLOR_0"] = json!(accessors.len() - 1);
    }
    // One primitive per material that has triangles, in material order.
    let mut per_material: Vec<Vec<u8>> = vec![Vec::new(); materials.len()];
    for (t, tri) in m.triangles.iter().enumerate() {
        let k = mesh.triangle_materials.get(t).map_or(0, |&k| k as usize);
        per_material[k].extend(tri.iter().flat_map(|i| i.to_le_bytes()));
    }
    let mut primitives = Vec::new();
    for (k, idx) in per_material.iter().enumerate() {
        if idx.is_empty() {
            continue;
        }
        let v = push_view(&mut bin, idx, Some(34963));
        accessors.push(json!({"bufferView": v, "componentType": 5125, "count": idx.len() / 4, "type": "SCALAR"}));
        primitives.push(json!({"attributes": attributes, "indices": accessors.len() - 1, "material": k, "mode": 4}));
    }
    // Images: each distinct texture once, as PNG.
    let mut images: Vec<(Arc<image::RgbImage>, usize)> = Vec::new();
    let mut json_materials = Vec::new();
    for mat in materials {
        let c = mat.base_color;
        let factor = if c.is_finite() { c.max(Vec3::ZERO) } else { Vec3::ONE };
        let mut material = json!({
            "name": mat.name,
            "pbrMetallicRoughness": {"baseColorFactor": [factor.x, factor.y, factor.z, 1.0],
                "metallicFactor": 0.0, "roughnessFactor": 1.0},
            "extensions": {"KHR_materials_unlit": {}},
        });
        if let (Some(tex), true) = (&mat.texture, textured) {
            let image_index = match images.iter().position(|(t, _)| Arc::ptr_eq(t, tex) || **t == **tex) {
                Some(i) => i,
                None => {
                    let mut png = Vec::new();
                    let encoder = image::codecs::png::PngEncoder::new_with_quality(
                        &mut png,
                        image::codecs::png::CompressionType::Fast,
                        image::codecs::png::FilterType::Adaptive,
                    );
                    image::ImageEncoder::write_image(
                        encoder,
                        tex.as_raw(),
                        tex.width(),
                        tex.height(),
                        image::ExtendedColorType::Rgb8,
                    )
                    .map_err(|e| enc(format!("texture PNG: {e}")))?;
                    let v = push_view(&mut bin, &png, None);
                    images.push((Arc::clone(tex), v));
                    images.len() - 1
                }
            };
            material["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": image_index});
        }
        json_materials.push(material);
    }
    let mut root = json!({
        "asset": {"version": "2.0", "generator": "r2human"},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "subject"}],
        "meshes": [{"primitives": primitives}],
        "materials": json_materials,
    });
    if !images.is_empty() {
        root["images"] =
            json!(images.iter().map(|(_, v)| json!({"bufferView": v, "mimeType": "image/png"})).collect::<Vec<_>>());
        root["samplers"] = json!([{"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497}]);
        root["textures"] = json!((0..images.len()).map(|i| json!({"sampler": 0, "source": i})).collect::<Vec<_>>());
    }
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    root["bufferViews"] = json!(views);
    root["accessors"] = json!(accessors);
    root["buffers"] = json!([{"byteLength": bin.len()}]);
    let js = serde_json::to_vec(&root).map_err(|e| enc(e.to_string()))?;
    glb_container(&js, Some(&bin)).map_err(|source| MeshIoError::Container { path: name.to_path_buf(), source })
}

/// Writes a mesh as `.glb` (see [`glb_bytes`]) atomically: a temporary file in the same folder, then a rename.
pub fn write_glb(path: &Path, mesh: &TexturedMesh) -> Result<(), MeshIoError> {
    let bytes = glb_bytes(mesh, path)?;
    crate::io::npy::write_atomic(path, &bytes).map_err(|source| MeshIoError::Io { path: path.to_path_buf(), source })
}

/// Converts a linear RGB colour in `[0, 1]` to 8-bit sRGB (through a 16k-entry table: at most one level off the
/// exact curve).
pub fn linear_to_srgb8(c: Vec3) -> [u8; 3] {
    const N: usize = 16384;
    static LUT: std::sync::LazyLock<Vec<u8>> = std::sync::LazyLock::new(|| {
        (0..N).map(|i| (linear_to_srgb(i as f32 / (N - 1) as f32) * 255.0 + 0.5) as u8).collect()
    });
    c.to_array().map(|v| {
        let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        LUT[(v * (N - 1) as f32 + 0.5) as usize]
    })
}
