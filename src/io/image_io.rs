//! Reading photos and masks, and writing PNGs atomically (a temporary file in the same folder, then a rename),
//! so a failure never leaves a half-written output.

use std::io::Write;
use std::path::{Path, PathBuf};

use glam::{Vec3, Vec4};
use image::{ImageFormat, ImageReader, Limits};

use crate::buffer::{
    linear_to_srgb, srgb8_to_linear, srgb_to_linear, unpremultiply, GrayImage, Image, RgbImage, RgbaImage,
};

/// The largest side accepted for an input image, in pixels. Larger photos are rejected with advice to downscale,
/// instead of exhausting memory (a 20000x20000 RGBA photo alone needs 1.6 GB decoded).
pub const MAX_INPUT_SIDE: u32 = 8192;

/// Errors of the `io` layer.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be opened or read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a decodable image (corrupt, truncated or an unsupported format).
    #[error("cannot decode {path} as an image ({reason}); is it a complete PNG, JPEG or Radiance .hdr file?")]
    Decode {
        /// The file.
        path: PathBuf,
        /// What the decoder said.
        reason: String,
    },
    /// The image's header (or a WebP frame's) claims a size its bytes cannot hold ([`check_plausible`],
    /// [`check_webp_frames`]): refused before any pixel buffer is allocated.
    #[error("cannot decode {path} as an image ({source}); is it a complete PNG, JPEG or Radiance .hdr file?")]
    Header {
        /// The file.
        path: PathBuf,
        /// What the header claims.
        source: HeaderError,
    },
    /// The image is larger than [`MAX_INPUT_SIDE`].
    #[error("{path} is {width}x{height} pixels; the limit is {max}x{max}: downscale it first (e.g. `convert IN -resize 4096x4096 OUT`)")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
        /// The limit per side.
        max: u32,
    },
    /// A mask does not match its image.
    #[error("mask {path} is {mask_w}x{mask_h} but the image is {image_w}x{image_h}; give a mask of the same size")]
    MaskSize {
        /// The mask file.
        path: PathBuf,
        /// Mask width.
        mask_w: usize,
        /// Mask height.
        mask_h: usize,
        /// Image width.
        image_w: usize,
        /// Image height.
        image_h: usize,
    },
    /// Writing an output failed; nothing was left at the destination.
    #[error("cannot write {path}: {source}")]
    Write {
        /// The destination.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The destination's folder could not be created; nothing was written.
    #[error("cannot write {path}: cannot create folder {}: {source}", folder.display())]
    CreateFolder {
        /// The destination.
        path: PathBuf,
        /// The folder that could not be created.
        folder: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

/// What [`check_plausible`] and [`check_webp_frames`] find wrong in an image's header, before anything is decoded.
/// The loaders wrap it with the file's name ([`IoError::Header`], `MeshIoError::Texture`).
#[derive(Debug, thiserror::Error)]
pub enum HeaderError {
    /// The header claims more pixels than a file of this size and format can encode ([`max_plausible_pixels`]).
    #[error(
        "its header claims {width}x{height} pixels, more than a {len}-byte {} file can hold: it is truncated or \
         corrupt",
        format_name(*format)
    )]
    Implausible {
        /// The format the content was recognised as.
        format: Option<ImageFormat>,
        /// Claimed width.
        width: u32,
        /// Claimed height.
        height: u32,
        /// The file's size in bytes.
        len: u64,
    },
    /// A WebP frame claims to be larger than the canvas it is drawn on.
    #[error("its {kind} frame claims {width}x{height} pixels, larger than its {canvas_width}x{canvas_height} canvas")]
    FrameLargerThanCanvas {
        /// The frame's chunk (`ANMF`, `VP8`, `VP8L`).
        kind: &'static str,
        /// Claimed frame width.
        width: u32,
        /// Claimed frame height.
        height: u32,
        /// The canvas width (`VP8X`, or the enclosing animation frame's).
        canvas_width: u32,
        /// The canvas height.
        canvas_height: u32,
    },
}

/// An image format's name in messages (`PNG`, `WEBP`); empty when the format is unknown.
fn format_name(format: Option<ImageFormat>) -> String {
    format.map(|f| format!("{f:?}").to_uppercase()).unwrap_or_default()
}

/// A decoded photo: linear RGB (straight, not premultiplied) and its alpha channel when the file has one.
#[derive(Clone, Debug)]
pub struct LoadedImage {
    /// Linear RGB in `[0, 1]`.
    pub rgb: RgbImage,
    /// Alpha in `[0, 1]` when the file carries an alpha channel.
    pub alpha: Option<GrayImage>,
}

/// The most pixels an image file of `len` bytes can describe, by format: the format's best compression of the
/// simplest possible content. A header claiming more (a 40-byte PNG claiming 8000x8000 pixels) belongs to a
/// truncated or forged file, refused before any pixel buffer is allocated.
///
/// - PNG: 1-bit pixels (8 per byte) after deflate's largest ratio, 1032:1.
/// - JPEG: an 8x8 block of one channel takes at least 2 bits (a DC difference code and an end-of-block code).
/// - Radiance HDR: old-style run-length markers of 4 bytes repeat the previous pixel up to 255 times, and
///   consecutive markers multiply (a whole scanline in a few markers): counted as 1024 pixels per byte.
/// - GIF: a 12-bit LZW code stands for at most 4096 pixels.
/// - TGA: a run-length packet of at least 2 bytes (header and an 8-bit pixel) stands for at most 128 pixels.
/// - BMP: 256. Encoders write at most 255 pixels per 2-byte RLE run (uncompressed 1-bit BMPs hold 8 per byte);
///   RLE's end-of-bitmap and delta escapes can leave any number of pixels unset, which no texture writer does.
/// - WebP: 65536. Lossless WebP codes a single-colour image at almost 0 bits per pixel: libwebp writes a uniform
///   4096x4096 or 8192x8192 image in about 25,000 pixels per byte (lossy: about 560).
/// - Other formats: no bound (`u64::MAX`); the side limit still applies.
///
/// A constant 4096 pixels are always allowed, so small valid images never hit the bound.
pub fn max_plausible_pixels(format: Option<ImageFormat>, len: u64) -> u64 {
    let per_byte: u64 = match format {
        Some(ImageFormat::Png) => 8 * 1032,
        Some(ImageFormat::Jpeg) => 8 * 64 / 2,
        Some(ImageFormat::Hdr) => 1024,
        Some(ImageFormat::Gif) => 4096 * 8 / 12,
        Some(ImageFormat::Tga) => 128 / 2,
        Some(ImageFormat::Bmp) => 256,
        Some(ImageFormat::WebP) => 65536,
        _ => return u64::MAX,
    };
    len.saturating_mul(per_byte).saturating_add(4096)
}

/// Checks an image's declared size before decoding: within [`MAX_INPUT_SIDE`], not empty, and plausible for a
/// file of `len` bytes ([`max_plausible_pixels`]).
pub fn check_dimensions(
    path: &Path,
    format: Option<ImageFormat>,
    width: u32,
    height: u32,
    len: u64,
) -> Result<(), IoError> {
    if width > MAX_INPUT_SIDE || height > MAX_INPUT_SIDE {
        return Err(IoError::TooLarge { path: path.to_owned(), width, height, max: MAX_INPUT_SIDE });
    }
    if width == 0 || height == 0 {
        return Err(IoError::Decode { path: path.to_owned(), reason: "the image has no pixels".into() });
    }
    check_plausible(format, width, height, len).map_err(|source| IoError::Header { path: path.to_owned(), source })
}

/// Checks only that `width x height` is plausible for `len` bytes of `format` ([`max_plausible_pixels`]); the
/// error says why (for loaders with their own size limits, such as mesh textures).
pub fn check_plausible(format: Option<ImageFormat>, width: u32, height: u32, len: u64) -> Result<(), HeaderError> {
    if width as u64 * height as u64 > max_plausible_pixels(format, len) {
        return Err(HeaderError::Implausible { format, width, height, len });
    }
    Ok(())
}

/// Checks that every frame of a WebP file fits its canvas: the canvas size (the `VP8X` chunk) is what the
/// header reports and what [`check_dimensions`] bounds, but the `image` crate's decoder allocates each `VP8 `/
/// `VP8L` frame at the size that frame's own header claims (a 182-byte file with a 24x16 canvas and a frame
/// claiming 16152x4369 made it allocate 106 MiB; found by `tests/fuzz.rs`, input in `tests/corpus/scan_image`).
/// Animation frames (`ANMF`) are checked the same way, and so is a chunk cut short by the end of the file (the
/// decoder reads what there is: truncated copies of that input allocated 381 MiB). Files that are not RIFF/WebP
/// are left to the decoder.
pub fn check_webp_frames(bytes: &[u8]) -> Result<(), HeaderError> {
    if bytes.len() < 12 || &bytes[..4] != b"RIFF" || &bytes[8..12] != b"WEBP" {
        return Ok(());
    }
    let u24 = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], 0]) + 1;
    let mut canvas: Option<(u32, u32)> = None;
    // Chunk lists to walk: the file's, then each animation frame's with the frame's size.
    type Size = (u32, u32);
    let mut stack: Vec<(&[u8], Option<Size>)> = vec![(&bytes[12..], None)];
    while let Some((mut data, frame)) = stack.pop() {
        while data.len() >= 8 {
            let tag = &data[..4];
            let size = u32::from_le_bytes([data[4], data[5], data[6], data[7]]) as usize;
            // A chunk cut short by the end of the file is still read by the decoder: check what it holds.
            let body = &data[8..data.len().min(8 + size)];
            let claimed = match tag {
                b"VP8X" if body.len() >= 10 && frame.is_none() => {
                    canvas = Some((u24(&body[4..7]), u24(&body[7..10])));
                    None
                }
                b"ANMF" if body.len() >= 16 => {
                    let size = (u24(&body[6..9]), u24(&body[9..12]));
                    stack.push((&body[16..], Some(size)));
                    Some(("ANMF", size))
                }
                b"VP8 " if body.len() >= 10 && body[3..6] == [0x9D, 0x01, 0x2A] => {
                    let dim = |b: &[u8]| u16::from_le_bytes([b[0], b[1]]) as u32 & 0x3FFF;
                    Some(("VP8", (dim(&body[6..8]), dim(&body[8..10]))))
                }
                b"VP8L" if body.len() >= 5 && body[0] == 0x2F => {
                    let bits = u32::from_le_bytes([body[1], body[2], body[3], body[4]]);
                    Some(("VP8L", ((bits & 0x3FFF) + 1, ((bits >> 14) & 0x3FFF) + 1)))
                }
                _ => None,
            };
            if let (Some((kind, (w, h))), Some((cw, ch))) = (claimed, frame.or(canvas)) {
                if w > cw || h > ch {
                    return Err(HeaderError::FrameLargerThanCanvas {
                        kind,
                        width: w,
                        height: h,
                        canvas_width: cw,
                        canvas_height: ch,
                    });
                }
            }
            data = data.get(8 + size + size % 2..).unwrap_or(&[]);
        }
    }
    Ok(())
}

/// Decodes an image with the size checks of [`check_dimensions`] applied to its header first. `open` gives a
/// fresh reader at the start of the data (it is called twice: header, then pixels); `len` is the data's size.
fn decode_checked<R: std::io::BufRead + std::io::Seek>(
    path: &Path,
    len: u64,
    open: impl Fn() -> std::io::Result<ImageReader<R>>,
) -> Result<image::DynamicImage, IoError> {
    let read_err = |e: std::io::Error| IoError::Read { path: path.to_owned(), source: e };
    let decode_err = |e: image::ImageError| IoError::Decode { path: path.to_owned(), reason: e.to_string() };
    let header = open().and_then(|r| r.with_guessed_format()).map_err(read_err)?;
    let format = header.format();
    let (width, height) = header.into_dimensions().map_err(decode_err)?;
    check_dimensions(path, format, width, height, len)?;
    if format == Some(ImageFormat::WebP) {
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut open().map_err(read_err)?.into_inner(), &mut bytes).map_err(read_err)?;
        check_webp_frames(&bytes).map_err(|source| IoError::Header { path: path.to_owned(), source })?;
    }
    let mut reader = open().and_then(|r| r.with_guessed_format()).map_err(read_err)?;
    let mut limits = Limits::default();
    limits.max_image_width = Some(MAX_INPUT_SIDE);
    limits.max_image_height = Some(MAX_INPUT_SIDE);
    reader.limits(limits);
    reader.decode().map_err(decode_err)
}

/// Decodes an image file (PNG, JPEG, HDR, GIF, BMP, TGA, WebP) after checking its declared size ([`check_dimensions`]).
pub fn decode_file(path: &Path) -> Result<image::DynamicImage, IoError> {
    let len = std::fs::metadata(path).map_err(|e| IoError::Read { path: path.to_owned(), source: e })?.len();
    decode_checked(path, len, || ImageReader::open(path))
}

/// Decodes an in-memory image after checking its declared size; `name` labels it in errors.
pub fn decode_bytes(bytes: &[u8], name: &Path) -> Result<image::DynamicImage, IoError> {
    decode_checked(name, bytes.len() as u64, || Ok(ImageReader::new(std::io::Cursor::new(bytes))))
}

/// Decodes a PNG/JPEG photo into linear RGB plus alpha (when present). 8- and 16-bit files are accepted.
pub fn load_image(path: &Path) -> Result<LoadedImage, IoError> {
    Ok(from_dynamic(&decode_file(path)?))
}

/// Decodes an in-memory encoded image (PNG/JPEG), e.g. an embedded asset.
pub fn load_image_bytes(bytes: &[u8], name: &str) -> Result<LoadedImage, IoError> {
    Ok(from_dynamic(&decode_bytes(bytes, Path::new(name))?))
}

/// Converts a decoded image to linear RGB + optional alpha.
pub fn from_dynamic(img: &image::DynamicImage) -> LoadedImage {
    let has_alpha = img.color().has_alpha();
    // 8-bit files (most photos and frames) through the 256-value table, bit for bit the same as the general path.
    if let image::DynamicImage::ImageRgb8(_) | image::DynamicImage::ImageRgba8(_) = img {
        let rgba = img.to_rgba8();
        let size = (rgba.width() as usize, rgba.height() as usize);
        return linear_rgba(rgba.as_raw(), size, has_alpha, srgb8_to_linear, |a| f32::from(a) / 255.0);
    }
    let rgba = img.to_rgba32f();
    let size = (rgba.width() as usize, rgba.height() as usize);
    linear_rgba(rgba.as_raw(), size, has_alpha, srgb_to_linear, |a| a.clamp(0.0, 1.0))
}

/// Interleaved RGBA samples of a `(width, height)` image to linear RGB (`to_linear` per colour sample) and, when
/// `has_alpha`, the alpha (`to_alpha`).
fn linear_rgba<T: Copy>(
    px: &[T],
    (w, h): (usize, usize),
    has_alpha: bool,
    to_linear: impl Fn(T) -> f32,
    to_alpha: impl Fn(T) -> f32,
) -> LoadedImage {
    let rgb = Image::from_fn(w, h, |c, r| {
        let i = (r * w + c) * 4;
        Vec3::new(to_linear(px[i]), to_linear(px[i + 1]), to_linear(px[i + 2]))
    });
    let alpha = has_alpha.then(|| Image::from_fn(w, h, |c, r| to_alpha(px[(r * w + c) * 4 + 3])));
    LoadedImage { rgb, alpha }
}

/// Loads a mask file: its alpha channel when it has one, else its luminance; values in `[0, 1]`.
pub fn load_mask(path: &Path, expect_w: usize, expect_h: usize) -> Result<GrayImage, IoError> {
    let img = decode_file(path)?;
    let (w, h) = (img.width() as usize, img.height() as usize);
    if (w, h) != (expect_w, expect_h) {
        return Err(IoError::MaskSize {
            path: path.to_owned(),
            mask_w: w,
            mask_h: h,
            image_w: expect_w,
            image_h: expect_h,
        });
    }
    let use_alpha = img.color().has_alpha();
    let rgba = img.to_rgba32f();
    let px = rgba.as_raw();
    Ok(Image::from_fn(w, h, |c, r| {
        let i = (r * w + c) * 4;
        let v = if use_alpha { px[i + 3] } else { (px[i] + px[i + 1] + px[i + 2]) / 3.0 };
        v.clamp(0.0, 1.0)
    }))
}

/// Encodes a linear RGB image as 8-bit sRGB.
pub fn to_srgb8(img: &RgbImage) -> image::RgbImage {
    let mut out = image::RgbImage::new(img.width as u32, img.height as u32);
    for (p, v) in out.pixels_mut().zip(&img.data) {
        *p = image::Rgb([q8(v.x), q8(v.y), q8(v.z)]);
    }
    out
}

/// Encodes a premultiplied linear RGBA image as 8-bit sRGB with straight alpha (what PNG stores).
pub fn to_srgba8(img: &RgbaImage) -> image::RgbaImage {
    let mut out = image::RgbaImage::new(img.width as u32, img.height as u32);
    for (p, v) in out.pixels_mut().zip(&img.data) {
        let rgb = unpremultiply(*v);
        let a = if v.w.is_finite() { v.w.clamp(0.0, 1.0) } else { 0.0 };
        *p = image::Rgba([q8(rgb.x), q8(rgb.y), q8(rgb.z), (a * 255.0).round() as u8]);
    }
    out
}

#[inline]
fn q8(linear: f32) -> u8 {
    (linear_to_srgb(linear) * 255.0).round() as u8
}

/// Writes `path` atomically: `write` fills a temporary file in the destination folder, which is then renamed
/// over `path`. On any error the temporary file is removed and `path` is untouched.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>) -> Result<(), IoError> {
    let err = |source: std::io::Error| IoError::Write { path: path.to_owned(), source };
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_owned(),
        _ => PathBuf::from("."),
    };
    std::fs::create_dir_all(&dir).map_err(|source| IoError::CreateFolder {
        path: path.to_owned(),
        folder: dir.clone(),
        source,
    })?;
    let mut tmp = tempfile::Builder::new().prefix(".r2human-").suffix(".part").tempfile_in(&dir).map_err(err)?;
    write(tmp.as_file_mut()).map_err(err)?;
    tmp.as_file_mut().flush().map_err(err)?;
    tmp.persist(path).map_err(|e| err(e.error))?;
    Ok(())
}

/// Saves a linear RGB image as an sRGB PNG, atomically.
pub fn save_rgb_png(path: &Path, img: &RgbImage) -> Result<(), IoError> {
    let buf = to_srgb8(img);
    write_encoded(path, image::DynamicImage::ImageRgb8(buf))
}

/// Saves a premultiplied linear RGBA image as an sRGB PNG with straight alpha, atomically.
pub fn save_rgba_png(path: &Path, img: &RgbaImage) -> Result<(), IoError> {
    let buf = to_srgba8(img);
    write_encoded(path, image::DynamicImage::ImageRgba8(buf))
}

/// Saves a mask / gray image in `[0, 1]` as an 8-bit gray PNG (linear values, no sRGB curve), atomically.
pub fn save_gray_png(path: &Path, img: &GrayImage) -> Result<(), IoError> {
    let mut buf = image::GrayImage::new(img.width as u32, img.height as u32);
    for (p, v) in buf.pixels_mut().zip(&img.data) {
        let v = if v.is_finite() { v.clamp(0.0, 1.0) } else { 0.0 };
        *p = image::Luma([(v * 255.0).round() as u8]);
    }
    write_encoded(path, image::DynamicImage::ImageLuma8(buf))
}

/// Encodes a dynamic image as PNG into `path`, atomically.
pub fn write_encoded(path: &Path, img: image::DynamicImage) -> Result<(), IoError> {
    write_atomic(path, |f| {
        let mut w = std::io::BufWriter::new(f);
        img.write_to(&mut w, image::ImageFormat::Png).map_err(std::io::Error::other)?;
        w.flush()
    })
}

/// Composites a premultiplied RGBA image over a constant background colour (linear), for previews.
pub fn over_background(img: &RgbaImage, background: Vec3) -> RgbImage {
    img.map(|p: &Vec4| p.truncate() + background * (1.0 - p.w))
}

/// CRC-32 (ISO-HDLC, the PNG chunk checksum).
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_8_bit_image_loads_as_the_general_path_loads_it() {
        // The table's path for 8-bit files against the 32-bit float path every other depth takes, with and without
        // alpha: the same bits.
        let rgba = image::RgbaImage::from_fn(16, 16, |x, y| {
            image::Rgba([(x * 16) as u8, (y * 16) as u8, (x * y) as u8, (255 - x * 9) as u8])
        });
        for img in [
            image::DynamicImage::ImageRgba8(rgba.clone()),
            image::DynamicImage::ImageRgb8(image::DynamicImage::ImageRgba8(rgba).to_rgb8()),
        ] {
            let fast = from_dynamic(&img);
            let general = from_dynamic(&image::DynamicImage::ImageRgba32F(img.to_rgba32f()));
            assert_eq!(fast.rgb, general.rgb);
            match (fast.alpha, img.color().has_alpha()) {
                (Some(a), true) => assert_eq!(Some(a), general.alpha),
                (None, false) => {}
                (a, has) => panic!("alpha {:?} for an image with alpha {has}", a.is_some()),
            }
        }
    }

    #[test]
    fn atomic_write_leaves_nothing_on_failure() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("out.png");
        let r = write_atomic(&out, |f| {
            f.write_all(b"partial")?;
            Err(std::io::Error::other("simulated failure"))
        });
        assert!(r.is_err());
        assert!(!out.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "temporary file removed");
    }

    #[test]
    fn png_round_trip_keeps_alpha_and_colour() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("a.png");
        let img = Image::from_fn(4, 3, |c, r| {
            let a = (c as f32) / 3.0;
            (Vec3::new(0.5, 0.25, r as f32 / 2.0) * a).extend(a)
        });
        save_rgba_png(&out, &img).unwrap();
        let back = load_image(&out).unwrap();
        let alpha = back.alpha.unwrap();
        assert!((alpha.get(3, 0) - 1.0).abs() < 1e-6);
        assert!((back.rgb.get(3, 0).x - 0.5).abs() < 0.01);
    }

    #[test]
    fn truncated_and_garbage_files_give_clear_errors() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("g.png");
        save_rgb_png(&good, &Image::new(64, 64, Vec3::splat(0.3))).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let cut = dir.path().join("cut.png");
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let e = load_image(&cut).unwrap_err().to_string();
        assert!(e.contains("cut.png"), "{e}");
        let junk = dir.path().join("junk.jpg");
        std::fs::write(&junk, b"not an image at all").unwrap();
        assert!(matches!(load_image(&junk), Err(IoError::Decode { .. })));
        assert!(matches!(load_image(&dir.path().join("missing.png")), Err(IoError::Read { .. })));
    }

    #[test]
    fn oversized_image_is_refused_from_its_header() {
        // A valid PNG header claiming 20000x20000 pixels: refused before decoding.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("huge.png");
        let mut png = Vec::new();
        {
            let mut enc = png_header_only(&mut png, 20000, 20000);
            enc.flush().unwrap();
        }
        std::fs::write(&path, &png).unwrap();
        match load_image(&path) {
            Err(IoError::TooLarge { width: 20000, height: 20000, .. }) => {}
            other => panic!("expected TooLarge, got {other:?}"),
        }
    }

    #[test]
    fn a_header_larger_than_its_file_can_hold_is_refused() {
        // Closed forms of the bound: 1-bit PNG at deflate's 1032:1, 2 bits per JPEG block, plus 4096 pixels.
        assert_eq!(max_plausible_pixels(Some(ImageFormat::Png), 10), 10 * 8 * 1032 + 4096);
        assert_eq!(max_plausible_pixels(Some(ImageFormat::Jpeg), 1000), 256_000 + 4096);
        assert_eq!(max_plausible_pixels(Some(ImageFormat::Tga), 100), 6400 + 4096);
        assert_eq!(max_plausible_pixels(Some(ImageFormat::Bmp), 100), 25_600 + 4096);
        assert_eq!(max_plausible_pixels(Some(ImageFormat::WebP), 100), 6_553_600 + 4096);
        assert_eq!(max_plausible_pixels(Some(ImageFormat::Tiff), 1), u64::MAX);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("forged.png");
        let mut png = Vec::new();
        png_header_only(&mut png, 8000, 8000).flush().unwrap();
        std::fs::write(&path, &png).unwrap();
        let e = load_image(&path).unwrap_err().to_string();
        assert!(e.contains("forged.png") && e.contains("8000x8000") && e.contains("truncated or corrupt"), "{e}");
        // The same header on a file long enough to hold it passes the check (and then fails to decode).
        assert!(check_dimensions(&path, Some(ImageFormat::Png), 8000, 8000, 64_000_000 / 8256 + 1).is_ok());
    }

    /// Writes a PNG signature, an IHDR chunk and empty IDAT/IEND chunks: a header that claims a size, no pixels.
    fn png_header_only(out: &mut Vec<u8>, w: u32, h: u32) -> std::io::Cursor<&mut Vec<u8>> {
        out.extend_from_slice(&[0x89, b'P', b'N', b'G', 0x0D, 0x0A, 0x1A, 0x0A]);
        let mut ihdr = Vec::new();
        ihdr.extend_from_slice(b"IHDR");
        ihdr.extend_from_slice(&w.to_be_bytes());
        ihdr.extend_from_slice(&h.to_be_bytes());
        ihdr.extend_from_slice(&[8, 6, 0, 0, 0]);
        out.extend_from_slice(&13u32.to_be_bytes());
        out.extend_from_slice(&ihdr);
        out.extend_from_slice(&crc32(&ihdr).to_be_bytes());
        for chunk in [&b"IDAT"[..], &b"IEND"[..]] {
            out.extend_from_slice(&0u32.to_be_bytes());
            out.extend_from_slice(chunk);
            out.extend_from_slice(&crc32(chunk).to_be_bytes());
        }
        std::io::Cursor::new(out)
    }
}
