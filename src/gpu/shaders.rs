//! SPIR-V of the shaders in `shaders/`, compiled by `build.rs` (naga) at build time.

macro_rules! spv {
    ($name:literal) => {
        include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".spv"))
    };
}

/// Mesh rasterisation, vertex stage.
pub const RASTER_VERT: &[u8] = spv!("raster.vert");
/// Mesh rasterisation, fragment stage.
pub const RASTER_FRAG: &[u8] = spv!("raster.frag");
/// VR composite over the equirectangular panorama.
pub const PANORAMA: &[u8] = spv!("panorama.comp");
/// AR alpha layer (sanitised premultiplied RGBA).
pub const AR: &[u8] = spv!("ar.comp");
/// Linear float output to packed 8-bit sRGB (window and screenshots).
pub const ENCODE: &[u8] = spv!("encode.comp");
/// Flow, Z-map (Eq. 4) and visibility (Eq. 9).
pub const FLOW: &[u8] = spv!("flow.comp");
