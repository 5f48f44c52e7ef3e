//! Pinhole cameras.
//!
//! Convention (as the paper's reference implementation): camera-to-world `c2w` maps
//! camera coordinates with x right, y down, z forward (OpenCV) to world. Pixel `(u, v)`
//! (column, row; centres at `+0.5`) looks along `((u+0.5−cx)/fx, (v+0.5−cy)/fy, 1)`.
//! Blender/NeRF-synthetic files store OpenGL cameras (y up, looking down −z); the loader
//! converts them with [`Camera::from_opengl`].

use glam::{DMat3, DVec3};

/// A pinhole camera with its image size.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// Camera-to-world rotation (columns = camera axes in world) and translation
    /// (column 3 = camera centre), OpenCV axes.
    pub c2w: [[f64; 4]; 3],
    /// Near plane: geometry closer than this (camera z) is not drawn.
    pub near: f64,
}

/// Default near plane, as the reference implementation.
pub const DEFAULT_NEAR: f64 = 0.02;

impl Camera {
    /// From an OpenGL camera-to-world matrix (Blender `transform_matrix`) and the
    /// horizontal field of view; square pixels, principal point at the image centre.
    pub fn from_opengl(
        c2w_gl: [[f64; 4]; 4],
        camera_angle_x: f64,
        width: u32,
        height: u32,
    ) -> Camera {
        let mut c2w = [[0.0; 4]; 3];
        for (r, row) in c2w.iter_mut().enumerate() {
            row[0] = c2w_gl[r][0];
            row[1] = -c2w_gl[r][1];
            row[2] = -c2w_gl[r][2];
            row[3] = c2w_gl[r][3];
        }
        Camera::centred(c2w, camera_angle_x, width, height)
    }

    /// Square pixels, principal point at the image centre, horizontal field of view.
    fn centred(c2w: [[f64; 4]; 3], fov_x: f64, width: u32, height: u32) -> Camera {
        let fx = 0.5 * width as f64 / (0.5 * fov_x).tan();
        Camera {
            width,
            height,
            fx,
            fy: fx,
            cx: 0.5 * width as f64,
            cy: 0.5 * height as f64,
            c2w,
            near: DEFAULT_NEAR,
        }
    }

    /// A camera at `eye` looking at `target` with `up` roughly up on screen.
    pub fn look_at(
        eye: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        fov_x: f64,
        width: u32,
        height: u32,
    ) -> Camera {
        let (eye, target, up) = (DVec3::from(eye), DVec3::from(target), DVec3::from(up));
        let z = unit(target - eye);
        let x = unit(z.cross(up));
        let y = z.cross(x);
        let c2w = std::array::from_fn(|r| [x[r], y[r], z[r], eye[r]]);
        Camera::centred(c2w, fov_x, width, height)
    }

    /// The same view at another image size (intrinsics scaled per axis).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let sx = width as f64 / self.width as f64;
        let sy = height as f64 / self.height as f64;
        Camera {
            width,
            height,
            fx: self.fx * sx,
            fy: self.fy * sy,
            cx: self.cx * sx,
            cy: self.cy * sy,
            ..self.clone()
        }
    }

    /// Camera centre in world space.
    pub fn origin(&self) -> [f64; 3] {
        [self.c2w[0][3], self.c2w[1][3], self.c2w[2][3]]
    }

    /// Unnormalised camera-space direction of pixel position `(u, v)` (pixel centres
    /// at `i + 0.5`); its z component is 1.
    pub fn camera_dir(&self, u: f64, v: f64) -> [f64; 3] {
        [(u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0]
    }

    /// World-space ray of pixel `(px, py)` through its centre: origin and unit direction.
    pub fn pixel_ray(&self, px: u32, py: u32) -> ([f64; 3], [f64; 3]) {
        let d = self.camera_dir(px as f64 + 0.5, py as f64 + 0.5);
        (self.origin(), unit(self.rotate(d).into()).to_array())
    }

    /// Camera-to-world rotation of a vector.
    pub fn rotate(&self, d: [f64; 3]) -> [f64; 3] {
        (self.rotation() * DVec3::from(d)).to_array()
    }

    /// Camera-to-world rotation (columns = camera axes in world).
    pub fn rotation(&self) -> DMat3 {
        DMat3::from_cols_array_2d(&std::array::from_fn(|c| {
            std::array::from_fn(|r| self.c2w[r][c])
        }))
    }

    /// World-to-camera matrix: rows `[Rᵀ | −Rᵀ·origin]`.
    pub fn w2c(&self) -> [[f64; 4]; 3] {
        let rt = self.rotation().transpose();
        let t = -(rt * DVec3::from(self.origin()));
        std::array::from_fn(|r| {
            let row = rt.row(r);
            [row.x, row.y, row.z, t[r]]
        })
    }

    /// World-to-camera transform of a point.
    pub fn world_to_camera(&self, p: [f64; 3]) -> [f64; 3] {
        let q = DVec3::from(p) - DVec3::from(self.origin());
        (self.rotation().transpose() * q).to_array()
    }

    /// Checks the camera is usable; the message names the problem.
    pub fn validate(&self) -> crate::error::Result<()> {
        let finite = [self.fx, self.fy, self.cx, self.cy, self.near]
            .iter()
            .chain(self.c2w.iter().flatten())
            .all(|v| v.is_finite());
        if !finite {
            return Err(crate::error::Error::Invalid(
                "camera has a non-finite parameter".into(),
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err(crate::error::Error::Invalid(format!(
                "camera image size {}×{} is empty",
                self.width, self.height
            )));
        }
        if self.fx <= 0.0 || self.fy <= 0.0 || self.near <= 0.0 {
            return Err(crate::error::Error::Invalid(format!(
                "camera focal lengths and near plane must be > 0 (fx {}, fy {}, near {})",
                self.fx, self.fy, self.near
            )));
        }
        Ok(())
    }
}

/// `v` scaled to unit length (a true division, as the f64 references in tests/ do).
fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}
