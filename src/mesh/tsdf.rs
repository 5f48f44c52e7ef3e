//! Truncated signed distance fusion on sparse grid points (kernel `mesh/tsdf_fuse`).
//!
//! Each view contributes, at every grid point `p` it observes, the projective signed
//! distance `sdf = (D(π(p)) − z(p)) / band` between the view's rendered surface depth
//! `D` (camera z; bilinear at the projected pixel) and the point's own camera z,
//! truncated to `[−1, 1]` (points more than one band behind the surface are not
//! observed), weighted by the rendered opacity at that pixel. The fused value is the
//! weighted mean `Σ w·sdf / Σ w` in band units: positive in front of the surface (free
//! space), negative behind it, NaN where no view observed the point. A view observes a
//! point when it lies in front of the near plane, projects inside the image shrunk by
//! `crop` (fraction of the half-size, the reference's `crop_border`), and all four
//! bilinear taps are surface pixels (opacity ≥ `alpha_min` and depth > 0), so no value
//! mixes a surface with the empty pixels around it.
//!
//! The kernel runs one dispatch per view over all points, all views in one submission;
//! views are uploaded once ([`TsdfFuser::new`]) and fused into any number of point sets
//! (the coarse-to-fine refinement of [`super::extract`](mod@super::extract)).

use bytemuck::{Pod, Zeroable};

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::kernels::push_constants;
use crate::gpu::{kernels, recorder, Buffer, Context, Kernel};

/// A rendered view: its camera (model frame) and per-pixel surface depth and opacity.
#[derive(Clone, Debug)]
pub struct DepthView {
    pub camera: Camera,
    /// Row-major surface depth as camera z (≤ 0: no surface).
    pub depth: Vec<f32>,
    /// Row-major opacity `1 − T`.
    pub alpha: Vec<f32>,
}

/// How views are fused.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FuseParams {
    /// Truncation band in model units (the fused values are in units of it).
    pub band: f64,
    /// Pixels below this opacity are not surface.
    pub alpha_min: f32,
    /// Border excluded, as a fraction of the image's half-size.
    pub crop: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct FusePush {
    points: u64,
    views: u64,
    cams: u64,
    sd: u64,
    wt: u64,
    count: u32,
    view: u32,
    band: f32,
    alpha_min: f32,
    crop: f32,
    pad: u32,
}
push_constants!(MESH_TSDF_FUSE, FusePush);

const CAM_FLOATS: usize = 20;

/// The views on the device and the fusion kernel.
pub struct TsdfFuser {
    ctx: Context,
    kernel: Kernel,
    views: Buffer,
    cams: Buffer,
    count: u32,
}

impl TsdfFuser {
    /// Uploads `views` (depth and opacity interleaved, all views in one buffer).
    pub fn new(ctx: &Context, views: &[DepthView]) -> Result<TsdfFuser> {
        let mut data: Vec<f32> = Vec::new();
        let mut cams: Vec<f32> = Vec::with_capacity(views.len() * CAM_FLOATS);
        for (i, v) in views.iter().enumerate() {
            let c = &v.camera;
            let n = c.width as usize * c.height as usize;
            if v.depth.len() != n || v.alpha.len() != n {
                return Err(Error::Invalid(format!(
                    "TSDF view {i}: {} depths and {} opacities for a {}×{} camera",
                    v.depth.len(),
                    v.alpha.len(),
                    c.width,
                    c.height
                )));
            }
            let offset = u32::try_from(data.len())
                .ok()
                .filter(|o| (*o as usize) + 2 * n < u32::MAX as usize)
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "TSDF fusion: {} views of up to {}×{} exceed 2^32 floats; fuse fewer or \
                         smaller views (--downscale)",
                        views.len(),
                        c.width,
                        c.height
                    ))
                })?;
            data.reserve(2 * n);
            for (d, a) in v.depth.iter().zip(&v.alpha) {
                data.push(*d);
                data.push(*a);
            }
            let w2c = c.w2c();
            for row in w2c {
                cams.extend(row.iter().map(|&x| x as f32));
            }
            cams.extend([c.fx as f32, c.fy as f32, c.cx as f32, c.cy as f32]);
            cams.push(f32::from_bits(c.width));
            cams.push(f32::from_bits(c.height));
            cams.push(c.near as f32);
            cams.push(f32::from_bits(offset));
        }
        if views.is_empty() {
            cams.resize(CAM_FLOATS, 0.0);
        }
        Ok(TsdfFuser {
            ctx: ctx.clone(),
            kernel: Kernel::new(ctx, &kernels::MESH_TSDF_FUSE)?,
            views: ctx.buffer_from("mesh.views", &data)?,
            cams: ctx.buffer_from("mesh.cameras", &cams)?,
            count: views.len() as u32,
        })
    }

    /// Device bytes the views occupy.
    pub fn bytes(&self) -> u64 {
        self.views.size() + self.cams.size()
    }

    /// Fuses every view into `points` (model frame): per point, the weighted mean
    /// signed distance in band units (NaN where unobserved) and the total weight.
    pub fn fuse(&self, points: &[[f64; 3]], p: &FuseParams) -> Result<(Vec<f32>, Vec<f32>)> {
        if !(p.band.is_finite() && p.band > 0.0) {
            return Err(Error::Invalid(format!(
                "TSDF band must be finite and > 0, not {}",
                p.band
            )));
        }
        let n = u32::try_from(points.len()).map_err(|_| {
            Error::Invalid(format!(
                "TSDF fusion of {} grid points exceeds 2^32",
                points.len()
            ))
        })?;
        if n == 0 {
            return Ok((Vec::new(), Vec::new()));
        }
        let xyz: Vec<f32> = points.iter().flatten().map(|&x| x as f32).collect();
        let pts = self.ctx.buffer_from("mesh.points", &xyz)?;
        let sd = self.ctx.zeroed_buffer("mesh.sd", u64::from(n) * 4)?;
        let wt = self.ctx.zeroed_buffer("mesh.weight", u64::from(n) * 4)?;
        self.ctx.submit_and_wait(|cmd| {
            for view in 0..self.count {
                let push = FusePush {
                    points: pts.address(),
                    views: self.views.address(),
                    cams: self.cams.address(),
                    sd: sd.address(),
                    wt: wt.address(),
                    count: n,
                    view,
                    band: p.band as f32,
                    alpha_min: p.alpha_min,
                    crop: p.crop,
                    pad: 0,
                };
                self.kernel.dispatch_1d(cmd, &push, n);
                recorder::barrier(&self.ctx, cmd);
            }
            Ok(())
        })?;
        let sd: Vec<f32> = self.ctx.download_all(&sd)?;
        let wt: Vec<f32> = self.ctx.download_all(&wt)?;
        let tsdf = sd
            .iter()
            .zip(&wt)
            .take(points.len())
            .map(|(&s, &w)| if w > 0.0 { s / w } else { f32::NAN })
            .collect();
        Ok((tsdf, wt[..points.len()].to_vec()))
    }
}
