//! The host's camera: its view, projection and model matrices turned into our pinhole
//! camera and the depth convention of its depth buffer (see the parent module's docs).

use glam::{DMat4, DVec3, DVec4, Mat4};

use crate::camera::Camera;
use crate::error::{Error, Result};

/// The host's camera: matrices in its conventions.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostView {
    /// World to view space (any handedness).
    pub view: Mat4,
    /// View to Vulkan clip space: NDC x right, y down, depth 0..1 (standard or
    /// reverse-Z, finite or infinite far plane). A perspective projection.
    pub projection: Mat4,
    /// The field's coordinates to the host's world (rigid motion, uniform scale).
    pub model: Mat4,
    /// The viewport (and target) size in pixels.
    pub width: u32,
    pub height: u32,
    /// The host draws with a negative-height viewport (VK_KHR_maintenance1), i.e. its
    /// projection has NDC y pointing up.
    pub viewport_y_up: bool,
}

/// How the host's depth values relate to camera depth: at pixel direction `(x', y', 1)`
/// (camera space, `x' = (u − cx)/fx`, `y' = (v − cy)/fy`) a point at camera depth `d`
/// has depth value `z = a·(x', y', 1) + b / d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthConvention {
    pub a: [f64; 3],
    pub b: f64,
    /// Depth decreases with distance (reverse-Z).
    pub reverse: bool,
    /// Camera depth of the near plane on the optical axis.
    pub near: f64,
    /// Camera depth of the far plane on the optical axis (infinite for an infinite
    /// projection).
    pub far: f64,
}

impl DepthConvention {
    /// The value of "nothing here": the far end of the depth range.
    pub fn clear_value(&self) -> f32 {
        if self.reverse {
            0.0
        } else {
            1.0
        }
    }

    /// Depth value of camera depth `d` at camera-space direction `(x', y', 1)`.
    pub fn depth_value(&self, d: f64, x: f64, y: f64) -> f64 {
        self.a[0] * x + self.a[1] * y + self.a[2] + self.b / d
    }

    /// Camera depth of depth value `z` at `(x', y', 1)` (infinite where `z` is at or
    /// beyond the far end of an infinite projection).
    pub fn camera_depth(&self, z: f64, x: f64, y: f64) -> f64 {
        let d = self.b / (z - (self.a[0] * x + self.a[1] * y + self.a[2]));
        if d > 0.0 {
            d
        } else {
            f64::INFINITY
        }
    }

    pub(super) fn packed(&self) -> [f32; 4] {
        [
            self.a[0] as f32,
            self.a[1] as f32,
            self.a[2] as f32,
            self.b as f32,
        ]
    }
}

impl HostView {
    /// The pinhole camera (in the field's coordinates) and depth convention of this view.
    pub fn camera(&self) -> Result<(Camera, DepthConvention)> {
        let bad = |why: &str| Error::Invalid(format!("host view: {why}"));
        if self.width == 0 || self.height == 0 {
            return Err(bad("the viewport is empty"));
        }
        let m: DMat4 = self.projection.as_dmat4() * self.view.as_dmat4() * self.model.as_dmat4();
        if !m.is_finite() {
            return Err(bad("the matrices have a non-finite entry"));
        }
        let (w, h) = (self.width as f64, self.height as f64);
        let sy = if self.viewport_y_up { -1.0 } else { 1.0 };
        let (r0, r1, r2, r3) = (m.row(0), m.row(1), m.row(2), m.row(3));
        if r3.truncate().length() <= 1e-12 * r3.w.abs().max(1.0) {
            return Err(bad(
                "the projection is orthographic (clip w does not depend on the position); \
                 only perspective projections are supported",
            ));
        }
        // Pixel coordinates (centres at i + 0.5) of a world point X: (q0·X, q1·X) / q2·X.
        let q0 = 0.5 * w * (r0 + r3);
        let q1 = 0.5 * h * (sy * r1 + r3);
        let q2 = r3;
        let a = glam::DMat3::from_cols(q0.truncate(), q1.truncate(), q2.truncate()).transpose();
        if a.determinant() <= 0.0 || !a.determinant().is_finite() {
            return Err(bad(
                "the projection mirrors the image: Vulkan's NDC y points down. Flip the \
                 projection's y (projection.y_axis.y *= -1) or set viewport_y_up for a \
                 negative-height viewport",
            ));
        }
        let rows: [[f64; 4]; 4] = [
            q0.to_array(),
            q1.to_array(),
            q2.to_array(),
            [0.0, 0.0, 0.0, 1.0],
        ];
        let (intr, c2w) = crate::data::neus::decompose_projection(&rows)
            .ok_or_else(|| bad("the projection cannot be decomposed into a pinhole camera"))?;
        let mut cam = Camera {
            width: self.width,
            height: self.height,
            fx: intr[0],
            fy: intr[1],
            cx: intr[2],
            cy: intr[3],
            c2w,
            near: crate::camera::DEFAULT_NEAR,
        };
        // The pinhole model has no skew: check it reproduces the projection.
        let c = DVec3::from(cam.origin());
        let rot = cam.rotation();
        let scale = q2.dot(c.extend(1.0) + rot.z_axis.extend(0.0));
        for p in [[0.3, -0.2, 1.0], [-0.4, 0.5, 2.0], [0.1, 0.1, 0.5]] {
            let x = c + rot * DVec3::from(p);
            let hx = x.extend(1.0);
            let (u, v) = (q0.dot(hx) / q2.dot(hx), q1.dot(hx) / q2.dot(hx));
            let (eu, ev) = (cam.cx + cam.fx * p[0] / p[2], cam.cy + cam.fy * p[1] / p[2]);
            if (u - eu).abs() > 1e-6 * w.max(1.0) || (v - ev).abs() > 1e-6 * h.max(1.0) {
                return Err(bad(
                    "the projection has skew or is not a pinhole projection; \
                     only skew-free perspective projections are supported",
                ));
            }
        }
        if scale.is_nan() || scale <= 0.0 {
            return Err(bad("clip w is not positive in front of the camera"));
        }
        // z_ndc = r2·X / r3·X with X = C + d·R·(x', y', 1) and r3·X = scale·d.
        let ra = rot.transpose() * r2.truncate() / scale;
        let b = r2.dot(c.extend(1.0)) / scale;
        if b == 0.0 || !b.is_finite() {
            return Err(bad("the projection's depth does not vary with distance"));
        }
        let reverse = b > 0.0;
        let at = |z: f64| b / (z - ra.z);
        let (near, far) = if reverse {
            (at(1.0), at(0.0))
        } else {
            (at(0.0), at(1.0))
        };
        if !(near > 0.0 && near.is_finite()) {
            return Err(bad(&format!(
                "the near plane is not in front of the camera ({near})"
            )));
        }
        let far = if far > near { far } else { f64::INFINITY };
        cam.near = near;
        cam.validate()?;
        Ok((
            cam,
            DepthConvention {
                a: ra.to_array(),
                b,
                reverse,
                near,
                far,
            },
        ))
    }
}

/// A view/projection pair for `cam` in Vulkan conventions (view space x right, y down,
/// z forward; NDC y down), standard or reverse-Z, with a finite `far` or an infinite
/// one (`None`). The inverse of [`HostView::camera`]; for tests and examples.
pub fn matrices_for(cam: &Camera, far: Option<f64>, reverse: bool) -> (Mat4, Mat4) {
    let w2c = cam.w2c();
    let view = DMat4::from_cols_array_2d(&std::array::from_fn(|c| {
        std::array::from_fn(|r| {
            if r < 3 {
                w2c[r][c]
            } else if c == 3 {
                1.0
            } else {
                0.0
            }
        })
    }));
    let (w, h) = (cam.width as f64, cam.height as f64);
    let n = cam.near;
    // Depth row: z_ndc·d = za·d + zb for camera depth d.
    let (za, zb) = match (far, reverse) {
        (Some(f), false) => (f / (f - n), -f * n / (f - n)),
        (None, false) => (1.0, -n),
        (Some(f), true) => (-n / (f - n), f * n / (f - n)),
        (None, true) => (0.0, n),
    };
    // x_ndc = 2(u/w) − 1 with u = fx·x/z + cx, likewise y.
    let proj = DMat4::from_cols(
        DVec4::new(2.0 * cam.fx / w, 0.0, 0.0, 0.0),
        DVec4::new(0.0, 2.0 * cam.fy / h, 0.0, 0.0),
        DVec4::new(2.0 * cam.cx / w - 1.0, 2.0 * cam.cy / h - 1.0, za, 1.0),
        DVec4::new(0.0, 0.0, zb, 0.0),
    );
    (view.as_mat4(), proj.as_mat4())
}
