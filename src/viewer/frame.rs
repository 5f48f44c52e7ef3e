//! The viewer's frames: the swapchain and its per-image resources, one frame drawn
//! (the engine's frame recorded into the host's command buffer, composited with the
//! host's geometry by depth, then the overlay), and screenshots.

use image::ImageEncoder as _;

use super::*;

/// The overlay's largest size (its buffer per frame in flight).
const HUD_MAX: (u32, u32) = (1024, 128);

impl Gpu {
    /// (Re)creates the swapchain and the per-frame images at the window's size.
    pub(super) fn create_swapchain(&mut self) -> Result<(), String> {
        unsafe {
            self.device
                .device_wait_idle()
                .map_err(vkerr("vkDeviceWaitIdle"))?;
            self.destroy_frames();
            let caps = self
                .surface_loader
                .get_physical_device_surface_capabilities(self.pdev, self.surface)
                .map_err(vkerr("surface capabilities"))?;
            let size = self.window.inner_size();
            self.extent = if caps.current_extent.width != u32::MAX {
                caps.current_extent
            } else {
                vk::Extent2D {
                    width: size.width,
                    height: size.height,
                }
            };
            if self.extent.width == 0 || self.extent.height == 0 {
                // Minimised: nothing to draw until the next resize.
                self.resized = false;
                return Ok(());
            }
            if !caps
                .supported_usage_flags
                .contains(vk::ImageUsageFlags::TRANSFER_DST)
            {
                return Err(
                    "the surface's swapchain images cannot be transfer destinations (the \
                     viewer blits its frame into them)"
                        .into(),
                );
            }
            let composite_alpha = [
                vk::CompositeAlphaFlagsKHR::OPAQUE,
                vk::CompositeAlphaFlagsKHR::INHERIT,
                vk::CompositeAlphaFlagsKHR::PRE_MULTIPLIED,
                vk::CompositeAlphaFlagsKHR::POST_MULTIPLIED,
            ]
            .into_iter()
            .find(|&a| caps.supported_composite_alpha.contains(a))
            .ok_or("the surface supports no composite alpha mode")?;
            let formats = self
                .surface_loader
                .get_physical_device_surface_formats(self.pdev, self.surface)
                .map_err(vkerr("surface formats"))?;
            // A swapchain of the attachment's encoding (sRGB, or UNORM holding display
            // values): the blit between them keeps the values shown.
            let srgb = self.colour_format == vk::Format::R8G8B8A8_SRGB;
            let wanted = if srgb {
                [vk::Format::B8G8R8A8_SRGB, vk::Format::R8G8B8A8_SRGB]
            } else {
                [vk::Format::B8G8R8A8_UNORM, vk::Format::R8G8B8A8_UNORM]
            };
            let format = formats
                .iter()
                .find(|f| wanted.contains(&f.format))
                .or_else(|| {
                    eprintln!(
                        "warning: no {} swapchain format: the picture is shown too {} (the \
                         screenshot is right)",
                        if srgb { "sRGB" } else { "UNORM" },
                        if srgb { "dark" } else { "bright" }
                    );
                    formats.first()
                })
                .copied()
                .ok_or("the surface has no formats")?;
            let images = caps
                .min_image_count
                .max(2)
                .min(if caps.max_image_count > 0 {
                    caps.max_image_count
                } else {
                    u32::MAX
                });
            let old = self.swapchain;
            self.swapchain = self
                .swapchain_loader
                .create_swapchain(
                    &vk::SwapchainCreateInfoKHR::default()
                        .surface(self.surface)
                        .min_image_count(images)
                        .image_format(format.format)
                        .image_color_space(format.color_space)
                        .image_extent(self.extent)
                        .image_array_layers(1)
                        .image_usage(vk::ImageUsageFlags::TRANSFER_DST)
                        .pre_transform(caps.current_transform)
                        .composite_alpha(composite_alpha)
                        .present_mode(vk::PresentModeKHR::FIFO)
                        .clipped(true)
                        .old_swapchain(old),
                    None,
                )
                .map_err(vkerr("vkCreateSwapchainKHR"))?;
            if old != vk::SwapchainKHR::null() {
                self.swapchain_loader.destroy_swapchain(old, None);
            }
            self.images = self
                .swapchain_loader
                .get_swapchain_images(self.swapchain)
                .map_err(vkerr("swapchain images"))?;
            for s in self.presented.drain(..) {
                self.device.destroy_semaphore(s, None);
            }
            for _ in 0..self.images.len() {
                self.presented.push(
                    self.device
                        .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
                        .map_err(vkerr("semaphore"))?,
                );
            }
            let cmds = self
                .device
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(self.pool)
                        .command_buffer_count(FRAMES_IN_FLIGHT as u32),
                )
                .map_err(vkerr("command buffers"))?;
            let npix = self.extent.width as u64 * self.extent.height as u64;
            for cmd in cmds {
                let colour = self.image(
                    self.colour_format,
                    vk::ImageUsageFlags::COLOR_ATTACHMENT | vk::ImageUsageFlags::TRANSFER_SRC,
                    vk::ImageAspectFlags::COLOR,
                )?;
                let depth = self.image(
                    vk::Format::D32_SFLOAT,
                    vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
                        | vk::ImageUsageFlags::TRANSFER_SRC
                        | vk::ImageUsageFlags::TRANSFER_DST,
                    vk::ImageAspectFlags::DEPTH,
                )?;
                let field = self.buffer(
                    npix * ColorFormat::Rgba16Float.bytes(),
                    vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::STORAGE_BUFFER,
                    false,
                )?;
                let hud_size = (
                    self.extent.width.min(HUD_MAX.0),
                    self.extent.height.min(HUD_MAX.1),
                );
                let hud = self.buffer(
                    hud_size.0 as u64 * hud_size.1 as u64 * 8,
                    vk::BufferUsageFlags::STORAGE_BUFFER,
                    true,
                )?;
                self.frames.push(FrameRes {
                    cmd,
                    fence: self
                        .device
                        .create_fence(
                            &vk::FenceCreateInfo::default().flags(vk::FenceCreateFlags::SIGNALED),
                            None,
                        )
                        .map_err(vkerr("fence"))?,
                    acquired: self
                        .device
                        .create_semaphore(&vk::SemaphoreCreateInfo::default(), None)
                        .map_err(vkerr("semaphore"))?,
                    colour,
                    depth,
                    field,
                    hud,
                    hud_size,
                    timestamps: Timestamps::new(&self.ctx, 4).map_err(|e| e.to_string())?,
                    pending: false,
                });
            }
            self.resized = false;
            Ok(())
        }
    }

    pub(super) fn destroy_frames(&mut self) {
        unsafe {
            for f in self.frames.drain(..) {
                self.device.destroy_fence(f.fence, None);
                self.device.destroy_semaphore(f.acquired, None);
                self.device.free_command_buffers(self.pool, &[f.cmd]);
                for (i, m, v) in [f.colour, f.depth] {
                    self.device.destroy_image_view(v, None);
                    self.device.destroy_image(i, None);
                    self.device.free_memory(m, None);
                }
                for (b, m, _) in [f.field, f.hud] {
                    self.device.destroy_buffer(b, None);
                    self.device.free_memory(m, None);
                }
            }
        }
    }

    /// Records and submits one frame; returns the field's GPU time (ms) of the frame
    /// that last used this slot, once known.
    pub(super) fn draw(
        &mut self,
        frame: u64,
        fv: &FrameView,
        screenshot: bool,
    ) -> Result<Option<f64>, String> {
        if self.resized {
            self.create_swapchain()?;
        }
        if self.extent.width == 0 || self.extent.height == 0 {
            return Ok(None);
        }
        let s = (frame % FRAMES_IN_FLIGHT as u64) as usize;
        unsafe {
            let dev = self.device.clone();
            let f = &self.frames[s];
            dev.wait_for_fences(&[f.fence], true, u64::MAX)
                .map_err(vkerr("vkWaitForFences"))?;
            let field_ms = if f.pending {
                f.timestamps
                    .stages()
                    .map_err(|e| e.to_string())?
                    .iter()
                    .find(|(l, _)| l == "field")
                    .map(|(_, ms)| *ms)
            } else {
                None
            };
            let (index, _) = match self.swapchain_loader.acquire_next_image(
                self.swapchain,
                u64::MAX,
                f.acquired,
                vk::Fence::null(),
            ) {
                Ok(r) => r,
                Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => {
                    self.resized = true;
                    return Ok(None);
                }
                Err(e) => return Err(format!("vkAcquireNextImageKHR: {e}")),
            };
            let (w, h) = (self.extent.width, self.extent.height);
            // Reverse-Z with an infinite far plane (the viewer's depth convention).
            let (view, proj) = matrices_for(&fv.nav.camera(w, h), None, true);
            let hv = HostView {
                view,
                projection: proj,
                model: Mat4::IDENTITY,
                width: w,
                height: h,
                viewport_y_up: false,
            };
            let dl = vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL;
            // The field's colour goes to a 16F buffer the blend pass reads; the rays end
            // at the host's depth, which receives the field's depth back.
            let field_target = HostTarget {
                color: ColorTarget::Buffer {
                    buffer: f.field.0,
                    offset: 0,
                    format: ColorFormat::Rgba16Float,
                },
                depth: Some(DepthTarget {
                    image: f.depth.0,
                    layout: dl,
                    final_layout: dl,
                    cut_rays: true,
                    write: Some(DepthMode::Median),
                }),
            };
            self.hr.set_image(match fv.mode {
                ViewMode::Colour => HostImage::Colour,
                ViewMode::Depth => {
                    let (near, far) = fv.nav.depth_range();
                    HostImage::Depth { near, far }
                }
                ViewMode::Normal => HostImage::Normal,
            });
            if fv.draw_field {
                // Before recording: reads this slot's previous frame's stats (its fence
                // was waited for above) and grows what it found short.
                let report = self
                    .hr
                    .prepare(frame, &self.scene, &hv, &self.opts, &field_target)
                    .map_err(|e| e.to_string())?;
                if report.grew {
                    eprintln!(
                        "frame {frame}: the field's buffers grew (a frame before missed entries)"
                    );
                }
            }
            dev.reset_fences(&[f.fence]).map_err(vkerr("reset fence"))?;
            let cmd = f.cmd;
            dev.reset_command_buffer(cmd, vk::CommandBufferResetFlags::empty())
                .map_err(vkerr("reset"))?;
            dev.begin_command_buffer(
                cmd,
                &vk::CommandBufferBeginInfo::default()
                    .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
            )
            .map_err(vkerr("begin"))?;
            let area = vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent: self.extent,
            };
            let viewport = vk::Viewport {
                x: 0.0,
                y: 0.0,
                width: w as f32,
                height: h as f32,
                min_depth: 0.0,
                max_depth: 1.0,
            };
            let shot = if screenshot {
                let (b, m, _) = self.buffer(
                    w as u64 * h as u64 * 4,
                    vk::BufferUsageFlags::TRANSFER_DST,
                    true,
                )?;
                Some((b, m))
            } else {
                None
            };
            let f = &mut self.frames[s];
            f.timestamps.begin(cmd);
            // 1. The host's own pass: clear, draw the mesh (reverse-Z: clear 0, GREATER).
            image_barrier(
                &dev,
                cmd,
                f.colour.0,
                vk::ImageAspectFlags::COLOR,
                vk::ImageLayout::UNDEFINED,
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::TRANSFER_READ,
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                vk::AccessFlags::COLOR_ATTACHMENT_READ | vk::AccessFlags::COLOR_ATTACHMENT_WRITE,
            );
            image_barrier(
                &dev,
                cmd,
                f.depth.0,
                vk::ImageAspectFlags::DEPTH,
                vk::ImageLayout::UNDEFINED,
                vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE,
                vk::PipelineStageFlags::EARLY_FRAGMENT_TESTS
                    | vk::PipelineStageFlags::LATE_FRAGMENT_TESTS,
                vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_READ
                    | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE,
            );
            let colour_att = [vk::RenderingAttachmentInfo::default()
                .image_view(f.colour.2)
                .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                .load_op(vk::AttachmentLoadOp::CLEAR)
                .store_op(vk::AttachmentStoreOp::STORE)
                .clear_value(vk::ClearValue {
                    color: vk::ClearColorValue {
                        // Depth and normal images are drawn over black.
                        float32: if fv.mode == ViewMode::Colour {
                            self.clear
                        } else {
                            [0.0, 0.0, 0.0, 1.0]
                        },
                    },
                })];
            let depth_att = vk::RenderingAttachmentInfo::default()
                .image_view(f.depth.2)
                .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
                .load_op(vk::AttachmentLoadOp::CLEAR)
                .store_op(vk::AttachmentStoreOp::STORE)
                .clear_value(vk::ClearValue {
                    depth_stencil: vk::ClearDepthStencilValue {
                        depth: 0.0,
                        stencil: 0,
                    },
                });
            dev.cmd_begin_rendering(
                cmd,
                &vk::RenderingInfo::default()
                    .render_area(area)
                    .layer_count(1)
                    .color_attachments(&colour_att)
                    .depth_attachment(&depth_att),
            );
            if fv.draw_geometry {
                let draws = [
                    (self.mesh_pipeline, 0, self.triangle_vertices),
                    (
                        self.line_pipeline,
                        self.triangle_vertices,
                        self.line_vertices,
                    ),
                ];
                for (pipeline, first, count) in draws {
                    if count == 0 {
                        continue;
                    }
                    dev.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline.0);
                    dev.cmd_set_viewport(cmd, 0, &[viewport]);
                    dev.cmd_set_scissor(cmd, 0, &[area]);
                    let mut push = [0u8; 72];
                    push[..64].copy_from_slice(bytemuck::bytes_of(&(proj * view).to_cols_array()));
                    let address = self.vertices.2 + first as u64 * 24;
                    push[64..].copy_from_slice(&address.to_le_bytes());
                    dev.cmd_push_constants(cmd, pipeline.1, vk::ShaderStageFlags::VERTEX, 0, &push);
                    dev.cmd_draw(cmd, count, 1, 0, 0);
                }
            }
            dev.cmd_end_rendering(cmd);
            f.timestamps.mark(cmd, "mesh");
            // 2. The field, cut at the host's depth, writing its depth back.
            if fv.draw_field {
                self.hr
                    .record(cmd, frame, &self.scene, &hv, &self.opts, &field_target)
                    .map_err(|e| e.to_string())?;
            }
            f.timestamps.mark(cmd, "field");
            // 3. Blend the premultiplied field over the host's colour.
            let mb = [vk::MemoryBarrier::default()
                .src_access_mask(vk::AccessFlags::COLOR_ATTACHMENT_WRITE)
                .dst_access_mask(
                    vk::AccessFlags::COLOR_ATTACHMENT_READ
                        | vk::AccessFlags::COLOR_ATTACHMENT_WRITE,
                )];
            dev.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                vk::DependencyFlags::empty(),
                &mb,
                &[],
                &[],
            );
            // The overlay, rasterised into this slot's buffer (its previous frame is done).
            let hud = match fv.hud {
                Some(lines) => {
                    let (hw, hh) = f.hud_size;
                    let (hw, hh, px) = self.hud.raster(lines, hw, hh);
                    let bytes: &[u8] = bytemuck::cast_slice(&px);
                    let ptr = dev
                        .map_memory(f.hud.1, 0, bytes.len() as u64, vk::MemoryMapFlags::empty())
                        .map_err(vkerr("vkMapMemory"))?;
                    std::ptr::copy_nonoverlapping(bytes.as_ptr(), ptr as *mut u8, bytes.len());
                    dev.unmap_memory(f.hud.1);
                    Some((hw, hh))
                }
                None => None,
            };
            if fv.draw_field || hud.is_some() {
                let load_att = [vk::RenderingAttachmentInfo::default()
                    .image_view(f.colour.2)
                    .image_layout(vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL)
                    .load_op(vk::AttachmentLoadOp::LOAD)
                    .store_op(vk::AttachmentStoreOp::STORE)];
                dev.cmd_begin_rendering(
                    cmd,
                    &vk::RenderingInfo::default()
                        .render_area(area)
                        .layer_count(1)
                        .color_attachments(&load_att),
                );
                dev.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.blend_pipeline.0);
                dev.cmd_set_viewport(cmd, 0, &[viewport]);
                // The field over the whole frame, then the overlay in its corner (the
                // blend reads pixel (x, y) of a buffer `width` pixels wide).
                let mut blends = vec![];
                if fv.draw_field {
                    blends.push((f.field.2, w, area));
                }
                if let Some((hw, hh)) = hud {
                    let rect = vk::Rect2D {
                        offset: vk::Offset2D::default(),
                        extent: vk::Extent2D {
                            width: hw,
                            height: hh,
                        },
                    };
                    blends.push((f.hud.2, hw, rect));
                }
                let display = (self.colour_format == vk::Format::R8G8B8A8_UNORM) as u32;
                for (address, width, scissor) in blends {
                    dev.cmd_set_scissor(cmd, 0, &[scissor]);
                    let mut push = [0u8; 16];
                    push[..8].copy_from_slice(&address.to_le_bytes());
                    push[8..12].copy_from_slice(&width.to_le_bytes());
                    push[12..].copy_from_slice(&display.to_le_bytes());
                    dev.cmd_push_constants(
                        cmd,
                        self.blend_pipeline.1,
                        vk::ShaderStageFlags::FRAGMENT,
                        0,
                        &push,
                    );
                    dev.cmd_draw(cmd, 3, 1, 0, 0);
                }
                dev.cmd_end_rendering(cmd);
            }
            // 4. To the swapchain image (and the screenshot buffer).
            image_barrier(
                &dev,
                cmd,
                f.colour.0,
                vk::ImageAspectFlags::COLOR,
                vk::ImageLayout::COLOR_ATTACHMENT_OPTIMAL,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                vk::PipelineStageFlags::COLOR_ATTACHMENT_OUTPUT,
                vk::AccessFlags::COLOR_ATTACHMENT_WRITE,
                vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::TRANSFER_READ,
            );
            let target = self.images[index as usize];
            image_barrier(
                &dev,
                cmd,
                target,
                vk::ImageAspectFlags::COLOR,
                vk::ImageLayout::UNDEFINED,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::empty(),
                vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::TRANSFER_WRITE,
            );
            let layers = vk::ImageSubresourceLayers {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                mip_level: 0,
                base_array_layer: 0,
                layer_count: 1,
            };
            let corner = vk::Offset3D {
                x: w as i32,
                y: h as i32,
                z: 1,
            };
            dev.cmd_blit_image(
                cmd,
                f.colour.0,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                target,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[vk::ImageBlit {
                    src_subresource: layers,
                    src_offsets: [vk::Offset3D::default(), corner],
                    dst_subresource: layers,
                    dst_offsets: [vk::Offset3D::default(), corner],
                }],
                vk::Filter::NEAREST,
            );
            if screenshot {
                let (b, m) = shot.expect("made above");
                dev.cmd_copy_image_to_buffer(
                    cmd,
                    f.colour.0,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    b,
                    &[vk::BufferImageCopy {
                        buffer_offset: 0,
                        buffer_row_length: 0,
                        buffer_image_height: 0,
                        image_subresource: layers,
                        image_offset: vk::Offset3D::default(),
                        image_extent: vk::Extent3D {
                            width: w,
                            height: h,
                            depth: 1,
                        },
                    }],
                );
                let hb = [vk::MemoryBarrier::default()
                    .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                    .dst_access_mask(vk::AccessFlags::HOST_READ)];
                dev.cmd_pipeline_barrier(
                    cmd,
                    vk::PipelineStageFlags::TRANSFER,
                    vk::PipelineStageFlags::HOST,
                    vk::DependencyFlags::empty(),
                    &hb,
                    &[],
                    &[],
                );
                self.screenshot = Some((b, m));
                self.screenshot_frame = Some(s);
            }
            image_barrier(
                &dev,
                cmd,
                target,
                vk::ImageAspectFlags::COLOR,
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                vk::ImageLayout::PRESENT_SRC_KHR,
                vk::PipelineStageFlags::TRANSFER,
                vk::AccessFlags::TRANSFER_WRITE,
                vk::PipelineStageFlags::BOTTOM_OF_PIPE,
                vk::AccessFlags::empty(),
            );
            let f = &mut self.frames[s];
            f.timestamps.mark(cmd, "composite");
            dev.end_command_buffer(cmd).map_err(vkerr("end"))?;
            let waits = [f.acquired];
            let stages = [vk::PipelineStageFlags::TRANSFER];
            let cmds = [cmd];
            let signals = [self.presented[index as usize]];
            dev.queue_submit(
                self.queue,
                &[vk::SubmitInfo::default()
                    .wait_semaphores(&waits)
                    .wait_dst_stage_mask(&stages)
                    .command_buffers(&cmds)
                    .signal_semaphores(&signals)],
                f.fence,
            )
            .map_err(vkerr("vkQueueSubmit"))?;
            f.pending = true;
            let swapchains = [self.swapchain];
            let indices = [index];
            match self.swapchain_loader.queue_present(
                self.queue,
                &vk::PresentInfoKHR::default()
                    .wait_semaphores(&signals)
                    .swapchains(&swapchains)
                    .image_indices(&indices),
            ) {
                Ok(false) => {}
                Ok(true) | Err(vk::Result::ERROR_OUT_OF_DATE_KHR) => self.resized = true,
                Err(e) => return Err(format!("vkQueuePresentKHR: {e}")),
            }
            Ok(field_ms)
        }
    }

    /// Waits for the screenshot frame and writes it as a PNG.
    pub(super) fn save_screenshot(&mut self, path: &Path) -> Result<(), String> {
        let (Some((b, m)), Some(s)) = (self.screenshot.take(), self.screenshot_frame) else {
            return Err("no screenshot frame was recorded".into());
        };
        unsafe {
            self.device
                .wait_for_fences(&[self.frames[s].fence], true, u64::MAX)
                .map_err(vkerr("vkWaitForFences"))?;
            let (w, h) = (self.extent.width, self.extent.height);
            let n = (w * h * 4) as usize;
            let ptr = self
                .device
                .map_memory(m, 0, n as u64, vk::MemoryMapFlags::empty())
                .map_err(vkerr("vkMapMemory"))?;
            let mut pixels = std::slice::from_raw_parts(ptr as *const u8, n).to_vec();
            self.device.unmap_memory(m);
            self.device.destroy_buffer(b, None);
            self.device.free_memory(m, None);
            for p in pixels.chunks_mut(4) {
                p[3] = 255;
            }
            let mut png = vec![];
            image::codecs::png::PngEncoder::new(&mut png)
                .write_image(&pixels, w, h, image::ExtendedColorType::Rgba8)
                .map_err(|e| e.to_string())?;
            crate::fsio::write_atomic(path, &png).map_err(|e| e.to_string())
        }
    }
}
