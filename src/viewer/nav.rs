//! The viewer's navigation: the view being moved (orbit about a pivot, pan, zoom, fly,
//! jumps to cameras), the start view from outside, and the cameras' frusta.

use glam::{DMat3, DQuat, DVec3};

use crate::camera::Camera;
use crate::scene::Scene;

/// The view being navigated: a pose, a pivot distance along the view, and intrinsics
/// relative to the image size.
#[derive(Clone, Debug)]
pub(super) struct Nav {
    /// Camera-to-world rotation (columns: right, down, forward; OpenCV axes).
    rot: DMat3,
    eye: DVec3,
    /// Distance from the eye to the pivot along the view.
    pivot: f64,
    up: DVec3,
    /// fy / height, fx / fy, cx / width, cy / height.
    fy_rel: f64,
    aspect: f64,
    cx_rel: f64,
    cy_rel: f64,
    near: f64,
    /// The scene's size: fly steps, depth range.
    extent: f64,
    centre: DVec3,
}

impl Nav {
    pub(super) fn new(cam: &Camera, up: [f64; 3], scene: &Scene) -> Nav {
        let centre = DVec3::from(scene.center.map(f64::from));
        let mut n = Nav {
            rot: DMat3::IDENTITY,
            eye: DVec3::ZERO,
            pivot: 1.0,
            up: DVec3::from(up).normalize_or(DVec3::Z),
            fy_rel: 1.0,
            aspect: 1.0,
            cx_rel: 0.5,
            cy_rel: 0.5,
            near: cam.near,
            extent: f64::from(scene.extent).max(1e-6),
            centre,
        };
        n.jump(cam);
        n
    }

    /// Takes `cam`'s pose and intrinsics; the pivot is the scene centre's depth along
    /// the view (at least a tenth of the extent ahead).
    pub(super) fn jump(&mut self, cam: &Camera) {
        self.rot = cam.rotation();
        self.eye = DVec3::from(cam.origin());
        self.fy_rel = cam.fy / f64::from(cam.height);
        self.aspect = cam.fx / cam.fy;
        self.cx_rel = cam.cx / f64::from(cam.width);
        self.cy_rel = cam.cy / f64::from(cam.height);
        self.near = cam.near;
        let ahead = (self.centre - self.eye).dot(self.forward());
        self.pivot = ahead.max(0.1 * self.extent);
    }

    pub(super) fn forward(&self) -> DVec3 {
        self.rot.z_axis
    }

    pub(super) fn camera(&self, width: u32, height: u32) -> Camera {
        let fy = self.fy_rel * f64::from(height);
        let r = self.rot;
        Camera {
            width,
            height,
            fx: fy * self.aspect,
            fy,
            cx: self.cx_rel * f64::from(width),
            cy: self.cy_rel * f64::from(height),
            c2w: std::array::from_fn(|i| [r.x_axis[i], r.y_axis[i], r.z_axis[i], self.eye[i]]),
            near: self.near,
        }
    }

    /// Turns the view about the pivot: `yaw` about the up axis, `pitch` about the view's
    /// right axis (refused where it would look straight along the up axis).
    pub(super) fn orbit(&mut self, yaw: f64, pitch: f64) {
        let pivot = self.eye + self.forward() * self.pivot;
        let q = DQuat::from_axis_angle(self.rot.x_axis, pitch);
        let pitched = DMat3::from_quat(q) * self.rot;
        let q = if pitched.z_axis.dot(self.up).abs() < 0.995 {
            DQuat::from_axis_angle(self.up, yaw) * q
        } else {
            DQuat::from_axis_angle(self.up, yaw)
        };
        let m = DMat3::from_quat(q);
        self.rot = m * self.rot;
        self.eye = pivot + m * (self.eye - pivot);
    }

    /// Moves eye and pivot together, in steps of a twentieth of the extent (scaled by
    /// the pivot distance when panning with the mouse).
    pub(super) fn fly(&mut self, forward: f64, right: f64, lift: f64) {
        let step = 0.05 * self.extent;
        self.eye += step * (forward * self.forward() + right * self.rot.x_axis + lift * self.up);
    }

    pub(super) fn pan(&mut self, dx: f64, dy: f64) {
        let s = 0.0015 * self.pivot;
        self.eye += s * (-dx * self.rot.x_axis - dy * self.rot.y_axis);
    }

    /// Moves toward the pivot (factor < 1) or away.
    pub(super) fn zoom(&mut self, factor: f64) {
        let pivot = self.eye + self.forward() * self.pivot;
        self.pivot = (self.pivot * factor).max(1e-3 * self.extent);
        self.eye = pivot - self.forward() * self.pivot;
    }

    /// The depth range of the depth view: the scene centre's depth ± half the extent.
    pub(super) fn depth_range(&self) -> (f32, f32) {
        let d = (self.centre - self.eye).dot(self.forward());
        (
            (d - 0.5 * self.extent).max(0.0) as f32,
            (d + 0.5 * self.extent).max(1e-3) as f32,
        )
    }
}

/// Two horizontal unit axes (orthogonal to `up` and to each other).
pub fn horizontal_axes(up: DVec3) -> (DVec3, DVec3) {
    let a = if up.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let e1 = (a - up * a.dot(up)).normalize();
    (e1, up.cross(e1))
}

/// A view of the model from outside: `azimuth` and `elevation` (degrees) about `up`
/// around the scene's centre, `distance` extents away, a 50° vertical field of view at
/// `width` × `height`, the near plane at a hundredth of the extent.
pub fn orbit_view(
    scene: &Scene,
    up: [f64; 3],
    azimuth: f64,
    elevation: f64,
    distance: f64,
    width: u32,
    height: u32,
) -> Camera {
    let up = DVec3::from(up).normalize_or(DVec3::Z);
    let centre = DVec3::from(scene.center.map(f64::from));
    let extent = f64::from(scene.extent);
    let (e1, e2) = horizontal_axes(up);
    let (a, el) = (azimuth.to_radians(), elevation.to_radians());
    let eye =
        centre + distance * extent * (el.cos() * (a.cos() * e1 + a.sin() * e2) + el.sin() * up);
    let (w, h) = (width.max(1), height.max(1));
    let fov_x = 2.0 * (25f64.to_radians().tan() * f64::from(w) / f64::from(h)).atan();
    let mut c = Camera::look_at(eye.into(), centre.into(), up.into(), fov_x, w, h);
    c.near = 0.01 * extent;
    c
}

/// Frusta of `cams` as a line list (6 floats per vertex): apex to the four corners of
/// the image at depth `size`, the image's outline, and a tick above its top edge
/// (which way is up).
pub fn frusta_lines(cams: &[Camera], size: f64, colour: [f32; 3]) -> Vec<f32> {
    let mut v = vec![];
    for c in cams {
        let o = DVec3::from(c.origin());
        let (w, h) = (f64::from(c.width), f64::from(c.height));
        let at = |u: f64, vv: f64| {
            let d = [(u - c.cx) / c.fx * size, (vv - c.cy) / c.fy * size, size];
            o + DVec3::from(c.rotate(d))
        };
        let corners = [at(0.0, 0.0), at(w, 0.0), at(w, h), at(0.0, h)];
        let mut line = |a: DVec3, b: DVec3| {
            for p in [a, b] {
                v.extend_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
                v.extend_from_slice(&colour);
            }
        };
        for k in 0..4 {
            line(o, corners[k]);
            line(corners[k], corners[(k + 1) % 4]);
        }
        line(at(0.5 * w, 0.0), at(0.5 * w, -0.25 * h));
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> Scene {
        crate::data::demo::voxelize(2, 1).unwrap()
    }

    fn close(a: DVec3, b: DVec3) -> bool {
        (a - b).length() < 1e-9
    }

    /// Jumping to a camera gives it back exactly at its own size, and keeps its field of
    /// view (vertical) and principal point (relative) at another size.
    #[test]
    fn jump_gives_back_the_camera() {
        let s = scene();
        let mut cam = Camera::look_at(
            [3.0, -2.0, 1.5],
            [0.1, 0.2, 0.0],
            [0.0, 0.0, 1.0],
            0.9,
            64,
            48,
        );
        cam.cx += 3.0;
        cam.fx *= 1.1;
        cam.near = 0.05;
        let nav = Nav::new(&cam, [0.0, 0.0, 1.0], &s);
        let back = nav.camera(64, 48);
        assert_eq!((back.width, back.height), (64, 48));
        for (a, b) in [
            (back.fx, cam.fx),
            (back.fy, cam.fy),
            (back.cx, cam.cx),
            (back.cy, cam.cy),
            (back.near, cam.near),
        ] {
            assert!((a - b).abs() < 1e-9, "{a} {b}");
        }
        for r in 0..3 {
            for c in 0..4 {
                assert!((back.c2w[r][c] - cam.c2w[r][c]).abs() < 1e-12);
            }
        }
        let big = nav.camera(128, 96);
        assert!(
            (big.fy / 96.0 - cam.fy / 48.0).abs() < 1e-12
                && (big.cx / 128.0 - cam.cx / 64.0).abs() < 1e-12
        );
        assert!((big.fx / big.fy - cam.fx / cam.fy).abs() < 1e-12);
    }

    /// Orbiting turns about the pivot: it stays where it is, at the same distance; a
    /// full turn about the up axis comes back; pitching stops short of the up axis; the
    /// view stays upright (its right axis horizontal).
    #[test]
    fn orbit_turns_about_the_pivot_and_stays_upright() {
        let s = scene();
        let cam = Camera::look_at(
            [2.0, -2.0, 1.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            0.9,
            64,
            48,
        );
        let mut nav = Nav::new(&cam, [0.0, 0.0, 1.0], &s);
        let pivot = nav.eye + nav.forward() * nav.pivot;
        let (eye0, rot0) = (nav.eye, nav.rot);
        for k in 0..8 {
            nav.orbit(std::f64::consts::TAU / 8.0, if k < 4 { 0.1 } else { -0.1 });
            assert!(close(nav.eye + nav.forward() * nav.pivot, pivot));
            assert!(
                (nav.rot.x_axis.dot(nav.up)).abs() < 1e-9,
                "right axis tilted"
            );
        }
        assert!(close(nav.eye, eye0) && (nav.rot - rot0).abs_diff_eq(DMat3::ZERO, 1e-9));
        for _ in 0..100 {
            nav.orbit(0.0, 0.1);
            assert!(nav.forward().dot(nav.up).abs() < 0.995);
            assert!(close(nav.eye + nav.forward() * nav.pivot, pivot));
        }
        // Zoom keeps the pivot; panning and flying move eye and pivot together.
        nav.zoom(0.5);
        assert!(close(nav.eye + nav.forward() * nav.pivot, pivot));
        let before = nav.eye;
        nav.fly(1.0, 0.0, 0.0);
        assert!(close(nav.eye - before, nav.forward() * 0.05 * nav.extent));
    }

    /// Frusta: 9 lines per camera, the apex at the camera's centre, the corners at the
    /// given depth along the view.
    #[test]
    fn frusta_lines_start_at_the_cameras() {
        let cam = Camera::look_at(
            [2.0, -2.0, 1.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            0.9,
            64,
            48,
        );
        let v = frusta_lines(&[cam.clone(), cam.clone()], 0.5, [1.0, 0.0, 0.0]);
        assert_eq!(v.len(), 2 * 9 * 2 * 6);
        let p = |i: usize| DVec3::new(v[6 * i] as f64, v[6 * i + 1] as f64, v[6 * i + 2] as f64);
        let o = DVec3::from(cam.origin());
        assert!((p(0) - o).length() < 1e-6);
        let depth = (p(1) - o).dot(DVec3::from(cam.rotate([0.0, 0.0, 1.0])));
        assert!((depth - 0.5).abs() < 1e-6, "{depth}");
    }
}
