//! Fusion on the GPU: per view a frame, then per three channels the training backward
//! with the value planes as the colour's output gradient, and its per-voxel colour
//! gradients added to the sums (glsl/field/accumulate.comp).

use bytemuck::{Pod, Zeroable};

use super::{check_channels, Field, FieldKind};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::kernels::{self, push_constants};
use crate::gpu::{recorder, Buffer, Context, GrowBuffer, Kernel, Memory};
use crate::raster::{FrameOutputs, RenderOptions, Renderer};
use crate::scene::SceneGpu;
use crate::train::backward::{dout, Backward, EntryLosses, Gradients};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct AccPush {
    vgrad: u64,
    acc: u64,
    voxels: u32,
    channels: u32,
    first: u32,
    pad: u32,
}
push_constants!(FIELD_ACCUMULATE, AccPush);

/// Fuses per-pixel values of views into the voxels of one model.
pub struct Fuser {
    ctx: Context,
    renderer: Renderer,
    backward: Backward,
    grads: Gradients,
    kernel: Kernel,
    /// Planar `[channels + 1][voxels]`: Σ w·value per channel, then Σ w.
    acc: Buffer,
    staging: GrowBuffer,
    channels: u32,
    voxels: u32,
    views: u32,
}

impl Fuser {
    /// A fuser of `channels` channels for `scene`'s voxels (sums at zero).
    pub fn new(ctx: &Context, scene: &SceneGpu, channels: u32) -> Result<Fuser> {
        check_channels(channels)?;
        let bytes = Field::fusion_bytes(scene.voxels, channels);
        if bytes / 4 >= u64::from(u32::MAX) {
            return Err(Error::Capacity(format!(
                "fusing {channels} channels on {} voxels needs {} sums, more than 2^32: \
                 fuse fewer channels at a time",
                scene.voxels,
                bytes / 4
            )));
        }
        let mut renderer = Renderer::new(ctx)?;
        renderer.set_outputs(FrameOutputs {
            normals: false,
            distortion: false,
            distortion_contracted: false,
        });
        Ok(Fuser {
            ctx: ctx.clone(),
            renderer,
            backward: Backward::new(ctx, true)?,
            grads: Gradients::new(ctx, scene)?,
            kernel: Kernel::new(ctx, &kernels::FIELD_ACCUMULATE)?,
            acc: ctx.zeroed_buffer("field.sums", bytes.max(4))?,
            staging: GrowBuffer::with_memory("field.values", Memory::Upload),
            channels,
            voxels: scene.voxels,
            views: 0,
        })
    }

    /// Channels fused.
    pub fn channels(&self) -> u32 {
        self.channels
    }

    /// Views fused so far.
    pub fn views(&self) -> u32 {
        self.views
    }

    /// Device bytes held (sums, frame, backward scratch, staging).
    pub fn bytes(&self) -> u64 {
        self.acc.size() + self.renderer.bytes() + self.staging.bytes()
    }

    /// Fuses one view: `values` planar `[channels][height][width]` at the camera's size
    /// (row-major), every value finite.
    pub fn add_view(
        &mut self,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        values: &[f32],
    ) -> Result<()> {
        let n = cam.width as usize * cam.height as usize;
        if values.len() != self.channels as usize * n {
            return Err(Error::Invalid(format!(
                "{} values for {} channels of a {}×{} view",
                values.len(),
                self.channels,
                cam.width,
                cam.height
            )));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            let (ch, p) = (i / n, i % n);
            return Err(Error::Invalid(format!(
                "value of channel {ch} at pixel ({}, {}) is {}: fused values must be finite",
                p % cam.width as usize,
                p / cam.width as usize,
                values[i]
            )));
        }
        let bytes = (values.len() * 4) as u64;
        self.staging.ensure(&self.ctx, bytes)?;
        let dst = self
            .staging
            .buffer_mut()
            .and_then(|b| b.mapped_mut())
            .ok_or_else(|| Error::Gpu("field staging buffer is not host-visible".into()))?;
        dst[..bytes as usize].copy_from_slice(bytemuck::cast_slice(values));
        // Taken out for the call (it borrows self mutably), put back whatever happens.
        let staging = std::mem::replace(
            &mut self.staging,
            GrowBuffer::with_memory("field.values", Memory::Upload),
        );
        let r = self.add_view_device(scene, cam, opts, staging.get(), 0);
        self.staging = staging;
        r
    }

    /// Fuses one view whose values are already on the device: `values` holds, from
    /// byte `offset`, planar `[channels][height][width]` f32 at the camera's size
    /// (a host application's network output; not checked for NaN).
    pub fn add_view_device(
        &mut self,
        scene: &SceneGpu,
        cam: &Camera,
        opts: &RenderOptions,
        values: &Buffer,
        offset: u64,
    ) -> Result<()> {
        if scene.voxels != self.voxels {
            return Err(Error::Invalid(format!(
                "fuser made for {} voxels, scene has {}",
                self.voxels, scene.voxels
            )));
        }
        let opix = u64::from(cam.width) * u64::from(cam.height);
        let plane = opix * 4;
        if values.size() < offset + u64::from(self.channels) * plane {
            return Err(Error::Invalid(format!(
                "value buffer of {} bytes holds less than {} channels of {}×{} from byte {offset}",
                values.size(),
                self.channels,
                cam.width,
                cam.height
            )));
        }
        let stats = self.renderer.render_to_device(scene, cam, opts, None)?;
        let frame = self.renderer.last_frame()?;
        if (frame.out_width, frame.out_height) != (cam.width, cam.height) {
            return Err(Error::Gpu(format!(
                "fusion frame is {}×{}, its camera {}×{}",
                frame.out_width, frame.out_height, cam.width, cam.height
            )));
        }
        self.backward.prepare(&frame, scene.voxels)?;
        let ctx = self.ctx.clone();
        let planes = self.channels + 1;
        let losses = EntryLosses {
            lambda_dist: 0.0,
            lambda_r: 0.0,
            lambda_r_colour: 0.0,
            ..EntryLosses::default()
        };
        ctx.submit_and_wait(|cmd| {
            for pass in 0..planes.div_ceil(3) {
                let dout = self.backward.dout()?;
                recorder::zero(&ctx, cmd, dout);
                recorder::barrier(&ctx, cmd);
                for c in 0..3u32 {
                    let ch = 3 * pass + c;
                    let dst = (dout::R as u64 + u64::from(c)) * plane;
                    if ch < self.channels {
                        let src = offset + u64::from(ch) * plane;
                        recorder::copy(&ctx, cmd, values, dout, src, dst, plane);
                    } else if ch == self.channels {
                        recorder::fill(&ctx, cmd, dout, dst, plane, 1f32.to_bits());
                    }
                }
                recorder::barrier(&ctx, cmd);
                self.backward.record(
                    cmd,
                    &frame,
                    &stats,
                    scene,
                    opts.samples,
                    &self.grads,
                    &losses,
                )?;
                recorder::barrier(&ctx, cmd);
                let push = AccPush {
                    vgrad: self.backward.voxel_gradients()?.address(),
                    acc: self.acc.address(),
                    voxels: self.voxels,
                    channels: planes,
                    first: 3 * pass,
                    pad: 0,
                };
                self.kernel.dispatch_1d(cmd, &push, self.voxels);
                recorder::barrier(&ctx, cmd);
            }
            Ok(())
        })?;
        let lost = self.backward.read_lost()?;
        if lost != 0 {
            return Err(Error::Gpu(format!(
                "{lost} float additions of the fusion gave up (compare-and-swap contention)"
            )));
        }
        self.views += 1;
        Ok(())
    }

    /// The sums so far: Σ w·value planar `[channels][voxels]`, and Σ w per voxel.
    pub fn sums(&self) -> Result<(Vec<f32>, Vec<f32>)> {
        let all: Vec<f32> = self.ctx.download_all(&self.acc)?;
        let n = self.voxels as usize;
        let c = self.channels as usize;
        Ok((all[..c * n].to_vec(), all[c * n..(c + 1) * n].to_vec()))
    }

    /// The field fused so far (values normalised by Σ w).
    pub fn field(&self, kind: FieldKind, model_id: u64) -> Result<Field> {
        let (sums, weights) = self.sums()?;
        let mut f = Field::from_sums(kind, self.channels, &sums, &weights, model_id)?;
        f.meta.insert("views".into(), self.views.to_string());
        Ok(f)
    }
}
