//! A minimal host engine for the embedding tests: its own instance (validation layer,
//! optionally synchronisation validation, its own messenger), device, queue, command
//! pool, images and buffers, and a depth-only graphics pipeline of its own.

use std::ffi::{c_void, CStr};
use std::sync::{Arc, Mutex};

use ash::vk;
use svraster::gpu::{BorrowedHandles, Context};

/// The validation messages one host's messenger received. Each host has its own, so a
/// test that fails and leaks its objects does not fail the tests after it.
pub type HostLog = Arc<Mutex<Vec<String>>>;

unsafe extern "system" fn callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _ty: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    user: *mut c_void,
) -> vk::Bool32 {
    if severity.intersects(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
    ) {
        let msg = CStr::from_ptr((*data).p_message).to_string_lossy();
        eprintln!("[host validation] {msg}");
        // The host's log (Host::new passes it; it outlives the messenger).
        let log = &*(user as *const Mutex<Vec<String>>);
        log.lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(msg.into_owned());
    }
    vk::FALSE
}

/// Asserts the host whose log this is (`Host::log`) reported nothing.
pub fn assert_host_clean(log: &HostLog) {
    let l = log.lock().unwrap_or_else(|e| e.into_inner());
    assert!(
        l.is_empty(),
        "validation messages on the host's messenger:\n{}",
        l.join("\n")
    );
}

pub struct Host {
    pub entry: ash::Entry,
    pub instance: ash::Instance,
    du: ash::ext::debug_utils::Instance,
    messenger: vk::DebugUtilsMessengerEXT,
    pub pdev: vk::PhysicalDevice,
    pub device: ash::Device,
    pub qf: u32,
    pub queue: vk::Queue,
    pub pool: vk::CommandPool,
    log: HostLog,
}

/// A host-owned buffer in host-visible, coherent memory (mapped).
pub struct HostBuffer {
    pub buffer: vk::Buffer,
    memory: vk::DeviceMemory,
    pub ptr: *mut u8,
    pub size: u64,
}

impl HostBuffer {
    pub fn read<T: bytemuck::Pod>(&self) -> Vec<T> {
        let bytes = unsafe { std::slice::from_raw_parts(self.ptr, self.size as usize) };
        bytemuck::pod_collect_to_vec(bytes)
    }
}

/// A host-owned 2-D image in device memory.
pub struct HostImage {
    pub image: vk::Image,
    memory: vk::DeviceMemory,
}

impl Host {
    /// A host with the validation layer; `sync` adds synchronisation validation.
    pub fn new(sync: bool) -> Host {
        unsafe {
            let entry = ash::Entry::load().expect("libvulkan");
            let layers = [c"VK_LAYER_KHRONOS_validation".as_ptr()];
            let exts = [ash::ext::debug_utils::NAME.as_ptr()];
            let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
            let enables = [vk::ValidationFeatureEnableEXT::SYNCHRONIZATION_VALIDATION];
            let mut features = vk::ValidationFeaturesEXT::default()
                .enabled_validation_features(if sync { &enables } else { &[] });
            let instance = entry
                .create_instance(
                    &vk::InstanceCreateInfo::default()
                        .application_info(&app)
                        .enabled_layer_names(&layers)
                        .enabled_extension_names(&exts)
                        .push_next(&mut features),
                    None,
                )
                .expect("host instance (needs vulkan-validationlayers)");
            let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
            let log: HostLog = Arc::new(Mutex::new(Vec::new()));
            let messenger = du
                .create_debug_utils_messenger(
                    &vk::DebugUtilsMessengerCreateInfoEXT::default()
                        .message_severity(
                            vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
                                | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
                        )
                        .message_type(
                            vk::DebugUtilsMessageTypeFlagsEXT::VALIDATION
                                | vk::DebugUtilsMessageTypeFlagsEXT::GENERAL,
                        )
                        .pfn_user_callback(Some(callback))
                        .user_data(Arc::as_ptr(&log) as *mut c_void),
                    None,
                )
                .unwrap();
            // The host picks a device and a graphics + compute queue family and enables
            // what the engine documents as required (Context::required_device_features),
            // plus dynamic rendering for its own drawing.
            let pdev = instance.enumerate_physical_devices().unwrap()[0];
            let qf = instance
                .get_physical_device_queue_family_properties(pdev)
                .iter()
                .position(|f| {
                    f.queue_flags
                        .contains(vk::QueueFlags::COMPUTE | vk::QueueFlags::GRAPHICS)
                })
                .unwrap() as u32;
            let prio = [1.0f32];
            let qci = [vk::DeviceQueueCreateInfo::default()
                .queue_family_index(qf)
                .queue_priorities(&prio)];
            let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
                .buffer_device_address(true)
                .shader_buffer_int64_atomics(true);
            let mut f13 = vk::PhysicalDeviceVulkan13Features::default().dynamic_rendering(true);
            let mut f2 = vk::PhysicalDeviceFeatures2::default()
                .features(vk::PhysicalDeviceFeatures::default().shader_int64(true))
                .push_next(&mut f12)
                .push_next(&mut f13);
            let device = instance
                .create_device(
                    pdev,
                    &vk::DeviceCreateInfo::default()
                        .queue_create_infos(&qci)
                        .push_next(&mut f2),
                    None,
                )
                .expect("host device");
            let queue = device.get_device_queue(qf, 0);
            let pool = device
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default()
                        .queue_family_index(qf)
                        .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                    None,
                )
                .unwrap();
            Host {
                entry,
                instance,
                du,
                messenger,
                pdev,
                device,
                qf,
                queue,
                pool,
                log,
            }
        }
    }

    /// This host's validation log (see [`assert_host_clean`]); keep it past the host's
    /// drop, whose messages it also collects.
    pub fn log(&self) -> HostLog {
        self.log.clone()
    }

    /// The engine's context on the host's device and queue.
    pub fn context(&self) -> Context {
        Context::borrowed(BorrowedHandles {
            entry: self.entry.clone(),
            instance: self.instance.clone(),
            physical_device: self.pdev,
            device: self.device.clone(),
            queue_family_index: self.qf,
            queue_index: 0,
            debug_utils: true,
            float_atomic_add: false,
            full_subgroups: false,
            conditional_rendering: false,
        })
        .expect("borrow the host device")
    }

    fn memory_type(&self, bits: u32, flags: vk::MemoryPropertyFlags) -> u32 {
        let props = unsafe {
            self.instance
                .get_physical_device_memory_properties(self.pdev)
        };
        (0..props.memory_type_count)
            .find(|&i| {
                bits & (1 << i) != 0
                    && props.memory_types[i as usize]
                        .property_flags
                        .contains(flags)
            })
            .expect("memory type")
    }

    /// A mapped host-visible buffer.
    pub fn buffer(&self, size: u64, usage: vk::BufferUsageFlags) -> HostBuffer {
        unsafe {
            let buffer = self
                .device
                .create_buffer(
                    &vk::BufferCreateInfo::default()
                        .size(size)
                        .usage(usage | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS),
                    None,
                )
                .unwrap();
            let req = self.device.get_buffer_memory_requirements(buffer);
            let mut flags = vk::MemoryAllocateFlagsInfo::default()
                .flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
            let memory = self
                .device
                .allocate_memory(
                    &vk::MemoryAllocateInfo::default()
                        .allocation_size(req.size)
                        .memory_type_index(self.memory_type(
                            req.memory_type_bits,
                            vk::MemoryPropertyFlags::HOST_VISIBLE
                                | vk::MemoryPropertyFlags::HOST_COHERENT,
                        ))
                        .push_next(&mut flags),
                    None,
                )
                .unwrap();
            self.device.bind_buffer_memory(buffer, memory, 0).unwrap();
            let ptr = self
                .device
                .map_memory(memory, 0, size, vk::MemoryMapFlags::empty())
                .unwrap() as *mut u8;
            HostBuffer {
                buffer,
                memory,
                ptr,
                size,
            }
        }
    }

    pub fn address(&self, b: &HostBuffer) -> u64 {
        unsafe {
            self.device
                .get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(b.buffer))
        }
    }

    /// A device-local 2-D image.
    pub fn image(
        &self,
        w: u32,
        h: u32,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
    ) -> HostImage {
        unsafe {
            let image = self
                .device
                .create_image(
                    &vk::ImageCreateInfo::default()
                        .image_type(vk::ImageType::TYPE_2D)
                        .format(format)
                        .extent(vk::Extent3D {
                            width: w,
                            height: h,
                            depth: 1,
                        })
                        .mip_levels(1)
                        .array_layers(1)
                        .samples(vk::SampleCountFlags::TYPE_1)
                        .tiling(vk::ImageTiling::OPTIMAL)
                        .usage(usage)
                        .initial_layout(vk::ImageLayout::UNDEFINED),
                    None,
                )
                .unwrap();
            let req = self.device.get_image_memory_requirements(image);
            let memory = self
                .device
                .allocate_memory(
                    &vk::MemoryAllocateInfo::default()
                        .allocation_size(req.size)
                        .memory_type_index(self.memory_type(
                            req.memory_type_bits,
                            vk::MemoryPropertyFlags::DEVICE_LOCAL,
                        )),
                    None,
                )
                .unwrap();
            self.device.bind_image_memory(image, memory, 0).unwrap();
            HostImage { image, memory }
        }
    }

    pub fn destroy_buffer(&self, b: HostBuffer) {
        unsafe {
            self.device.destroy_buffer(b.buffer, None);
            self.device.free_memory(b.memory, None);
        }
    }

    pub fn destroy_image(&self, i: HostImage) {
        unsafe {
            self.device.destroy_image(i.image, None);
            self.device.free_memory(i.memory, None);
        }
    }

    pub fn command_buffers(&self, n: u32) -> Vec<vk::CommandBuffer> {
        unsafe {
            self.device
                .allocate_command_buffers(
                    &vk::CommandBufferAllocateInfo::default()
                        .command_pool(self.pool)
                        .command_buffer_count(n),
                )
                .unwrap()
        }
    }

    /// Records with `f` and submits; waits on the returned fence before reuse.
    pub fn submit(
        &self,
        cmd: vk::CommandBuffer,
        fence: vk::Fence,
        f: impl FnOnce(vk::CommandBuffer),
    ) {
        unsafe {
            self.device
                .reset_command_buffer(cmd, vk::CommandBufferResetFlags::empty())
                .unwrap();
            self.device
                .begin_command_buffer(
                    cmd,
                    &vk::CommandBufferBeginInfo::default()
                        .flags(vk::CommandBufferUsageFlags::ONE_TIME_SUBMIT),
                )
                .unwrap();
            f(cmd);
            self.device.end_command_buffer(cmd).unwrap();
            let cmds = [cmd];
            self.device
                .queue_submit(
                    self.queue,
                    &[vk::SubmitInfo::default().command_buffers(&cmds)],
                    fence,
                )
                .unwrap();
        }
    }

    pub fn fence(&self, signaled: bool) -> vk::Fence {
        let flags = if signaled {
            vk::FenceCreateFlags::SIGNALED
        } else {
            vk::FenceCreateFlags::empty()
        };
        unsafe {
            self.device
                .create_fence(&vk::FenceCreateInfo::default().flags(flags), None)
                .unwrap()
        }
    }

    pub fn wait(&self, fence: vk::Fence) {
        unsafe {
            self.device
                .wait_for_fences(&[fence], true, u64::MAX)
                .unwrap();
            self.device.reset_fences(&[fence]).unwrap();
        }
    }

    /// A depth-only pipeline (dynamic rendering, D32_SFLOAT) drawing the vertices of
    /// `glsl/host/mesh.vert`; `reverse` tests with GREATER.
    pub fn depth_pipeline(&self, reverse: bool) -> (vk::Pipeline, vk::PipelineLayout) {
        unsafe {
            let code = ash::util::read_spv(&mut std::io::Cursor::new(
                svraster::gpu::graphics::HOST_MESH_VERT,
            ))
            .unwrap();
            let module = self
                .device
                .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None)
                .unwrap();
            let ranges = [vk::PushConstantRange {
                stage_flags: vk::ShaderStageFlags::VERTEX,
                offset: 0,
                size: 72,
            }];
            let layout = self
                .device
                .create_pipeline_layout(
                    &vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&ranges),
                    None,
                )
                .unwrap();
            let stages = [vk::PipelineShaderStageCreateInfo::default()
                .stage(vk::ShaderStageFlags::VERTEX)
                .module(module)
                .name(c"main")];
            let vi = vk::PipelineVertexInputStateCreateInfo::default();
            let ia = vk::PipelineInputAssemblyStateCreateInfo::default()
                .topology(vk::PrimitiveTopology::TRIANGLE_LIST);
            let vp = vk::PipelineViewportStateCreateInfo::default()
                .viewport_count(1)
                .scissor_count(1);
            let rs = vk::PipelineRasterizationStateCreateInfo::default()
                .polygon_mode(vk::PolygonMode::FILL)
                .cull_mode(vk::CullModeFlags::NONE)
                .line_width(1.0);
            let ms = vk::PipelineMultisampleStateCreateInfo::default()
                .rasterization_samples(vk::SampleCountFlags::TYPE_1);
            let ds = vk::PipelineDepthStencilStateCreateInfo::default()
                .depth_test_enable(true)
                .depth_write_enable(true)
                .depth_compare_op(if reverse {
                    vk::CompareOp::GREATER
                } else {
                    vk::CompareOp::LESS
                });
            let cb = vk::PipelineColorBlendStateCreateInfo::default();
            let dynamic = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
            let dy = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic);
            let mut rendering = vk::PipelineRenderingCreateInfo::default()
                .depth_attachment_format(vk::Format::D32_SFLOAT);
            let info = vk::GraphicsPipelineCreateInfo::default()
                .stages(&stages)
                .vertex_input_state(&vi)
                .input_assembly_state(&ia)
                .viewport_state(&vp)
                .rasterization_state(&rs)
                .multisample_state(&ms)
                .depth_stencil_state(&ds)
                .color_blend_state(&cb)
                .dynamic_state(&dy)
                .layout(layout)
                .push_next(&mut rendering);
            let pipeline = self
                .device
                .create_graphics_pipelines(vk::PipelineCache::null(), &[info], None)
                .unwrap()[0];
            self.device.destroy_shader_module(module, None);
            (pipeline, layout)
        }
    }

    /// Records a depth pass: `depth` from UNDEFINED, cleared to `clear`, the triangles
    /// of `vertices` drawn, left in DEPTH_ATTACHMENT_OPTIMAL. Returns the attachment's
    /// view, to destroy once the command buffer completed.
    #[allow(clippy::too_many_arguments)]
    pub fn record_depth_pass(
        &self,
        cmd: vk::CommandBuffer,
        pipeline: (vk::Pipeline, vk::PipelineLayout),
        depth: vk::Image,
        w: u32,
        h: u32,
        clear: f32,
        view_projection: glam::Mat4,
        vertices: u64,
        count: u32,
    ) -> vk::ImageView {
        let dev = &self.device;
        let range = vk::ImageSubresourceRange {
            aspect_mask: vk::ImageAspectFlags::DEPTH,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        };
        unsafe {
            dev.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::PipelineStageFlags::EARLY_FRAGMENT_TESTS
                    | vk::PipelineStageFlags::LATE_FRAGMENT_TESTS,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[vk::ImageMemoryBarrier::default()
                    .src_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE)
                    .dst_access_mask(
                        vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_READ
                            | vk::AccessFlags::DEPTH_STENCIL_ATTACHMENT_WRITE,
                    )
                    .old_layout(vk::ImageLayout::UNDEFINED)
                    .new_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
                    .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                    .image(depth)
                    .subresource_range(range)],
            );
            let view = dev
                .create_image_view(
                    &vk::ImageViewCreateInfo::default()
                        .image(depth)
                        .view_type(vk::ImageViewType::TYPE_2D)
                        .format(vk::Format::D32_SFLOAT)
                        .subresource_range(range),
                    None,
                )
                .unwrap();
            let att = vk::RenderingAttachmentInfo::default()
                .image_view(view)
                .image_layout(vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL)
                .load_op(vk::AttachmentLoadOp::CLEAR)
                .store_op(vk::AttachmentStoreOp::STORE)
                .clear_value(vk::ClearValue {
                    depth_stencil: vk::ClearDepthStencilValue {
                        depth: clear,
                        stencil: 0,
                    },
                });
            let area = vk::Rect2D {
                offset: vk::Offset2D::default(),
                extent: vk::Extent2D {
                    width: w,
                    height: h,
                },
            };
            dev.cmd_begin_rendering(
                cmd,
                &vk::RenderingInfo::default()
                    .render_area(area)
                    .layer_count(1)
                    .depth_attachment(&att),
            );
            dev.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, pipeline.0);
            dev.cmd_set_viewport(
                cmd,
                0,
                &[vk::Viewport {
                    x: 0.0,
                    y: 0.0,
                    width: w as f32,
                    height: h as f32,
                    min_depth: 0.0,
                    max_depth: 1.0,
                }],
            );
            dev.cmd_set_scissor(cmd, 0, &[area]);
            let mut push = [0u8; 72];
            push[..64].copy_from_slice(bytemuck::bytes_of(&view_projection.to_cols_array()));
            push[64..].copy_from_slice(&vertices.to_le_bytes());
            dev.cmd_push_constants(cmd, pipeline.1, vk::ShaderStageFlags::VERTEX, 0, &push);
            dev.cmd_draw(cmd, count, 1, 0, 0);
            dev.cmd_end_rendering(cmd);
            view
        }
    }

    /// Records a colour image's transition `old` → `new` (full barrier).
    pub fn transition(
        &self,
        cmd: vk::CommandBuffer,
        image: vk::Image,
        old: vk::ImageLayout,
        new: vk::ImageLayout,
    ) {
        let b = vk::ImageMemoryBarrier::default()
            .src_access_mask(vk::AccessFlags::MEMORY_WRITE)
            .dst_access_mask(vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE)
            .old_layout(old)
            .new_layout(new)
            .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
            .image(image)
            .subresource_range(vk::ImageSubresourceRange {
                aspect_mask: vk::ImageAspectFlags::COLOR,
                base_mip_level: 0,
                level_count: 1,
                base_array_layer: 0,
                layer_count: 1,
            });
        unsafe {
            self.device.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[b],
            )
        };
    }

    /// Records a copy of a whole image aspect into `dst` (image in `layout`, left there),
    /// with the barriers around it.
    #[allow(clippy::too_many_arguments)]
    pub fn record_image_to_buffer(
        &self,
        cmd: vk::CommandBuffer,
        image: vk::Image,
        aspect: vk::ImageAspectFlags,
        layout: vk::ImageLayout,
        w: u32,
        h: u32,
        dst: &HostBuffer,
    ) {
        let dev = &self.device;
        let range = vk::ImageSubresourceRange {
            aspect_mask: aspect,
            base_mip_level: 0,
            level_count: 1,
            base_array_layer: 0,
            layer_count: 1,
        };
        let to = |old, new, src, dstm| {
            vk::ImageMemoryBarrier::default()
                .src_access_mask(src)
                .dst_access_mask(dstm)
                .old_layout(old)
                .new_layout(new)
                .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
                .image(image)
                .subresource_range(range)
        };
        unsafe {
            dev.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::ALL_COMMANDS,
                vk::PipelineStageFlags::TRANSFER,
                vk::DependencyFlags::empty(),
                &[],
                &[],
                &[to(
                    layout,
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    vk::AccessFlags::MEMORY_WRITE,
                    vk::AccessFlags::TRANSFER_READ,
                )],
            );
            dev.cmd_copy_image_to_buffer(
                cmd,
                image,
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.buffer,
                &[vk::BufferImageCopy {
                    buffer_offset: 0,
                    buffer_row_length: 0,
                    buffer_image_height: 0,
                    image_subresource: vk::ImageSubresourceLayers {
                        aspect_mask: aspect,
                        mip_level: 0,
                        base_array_layer: 0,
                        layer_count: 1,
                    },
                    image_offset: vk::Offset3D::default(),
                    image_extent: vk::Extent3D {
                        width: w,
                        height: h,
                        depth: 1,
                    },
                }],
            );
            dev.cmd_pipeline_barrier(
                cmd,
                vk::PipelineStageFlags::TRANSFER,
                vk::PipelineStageFlags::ALL_COMMANDS | vk::PipelineStageFlags::HOST,
                vk::DependencyFlags::empty(),
                &[vk::MemoryBarrier::default()
                    .src_access_mask(vk::AccessFlags::TRANSFER_WRITE)
                    .dst_access_mask(vk::AccessFlags::HOST_READ)],
                &[],
                &[to(
                    vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                    layout,
                    vk::AccessFlags::empty(),
                    vk::AccessFlags::MEMORY_READ | vk::AccessFlags::MEMORY_WRITE,
                )],
            );
        }
    }
}

/// Waits for the host's device to go idle when dropped: declared after a
/// `HostRenderer`, it drops first, so a test that panics with frames in flight does not
/// free the renderer's buffers under the GPU (on the H200 that panic's unwinding
/// destroyed buffers still in use, and the test binary later died of SIGSEGV).
pub struct IdleOnDrop<'a>(&'a ash::Device);

impl Drop for IdleOnDrop<'_> {
    fn drop(&mut self) {
        unsafe {
            let _ = self.0.device_wait_idle();
        }
    }
}

impl Host {
    /// See [`IdleOnDrop`].
    pub fn idle_on_drop(&self) -> IdleOnDrop<'_> {
        IdleOnDrop(&self.device)
    }
}

impl Drop for Host {
    fn drop(&mut self) {
        unsafe {
            self.device
                .device_wait_idle()
                .expect("host device still alive after the engine dropped");
            self.device.destroy_command_pool(self.pool, None);
            self.device.destroy_device(None);
            self.du.destroy_debug_utils_messenger(self.messenger, None);
            self.instance.destroy_instance(None);
        }
    }
}
