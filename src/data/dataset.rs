//! The format-neutral training data every loader produces (Blender/NeRF-synthetic here;
//! COLMAP, LLFF and nerfstudio next): frames with their camera and composited RGB, and the
//! exact area resampling used to downscale them.

use super::Camera;

/// One view of a split.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// File name stem of the image, e.g. `r_0`.
    pub name: String,
    /// The camera, at the (downscaled) image size.
    pub camera: Camera,
    /// Row-major RGB, composited over the dataset background.
    pub rgb: Vec<[f32; 3]>,
}

/// The frames of one split (of one size, or of several in a capture with several
/// cameras).
#[derive(Clone, Debug, PartialEq)]
pub struct Dataset {
    pub frames: Vec<Frame>,
    /// Image width after downscaling (the largest where a capture's frames differ in
    /// size; each frame's camera has its own).
    pub width: u32,
    /// Image height after downscaling (the largest, likewise).
    pub height: u32,
    /// Colour the images were composited over.
    pub background: [f32; 3],
    /// Whether the photos carry alpha (Blender RGBA) and `rgb` is composited over
    /// `background`; captures' photos are opaque.
    pub alpha: bool,
    /// Split name (`train`, `val`, `test`, ...).
    pub split: String,
    /// The capture's sparse 3-D points in world coordinates (COLMAP `points3D`; empty
    /// for synthetic data): one way to bound the scene ([`crate::train::bounds`]).
    pub points: Vec<[f64; 3]>,
    /// A sphere (centre, radius; world coordinates) the capture says holds the object
    /// (NeuS' `scale_mat`); the main region of bound `auto`/`sphere`.
    pub sphere: Option<([f64; 3], f64)>,
}

impl Dataset {
    /// Mean colour of every pixel of every frame (f64 sums; black for no pixels).
    pub fn mean_color(&self) -> [f32; 3] {
        let mut sum = [0f64; 3];
        let mut n = 0usize;
        for f in &self.frames {
            for p in &f.rgb {
                for c in 0..3 {
                    sum[c] += f64::from(p[c]);
                }
            }
            n += f.rgb.len();
        }
        sum.map(|v| if n > 0 { (v / n as f64) as f32 } else { 0.0 })
    }

    /// Whether every frame has the size `width × height`.
    pub fn uniform_size(&self) -> bool {
        self.frames
            .iter()
            .all(|f| (f.camera.width, f.camera.height) == (self.width, self.height))
    }

    /// Maps the cameras and points into a model's frame (a no-op for the identity).
    pub fn to_model(&mut self, world: &crate::scene::WorldFrame) {
        if world.is_identity() {
            return;
        }
        for f in &mut self.frames {
            f.camera = world.camera_to_model(&f.camera);
        }
        for p in &mut self.points {
            *p = world.point_to_model(*p);
        }
        if let Some((c, r)) = &mut self.sphere {
            *c = world.point_to_model(*c);
            *r /= world.scale;
        }
    }

    /// The cameras of all frames, in order.
    pub fn cameras(&self) -> Vec<Camera> {
        self.frames.iter().map(|f| f.camera.clone()).collect()
    }
}

/// Output size of downscaling `w × h` by `factor` (each at least 1).
pub fn downscaled_size(w: u32, h: u32, factor: f64) -> (u32, u32) {
    let f = |n: u32| ((n as f64 / factor).round() as u32).max(1);
    (f(w), f(h))
}

/// Resamples a row-major `w × h` image to `ow × oh` by exact area averaging: each output
/// pixel is the mean of the input over its footprint, input pixels weighted by overlap
/// area. For integer ratios this is a plain box average.
///
/// Panics if `rgb.len() != w·h` or an output size is zero.
pub fn area_resample(w: u32, h: u32, rgb: &[[f32; 3]], ow: u32, oh: u32) -> Vec<[f32; 3]> {
    let (w, h, ow, oh) = (w as usize, h as usize, ow as usize, oh as usize);
    assert_eq!(rgb.len(), w * h, "area_resample: image size mismatch");
    assert!(ow > 0 && oh > 0, "area_resample: empty output size");
    if (w, h) == (ow, oh) {
        return rgb.to_vec();
    }
    let wx = area_weights(w, ow);
    let wy = area_weights(h, oh);
    // Horizontal pass: h × ow.
    let mut tmp = vec![[0.0f64; 3]; h * ow];
    for y in 0..h {
        for (ox, ws) in wx.iter().enumerate() {
            let mut acc = [0.0f64; 3];
            for &(x, wt) in ws {
                let p = rgb[y * w + x];
                for c in 0..3 {
                    acc[c] += wt * p[c] as f64;
                }
            }
            tmp[y * ow + ox] = acc;
        }
    }
    // Vertical pass: oh × ow.
    let mut out = vec![[0.0f32; 3]; oh * ow];
    for (oy, ws) in wy.iter().enumerate() {
        for ox in 0..ow {
            let mut acc = [0.0f64; 3];
            for &(y, wt) in ws {
                let p = tmp[y * ow + ox];
                for c in 0..3 {
                    acc[c] += wt * p[c];
                }
            }
            out[oy * ow + ox] = acc.map(|v| v as f32);
        }
    }
    out
}

/// Per output index: the input indices it overlaps and their normalised overlap weights.
fn area_weights(n_in: usize, n_out: usize) -> Vec<Vec<(usize, f64)>> {
    let s = n_in as f64 / n_out as f64;
    (0..n_out)
        .map(|o| {
            let a = o as f64 * s;
            let b = ((o + 1) as f64 * s).min(n_in as f64);
            let i0 = (a.floor() as usize).min(n_in - 1);
            let i1 = (b.ceil() as usize).clamp(i0 + 1, n_in);
            let mut ws: Vec<(usize, f64)> = (i0..i1)
                .map(|i| (i, (b.min(i as f64 + 1.0) - a.max(i as f64)).max(0.0)))
                .filter(|&(_, wt)| wt > 0.0)
                .collect();
            let total: f64 = ws.iter().map(|&(_, wt)| wt).sum();
            if total > 0.0 {
                for (_, wt) in &mut ws {
                    *wt /= total;
                }
            } else {
                ws = vec![(i0, 1.0)];
            }
            ws
        })
        .collect()
}
