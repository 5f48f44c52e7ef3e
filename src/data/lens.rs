//! COLMAP's camera models (ids 0–17), in f64, with COLMAP's exact arithmetic
//! (`src/colmap/sensor/models.h`): projection of a normalised camera-space point `(u, v, 1)`
//! to a pixel ([`Lens::distort`]) and back ([`Lens::undistort`], Newton iteration with
//! COLMAP's trust region for the models without a closed-form inverse).
//!
//! Pixels follow COLMAP's (and our [`Camera`](super::Camera)'s) convention: the image
//! spans `[0, w] × [0, h]`, pixel centres at `i + 0.5`. The loaders use the lens to
//! resample photos into pinhole images ([`super::capture`]).

use std::fmt;

/// A COLMAP camera model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CameraModel {
    SimplePinhole,
    Pinhole,
    SimpleRadial,
    Radial,
    OpenCv,
    OpenCvFisheye,
    FullOpenCv,
    Fov,
    SimpleRadialFisheye,
    RadialFisheye,
    ThinPrismFisheye,
    RadTanThinPrismFisheye,
    SimpleDivision,
    Division,
    SimpleFisheye,
    Fisheye,
    Eucm,
    Equirectangular,
}

use CameraModel as M;

const MODELS: [(CameraModel, &str, &[&str]); 18] = [
    (M::SimplePinhole, "SIMPLE_PINHOLE", &["f", "cx", "cy"]),
    (M::Pinhole, "PINHOLE", &["fx", "fy", "cx", "cy"]),
    (M::SimpleRadial, "SIMPLE_RADIAL", &["f", "cx", "cy", "k"]),
    (M::Radial, "RADIAL", &["f", "cx", "cy", "k1", "k2"]),
    (
        M::OpenCv,
        "OPENCV",
        &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"],
    ),
    (
        M::OpenCvFisheye,
        "OPENCV_FISHEYE",
        &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"],
    ),
    (
        M::FullOpenCv,
        "FULL_OPENCV",
        &[
            "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6",
        ],
    ),
    (M::Fov, "FOV", &["fx", "fy", "cx", "cy", "omega"]),
    (
        M::SimpleRadialFisheye,
        "SIMPLE_RADIAL_FISHEYE",
        &["f", "cx", "cy", "k"],
    ),
    (
        M::RadialFisheye,
        "RADIAL_FISHEYE",
        &["f", "cx", "cy", "k1", "k2"],
    ),
    (
        M::ThinPrismFisheye,
        "THIN_PRISM_FISHEYE",
        &[
            "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1",
        ],
    ),
    (
        M::RadTanThinPrismFisheye,
        "RAD_TAN_THIN_PRISM_FISHEYE",
        &[
            "fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1",
            "s2", "s3",
        ],
    ),
    (
        M::SimpleDivision,
        "SIMPLE_DIVISION",
        &["f", "cx", "cy", "k"],
    ),
    (M::Division, "DIVISION", &["fx", "fy", "cx", "cy", "k"]),
    (M::SimpleFisheye, "SIMPLE_FISHEYE", &["f", "cx", "cy"]),
    (M::Fisheye, "FISHEYE", &["fx", "fy", "cx", "cy"]),
    (M::Eucm, "EUCM", &["fx", "fy", "cx", "cy", "alpha", "beta"]),
    (M::Equirectangular, "EQUIRECTANGULAR", &["w", "h"]),
];

impl CameraModel {
    /// Every model, in id order.
    pub fn all() -> impl Iterator<Item = CameraModel> {
        MODELS.iter().map(|m| m.0)
    }
    /// COLMAP's model id.
    pub fn id(self) -> i32 {
        self as i32
    }
    pub fn from_id(id: i32) -> Option<CameraModel> {
        usize::try_from(id)
            .ok()
            .and_then(|i| MODELS.get(i))
            .map(|m| m.0)
    }
    /// COLMAP's model name (as in cameras.txt).
    pub fn name(self) -> &'static str {
        MODELS[self as usize].1
    }
    pub fn from_name(name: &str) -> Option<CameraModel> {
        MODELS.iter().find(|m| m.1 == name).map(|m| m.0)
    }
    /// Parameter names, in file order.
    pub fn param_names(self) -> &'static [&'static str] {
        MODELS[self as usize].2
    }
    pub fn num_params(self) -> usize {
        self.param_names().len()
    }
    /// Whether distortion acts on the ray angle θ = atan(r) (COLMAP's fisheye models).
    pub fn is_fisheye(self) -> bool {
        matches!(
            self,
            M::OpenCvFisheye
                | M::SimpleRadialFisheye
                | M::RadialFisheye
                | M::ThinPrismFisheye
                | M::RadTanThinPrismFisheye
                | M::SimpleFisheye
                | M::Fisheye
        )
    }
    /// `"0 SIMPLE_PINHOLE, 1 PINHOLE, …"` for error messages.
    pub fn known_list() -> String {
        MODELS
            .iter()
            .map(|m| format!("{} {}", m.0 as i32, m.1))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

impl fmt::Display for CameraModel {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A perspective camera model with its parameters in pixels: focal lengths, principal
/// point and the model's extra (distortion) parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Lens {
    pub model: CameraModel,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// The model's parameters after the focal lengths and principal point.
    pub extra: Vec<f64>,
}

const EPS: f64 = f64::EPSILON;

impl Lens {
    /// From COLMAP's parameter list. Spherical (equirectangular) cameras are refused: the
    /// renderer is perspective.
    pub fn new(model: CameraModel, params: Vec<f64>) -> Result<Lens, String> {
        if params.len() != model.num_params() {
            return Err(format!(
                "{model} has {} parameters, expected {} ({})",
                params.len(),
                model.num_params(),
                model.param_names().join(", ")
            ));
        }
        if model == M::Equirectangular {
            return Err(
                "EQUIRECTANGULAR (360°) cameras are not supported: the renderer is perspective; \
                 cut the panoramas into perspective views first"
                    .into(),
            );
        }
        let single_f = model.param_names()[0] == "f";
        let (fx, fy, rest) = if single_f {
            (params[0], params[0], &params[1..])
        } else {
            (params[0], params[1], &params[2..])
        };
        let lens = Lens {
            model,
            fx,
            fy,
            cx: rest[0],
            cy: rest[1],
            extra: rest[2..].to_vec(),
        };
        if !(fx > 0.0 && fy > 0.0) || params.iter().any(|v| !v.is_finite()) {
            return Err(format!(
                "{model}: focal lengths must be > 0 and every parameter finite, got {params:?}"
            ));
        }
        Ok(lens)
    }

    /// The parameters in COLMAP's order (single-focal models need `fx == fy`).
    pub fn params(&self) -> Vec<f64> {
        let mut p = if self.model.param_names()[0] == "f" {
            vec![self.fx]
        } else {
            vec![self.fx, self.fy]
        };
        p.extend([self.cx, self.cy]);
        p.extend(&self.extra);
        p
    }

    /// The same lens for an image scaled by `sx × sy` (focal lengths and principal point
    /// scaled per axis; the distortion acts on normalised coordinates and is unchanged).
    pub fn scaled(&self, sx: f64, sy: f64) -> Lens {
        Lens {
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            ..self.clone()
        }
    }

    /// `(fx, fy, cx, cy)`.
    pub fn pinhole(&self) -> (f64, f64, f64, f64) {
        (self.fx, self.fy, self.cx, self.cy)
    }

    /// Whether the lens is an exact pinhole (no distortion model, or all its
    /// coefficients zero for a perspective model).
    pub fn is_pinhole(&self) -> bool {
        match self.model {
            M::SimplePinhole | M::Pinhole => true,
            M::SimpleRadial | M::Radial | M::OpenCv | M::FullOpenCv | M::Fov => {
                self.extra.iter().all(|&v| v == 0.0)
            }
            M::SimpleDivision | M::Division => self.extra[0] == 0.0,
            _ => false,
        }
    }

    /// COLMAP's `ImgFromCam(u, v, 1)`: the pixel where the normalised camera-space point
    /// `(u, v, 1)` is imaged; `None` where the model cannot project it.
    pub fn distort(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let (a, b) = match self.model {
            M::SimplePinhole | M::Pinhole => (u, v),
            M::SimpleRadial | M::Radial | M::OpenCv | M::FullOpenCv => {
                let (du, dv) = self.delta(u, v);
                (u + du, v + dv)
            }
            M::OpenCvFisheye
            | M::SimpleRadialFisheye
            | M::RadialFisheye
            | M::ThinPrismFisheye
            | M::RadTanThinPrismFisheye => {
                let (uu, vv) = fisheye_from_normal(u, v);
                let (du, dv) = self.delta(uu, vv);
                (uu + du, vv + dv)
            }
            M::SimpleFisheye | M::Fisheye => fisheye_from_normal(u, v),
            M::Fov => fov_distortion(self.extra[0], u, v),
            M::SimpleDivision | M::Division => {
                let k = self.extra[0];
                let rho = (u * u + v * v).sqrt();
                let disc_sq = 1.0 - 4.0 * rho * rho * k;
                if disc_sq < 0.0 {
                    return None;
                }
                let r = 2.0 / (1.0 + disc_sq.sqrt());
                return Some((self.fx * r * u + self.cx, self.fy * r * v + self.cy));
            }
            M::Eucm => {
                let (alpha, beta) = (self.extra[0], self.extra[1]);
                let rho2 = beta * (u * u + v * v) + 1.0;
                if rho2 < 0.0 {
                    return None;
                }
                let den = alpha * rho2.sqrt() + (1.0 - alpha);
                if den < EPS {
                    return None;
                }
                (u / den, v / den)
            }
            M::Equirectangular => return None,
        };
        let (x, y) = (self.fx * a + self.cx, self.fy * b + self.cy);
        (x.is_finite() && y.is_finite()).then_some((x, y))
    }

    /// COLMAP's `CamFromImg`: the normalised camera-space point `(u, v)` (at z = 1) that
    /// pixel `(x, y)` sees; `None` where the model cannot invert (Newton did not converge,
    /// or the pixel looks backwards).
    pub fn undistort(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (a, b) = ((x - self.cx) / self.fx, (y - self.cy) / self.fy);
        match self.model {
            M::SimplePinhole | M::Pinhole => Some((a, b)),
            M::SimpleRadial | M::Radial | M::OpenCv | M::FullOpenCv => {
                self.iterative_undistortion(a, b)
            }
            M::OpenCvFisheye
            | M::SimpleRadialFisheye
            | M::RadialFisheye
            | M::ThinPrismFisheye
            | M::RadTanThinPrismFisheye => {
                let (uu, vv) = self.iterative_undistortion(a, b)?;
                Some(normal_from_fisheye(uu, vv))
            }
            M::SimpleFisheye | M::Fisheye => Some(normal_from_fisheye(a, b)),
            M::Fov => Some(fov_undistortion(self.extra[0], a, b)),
            M::SimpleDivision | M::Division => {
                let denom = 1.0 + self.extra[0] * (a * a + b * b);
                Some((a / denom, b / denom))
            }
            M::Eucm => {
                let (alpha, beta) = (self.extra[0], self.extra[1]);
                let r2 = a * a + b * b;
                let gamma = 1.0 - alpha;
                let radicand = 1.0 - (alpha - gamma) * beta * r2;
                if radicand < 0.0 {
                    return None;
                }
                let helper_den = alpha * radicand.sqrt() + gamma;
                if helper_den < EPS {
                    return None;
                }
                let helper = (1.0 - alpha * alpha * beta * r2) / helper_den;
                if helper < EPS {
                    return None;
                }
                Some((a / helper, b / helper))
            }
            M::Equirectangular => None,
        }
    }

    /// The model's `Distortion(extra, u, v)`: the offset `(du, dv)` added to `(u, v)`
    /// (normalised coordinates; θ-scaled ones for the fisheye models).
    fn delta(&self, u: f64, v: f64) -> (f64, f64) {
        let e = &self.extra;
        match self.model {
            M::SimpleRadial | M::SimpleRadialFisheye => {
                let radial = e[0] * (u * u + v * v);
                (u * radial, v * radial)
            }
            M::Radial | M::RadialFisheye => {
                let r2 = u * u + v * v;
                let radial = e[0] * r2 + e[1] * r2 * r2;
                (u * radial, v * radial)
            }
            M::OpenCv => {
                let (k1, k2, p1, p2) = (e[0], e[1], e[2], e[3]);
                let (u2, uv, v2) = (u * u, u * v, v * v);
                let r2 = u2 + v2;
                let radial = k1 * r2 + k2 * r2 * r2;
                (
                    u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2),
                    v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2),
                )
            }
            M::OpenCvFisheye => {
                let t2 = u * u + v * v;
                let (t4, t6, t8) = (t2 * t2, t2 * t2 * t2, t2 * t2 * t2 * t2);
                let radial = e[0] * t2 + e[1] * t4 + e[2] * t6 + e[3] * t8;
                (u * radial, v * radial)
            }
            M::FullOpenCv => {
                let (k1, k2, p1, p2, k3, k4, k5, k6) =
                    (e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]);
                let (u2, uv, v2) = (u * u, u * v, v * v);
                let r2 = u2 + v2;
                let (r4, r6) = (r2 * r2, r2 * r2 * r2);
                let radial =
                    (1.0 + k1 * r2 + k2 * r4 + k3 * r6) / (1.0 + k4 * r2 + k5 * r4 + k6 * r6);
                (
                    u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2) - u,
                    v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2) - v,
                )
            }
            M::ThinPrismFisheye => {
                let (k1, k2, p1, p2, k3, k4, sx1, sy1) =
                    (e[0], e[1], e[2], e[3], e[4], e[5], e[6], e[7]);
                let (u2, uv, v2) = (u * u, u * v, v * v);
                let r2 = u2 + v2;
                let (r4, r6, r8) = (r2 * r2, r2 * r2 * r2, r2 * r2 * r2 * r2);
                let radial = k1 * r2 + k2 * r4 + k3 * r6 + k4 * r8;
                (
                    u * radial + 2.0 * p1 * uv + p2 * (r2 + 2.0 * u2) + sx1 * r2,
                    v * radial + 2.0 * p2 * uv + p1 * (r2 + 2.0 * v2) + sy1 * r2,
                )
            }
            M::RadTanThinPrismFisheye => {
                let t2 = u * u + v * v;
                let (mut th_radial, mut power) = (1.0, 1.0);
                for k in &e[0..6] {
                    power *= t2;
                    th_radial += k * power;
                }
                let (p0, p1, s) = (e[6], e[7], &e[8..12]);
                let (x, y) = (th_radial * u, th_radial * v);
                let (x2, y2, xy) = (x * x, y * y, x * y);
                let r2 = x2 + y2;
                let r4 = r2 * r2;
                let dx = x + (2.0 * p1 * xy + p0 * (r2 + 2.0 * x2)) + (s[0] * r2 + s[1] * r4);
                let dy = y + (2.0 * p0 * xy + p1 * (r2 + 2.0 * y2)) + (s[2] * r2 + s[3] * r4);
                (dx - u, dy - v)
            }
            _ => (0.0, 0.0),
        }
    }

    /// COLMAP's `IterativeUndistortion`: solves `x + delta(x) = x0` by Newton's method
    /// (Jacobian by central differences) with its trust region; `None` if 100 steps do
    /// not converge.
    fn iterative_undistortion(&self, u0: f64, v0: f64) -> Option<(f64, f64)> {
        let (mut u, mut v) = (u0, v0);
        for _ in 0..100 {
            let (du, dv) = self.delta(u, v);
            let hu = (1e-6 * u.abs()).max(1e-9);
            let hv = (1e-6 * v.abs()).max(1e-9);
            let (a1, b1) = self.delta(u + hu, v);
            let (a0, b0) = self.delta(u - hu, v);
            let (c1, d1) = self.delta(u, v + hv);
            let (c0, d0) = self.delta(u, v - hv);
            let j = [
                [1.0 + (a1 - a0) / (2.0 * hu), (c1 - c0) / (2.0 * hv)],
                [(b1 - b0) / (2.0 * hu), 1.0 + (d1 - d0) / (2.0 * hv)],
            ];
            let r = [u + du - u0, v + dv - v0];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            if det == 0.0 || !det.is_finite() {
                return None;
            }
            let mut s = [
                (j[1][1] * r[0] - j[0][1] * r[1]) / det,
                (j[0][0] * r[1] - j[1][0] * r[0]) / det,
            ];
            let radius_sqr = ((u * u + v * v) * 0.1 * 0.1).max(0.1 * 0.1);
            let s2 = s[0] * s[0] + s[1] * s[1];
            if s2 > radius_sqr {
                let f = (radius_sqr / s2).sqrt();
                s = [s[0] * f, s[1] * f];
            }
            u -= s[0];
            v -= s[1];
            if s[0] * s[0] + s[1] * s[1] < 1e-10 {
                return Some((u, v));
            }
        }
        None
    }
}

/// Normalised pinhole `(u, v)` → equidistant fisheye coordinates `θ·(u, v)/r`.
fn fisheye_from_normal(u: f64, v: f64) -> (f64, f64) {
    let r = (u * u + v * v).sqrt();
    if r > EPS {
        let s = r.atan() / r;
        (u * s, v * s)
    } else {
        (u, v)
    }
}

/// Inverse of [`fisheye_from_normal`] (COLMAP leaves θ ≥ π/2 unscaled).
fn normal_from_fisheye(uu: f64, vv: f64) -> (f64, f64) {
    let theta = (uu * uu + vv * vv).sqrt();
    let tct = theta * theta.cos();
    if tct > EPS {
        let s = theta.sin() / tct;
        (uu * s, vv * s)
    } else {
        (uu, vv)
    }
}

fn fov_distortion(omega: f64, u: f64, v: f64) -> (f64, f64) {
    let radius2 = u * u + v * v;
    let omega2 = omega * omega;
    let factor = if omega2 < 1e-4 {
        (omega2 * radius2) / 3.0 - omega2 / 12.0 + 1.0
    } else if radius2 < 1e-4 {
        let t = (omega / 2.0).tan();
        (-2.0 * t * (4.0 * radius2 * t * t - 3.0)) / (3.0 * omega)
    } else {
        let radius = radius2.sqrt();
        (radius * 2.0 * (omega / 2.0).tan()).atan() / (radius * omega)
    };
    (u * factor, v * factor)
}

fn fov_undistortion(omega: f64, u: f64, v: f64) -> (f64, f64) {
    let radius2 = u * u + v * v;
    let omega2 = omega * omega;
    let factor = if omega2 < 1e-4 {
        (omega2 * radius2) / 3.0 - omega2 / 12.0 + 1.0
    } else if radius2 < 1e-4 {
        (omega * (omega * omega * radius2 + 3.0)) / (6.0 * (omega / 2.0).tan())
    } else {
        let radius = radius2.sqrt();
        (radius * omega).tan() / (radius * 2.0 * (omega / 2.0).tan())
    };
    (u * factor, v * factor)
}
