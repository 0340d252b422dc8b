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
/// Geometric warp of the photo (level 0 of the hole-filling pyramid).
pub const WARP: &[u8] = spv!("warp.comp");
/// Push-pull hole filling: pull step.
pub const PULL: &[u8] = spv!("pull.comp");
/// Push-pull hole filling: push step.
pub const PUSH: &[u8] = spv!("push.comp");
/// End of the warp: premultiplied RGBA with the target coverage.
pub const RESOLVE: &[u8] = spv!("resolve.comp");
/// Spatial fusion (Eq. 8).
pub const FUSION: &[u8] = spv!("fusion.comp");
/// Feature warp for the neural decoder.
pub const FEATURES: &[u8] = spv!("features.comp");
