//! Camera paths for `svraster render --path`: an orbit around what the training cameras
//! look at, a smooth fly-through of the training cameras (SVRaster's), or nerfstudio's
//! `camera_path.json`; frames written as PNGs and, for an `.mp4`, encoded by the
//! system's ffmpeg (H.264). ffmpeg rather than an encoder crate: the maintained Rust
//! H.264 encoders wrap C libraries (openh264) that would add a C build to every build
//! for one optional output, while ffmpeg is one `apt-get install` where videos are
//! wanted — and when it is missing the frames are kept and the message says so.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _};
use glam::{DMat3, DQuat, DVec3};
use svraster::data::Camera;
use svraster::scene::WorldFrame;

/// The cameras of path `kind` (`orbit`, `spiral`, `train` or a camera_path.json file) through the
/// training cameras `train` (model frame), `frames` of them at `size` with horizontal
/// field of view `fov_x` (radians; None: the first training camera's). `scene_centre`
/// (model frame: the model's main region) is what a spiral looks at.
pub fn path_cameras(
    kind: &str,
    train: &[Camera],
    frames: usize,
    size: (u32, u32),
    fov_x: Option<f64>,
    world: &WorldFrame,
    scene_centre: Option<[f64; 3]>,
) -> anyhow::Result<Vec<Camera>> {
    if train.len() < 2 {
        bail!(
            "a camera path needs at least 2 training cameras, the split has {}",
            train.len()
        );
    }
    let first = &train[0];
    let fov = fov_x.unwrap_or(2.0 * (0.5 * first.width as f64 / first.fx).atan());
    let (w, h) = size;
    match kind {
        "orbit" => {
            if frames == 0 {
                bail!("--frames must be at least 1");
            }
            if viewing_agreement(train) >= FORWARD_AGREEMENT {
                eprintln!(
                    "note: these training cameras all look one way (a forward-facing \
                     capture): an orbit sees the scene from sides no photo shows, mostly \
                     empty; --path spiral stays within the capture"
                );
            }
            let centre = look_centre(train);
            let up = mean_up(train);
            let pos: Vec<DVec3> = train.iter().map(|c| DVec3::from(c.origin())).collect();
            let radius = pos.iter().map(|p| (*p - centre).length()).sum::<f64>() / pos.len() as f64;
            // Mean height above the centre along `up`, and the first camera's azimuth.
            let height = pos.iter().map(|p| (*p - centre).dot(up)).sum::<f64>() / pos.len() as f64;
            let ring = (radius * radius - height * height).max(1e-12).sqrt();
            let e1 = {
                let d = pos[0] - centre;
                let flat = d - up * d.dot(up);
                if flat.length() > 1e-9 * radius {
                    flat.normalize()
                } else {
                    up.any_orthonormal_vector()
                }
            };
            let e2 = up.cross(e1);
            Ok((0..frames)
                .map(|i| {
                    let a = std::f64::consts::TAU * i as f64 / frames as f64;
                    let eye = centre + up * height + (e1 * a.cos() + e2 * a.sin()) * ring;
                    Camera::look_at(eye.into(), centre.into(), up.into(), fov, w, h)
                })
                .collect())
        }
        "spiral" => {
            if frames == 0 {
                bail!("--frames must be at least 1");
            }
            let agree = viewing_agreement(train);
            if agree < FORWARD_AGREEMENT {
                bail!(
                    "--path spiral is for forward-facing captures (cameras looking one way); \
                     these training cameras look around (mean viewing direction {agree:.2} \
                     of unit length): use --path orbit"
                );
            }
            Ok(spiral(
                train,
                frames,
                fov,
                w,
                h,
                scene_centre.map(DVec3::from),
            ))
        }
        "train" => {
            if frames < 2 {
                bail!("--frames must be at least 2 for the `train` path");
            }
            Ok(fly_through(train, frames, fov, w, h))
        }
        file => nerfstudio_path(Path::new(file), world, w, h),
    }
}

/// The length of the training cameras' mean viewing direction: 1 when all look the same
/// way, about 0 when they look around.
fn viewing_agreement(train: &[Camera]) -> f64 {
    let f: DVec3 = train
        .iter()
        .map(|c| DVec3::from(c.rotate([0.0, 0.0, 1.0])))
        .sum();
    f.length() / train.len() as f64
}

/// The [`viewing_agreement`] from which cameras count as forward-facing.
const FORWARD_AGREEMENT: f64 = 0.7;

/// NeRF's spiral for forward-facing captures: around the mean camera position, in its
/// mean image plane with the 90th-percentile spread of the cameras along each of its
/// axes, two turns with half the rate along the viewing axis, looking along the mean
/// viewing direction at the depth of `scene_centre` (the model's main region), else of
/// the point the cameras look at (at least one spread ahead). The cameras' axes alone
/// mislead on real captures: on llff_flower their least-squares point lies 86 units
/// behind the cameras, the scene 22–222 ahead.
fn spiral(
    train: &[Camera],
    frames: usize,
    fov: f64,
    w: u32,
    h: u32,
    scene_centre: Option<DVec3>,
) -> Vec<Camera> {
    let n = train.len() as f64;
    let pos: Vec<DVec3> = train.iter().map(|c| DVec3::from(c.origin())).collect();
    let mean = pos.iter().copied().sum::<DVec3>() / n;
    let fwd = train
        .iter()
        .map(|c| DVec3::from(c.rotate([0.0, 0.0, 1.0])))
        .sum::<DVec3>()
        .try_normalize()
        .unwrap_or(DVec3::Z);
    let up = mean_up(train);
    let right = fwd
        .cross(-up)
        .try_normalize()
        .unwrap_or(fwd.any_orthonormal_vector());
    let down = fwd.cross(right);
    let spread = |axis: DVec3| -> f64 {
        let mut d: Vec<f64> = pos.iter().map(|p| (*p - mean).dot(axis).abs()).collect();
        d.sort_by(f64::total_cmp);
        d[((d.len() - 1) as f64 * 0.9).round() as usize].max(1e-6)
    };
    let (rx, ry, rz) = (spread(right), spread(down), spread(fwd));
    let ahead = |p: DVec3| Some((p - mean).dot(fwd)).filter(|d| *d > 0.0);
    let depth = scene_centre
        .and_then(ahead)
        .or_else(|| ahead(look_centre(train)))
        .unwrap_or(0.0)
        .max(rx.max(ry).max(rz));
    let focus = mean + fwd * depth;
    (0..frames)
        .map(|i| {
            let t = 2.0 * std::f64::consts::TAU * i as f64 / frames as f64;
            let eye = mean
                + right * (rx * t.cos())
                + down * (ry * t.sin())
                + fwd * (rz * (0.5 * t).sin());
            Camera::look_at(eye.into(), focus.into(), up.into(), fov, w, h)
        })
        .collect()
}

/// The point closest to every training camera's optical axis (least squares): what
/// they look at.
fn look_centre(cams: &[Camera]) -> DVec3 {
    let mut a = DMat3::ZERO;
    let mut b = DVec3::ZERO;
    for c in cams {
        let o = DVec3::from(c.origin());
        let d = DVec3::from(c.rotate([0.0, 0.0, 1.0])).normalize();
        let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * o;
    }
    if a.determinant().abs() < 1e-12 {
        // Parallel axes (a forward-facing capture): a point ahead of the mean camera.
        let n = cams.len() as f64;
        let o: DVec3 = cams.iter().map(|c| DVec3::from(c.origin())).sum::<DVec3>() / n;
        let d: DVec3 = cams
            .iter()
            .map(|c| DVec3::from(c.rotate([0.0, 0.0, 1.0])))
            .sum::<DVec3>();
        return o + d.normalize_or_zero();
    }
    a.inverse() * b
}

/// The training cameras' mean up direction (OpenCV: −y on screen).
fn mean_up(cams: &[Camera]) -> DVec3 {
    let s: DVec3 = cams
        .iter()
        .map(|c| -DVec3::from(c.rotate([0.0, 1.0, 0.0])))
        .sum();
    s.try_normalize().unwrap_or(DVec3::Z)
}

/// `frames` cameras along the training cameras in order: positions on a Catmull–Rom
/// spline through them, orientations slerped, the field of view `fov`.
fn fly_through(train: &[Camera], frames: usize, fov: f64, w: u32, h: u32) -> Vec<Camera> {
    let pos: Vec<DVec3> = train.iter().map(|c| DVec3::from(c.origin())).collect();
    let rot: Vec<DQuat> = train
        .iter()
        .map(|c| DQuat::from_mat3(&c.rotation()))
        .collect();
    let n = pos.len();
    (0..frames)
        .map(|i| {
            let t = i as f64 / (frames - 1) as f64 * (n - 1) as f64;
            let k = (t.floor() as usize).min(n - 2);
            let u = t - k as f64;
            let p = |j: isize| pos[j.clamp(0, n as isize - 1) as usize];
            let (p0, p1, p2, p3) = (
                p(k as isize - 1),
                p(k as isize),
                p(k as isize + 1),
                p(k as isize + 2),
            );
            let eye = 0.5
                * (2.0 * p1
                    + (p2 - p0) * u
                    + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * u * u
                    + (3.0 * p1 - p0 - 3.0 * p2 + p3) * u * u * u);
            let (q1, mut q2) = (rot[k], rot[k + 1]);
            if q1.dot(q2) < 0.0 {
                q2 = -q2;
            }
            let r = DMat3::from_quat(q1.slerp(q2, u));
            let c2w =
                std::array::from_fn(|row| [r.x_axis[row], r.y_axis[row], r.z_axis[row], eye[row]]);
            let fx = 0.5 * w as f64 / (0.5 * fov).tan();
            Camera {
                width: w,
                height: h,
                fx,
                fy: fx,
                cx: 0.5 * w as f64,
                cy: 0.5 * h as f64,
                c2w,
                near: train[0].near,
            }
        })
        .collect()
}

/// The cameras of a nerfstudio `camera_path.json`: `camera_path[i].camera_to_world` (16
/// numbers, row-major, OpenGL axes, the dataset's world coordinates) and `.fov`
/// (vertical, degrees); `render_width`/`render_height` unless `--size` says otherwise.
fn nerfstudio_path(path: &Path, world: &WorldFrame, w: u32, h: u32) -> anyhow::Result<Vec<Camera>> {
    let text = std::fs::read_to_string(path).with_context(|| {
        format!(
            "--path {}: not orbit, spiral, train or a readable camera_path.json",
            path.display()
        )
    })?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .with_context(|| format!("{} is not valid JSON", path.display()))?;
    if let Some(t) = v["camera_type"].as_str().filter(|t| *t != "perspective") {
        bail!(
            "{}: camera_type `{t}`: only perspective camera paths are rendered (export the \
             path with a perspective camera)",
            path.display()
        );
    }
    let frames = v["camera_path"]
        .as_array()
        .with_context(|| format!("{}: no `camera_path` array", path.display()))?;
    let mut out = Vec::with_capacity(frames.len());
    for (i, f) in frames.iter().enumerate() {
        let bad = |what: &str| anyhow::anyhow!("{}: camera_path[{i}]: {what}", path.display());
        let m: Vec<f64> = f["camera_to_world"]
            .as_array()
            .ok_or_else(|| bad("no `camera_to_world`"))?
            .iter()
            .map(|x| x.as_f64())
            .collect::<Option<_>>()
            .ok_or_else(|| bad("`camera_to_world` holds a non-number"))?;
        if m.len() != 16 || m.iter().any(|x| !x.is_finite()) {
            bail!(bad("`camera_to_world` is not 16 finite numbers"));
        }
        let fov_y = f["fov"]
            .as_f64()
            .ok_or_else(|| bad("no `fov` (vertical, degrees)"))?;
        if !(fov_y > 0.0 && fov_y < 180.0) {
            bail!(bad("`fov` is not in (0, 180) degrees"));
        }
        let gl: [[f64; 4]; 4] = std::array::from_fn(|r| std::array::from_fn(|c| m[4 * r + c]));
        // A pose: a rotation (orthonormal, determinant 1) and a translation. An all-zero
        // or scaled, sheared or mirrored matrix rendered blank or distorted frames.
        let r = DMat3::from_cols_array_2d(&std::array::from_fn(|c| {
            std::array::from_fn(|row| gl[row][c])
        }));
        let off = (r.transpose() * r - DMat3::IDENTITY).to_cols_array();
        if off.iter().any(|x| x.abs() > 1e-3) || (r.determinant() - 1.0).abs() > 1e-3 {
            bail!(bad(&format!(
                "`camera_to_world` is not a rigid pose (its 3×3 part has determinant {:.3} \
                 and is not a rotation): write rotation and translation only",
                r.determinant()
            )));
        }
        if gl[3] != [0.0, 0.0, 0.0, 1.0] {
            bail!(bad("`camera_to_world`'s last row is not 0 0 0 1"));
        }
        let fov_x = 2.0 * ((0.5 * fov_y.to_radians()).tan() * w as f64 / h as f64).atan();
        let cam = Camera::from_opengl(gl, fov_x, w, h);
        out.push(world.camera_to_model(&cam));
    }
    if out.is_empty() {
        bail!("{}: `camera_path` is empty", path.display());
    }
    Ok(out)
}

/// The image size of a nerfstudio camera path (`render_width`, `render_height`).
pub fn nerfstudio_size(path: &Path) -> Option<(u32, u32)> {
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).ok()?).ok()?;
    Some((
        u32::try_from(v["render_width"].as_u64()?).ok()?,
        u32::try_from(v["render_height"].as_u64()?).ok()?,
    ))
}

/// Encodes `dir/frame_%05d.png` into an H.264 MP4 at `out` with the system's ffmpeg.
/// ffmpeg writes into `dir`; the video is then written to `out` as every output is
/// ([`svraster::fsio::write_atomic_with`]: a symlink followed, a pipe written in place).
pub fn encode_mp4(dir: &Path, out: &Path, fps: u32) -> anyhow::Result<()> {
    let tmp = dir.join(".encoded.mp4.tmp");
    let status = std::process::Command::new("ffmpeg")
        .args([
            "-y",
            "-loglevel",
            "error",
            "-framerate",
            &fps.to_string(),
            "-i",
        ])
        .arg(dir.join("frame_%05d.png"))
        .args([
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-c:v",
            "libx264",
            "-pix_fmt",
            "yuv420p",
            "-f",
            "mp4",
        ])
        .arg(&tmp)
        .status();
    match status {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "ffmpeg not found: the frames are in {}; install ffmpeg (Debian: apt-get install \
             ffmpeg) for the MP4, or pass --out DIR for the PNGs alone",
            dir.display()
        ),
        Err(e) => bail!(
            "cannot run ffmpeg: {e}; the frames are in {}",
            dir.display()
        ),
        Ok(s) if !s.success() => {
            let _ = std::fs::remove_file(&tmp);
            bail!("ffmpeg failed ({s}); the frames are in {}", dir.display())
        }
        Ok(_) => {
            let copied = svraster::fsio::write_atomic_with(out, |w| {
                std::io::copy(&mut std::fs::File::open(&tmp)?, w).map(|_| ())
            });
            let _ = std::fs::remove_file(&tmp);
            Ok(copied?)
        }
    }
}

/// Where the frames of `out` go: `out` itself for a folder, `OUT.frames/` beside an
/// `.mp4`.
pub fn frames_dir(out: &Path) -> (PathBuf, bool) {
    let mp4 = out
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("mp4"));
    if mp4 {
        let mut name = out.file_name().unwrap_or_default().to_os_string();
        name.push(".frames");
        (out.with_file_name(name), true)
    } else {
        (out.to_path_buf(), false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Forward-facing cameras on a 3×3 grid looking at a point 4 units ahead.
    fn forward_rig() -> Vec<Camera> {
        let target = [0.0, 0.0, 4.0];
        (0..9)
            .map(|i| {
                let eye = [(i % 3) as f64 * 0.2 - 0.2, (i / 3) as f64 * 0.1 - 0.1, 0.0];
                Camera::look_at(eye, target, [0.0, -1.0, 0.0], 1.0, 40, 30)
            })
            .collect()
    }

    #[test]
    fn spiral_stays_within_the_rig_and_looks_at_its_target() {
        let rig = forward_rig();
        let world = WorldFrame::IDENTITY;
        let cams = path_cameras("spiral", &rig, 24, (40, 30), None, &world, None).unwrap();
        assert_eq!(cams.len(), 24);
        let target = DVec3::new(0.0, 0.0, 4.0);
        for c in &cams {
            let o = DVec3::from(c.origin());
            // Within the cameras' spread (0.2 across, 0.1 up; nothing along the view).
            assert!(
                o.x.abs() <= 0.2 + 1e-9 && o.y.abs() <= 0.1 + 1e-9 && o.z.abs() < 1e-3,
                "{o}"
            );
            let f = DVec3::from(c.rotate([0.0, 0.0, 1.0]));
            assert!(f.dot((target - o).normalize()) > 0.9999, "looks at {f}");
            // Upright: the screen's down is the rig's down.
            assert!(DVec3::from(c.rotate([0.0, 1.0, 0.0])).y > 0.99);
        }
        // Cameras all around (a 360° capture) are refused.
        let around: Vec<Camera> = (0..8)
            .map(|k| {
                let a = std::f64::consts::TAU * k as f64 / 8.0;
                Camera::look_at(
                    [4.0 * a.cos(), 4.0 * a.sin(), 1.0],
                    [0.0; 3],
                    [0.0, 0.0, 1.0],
                    1.0,
                    40,
                    30,
                )
            })
            .collect();
        let e = path_cameras("spiral", &around, 8, (40, 30), None, &world, None).unwrap_err();
        assert!(e.to_string().contains("--path orbit"), "{e}");
    }

    /// On a real forward-facing capture (llff_flower, COLMAP poses, main region from the
    /// cameras and points) every spiral frame sees the scene: most sparse points project
    /// inside each frame. The cameras' axes meet 86 units behind them there, and the
    /// frames looked at a point 4.8 units ahead with the flower at their edge.
    #[test]
    fn spiral_frames_see_a_real_forward_capture() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/llff_flower");
        if !dir.is_dir() {
            println!("skipped: {} is absent", dir.display());
            return;
        }
        let mut cfg = svraster::train::config::TrainConfig::preset("forward").unwrap();
        let source = svraster::data::SourceOptions {
            format: Some(svraster::data::Format::Colmap),
            images: Some("images_8".into()),
            holdout: None,
        };
        let mut ds = svraster::data::load(&dir, "train", 1.0, cfg.background, &source).unwrap();
        svraster::train::bounds::resolve_run(&mut cfg, &mut ds).unwrap();
        let centre = cfg.center.map(f64::from);
        let (w, h) = (126, 95);
        let cams = path_cameras(
            "spiral",
            &ds.cameras(),
            12,
            (w, h),
            None,
            &cfg.world(),
            Some(centre),
        )
        .unwrap();
        for (i, c) in cams.iter().enumerate() {
            let inside = ds
                .points
                .iter()
                .filter(|p| {
                    let q = c.world_to_camera(**p);
                    let (u, v) = (c.fx * q[0] / q[2] + c.cx, c.fy * q[1] / q[2] + c.cy);
                    q[2] > 0.0 && (0.0..w as f64).contains(&u) && (0.0..h as f64).contains(&v)
                })
                .count();
            let share = inside as f64 / ds.points.len() as f64;
            assert!(
                share > 0.6,
                "frame {i}: {:.0} % of the points in view",
                100.0 * share
            );
        }
    }
}
