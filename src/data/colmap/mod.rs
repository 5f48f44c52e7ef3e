//! COLMAP sparse models: `cameras`, `images` and `points3D`, binary (`.bin`) or text
//! (`.txt`), read and written exactly as COLMAP does.
//!
//! Formats (COLMAP's `src/colmap/scene/reconstruction_io.cc`; little-endian):
//!
//! ```text
//! cameras.bin   u64 n; n × { u32 camera_id, i32 model_id, u64 width, u64 height,
//!                            f64 params[num_params(model)] }
//! images.bin    u64 n; n × { u32 image_id, f64 qw qx qy qz, f64 tx ty tz, u32 camera_id,
//!                            name (bytes up to a NUL), u64 m,
//!                            m × { f64 x, f64 y, i64 point3D_id (−1: none) } }
//! points3D.bin  u64 n; n × { u64 point3D_id, f64 x y z, u8 r g b, f64 error, u64 t,
//!                            t × { u32 image_id, u32 point2D_idx } }
//! cameras.txt   CAMERA_ID MODEL_NAME WIDTH HEIGHT PARAMS...
//! images.txt    IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME
//!               X Y POINT3D_ID  X Y POINT3D_ID ...     (second line, may be empty)
//! points3D.txt  POINT3D_ID X Y Z R G B ERROR IMAGE_ID POINT2D_IDX ...
//! ```
//!
//! `#` starts a comment line. The pose `(q, t)` maps world to camera (`x_cam =
//! R(q)·x_world + t`), camera axes x right, y down, z forward (as
//! [`Camera`](super::Camera)). A missing
//! `points3D` file, points without tracks and images without 2-D points are all fine
//! (nerfstudio exports have none). Errors name the file and the entry.

mod write;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use write::{write_bin, write_txt};

use super::lens::CameraModel;
use crate::error::{Error, Result};

/// One COLMAP camera (intrinsics shared by the images that name it).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    pub id: u32,
    pub model: CameraModel,
    pub width: u64,
    pub height: u64,
    /// In the model's order (see [`CameraModel::param_names`]), pixels of `width × height`.
    pub params: Vec<f64>,
}

/// One registered image.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation as a unit quaternion `[w, x, y, z]`.
    pub qvec: [f64; 4],
    /// World-to-camera translation.
    pub tvec: [f64; 3],
    pub camera_id: u32,
    /// File name relative to the image folder.
    pub name: String,
    /// Observed 2-D points: pixel position and the 3-D point id (−1: none).
    pub points2d: Vec<([f64; 2], i64)>,
}

/// One triangulated point.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapPoint {
    pub id: u64,
    pub xyz: [f64; 3],
    pub rgb: [u8; 3],
    pub error: f64,
    /// `(image_id, point2D_idx)` observations.
    pub track: Vec<(u32, u32)>,
}

/// A COLMAP sparse model.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Reconstruction {
    pub cameras: BTreeMap<u32, ColmapCamera>,
    pub images: BTreeMap<u32, ColmapImage>,
    pub points: Vec<ColmapPoint>,
}

impl ColmapImage {
    /// World-to-camera rotation matrix (rows), from the normalised quaternion.
    pub fn rotation(&self) -> [[f64; 3]; 3] {
        let n = self.qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
        let [w, x, y, z] = self.qvec.map(|v| v / n);
        [
            [
                1.0 - 2.0 * (y * y + z * z),
                2.0 * (x * y - w * z),
                2.0 * (x * z + w * y),
            ],
            [
                2.0 * (x * y + w * z),
                1.0 - 2.0 * (x * x + z * z),
                2.0 * (y * z - w * x),
            ],
            [
                2.0 * (x * z - w * y),
                2.0 * (y * z + w * x),
                1.0 - 2.0 * (x * x + y * y),
            ],
        ]
    }

    /// Camera-to-world `[R | c]` (OpenCV axes), as [`Camera::c2w`](super::Camera).
    pub fn c2w(&self) -> [[f64; 4]; 3] {
        let r = self.rotation();
        let t = self.tvec;
        // R^T and c = −R^T t.
        std::array::from_fn(|i| {
            let c = -(r[0][i] * t[0] + r[1][i] * t[1] + r[2][i] * t[2]);
            [r[0][i], r[1][i], r[2][i], c]
        })
    }
}

/// Where a sparse model lives: `DIR/sparse/0`, `DIR/sparse`, `DIR/colmap/sparse/0`, or
/// `DIR` itself — the first holding a `cameras.bin` or `cameras.txt`.
pub fn find_model(dir: &Path) -> Option<PathBuf> {
    [
        dir.join("sparse/0"),
        dir.join("sparse"),
        dir.join("colmap/sparse/0"),
        dir.to_path_buf(),
    ]
    .into_iter()
    .find(|d| d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file())
}

/// Reads the model in `dir` (a folder with `cameras`, `images`, `points3D`): the binary
/// files when `cameras.bin` exists, else the text files. Cross-checks that every image's
/// camera exists.
pub fn read_model(dir: &Path) -> Result<Reconstruction> {
    let bin = dir.join("cameras.bin").is_file();
    let ext = if bin { "bin" } else { "txt" };
    let file = |stem: &str| dir.join(format!("{stem}.{ext}"));
    let read = |p: &Path| {
        std::fs::read(p).map_err(|error| Error::Io {
            path: p.display().to_string(),
            error,
        })
    };
    let (cams, imgs) = (file("cameras"), file("images"));
    let pts = file("points3D");
    let cameras = if bin {
        parse_cameras_bin(&read(&cams)?, &cams)?
    } else {
        parse_cameras_txt(&text(&read(&cams)?, &cams)?, &cams)?
    };
    let images = if bin {
        parse_images_bin(&read(&imgs)?, &imgs)?
    } else {
        parse_images_txt(&text(&read(&imgs)?, &imgs)?, &imgs)?
    };
    let points = if !pts.is_file() {
        Vec::new()
    } else if bin {
        parse_points_bin(&read(&pts)?, &pts)?
    } else {
        parse_points_txt(&text(&read(&pts)?, &pts)?, &pts)?
    };
    // COLMAP writes finite positions: NaN was dropped without a word further on, +Inf
    // refused without naming the file.
    if let Some(p) = points.iter().find(|p| p.xyz.iter().any(|v| !v.is_finite())) {
        return Err(invalid(
            &pts,
            format!(
                "point {} is at {:?}, not a finite position: the model is damaged; export \
                 it from COLMAP again (or remove the point)",
                p.id, p.xyz
            ),
        ));
    }
    for img in images.values() {
        if !cameras.contains_key(&img.camera_id) {
            return Err(invalid(
                &imgs,
                format!(
                    "image {} (`{}`) uses camera {}, which {} does not define",
                    img.id,
                    img.name,
                    img.camera_id,
                    cams.display()
                ),
            ));
        }
    }
    Ok(Reconstruction {
        cameras,
        images,
        points,
    })
}

fn invalid(path: &Path, msg: String) -> Error {
    Error::Invalid(format!("{}: {msg}", path.display()))
}

fn text(bytes: &[u8], path: &Path) -> Result<String> {
    String::from_utf8(bytes.to_vec())
        .map_err(|e| invalid(path, format!("not UTF-8 text ({e}); is it a binary file?")))
}

// ---------------------------------------------------------------------------------------
// Binary

/// A little-endian cursor whose errors name the file, the entry and the byte offset.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
    path: &'a Path,
}

impl<'a> Cursor<'a> {
    fn new(bytes: &'a [u8], path: &'a Path) -> Cursor<'a> {
        Cursor {
            bytes,
            pos: 0,
            path,
        }
    }

    fn take(&mut self, n: usize, what: &dyn Fn() -> String) -> Result<&'a [u8]> {
        if self.bytes.len() - self.pos < n {
            return Err(invalid(
                self.path,
                format!(
                    "truncated: {} needs {n} bytes at offset {}, the file has {} (re-export the model)",
                    what(),
                    self.pos,
                    self.bytes.len()
                ),
            ));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }
    fn u64(&mut self, what: &dyn Fn() -> String) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn i64(&mut self, what: &dyn Fn() -> String) -> Result<i64> {
        Ok(i64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn u32(&mut self, what: &dyn Fn() -> String) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn i32(&mut self, what: &dyn Fn() -> String) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().unwrap()))
    }
    fn f64(&mut self, what: &dyn Fn() -> String) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().unwrap()))
    }
    fn f64s<const N: usize>(&mut self, what: &dyn Fn() -> String) -> Result<[f64; N]> {
        let mut v = [0.0; N];
        for x in &mut v {
            *x = self.f64(what)?;
        }
        Ok(v)
    }
    /// A count, bounded by what the rest of the file could hold at `min_bytes` each.
    fn count(&mut self, min_bytes: usize, what: &dyn Fn() -> String) -> Result<usize> {
        let n = self.u64(what)?;
        let rest = (self.bytes.len() - self.pos) as u64;
        if min_bytes > 0 && n > rest / min_bytes as u64 {
            return Err(invalid(
                self.path,
                format!(
                    "{} says {n} entries, but only {rest} bytes follow (at least {min_bytes} each): truncated or corrupt",
                    what()
                ),
            ));
        }
        Ok(n as usize)
    }
    fn finish(&self) -> Result<()> {
        if self.pos != self.bytes.len() {
            return Err(invalid(
                self.path,
                format!(
                    "{} trailing bytes after the last entry: corrupt, or not a COLMAP file",
                    self.bytes.len() - self.pos
                ),
            ));
        }
        Ok(())
    }
}

fn parse_cameras_bin(bytes: &[u8], path: &Path) -> Result<BTreeMap<u32, ColmapCamera>> {
    let mut c = Cursor::new(bytes, path);
    let n = c.count(24, &|| "the camera count".into())?;
    let mut out = BTreeMap::new();
    for k in 0..n {
        let entry = |f: &'static str| move || format!("camera #{k} ({f})");
        let id = c.u32(&entry("camera_id"))?;
        let model_id = c.i32(&entry("model_id"))?;
        let model = CameraModel::from_id(model_id).ok_or_else(|| {
            invalid(
                path,
                format!(
                    "camera {id}: unknown camera model id {model_id} (known: {})",
                    CameraModel::known_list()
                ),
            )
        })?;
        let width = c.u64(&entry("width"))?;
        let height = c.u64(&entry("height"))?;
        let mut params = Vec::with_capacity(model.num_params());
        for _ in 0..model.num_params() {
            params.push(c.f64(&entry("params"))?);
        }
        insert_camera(
            &mut out,
            ColmapCamera {
                id,
                model,
                width,
                height,
                params,
            },
            path,
        )?;
    }
    c.finish()?;
    Ok(out)
}

fn parse_images_bin(bytes: &[u8], path: &Path) -> Result<BTreeMap<u32, ColmapImage>> {
    let mut c = Cursor::new(bytes, path);
    let n = c.count(69, &|| "the image count".into())?;
    let mut out = BTreeMap::new();
    for k in 0..n {
        let entry = |f: &'static str| move || format!("image #{k} ({f})");
        let id = c.u32(&entry("image_id"))?;
        let qvec = c.f64s::<4>(&entry("qvec"))?;
        let tvec = c.f64s::<3>(&entry("tvec"))?;
        let camera_id = c.u32(&entry("camera_id"))?;
        let rest = &bytes[c.pos..];
        let len = rest.iter().position(|&b| b == 0).ok_or_else(|| {
            invalid(
                path,
                format!("truncated: image {id}'s name has no terminating NUL byte"),
            )
        })?;
        let name = String::from_utf8(rest[..len].to_vec())
            .map_err(|_| invalid(path, format!("image {id}: the name is not UTF-8")))?;
        c.pos += len + 1;
        let what = || format!("image {id} (`{name}`) points2D");
        let m = c.count(24, &what)?;
        let mut points2d = Vec::with_capacity(m);
        for _ in 0..m {
            let xy = c.f64s::<2>(&what)?;
            points2d.push((xy, c.i64(&what)?));
        }
        insert_image(
            &mut out,
            ColmapImage {
                id,
                qvec,
                tvec,
                camera_id,
                name,
                points2d,
            },
            path,
        )?;
    }
    c.finish()?;
    Ok(out)
}

fn parse_points_bin(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut c = Cursor::new(bytes, path);
    let n = c.count(43, &|| "the point count".into())?;
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let entry = |f: &'static str| move || format!("point #{k} ({f})");
        let id = c.u64(&entry("point3D_id"))?;
        let xyz = c.f64s::<3>(&entry("xyz"))?;
        let rgb = c.take(3, &entry("rgb"))?;
        let rgb = [rgb[0], rgb[1], rgb[2]];
        let error = c.f64(&entry("error"))?;
        let t = c.count(8, &entry("track length"))?;
        let mut track = Vec::with_capacity(t);
        for _ in 0..t {
            let image = c.u32(&entry("track"))?;
            track.push((image, c.u32(&entry("track"))?));
        }
        out.push(ColmapPoint {
            id,
            xyz,
            rgb,
            error,
            track,
        });
    }
    c.finish()?;
    Ok(out)
}

fn insert_camera(
    out: &mut BTreeMap<u32, ColmapCamera>,
    cam: ColmapCamera,
    path: &Path,
) -> Result<()> {
    if cam.width == 0 || cam.height == 0 || cam.width > 1 << 20 || cam.height > 1 << 20 {
        return Err(invalid(
            path,
            format!(
                "camera {}: image size {}×{} is empty or absurd",
                cam.id, cam.width, cam.height
            ),
        ));
    }
    if let Some(i) = cam.params.iter().position(|v| !v.is_finite()) {
        return Err(invalid(
            path,
            format!(
                "camera {}: parameter {} ({}) is not finite",
                cam.id,
                i,
                cam.model.param_names()[i]
            ),
        ));
    }
    let id = cam.id;
    if out.insert(id, cam).is_some() {
        return Err(invalid(path, format!("camera id {id} appears twice")));
    }
    Ok(())
}

fn insert_image(out: &mut BTreeMap<u32, ColmapImage>, img: ColmapImage, path: &Path) -> Result<()> {
    let finite = img.qvec.iter().chain(&img.tvec).all(|v| v.is_finite());
    let qn = img.qvec.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !finite || !(0.5..2.0).contains(&qn) {
        return Err(invalid(
            path,
            format!(
                "image {} (`{}`): the pose is not a rigid transform (quaternion {:?}, norm {qn}; translation {:?})",
                img.id, img.name, img.qvec, img.tvec
            ),
        ));
    }
    if img.name.is_empty() {
        return Err(invalid(path, format!("image {} has an empty name", img.id)));
    }
    let id = img.id;
    if out.insert(id, img).is_some() {
        return Err(invalid(path, format!("image id {id} appears twice")));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------
// Text

/// Non-comment lines with their 1-based line numbers (images.txt keeps empty lines: the
/// points line of an image without points is empty).
fn data_lines(text: &str, keep_empty: bool) -> Vec<(usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.starts_with('#') && (keep_empty || !l.is_empty()))
        .collect()
}

fn field<T: std::str::FromStr>(path: &Path, line: usize, what: &str, s: Option<&str>) -> Result<T> {
    let s = s.ok_or_else(|| invalid(path, format!("line {line}: missing {what}")))?;
    s.parse().map_err(|_| {
        invalid(
            path,
            format!("line {line}: {what} `{s}` is not a valid number"),
        )
    })
}

fn parse_cameras_txt(text: &str, path: &Path) -> Result<BTreeMap<u32, ColmapCamera>> {
    let mut out = BTreeMap::new();
    for (line, l) in data_lines(text, false) {
        let mut it = l.split_whitespace();
        let id = field(path, line, "CAMERA_ID", it.next())?;
        let name = it
            .next()
            .ok_or_else(|| invalid(path, format!("line {line}: missing MODEL")))?;
        let model = CameraModel::from_name(name).ok_or_else(|| {
            invalid(
                path,
                format!(
                    "line {line}: camera {id}: unknown camera model `{name}` (known: {})",
                    CameraModel::known_list()
                ),
            )
        })?;
        let width = field(path, line, "WIDTH", it.next())?;
        let height = field(path, line, "HEIGHT", it.next())?;
        let params: Vec<f64> = it
            .map(|s| field(path, line, "a parameter", Some(s)))
            .collect::<Result<_>>()?;
        if params.len() != model.num_params() {
            return Err(invalid(
                path,
                format!(
                    "line {line}: camera {id} ({}) has {} parameters, the model needs {} ({})",
                    model.name(),
                    params.len(),
                    model.num_params(),
                    model.param_names().join(", ")
                ),
            ));
        }
        insert_camera(
            &mut out,
            ColmapCamera {
                id,
                model,
                width,
                height,
                params,
            },
            path,
        )?;
    }
    Ok(out)
}

fn parse_images_txt(text: &str, path: &Path) -> Result<BTreeMap<u32, ColmapImage>> {
    let mut out = BTreeMap::new();
    let lines = data_lines(text, true);
    let mut k = 0;
    while k < lines.len() {
        let (line, l) = lines[k];
        if l.is_empty() {
            k += 1;
            continue;
        }
        let mut it = l.split_whitespace();
        let id: u32 = field(path, line, "IMAGE_ID", it.next())?;
        let mut q = [0.0; 4];
        for (v, n) in q.iter_mut().zip(["QW", "QX", "QY", "QZ"]) {
            *v = field(path, line, n, it.next())?;
        }
        let mut t = [0.0; 3];
        for (v, n) in t.iter_mut().zip(["TX", "TY", "TZ"]) {
            *v = field(path, line, n, it.next())?;
        }
        let camera_id = field(path, line, "CAMERA_ID", it.next())?;
        // The name is the rest of the line (COLMAP names may contain spaces).
        let name = l
            .splitn(10, char::is_whitespace)
            .nth(9)
            .map(str::trim)
            .unwrap_or("")
            .to_string();
        if name.is_empty() {
            return Err(invalid(
                path,
                format!("line {line}: image {id} has no NAME"),
            ));
        }
        let mut points2d = Vec::new();
        if let Some(&(pline, p)) = lines.get(k + 1) {
            let v: Vec<&str> = p.split_whitespace().collect();
            if !v.len().is_multiple_of(3) {
                return Err(invalid(
                    path,
                    format!(
                        "line {pline}: image {id}'s points line has {} values, not triples X Y POINT3D_ID",
                        v.len()
                    ),
                ));
            }
            for c in v.chunks_exact(3) {
                points2d.push((
                    [
                        field(path, pline, "X", Some(c[0]))?,
                        field(path, pline, "Y", Some(c[1]))?,
                    ],
                    field(path, pline, "POINT3D_ID", Some(c[2]))?,
                ));
            }
        }
        insert_image(
            &mut out,
            ColmapImage {
                id,
                qvec: q,
                tvec: t,
                camera_id,
                name,
                points2d,
            },
            path,
        )?;
        k += 2;
    }
    Ok(out)
}

fn parse_points_txt(text: &str, path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut out = Vec::new();
    for (line, l) in data_lines(text, false) {
        let v: Vec<&str> = l.split_whitespace().collect();
        if v.len() < 8 || !(v.len() - 8).is_multiple_of(2) {
            return Err(invalid(
                path,
                format!(
                    "line {line}: expected POINT3D_ID X Y Z R G B ERROR then (IMAGE_ID POINT2D_IDX) pairs, got {} values",
                    v.len()
                ),
            ));
        }
        let f = |i: usize, what: &str| field::<f64>(path, line, what, Some(v[i]));
        let b = |i: usize, what: &str| field::<u8>(path, line, what, Some(v[i]));
        let track = v[8..]
            .chunks_exact(2)
            .map(|c| {
                Ok((
                    field(path, line, "IMAGE_ID", Some(c[0]))?,
                    field(path, line, "POINT2D_IDX", Some(c[1]))?,
                ))
            })
            .collect::<Result<_>>()?;
        out.push(ColmapPoint {
            id: field(path, line, "POINT3D_ID", Some(v[0]))?,
            xyz: [f(1, "X")?, f(2, "Y")?, f(3, "Z")?],
            rgb: [b(4, "R")?, b(5, "G")?, b(6, "B")?],
            error: f(7, "ERROR")?,
            track,
        });
    }
    Ok(out)
}
