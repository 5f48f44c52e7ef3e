//! Pixel losses of a training frame (glsl/train/loss.comp): MSE on rgb, the
//! transmittance concentration T²(1−T)² and the inside term T² (T = 1 − alpha, the
//! transmittance left after the model's last voxel), written as gradients w.r.t. the
//! frame's outputs into the backward's `dout` image (every channel, so SSIM can add to
//! it next), plus per-workgroup partial sums of the squared error, the two
//! transmittance terms and the frame's per-pixel distortion values for logging.

use ash::vk;

use crate::error::Result;
use crate::gpu::kernels::push_constants;
use crate::gpu::{kernels, recorder, Buffer, Context, GrowBuffer, Kernel};
use crate::raster::FrameGeometry;

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct LossPush {
    frame: u64,
    out_img: u64,
    gt: u64,
    dout: u64,
    partials: u64,
    w_mse: f32,
    w_t: f32,
    nout: u32,
    nrender: u32,
    w_tin: f32,
    clamp_rgb: u32,
    clamped: u64,
}
push_constants!(TRAIN_LOSS, LossPush);

/// Partial sums per workgroup: squared error, concentration, distortion, inside.
const PARTIALS: usize = 4;

/// Sums of the last recorded frame's pixel losses.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossSums {
    /// Σ over output pixels and channels of (rgb − gt)².
    pub squared_error: f64,
    /// Σ over output pixels of T²(1−T)².
    pub t_concentration: f64,
    /// Σ over render pixels of the distortion loss value.
    pub distortion: f64,
    /// Σ over output pixels of T².
    pub t_inside: f64,
    pub out_pixels: u32,
    pub render_pixels: u32,
}

/// Weights of the pixel losses (each term is a mean over the frame's pixels).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossWeights {
    /// λ of mean((rgb − gt)²) over 3·pixels.
    pub mse: f32,
    /// λ of mean(T²(1−T)²): transmittance pushed to 0 or 1 (objects on a background).
    pub t_concentration: f32,
    /// λ of mean(T²): every ray ends inside the model (the reference's
    /// `lambda_T_inside`; unbounded scenes, whose shells hold the background).
    pub t_inside: f32,
}

/// The pixel-loss kernel, its partial-sum buffer and the clamped image.
pub struct PixelLoss {
    ctx: Context,
    kernel: Kernel,
    partials: GrowBuffer,
    clamped: GrowBuffer,
    groups: u32,
    pixels: (u32, u32),
    /// The last recorded frame's rgb was clamped (its image is in `clamped`).
    clamped_last: bool,
}

impl PixelLoss {
    pub fn new(ctx: &Context) -> Result<PixelLoss> {
        Ok(PixelLoss {
            ctx: ctx.clone(),
            kernel: Kernel::new(ctx, &kernels::TRAIN_LOSS)?,
            partials: GrowBuffer::new("loss.partials"),
            clamped: GrowBuffer::new("loss.clamped-rgb"),
            groups: 0,
            pixels: (0, 0),
            clamped_last: false,
        })
    }

    /// The clamped rgb of the last frame recorded with `clamp_rgb` (planar `[3][H][W]`
    /// f32 at output resolution), the image SSIM compares then.
    pub fn clamped_rgb(&self) -> Option<&Buffer> {
        self.clamped_last.then(|| self.clamped.get())
    }

    /// Records the losses of `frame` (its output image at `out_img`, planar
    /// [`crate::raster::CHANNELS`]) against `gt` (planar rgb at output resolution) into
    /// `dout` with the weights `w` ([`LossWeights`]). With `clamp_rgb` the rgb losses
    /// are those of clamp(rgb, 0, 1), as SVRaster trains (its `renderer.py` clamps the
    /// output before the loss) and as eval measures: their gradient passes only where
    /// rgb is in [0, 1], and the clamped image is kept for SSIM
    /// ([`PixelLoss::clamped_rgb`]). Ends with a barrier.
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        frame: &FrameGeometry,
        out_img: u64,
        gt: u64,
        dout: u64,
        w: LossWeights,
        clamp_rgb: bool,
    ) -> Result<()> {
        let nout = frame.out_width * frame.out_height;
        let nrender = frame.render_width * frame.render_height;
        let items = nout.max(nrender);
        let groups = self.kernel.groups_1d(items);
        let need = groups as u64 * PARTIALS as u64 * 4;
        self.partials.ensure(&self.ctx, need)?;
        if clamp_rgb {
            self.clamped.ensure(&self.ctx, 3 * nout as u64 * 4)?;
        }
        self.kernel.dispatch_1d(
            cmd,
            &LossPush {
                frame: frame.params,
                out_img,
                gt,
                dout,
                partials: self.partials.address(),
                w_mse: w.mse / (3.0 * nout as f32),
                w_t: w.t_concentration / nout as f32,
                nout,
                nrender,
                w_tin: w.t_inside / nout as f32,
                clamp_rgb: u32::from(clamp_rgb),
                clamped: if clamp_rgb { self.clamped.address() } else { 0 },
            },
            items,
        );
        recorder::barrier(&self.ctx, cmd);
        self.clamped_last = clamp_rgb;
        self.groups = groups;
        self.pixels = (nout, nrender);
        Ok(())
    }

    /// The sums of the last recorded frame (after it completed).
    pub fn read(&self) -> Result<LossSums> {
        let parts: Vec<f32> = match self.partials.buffer() {
            Some(b) if self.groups > 0 => {
                self.ctx.download(b, 0, self.groups as usize * PARTIALS)?
            }
            _ => Vec::new(),
        };
        let mut s = [0f64; PARTIALS];
        for g in parts.chunks_exact(PARTIALS) {
            for k in 0..PARTIALS {
                s[k] += g[k] as f64;
            }
        }
        Ok(LossSums {
            squared_error: s[0],
            t_concentration: s[1],
            distortion: s[2],
            t_inside: s[3],
            out_pixels: self.pixels.0,
            render_pixels: self.pixels.1,
        })
    }
}

#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct NormalPush {
    r0: [f32; 4],
    r1: [f32; 4],
    r2: [f32; 4],
    out_img: u64,
    dout: u64,
    partials: u64,
    cy: f32,
    w_med: f32,
    w_mean: f32,
    width: u32,
    height: u32,
    pad: u32,
}
push_constants!(TRAIN_NORMAL_LOSS, NormalPush);

/// Sums of the last recorded frame's depth–normal terms (unweighted).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NormalSums {
    /// Σ over pixels of `1 − N·n_med` (where the median-depth normal is defined).
    pub median: f64,
    /// Σ over pixels of `α² − α N·n_mean` (where the mean-depth normal is defined).
    pub mean: f64,
    pub pixels: u32,
}

/// The depth–normal consistency kernel (glsl/train/normal_loss.comp: the paper's mesh
/// regularisers, median- and mean-depth terms) and its partial sums.
pub struct NormalLoss {
    ctx: Context,
    kernel: Kernel,
    partials: GrowBuffer,
    groups: u32,
    pixels: u32,
}

impl NormalLoss {
    pub fn new(ctx: &Context) -> Result<NormalLoss> {
        Ok(NormalLoss {
            ctx: ctx.clone(),
            kernel: Kernel::new(ctx, &kernels::TRAIN_NORMAL_LOSS)?,
            partials: GrowBuffer::new("loss.normal-partials"),
            groups: 0,
            pixels: 0,
        })
    }

    /// Records the terms of a frame of `cam` (output resolution; its image at `out_img`,
    /// planar [`crate::raster::CHANNELS`]) with weights `lambda_median`, `lambda_mean`
    /// (each term a mean over the pixels), ADDING the gradients to `dout`'s depth and
    /// normal channels. Ends with a barrier.
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        cam: &crate::camera::Camera,
        out_img: u64,
        dout: u64,
        lambda_median: f32,
        lambda_mean: f32,
    ) -> Result<()> {
        let npix = cam.width * cam.height;
        let groups = self.kernel.groups_1d(npix);
        self.partials.ensure(&self.ctx, groups as u64 * 2 * 4)?;
        let w = cam.w2c();
        let row =
            |r: usize, extra: f64| [w[r][0] as f32, w[r][1] as f32, w[r][2] as f32, extra as f32];
        self.kernel.dispatch_1d(
            cmd,
            &NormalPush {
                out_img,
                dout,
                partials: self.partials.address(),
                r0: row(0, cam.fx),
                r1: row(1, cam.fy),
                r2: row(2, cam.cx),
                cy: cam.cy as f32,
                w_med: lambda_median / npix as f32,
                w_mean: lambda_mean / npix as f32,
                width: cam.width,
                height: cam.height,
                pad: 0,
            },
            npix,
        );
        recorder::barrier(&self.ctx, cmd);
        self.groups = groups;
        self.pixels = npix;
        Ok(())
    }

    /// The sums of the last recorded frame (after it completed).
    pub fn read(&self) -> Result<NormalSums> {
        let parts: Vec<f32> = match self.partials.buffer() {
            Some(b) if self.groups > 0 => self.ctx.download(b, 0, self.groups as usize * 2)?,
            _ => Vec::new(),
        };
        let (mut m, mut e) = (0f64, 0f64);
        for g in parts.chunks_exact(2) {
            m += f64::from(g[0]);
            e += f64::from(g[1]);
        }
        Ok(NormalSums {
            median: m,
            mean: e,
            pixels: self.pixels,
        })
    }
}
