//! Rendering inside a host engine's frame: the host's camera matrices, its colour and
//! depth images, its command buffers, its device.
//!
//! A [`HostRenderer`] keeps one set of frame resources per frame in flight (slot
//! `frame_index % frames_in_flight`). Each frame is two calls:
//! [`HostRenderer::prepare`] (before the host records; reads the slot's previous frame's
//! stats, grows what that frame found short — more entries than its buffers held,
//! longer tile lists than its recorded chunks — and allocates; it submits one-time
//! initialisation to the context's queue and waits for it only when it allocates: a
//! slot's first frame, growth, a larger view) and [`HostRenderer::record`] (records
//! commands into the host's command buffer: no allocation, no submission, no wait). A
//! shortfall found by one slot is applied to every slot at its next `prepare`, so it
//! costs at most one incomplete frame per slot, never a device loss
//! ([`HostFrameReport`]).
//!
//! # Camera
//! [`HostView`]: the host's view and projection matrices (Vulkan clip space: x right,
//! y down, depth 0..1 — standard or reverse-Z, finite or infinite far plane, centred or
//! off-centre) and an optional model matrix placing the field in the host's world
//! (rigid motion and uniform scale). The pinhole camera is recovered exactly from
//! `P·V·M`; the near plane is the one on the optical axis (an oblique near plane is not
//! followed). A projection that mirrors the image (a y-up NDC without a negative-height
//! viewport), has skew or is orthographic is rejected with a message.
//!
//! # Colour and depth
//! The colour target (an image of a [`ColorFormat`], or a buffer with the same packed
//! pixels) receives the field as **premultiplied linear light** over a transparent
//! background: blend it over the host's linear image with `src + (1 − src.a)·dst`. The
//! model's colours are sRGB-encoded display values (those of the photos it was trained
//! on), so a pixel of composited colour `C` and alpha `α` is written as
//! `α·srgb_decode(C/α)`; float targets take that unclamped, `Rgba8Unorm` clamped to
//! 0..1, and `Rgba8Srgb` stores its sRGB encoding (the hardware decodes it back).
//!
//! A [`DepthTarget`] (`D32_SFLOAT`) with `cut_rays` ends every ray at the host's depth:
//! voxels behind the host's surface are not composited and a voxel straddling it
//! contributes only its part in front. With `write` set, the image receives, where the
//! field's alpha reaches 0.5, the nearer of the field's depth (median or mean, in the
//! host's convention; with supersampling the nearest over the pixel's sub-pixels that
//! reach 0.5) and the host's own; elsewhere the host's value is kept.
//!
//! # Synchronisation contract
//! The recorded commands are compute dispatches, buffer and image copies and fills.
//! They begin with a barrier from `ALL_COMMANDS` / `MEMORY_WRITE` (everything the host
//! recorded before is finished and visible) and end with one to `ALL_COMMANDS` /
//! `MEMORY_READ | MEMORY_WRITE`, so the host needs no barriers of its own around them.
//! Images are expected in the layout the target names (`layout`: `GENERAL`,
//! `TRANSFER_*_OPTIMAL`, or any layout the image's contents may be read from — for a
//! depth attachment `DEPTH_STENCIL_ATTACHMENT_OPTIMAL` or `DEPTH_ATTACHMENT_OPTIMAL`;
//! `UNDEFINED` for a colour image whose contents are to be replaced) and are left in
//! `final_layout`. A colour image needs `TRANSFER_DST` usage, a depth image
//! `TRANSFER_SRC` and (to be written) `TRANSFER_DST`, a colour buffer `TRANSFER_DST`.
//! All recorded work must run on the queue family of the [`Context`]. Before `prepare`
//! of frame `i`, the host must have waited for the submission that contained the
//! slot's previous frame (`i − frames_in_flight`, its usual per-frame fence); `prepare`
//! may use the context's queue (see above), so call it from the thread that submits to
//! that queue, outside `Context::submit_and_wait`.

use ash::vk;

use super::params::HostOutputPush;
use super::plan::Plan;
use super::{FrameStats, HostFrame, RenderOptions, Renderer, STATS_WORDS};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{glsl, recorder, Buffer, Context, GrowBuffer, Memory};
use crate::scene::SceneGpu;

mod view;
pub use view::{matrices_for, DepthConvention, HostView};

/// Pixel formats of a colour target (premultiplied alpha).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ColorFormat {
    /// `R8G8B8A8_UNORM`: premultiplied linear light clamped to 0..1.
    Rgba8Unorm,
    /// `R8G8B8A8_SRGB`: premultiplied linear light, sRGB-encoded (the hardware
    /// decodes it back to linear when the host samples or blends it).
    Rgba8Srgb,
    /// `R16G16B16A16_SFLOAT`: unclamped.
    Rgba16Float,
    /// `R32G32B32A32_SFLOAT`: unclamped.
    Rgba32Float,
}

impl ColorFormat {
    /// The Vulkan format.
    pub fn vk(self) -> vk::Format {
        match self {
            ColorFormat::Rgba8Unorm => vk::Format::R8G8B8A8_UNORM,
            ColorFormat::Rgba8Srgb => vk::Format::R8G8B8A8_SRGB,
            ColorFormat::Rgba16Float => vk::Format::R16G16B16A16_SFLOAT,
            ColorFormat::Rgba32Float => vk::Format::R32G32B32A32_SFLOAT,
        }
    }

    /// Bytes per pixel.
    pub fn bytes(self) -> u64 {
        match self {
            ColorFormat::Rgba8Unorm | ColorFormat::Rgba8Srgb => 4,
            ColorFormat::Rgba16Float => 8,
            ColorFormat::Rgba32Float => 16,
        }
    }

    fn code(self) -> u32 {
        match self {
            ColorFormat::Rgba8Unorm => glsl::HOST_RGBA8_UNORM,
            ColorFormat::Rgba8Srgb => glsl::HOST_RGBA8_SRGB,
            ColorFormat::Rgba16Float => glsl::HOST_RGBA16F,
            ColorFormat::Rgba32Float => glsl::HOST_RGBA32F,
        }
    }
}

/// Which depth of the field a host depth target receives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum DepthMode {
    /// The median depth (where the transmittance falls to one half): a surface.
    #[default]
    Median,
    /// The mean depth (Σ w·t / α).
    Mean,
}

/// What the colour target shows ([`HostRenderer::set_image`]). Depth and normal are
/// display values like the model's colours (written the same way: premultiplied linear
/// light, α·srgb_decode(v/α)), as `svraster render --depth/--normal` draws them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum HostImage {
    /// The field's colour.
    #[default]
    Colour,
    /// Grey by camera depth: `1 − 0.8·clamp((d − near)/(far − near), 0, 1)`, opaque where
    /// the alpha reaches 0.5 (d: the nearest median depth over the output pixel's render
    /// pixels, camera z in the field's units), transparent elsewhere.
    Depth { near: f32, far: f32 },
    /// The outward unit normal −n/|n| of the composited density gradient n as
    /// `(−n/|n|)·0.5 + 0.5`, in the field's axes, times the alpha.
    Normal,
}

/// Where the colour goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ColorTarget {
    /// A 2-D colour image of the view's size (mip 0, layer 0).
    Image {
        image: vk::Image,
        format: ColorFormat,
        layout: vk::ImageLayout,
        final_layout: vk::ImageLayout,
    },
    /// A buffer receiving row-major packed pixels at `offset`.
    Buffer {
        buffer: vk::Buffer,
        offset: u64,
        format: ColorFormat,
    },
}

/// The host's depth image (`D32_SFLOAT`, the view's size, mip 0, layer 0).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthTarget {
    pub image: vk::Image,
    pub layout: vk::ImageLayout,
    pub final_layout: vk::ImageLayout,
    /// End every ray at the host's depth.
    pub cut_rays: bool,
    /// Write the field's depth (where it is opaque enough) into the image.
    pub write: Option<DepthMode>,
}

/// A frame's targets.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HostTarget {
    pub color: ColorTarget,
    pub depth: Option<DepthTarget>,
}

/// What [`HostRenderer::prepare`] found about the slot's previous frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HostFrameReport {
    /// The stats of the previous frame recorded in this slot (complete once its
    /// submission finished; `None` for a slot's first frame).
    pub previous: Option<FrameStats>,
    /// That frame was incomplete and the slot grew (its image missed entries).
    pub grew: bool,
}

struct Slot {
    renderer: Renderer,
    color: GrowBuffer,
    depth_in: GrowBuffer,
    depth_out: GrowBuffer,
    /// The frame's stats words, copied here at its end.
    readback: Buffer,
    /// The frame last recorded here and its plan (its stats are in `readback` once its
    /// submission completed).
    pending: Option<(u64, Plan)>,
    /// What [`HostRenderer::prepare`] set this slot up for.
    prepared: Option<Prepared>,
}

struct Prepared {
    frame: u64,
    view: HostView,
    opts: RenderOptions,
    target: HostTarget,
    cam: Camera,
    conv: DepthConvention,
}

/// Records frames of a model into a host's command buffers (see the module docs).
pub struct HostRenderer {
    ctx: Context,
    slots: Vec<Slot>,
    /// Capacities any slot found it needed: every slot grows to them at its next
    /// `prepare`, so a shortfall costs one incomplete frame per slot at most.
    min_entries: u64,
    min_chunks: u32,
    image: HostImage,
}

impl HostRenderer {
    /// A renderer for `frames_in_flight` (≥ 1) frames recorded before the oldest is
    /// waited for.
    pub fn new(ctx: &Context, frames_in_flight: u32) -> Result<HostRenderer> {
        if frames_in_flight == 0 {
            return Err(Error::Invalid("frames in flight must be at least 1".into()));
        }
        let first = Renderer::new(ctx)?;
        let mut renderers = vec![];
        for _ in 1..frames_in_flight {
            renderers.push(Renderer::sharing(&first)?);
        }
        renderers.insert(0, first);
        let slots = renderers
            .into_iter()
            .map(|renderer| {
                Ok(Slot {
                    renderer,
                    color: GrowBuffer::new("host.color"),
                    depth_in: GrowBuffer::new("host.depth-in"),
                    depth_out: GrowBuffer::new("host.depth-out"),
                    readback: ctx.buffer("host.stats", STATS_WORDS as u64 * 4, Memory::Readback)?,
                    pending: None,
                    prepared: None,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(HostRenderer {
            ctx: ctx.clone(),
            slots,
            min_entries: 0,
            min_chunks: 1,
            image: HostImage::Colour,
        })
    }

    /// Overrides every slot's composite chunk size (tests use small chunks to make a
    /// slot grow).
    pub fn set_chunk_size(&mut self, entries: u32) {
        for s in &mut self.slots {
            s.renderer.set_chunk_size(entries);
        }
    }

    /// What the colour target shows from the next recorded frame on (default: the
    /// colour). The depth target, when given, behaves the same in every mode.
    pub fn set_image(&mut self, image: HostImage) {
        self.image = image;
    }

    /// Entries per segment of a tile's list (0: off; see
    /// [`Renderer::set_segment_entries`]), for the frames prepared from now on.
    pub fn set_segment_entries(&mut self, entries: u32) {
        for s in &mut self.slots {
            s.renderer.set_segment_entries(entries);
        }
    }

    /// The stats of frame `frame_index` once the host has waited for its submission;
    /// `None` unless it is the latest frame recorded in its slot.
    pub fn finished(&self, frame_index: u64) -> Option<FrameStats> {
        let slot = &self.slots[(frame_index % self.slots.len() as u64) as usize];
        let (frame, plan) = slot.pending?;
        if frame != frame_index {
            return None;
        }
        let words: &[u32] = bytemuck::cast_slice(
            &slot.readback.mapped().expect("readback memory is mapped")[..STATS_WORDS * 4],
        );
        Some(FrameStats::from_words(words, &plan))
    }

    /// Frames in flight (slots).
    pub fn frames_in_flight(&self) -> u32 {
        self.slots.len() as u32
    }

    /// Device bytes held by the slots' frame buffers.
    pub fn bytes(&self) -> u64 {
        self.slots
            .iter()
            .map(|s| {
                s.renderer.bytes() + s.color.bytes() + s.depth_in.bytes() + s.depth_out.bytes()
            })
            .sum()
    }

    /// Sets slot `frame_index % frames_in_flight` up for a frame: reads the stats of the
    /// slot's previous frame (the host must have waited for it), grows what it found
    /// short, checks the view, options and target, and allocates what the frame needs.
    /// Call it before recording the frame, outside any command-buffer recording that
    /// holds the context's queue: when it allocates (a slot's first frames, growth, a
    /// larger view) it may submit one-time initialisation to the context's queue and
    /// wait for it; otherwise it touches no queue.
    pub fn prepare(
        &mut self,
        frame_index: u64,
        scene: &SceneGpu,
        view: &HostView,
        opts: &RenderOptions,
        target: &HostTarget,
    ) -> Result<HostFrameReport> {
        if let Some(d) = target.depth {
            if !d.cut_rays && d.write.is_none() {
                return Err(Error::Invalid(
                    "host depth target: set cut_rays, write or both (or pass no depth target)"
                        .into(),
                ));
            }
        }
        let (cam, conv) = view.camera()?;
        let n = self.slots.len() as u64;
        let ctx = self.ctx.clone();
        let mut report = HostFrameReport::default();
        let slot = &mut self.slots[(frame_index % n) as usize];
        if let Some((_, plan)) = slot.pending.take() {
            let words: &[u32] = bytemuck::cast_slice(
                &slot.readback.mapped().expect("readback memory is mapped")[..STATS_WORDS * 4],
            );
            let stats = FrameStats::from_words(words, &plan);
            report.previous = Some(stats);
            if !stats.complete() {
                report.grew = slot.renderer.grow_for(&stats)?;
                self.min_entries = self.min_entries.max(slot.renderer.entry_capacity() as u64);
                self.min_chunks = self.min_chunks.max(slot.renderer.chunks);
            }
        }
        slot.renderer.reserve_entries(self.min_entries)?;
        slot.renderer.chunks = slot.renderer.chunks.max(self.min_chunks);
        slot.renderer.prepare(scene, &cam, opts)?;
        let npix = view.width as u64 * view.height as u64;
        let format = match target.color {
            ColorTarget::Image { format, .. } | ColorTarget::Buffer { format, .. } => format,
        };
        slot.color.ensure(&ctx, npix * format.bytes())?;
        if let Some(d) = target.depth {
            slot.depth_in.ensure(&ctx, npix * 4)?;
            if d.write.is_some() {
                slot.depth_out.ensure(&ctx, npix * 4)?;
            }
        }
        slot.prepared = Some(Prepared {
            frame: frame_index,
            view: *view,
            opts: *opts,
            target: *target,
            cam,
            conv,
        });
        Ok(report)
    }

    /// Records frame `frame_index` into `cmd` after [`HostRenderer::prepare`] with the
    /// same arguments (see the module docs for the synchronisation contract). Records
    /// commands only: no allocation, no submission, no wait.
    pub fn record(
        &mut self,
        cmd: vk::CommandBuffer,
        frame_index: u64,
        scene: &SceneGpu,
        view: &HostView,
        opts: &RenderOptions,
        target: &HostTarget,
    ) -> Result<()> {
        let n = self.slots.len() as u64;
        let ctx = self.ctx.clone();
        let image = self.image;
        let slot = &mut self.slots[(frame_index % n) as usize];
        let p = match slot.prepared.take() {
            Some(p)
                if p.frame == frame_index
                    && p.view == *view
                    && p.opts == *opts
                    && p.target == *target =>
            {
                p
            }
            _ => {
                return Err(Error::Invalid(format!(
                    "HostRenderer::record of frame {frame_index}: call HostRenderer::prepare \
                     for this frame with the same view, options and target first"
                )))
            }
        };
        let (cam, conv) = (p.cam, p.conv);
        let npix = view.width as u64 * view.height as u64;
        let format = match target.color {
            ColorTarget::Image { format, .. } | ColorTarget::Buffer { format, .. } => format,
        };
        let depth = target.depth;
        let cut = depth.is_some_and(|d| d.cut_rays);
        let write = depth.and_then(|d| d.write);
        let dev = ctx.device();
        let colour_range = subresource(vk::ImageAspectFlags::COLOR);
        let depth_range = subresource(vk::ImageAspectFlags::DEPTH);

        // Entry: the host's work is done and visible; images into transfer layouts
        // (depth: read first, then written).
        let mut entry_images = vec![];
        if let ColorTarget::Image { image, layout, .. } = target.color {
            entry_images.push(image_barrier(
                image,
                colour_range,
                layout,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                vk::AccessFlags::MEMORY_WRITE,
                vk::AccessFlags::TRANSFER_WRITE,
            ));
        }
        if let Some(d) = depth {
            entry_images.push(image_barrier(
                d.image,
                depth_range,
                d.layout,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                vk::AccessFlags::MEMORY_WRITE,
                vk::AccessFlags::TRANSFER_READ,
            ));
        }
        let all = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
            .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE)];
        unsafe {
            dev.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::PipelineStageFlags::TRANSFER | vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::DependencyFlags::empty(),
                &all,
                &[],
                &entry_images,
            );
        }
        let region = vk::BufferImageCopy {
            buffer_offset: 0,
            buffer_row_length: 0,
            buffer_image_height: 0,
            image_subresource: vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::DEPTH,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            },
            image_offset: vk::Offset3D::default(),
            image_extent: vk::Extent3D {
                width: view.width,
                height: view.height,
                depth: 1,
            },
        };
        if let Some(d) = depth {
            unsafe {
                dev.cmd_copy_image_to_buffer(
                    cmd,
                    d.image,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    slot.depth_in.get().raw(),
                    &[region],
                );
            }
            recorder::barrier(&ctx, cmd);
        }

        slot.renderer.host = Some(HostFrame {
            depth: if cut { slot.depth_in.address() } else { 0 },
            depth_map: conv.packed(),
        });
        let recorded = slot.renderer.record(cmd, scene, &cam, opts, None);
        slot.renderer.host = None;
        recorded?;
        let plan = slot.renderer.last_plan()?;
        slot.renderer.k.host_output.dispatch_1d(
            cmd,
            &HostOutputPush {
                frame: slot.renderer.params.address(),
                color: slot.color.address(),
                depth: if write.is_some() {
                    slot.depth_out.address()
                } else {
                    0
                },
                host_depth: if depth.is_some() {
                    slot.depth_in.address()
                } else {
                    0
                },
                format: format.code(),
                depth_mode: match write {
                    Some(DepthMode::Mean) => glsl::HOST_DEPTH_MEAN,
                    _ => glsl::HOST_DEPTH_MEDIAN,
                },
                depth_clear: conv.clear_value(),
                reverse: conv.reverse as u32,
                image: match image {
                    HostImage::Colour => glsl::HOST_IMAGE_COLOUR,
                    HostImage::Depth { .. } => glsl::HOST_IMAGE_DEPTH,
                    HostImage::Normal => glsl::HOST_IMAGE_NORMAL,
                },
                near_depth: match image {
                    HostImage::Depth { near, .. } => near,
                    _ => 0.0,
                },
                far_depth: match image {
                    HostImage::Depth { far, .. } => far,
                    _ => 1.0,
                },
                pad_: 0,
            },
            npix as u32,
        );
        recorder::barrier(&ctx, cmd);

        // Results to the host's targets.
        let colour_bytes = npix * format.bytes();
        match target.color {
            ColorTarget::Image { image, .. } => unsafe {
                let mut r = region;
                r.image_subresource.aspect_mask = vk::ImageAspectFlags::COLOR;
                dev.cmd_copy_buffer_to_image(
                    cmd,
                    slot.color.get().raw(),
                    image,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &[r],
                );
            },
            ColorTarget::Buffer { buffer, offset, .. } => unsafe {
                dev.cmd_copy_buffer(
                    cmd,
                    slot.color.get().raw(),
                    buffer,
                    &[vk::BufferCopy {
                        src_offset: 0,
                        dst_offset: offset,
                        size: colour_bytes,
                    }],
                );
            },
        }
        if let (Some(d), Some(_)) = (depth, write) {
            let b = [image_barrier(
                d.image,
                depth_range,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                vk::AccessFlags::TRANSFER_READ,
                vk::AccessFlags::TRANSFER_WRITE,
            )];
            unsafe {
                dev.cmd_pipeline_barrier(
                    cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::DependencyFlags::empty(),
                    &[],
                    &[],
                    &b,
                );
                dev.cmd_copy_buffer_to_image(
                    cmd,
                    slot.depth_out.get().raw(),
                    d.image,
                    vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                    &[region],
                );
            }
        }
        recorder::copy(
            &ctx,
            cmd,
            &slot.renderer.stats,
            &slot.readback,
            0,
            0,
            STATS_WORDS as u64 * 4,
        );

        // Exit: everything written is visible to whatever the host does next (and the
        // stats to the host once the submission completed); final layouts.
        let mut exit_images = vec![];
        if let ColorTarget::Image {
            image,
            final_layout,
            ..
        } = target.color
        {
            exit_images.push(image_barrier(
                image,
                colour_range,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                final_layout,
                vk::AccessFlags::TRANSFER_WRITE,
                vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE,
            ));
        }
        if let Some(d) = depth {
            let last = if write.is_some() {
                vk::ImageLayout::TRANSFER_DST_OPTIMAL
            } else {
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL
            };
            exit_images.push(image_barrier(
                d.image,
                depth_range,
                last,
                d.final_layout,
                vk::AccessFlags::TRANSFER_WRITE,
                vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE,
            ));
        }
        let exit = [vk::MemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::TRANSFER_WRITE | vk::AccessFlags::SHADER_WRITE)
            .dst_access_mask(
                vk::AccessFlags::MEMORY_READ
                    | vk::AccessFlags::MEMORY_WRITE
                    | vk::AccessFlags::HOST_READ,
            )];
        unsafe {
            dev.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER | vk::PipelineStageFlags::COMPUTE_SHADER,
                vk::PipelineStageFlags::ALL_COMMANDS | vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &exit,
                &[],
                &exit_images,
            );
        }
        slot.pending = Some((frame_index, plan));
        Ok(())
    }
}

fn image_barrier(
    image: vk::Image,
    range: vk::ImageSubresourceRange,
    old: vk::ImageLayout,
    new: vk::ImageLayout,
    src: vk::AccessFlags,
    dst: vk::AccessFlags,
) -> vk::ImageMemoryBarrier<'static> {
    vk::ImageMemoryBarrier::default()
        .src_access_mask(src)
        .dst_access_mask(dst)
        .old_layout(old)
        .new_layout(new)
        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .image(image)
        .subresource_range(range)
}

fn subresource(aspect: vk::ImageAspectFlags) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: aspect,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    }
}
