//! The vocabulary every capture loader shares (COLMAP in capture.rs, LLFF, nerfstudio,
//! NeuS): a posed photo before loading ([`Shot`]), where a capture's images are, and the
//! natural name order its views are sorted in.

use std::path::{Path, PathBuf};

use super::lens::Lens;
use crate::error::{Error, Result};

/// One posed photo before loading.
#[derive(Clone, Debug)]
pub struct Shot {
    /// Name in the capture (file name relative to the image folder).
    pub name: String,
    /// The lens for an image of `lens_size`.
    pub lens: Lens,
    pub lens_size: (u64, u64),
    /// Camera-to-world `[R | c]`, OpenCV axes.
    pub c2w: [[f64; 4]; 3],
}

/// Photo file extensions captures are read with (PNG and JPEG).
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "JPG", "jpeg", "PNG", "JPEG"];

/// The image folder of a capture in `dir`.
pub fn image_folder(dir: &Path, choice: Option<&str>) -> Result<PathBuf> {
    if let Some(c) = choice {
        let p = dir.join(c);
        if !p.is_dir() {
            return Err(Error::Invalid(format!(
                "image folder {} does not exist (--images names a folder inside the capture)",
                p.display()
            )));
        }
        return Ok(p);
    }
    let images = dir.join("images");
    if images.is_dir() {
        return Ok(images);
    }
    let mut scaled: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|error| Error::Io {
            path: dir.display().to_string(),
            error,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_dir()
                && p.file_name()
                    .and_then(|n| n.to_str())
                    .and_then(|n| n.strip_prefix("images_"))
                    .is_some_and(|s| s.parse::<u32>().is_ok())
        })
        .collect();
    scaled.sort();
    match scaled.len() {
        1 => Ok(scaled.remove(0)),
        0 => Err(Error::Invalid(format!(
            "{} has no images/ folder (nor an images_N one): where are the photos?",
            dir.display()
        ))),
        _ => Err(Error::Invalid(format!(
            "{} has no images/ folder but several scaled ones ({}): choose one with --images",
            dir.display(),
            scaled
                .iter()
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect::<Vec<_>>()
                .join(", ")
        ))),
    }
}

/// Natural order of names: digit runs compare as numbers (`img2` < `img10`).
pub fn natural_cmp(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (mut a, mut b) = (a.as_bytes(), b.as_bytes());
    loop {
        match (a.first(), b.first()) {
            (None, None) => return Ordering::Equal,
            (None, _) => return Ordering::Less,
            (_, None) => return Ordering::Greater,
            (Some(x), Some(y)) if x.is_ascii_digit() && y.is_ascii_digit() => {
                let na = a.iter().take_while(|c| c.is_ascii_digit()).count();
                let nb = b.iter().take_while(|c| c.is_ascii_digit()).count();
                let (da, db) = (&a[..na], &b[..nb]);
                let ta = da.iter().skip_while(|&&c| c == b'0').count();
                let tb = db.iter().skip_while(|&&c| c == b'0').count();
                let ord = ta
                    .cmp(&tb)
                    .then_with(|| da[na - ta..].cmp(&db[nb - tb..]))
                    .then_with(|| na.cmp(&nb));
                if ord != Ordering::Equal {
                    return ord;
                }
                a = &a[na..];
                b = &b[nb..];
            }
            (Some(x), Some(y)) => {
                if x != y {
                    return x.cmp(y);
                }
                a = &a[1..];
                b = &b[1..];
            }
        }
    }
}
