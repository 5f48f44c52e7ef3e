//! PNG input and output.
//!
//! Images are row-major arrays of `f32` pixels in `[0, 1]`, top row first. Writers clamp
//! to `[0, 1]`, round to 8 bits (NaN writes as 0) and write atomically: the PNG is
//! encoded in memory, written to a temporary file in the destination folder and renamed
//! over the destination, so a failed write never leaves a half-written file behind.
//! [`load_rgba`] reads 8- and 16-bit gray, gray+alpha, RGB and RGBA PNGs.

use std::path::Path;

use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder, ImageFormat};

use crate::error::{Error, Result};

/// Writes an 8-bit RGB PNG from `width × height` row-major pixels.
pub fn save_rgb_png(path: &Path, width: u32, height: u32, rgb: &[[f32; 3]]) -> Result<()> {
    check_len(path, width, height, rgb.len())?;
    let bytes: Vec<u8> = rgb.iter().flatten().map(|&v| to_u8(v)).collect();
    save_png(path, width, height, &bytes, ExtendedColorType::Rgb8)
}

/// Writes an 8-bit RGBA PNG (straight, not premultiplied, alpha) from `width × height`
/// row-major pixels.
pub fn save_rgba_png(path: &Path, width: u32, height: u32, rgba: &[[f32; 4]]) -> Result<()> {
    check_len(path, width, height, rgba.len())?;
    let bytes: Vec<u8> = rgba.iter().flatten().map(|&v| to_u8(v)).collect();
    save_png(path, width, height, &bytes, ExtendedColorType::Rgba8)
}

/// Writes an 8-bit grayscale PNG from `width × height` row-major values.
pub fn save_gray_png(path: &Path, width: u32, height: u32, gray: &[f32]) -> Result<()> {
    check_len(path, width, height, gray.len())?;
    let bytes: Vec<u8> = gray.iter().map(|&v| to_u8(v)).collect();
    save_png(path, width, height, &bytes, ExtendedColorType::L8)
}

/// Writes an 8-bit grayscale PNG of exact values (labels).
pub fn save_gray8_png(path: &Path, width: u32, height: u32, gray: &[u8]) -> Result<()> {
    check_len(path, width, height, gray.len())?;
    save_png(path, width, height, gray, ExtendedColorType::L8)
}

/// Writes a 16-bit grayscale PNG from `width × height` row-major values (the encoder
/// takes native-endian samples and stores them big-endian, as PNG requires).
pub fn save_gray16_png(path: &Path, width: u32, height: u32, gray: &[u16]) -> Result<()> {
    check_len(path, width, height, gray.len())?;
    let bytes: Vec<u8> = gray.iter().flat_map(|v| v.to_ne_bytes()).collect();
    save_png(path, width, height, &bytes, ExtendedColorType::L16)
}

/// The most pixels an image read as input may have: 2^28 (a 16 384² photo; 4 GiB as the
/// f32 RGBA pixels it is read into).
pub const MAX_INPUT_PIXELS: u64 = 1 << 28;

/// Refuses an image whose header announces more than [`MAX_INPUT_PIXELS`] pixels or an
/// edge over [`crate::raster::MAX_IMAGE_EDGE`], before anything is decoded: the size comes
/// from the file (a PNG whose IHDR said 2^31 − 1 rows aborted the process).
pub(crate) fn check_decoded_size(path: &Path, w: u32, h: u32) -> Result<()> {
    let edge = crate::raster::MAX_IMAGE_EDGE;
    if u64::from(w) * u64::from(h) > MAX_INPUT_PIXELS || w > edge || h > edge {
        return Err(Error::Invalid(format!(
            "{}: the header says {w}×{h} pixels, more than the {MAX_INPUT_PIXELS} pixels \
             ({edge} per edge) an input image may have: the file is corrupt, or downscale it \
             first",
            path.display()
        )));
    }
    Ok(())
}

/// Reads a PNG or JPEG (told apart by content) as `(width, height, rgba)`: row-major,
/// values in `[0, 1]`, turned upright by the file's EXIF orientation when it has one.
/// Gray images are replicated to RGB; alpha is 1 where the file has none. The error names
/// the file when it is missing or cannot be decoded.
pub fn load_rgba(path: &Path) -> Result<(u32, u32, Vec<[f32; 4]>)> {
    use image::ImageDecoder;
    let bytes = std::fs::read(path).map_err(|e| io_error(path, e))?;
    let bad = |e: String| {
        Error::Invalid(format!(
            "{}: cannot decode the image ({e}); the file is corrupt or not a PNG/JPEG, \
             re-export it as an 8- or 16-bit PNG or a JPEG",
            path.display()
        ))
    };
    let reader = image::ImageReader::new(std::io::Cursor::new(&bytes))
        .with_guessed_format()
        .map_err(|e| bad(e.to_string()))?;
    match reader.format() {
        Some(ImageFormat::Png) => {}
        // The JPEG decoder fills what a truncated file lacks with grey and succeeds.
        Some(ImageFormat::Jpeg) => jpeg_complete(&bytes).map_err(|why| {
            Error::Invalid(format!(
                "{}: the JPEG {why}: the file is truncated or corrupt (an interrupted copy or \
                 download?); copy or export it again",
                path.display()
            ))
        })?,
        other => return Err(bad(format!("format {other:?} is not supported"))),
    }
    let mut decoder = reader.into_decoder().map_err(|e| bad(e.to_string()))?;
    let (w, h) = decoder.dimensions();
    check_decoded_size(path, w, h)?;
    let orientation = decoder.orientation().map_err(|e| bad(e.to_string()))?;
    let mut img = image::DynamicImage::from_decoder(decoder).map_err(|e| bad(e.to_string()))?;
    img.apply_orientation(orientation);
    use image::DynamicImage as D;
    let (w, h) = (img.width(), img.height());
    if w == 0 || h == 0 {
        return Err(Error::Invalid(format!(
            "{}: image is empty ({w}×{h})",
            path.display()
        )));
    }
    // Exact `v / max` per channel (gray replicates to RGB, missing alpha is opaque).
    let pixels: Vec<[f32; 4]> = match img {
        D::ImageLuma8(_) | D::ImageLumaA8(_) | D::ImageRgb8(_) | D::ImageRgba8(_) => img
            .into_rgba8()
            .pixels()
            .map(|p| p.0.map(|v| v as f32 / 255.0))
            .collect(),
        D::ImageLuma16(_) | D::ImageLumaA16(_) | D::ImageRgb16(_) | D::ImageRgba16(_) => img
            .into_rgba16()
            .pixels()
            .map(|p| p.0.map(|v| v as f32 / 65535.0))
            .collect(),
        other => {
            return Err(Error::Invalid(format!(
                "{}: unsupported pixel format {:?}; use 8- or 16-bit gray/RGB/RGBA",
                path.display(),
                other.color()
            )))
        }
    };
    Ok((w, h, pixels))
}

/// Writes `bytes` to `path` atomically ([`crate::fsio::write_atomic`]).
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::fsio::write_atomic(path, bytes)
}

pub(crate) fn io_error(path: &Path, error: std::io::Error) -> Error {
    Error::Io {
        path: path.display().to_string(),
        error,
    }
}

fn to_u8(v: f32) -> u8 {
    // `as` saturates and maps NaN to 0.
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn check_len(path: &Path, width: u32, height: u32, len: usize) -> Result<()> {
    let expected = width as u64 * height as u64;
    if width == 0 || height == 0 || expected != len as u64 {
        return Err(Error::Invalid(format!(
            "{}: cannot write a {width}×{height} image from {len} pixels",
            path.display()
        )));
    }
    Ok(())
}

fn save_png(
    path: &Path,
    width: u32,
    height: u32,
    bytes: &[u8],
    color: ExtendedColorType,
) -> Result<()> {
    let mut buf = Vec::new();
    PngEncoder::new(&mut buf)
        .write_image(bytes, width, height, color)
        .map_err(|e| Error::Invalid(format!("{}: cannot encode PNG: {e}", path.display())))?;
    write_atomic(path, &buf)
}

/// Whether a JPEG's main image is complete: its segments are walked from the
/// start-of-image marker (lengths skipped, entropy-coded data scanned to the next marker)
/// until the end-of-image marker. Data after it (a motion photo's video) is not read;
/// an EXIF thumbnail's own markers lie inside its APP1 segment and are skipped with it.
pub fn jpeg_complete(bytes: &[u8]) -> std::result::Result<(), String> {
    let n = bytes.len();
    let truncated = |at: usize| format!("ends at byte {at} before its end-of-image marker");
    if n < 2 || bytes[0] != 0xFF || bytes[1] != 0xD8 {
        return Err("has no start-of-image marker".into());
    }
    let mut i = 2;
    loop {
        // The next marker: 0xFF (fill bytes allowed), then its code.
        while i < n && bytes[i] != 0xFF {
            i += 1;
        }
        while i < n && bytes[i] == 0xFF {
            i += 1;
        }
        if i >= n {
            return Err(truncated(n));
        }
        let code = bytes[i];
        i += 1;
        match code {
            0xD9 => return Ok(()),
            0x01 | 0xD0..=0xD8 => continue, // markers without a segment
            _ => {
                if i + 2 > n {
                    return Err(truncated(n));
                }
                let len = usize::from(bytes[i]) << 8 | usize::from(bytes[i + 1]);
                if len < 2 {
                    return Err(format!("has a segment of length {len} at byte {i}"));
                }
                i += len;
                if i > n {
                    return Err(truncated(n));
                }
                if code == 0xDA {
                    // Entropy-coded data: 0xFF is followed by 0x00 (a stuffed byte) or a
                    // restart marker; anything else starts the next marker.
                    loop {
                        if i + 1 >= n {
                            return Err(truncated(n));
                        }
                        let next = bytes[i + 1];
                        if bytes[i] == 0xFF && next != 0x00 && !(0xD0..=0xD7).contains(&next) {
                            break;
                        }
                        i += 1;
                    }
                }
            }
        }
    }
}
