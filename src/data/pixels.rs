//! Per-pixel values of views for field fusion (`crate::field`): 8-bit label PNGs and
//! H×W×C float `.npy` feature maps, resampled to a view's size by exact area averaging
//! (the photos' own downscale, [`super::area_resample`]).

use std::path::Path;

use crate::error::{Error, Result};

/// Reads an 8-bit label image: gray (alpha ignored), or RGB(A) whose r, g, b are equal
/// at every pixel. Returns (width, height, row-major values).
pub fn load_labels(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let bytes = std::fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let dims =
        image::ImageReader::with_format(std::io::Cursor::new(&bytes), image::ImageFormat::Png)
            .into_dimensions();
    if let Ok((w, h)) = dims {
        super::image::check_decoded_size(path, w, h)?;
    }
    let img =
        image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| {
            bad(format!(
                "cannot decode it as a PNG ({e}); label images are 8-bit PNGs (lossless: a JPEG's \
             compression would invent labels)"
            ))
        })?;
    use image::DynamicImage as D;
    let (w, h) = (img.width(), img.height());
    if w == 0 || h == 0 {
        return Err(bad(format!("image is empty ({w}×{h})")));
    }
    let values = match img {
        D::ImageLuma8(g) => g.into_raw(),
        D::ImageLumaA8(_) => img.into_luma8().into_raw(),
        D::ImageRgb8(_) | D::ImageRgba8(_) => {
            let rgba = img.into_rgba8();
            let mut out = Vec::with_capacity((w * h) as usize);
            for (i, p) in rgba.pixels().enumerate() {
                let [r, g, b, _] = p.0;
                if r != g || g != b {
                    return Err(bad(format!(
                        "pixel ({}, {}) is ({r}, {g}, {b}): a label image has one value per \
                         pixel (gray, or equal r, g, b)",
                        i as u32 % w,
                        i as u32 / w
                    )));
                }
                out.push(r);
            }
            out
        }
        other => {
            return Err(bad(format!(
                "pixel format {:?}: labels are 8-bit gray or RGB PNGs",
                other.color()
            )))
        }
    };
    Ok((w, h, values))
}

/// Reads a mask as labels {0, 255}: 255 where the mean of its colour channels exceeds
/// one half (any PNG or JPEG [`super::image::load_rgba`] reads; soft edges, slightly
/// different channels and 16 bits allowed). Returns (width, height, values).
pub fn load_mask(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let (w, h, rgba) = super::image::load_rgba(path)?;
    let v = rgba
        .iter()
        .map(|p| if p[0] + p[1] + p[2] > 1.5 { 255 } else { 0 })
        .collect();
    Ok((w, h, v))
}

/// Resamples labels from `w × h` to `ow × oh`: each output pixel takes the label
/// covering most of its footprint (exact area weights; ties go to the lower value).
pub fn resample_labels(w: u32, h: u32, labels: &[u8], ow: u32, oh: u32) -> Vec<u8> {
    if (w, h) == (ow, oh) {
        return labels.to_vec();
    }
    let classes: Vec<u8> = {
        let mut seen = [false; 256];
        labels.iter().for_each(|&l| seen[l as usize] = true);
        (0..=255u8).filter(|&l| seen[l as usize]).collect()
    };
    let k = classes.len();
    let mut onehot = vec![0f32; labels.len() * k];
    for (i, l) in labels.iter().enumerate() {
        onehot[i * k + classes.binary_search(l).unwrap_or(0)] = 1.0;
    }
    let planes = resample_planar(w, h, k as u32, &onehot, ow, oh);
    let np = (ow * oh) as usize;
    (0..np)
        .map(|p| {
            let best = (0..k).fold(0, |b, c| {
                if planes[c * np + p] > planes[b * np + p] {
                    c
                } else {
                    b
                }
            });
            classes[best]
        })
        .collect()
}

/// Reads an H×W×C float `.npy` (f32, f16 or f64; C-order) as (width, height,
/// channels, row-major pixel-interleaved values). Refuses other shapes and NaN/∞.
pub fn load_features(path: &Path) -> Result<(u32, u32, u32, Vec<f32>)> {
    let bad = |m: String| Error::Invalid(format!("{}: {m}", path.display()));
    let bytes = std::fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    let npy = npyz::NpyFile::new(&bytes[..]).map_err(|e| bad(format!("not a .npy file ({e})")))?;
    if npy.order() != npyz::Order::C {
        return Err(bad("array is in Fortran order; save it C-contiguous".into()));
    }
    let shape = npy.shape().to_vec();
    let [h, w, c] = shape[..] else {
        return Err(bad(format!(
            "shape {shape:?}: features are an H×W×C array (C = channels)"
        )));
    };
    if h == 0 || w == 0 || c == 0 || h > u64::from(u32::MAX) || w > u64::from(u32::MAX) {
        return Err(bad(format!("shape {shape:?} is empty or too large")));
    }
    let values: Vec<f32> = match npy.dtype() {
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float => match t.size_field() {
            4 => npy.into_vec::<f32>(),
            8 => npy
                .into_vec::<f64>()
                .map(|v| v.into_iter().map(|x| x as f32).collect()),
            2 => npy.into_vec::<u16>().map(|v| {
                v.into_iter()
                    .map(|b| half::f16::from_bits(b).to_f32())
                    .collect()
            }),
            s => return Err(bad(format!("{}-byte floats: use f32, f16 or f64", s))),
        },
        d => {
            return Err(bad(format!(
                "dtype {d:?}: features are floats (f32, f16, f64)"
            )))
        }
    }
    .map_err(|e| bad(format!("cannot read its values ({e})")))?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        let (p, ch) = (i as u64 / c, i as u64 % c);
        return Err(bad(format!(
            "value at row {}, column {}, channel {ch} is {}: features must be finite",
            p / w,
            p % w,
            values[i]
        )));
    }
    Ok((w as u32, h as u32, c as u32, values))
}

/// Resamples pixel-interleaved `channels`-channel values from `w × h` to `ow × oh` by
/// exact area averaging, into planar `[channels][oh][ow]` (the layout fusion takes).
pub fn resample_planar(
    w: u32,
    h: u32,
    channels: u32,
    values: &[f32],
    ow: u32,
    oh: u32,
) -> Vec<f32> {
    let c = channels as usize;
    let (np, onp) = ((w * h) as usize, (ow * oh) as usize);
    let mut out = vec![0f32; c * onp];
    for first in (0..c).step_by(3) {
        let rgb: Vec<[f32; 3]> = (0..np)
            .map(|p| {
                std::array::from_fn(|k| {
                    if first + k < c {
                        values[p * c + first + k]
                    } else {
                        0.0
                    }
                })
            })
            .collect();
        let r = super::area_resample(w, h, &rgb, ow, oh);
        for (p, v) in r.iter().enumerate() {
            for (k, x) in v.iter().enumerate() {
                if first + k < c {
                    out[(first + k) * onp + p] = *x;
                }
            }
        }
    }
    out
}

/// Writes `values` (C-order f32 of `shape`) as a `.npy` file, atomically.
pub fn save_npy(path: &Path, shape: &[u64], values: &[f32]) -> Result<()> {
    use npyz::WriterBuilder;
    let n: u64 = shape.iter().product();
    if n != values.len() as u64 {
        return Err(Error::Invalid(format!(
            "{}: {} values for shape {shape:?}",
            path.display(),
            values.len()
        )));
    }
    let mut bytes = Vec::with_capacity(values.len() * 4 + 128);
    let io = |e: std::io::Error| Error::Io {
        path: path.display().to_string(),
        error: e,
    };
    let mut w = npyz::WriteOptions::<f32>::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut bytes)
        .begin_nd()
        .map_err(io)?;
    w.extend(values.iter().copied()).map_err(io)?;
    w.finish().map_err(io)?;
    crate::fsio::write_atomic(path, &bytes)
}
