//! The viewer's Vulkan set-up: device, queue, memory, buffers, images and the three
//! graphics pipelines (the host's triangles and lines, and the blend of the engine's
//! frame and of the overlay).

use super::*;

/// The graphics pipelines.
#[derive(Clone, Copy, PartialEq, Eq)]
pub(super) enum Pass {
    Triangles,
    Lines,
    Blend,
}

impl Gpu {
    pub(super) fn new(window: Window, scene: &Scene, opts: &ViewerOptions) -> Result<Gpu, String> {
        unsafe {
            let entry = ash::Entry::load().map_err(|e| format!("no Vulkan loader: {e}"))?;
            let display = window.display_handle().map_err(|e| e.to_string())?.as_raw();
            let win = window.window_handle().map_err(|e| e.to_string())?.as_raw();
            let mut exts = ash_window::enumerate_required_extensions(display)
                .map_err(vkerr("surface extensions"))?
                .to_vec();
            let mut layers = vec![];
            if opts.validation {
                exts.push(ash::ext::debug_utils::NAME.as_ptr());
                layers.push(c"VK_LAYER_KHRONOS_validation".as_ptr());
            }
            let app = vk::ApplicationInfo::default().api_version(vk::API_VERSION_1_3);
            let instance = entry
                .create_instance(
                    &vk::InstanceCreateInfo::default()
                        .application_info(&app)
                        .enabled_extension_names(&exts)
                        .enabled_layer_names(&layers),
                    None,
                )
                .map_err(vkerr("vkCreateInstance"))?;
            let debug = if opts.validation {
                let du = ash::ext::debug_utils::Instance::new(&entry, &instance);
                let m = du
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
                            .pfn_user_callback(Some(debug_callback)),
                        None,
                    )
                    .map_err(vkerr("debug messenger"))?;
                Some((du, m))
            } else {
                None
            };
            let surface = ash_window::create_surface(&entry, &instance, display, win, None)
                .map_err(vkerr("vkCreate*SurfaceKHR"))?;
            let surface_loader = ash::khr::surface::Instance::new(&entry, &instance);
            // A device with a queue family that draws, computes and presents.
            let mut pick = None;
            for pdev in instance
                .enumerate_physical_devices()
                .map_err(vkerr("devices"))?
            {
                let fams = instance.get_physical_device_queue_family_properties(pdev);
                for (i, f) in fams.iter().enumerate() {
                    let ok = f
                        .queue_flags
                        .contains(vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE)
                        && surface_loader
                            .get_physical_device_surface_support(pdev, i as u32, surface)
                            .unwrap_or(false);
                    if ok && pick.is_none() {
                        pick = Some((pdev, i as u32));
                    }
                }
            }
            let (pdev, qf) =
                pick.ok_or("no device can draw, compute and present to this window")?;
            let props = instance.get_physical_device_properties(pdev);
            let device_name = props
                .device_name_as_c_str()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            // What the engine requires (Context::required_device_features), plus dynamic
            // rendering and, where the device has them, full subgroups.
            let mut sup13 = vk::PhysicalDeviceVulkan13Features::default();
            let mut sup = vk::PhysicalDeviceFeatures2::default().push_next(&mut sup13);
            instance.get_physical_device_features2(pdev, &mut sup);
            let full_subgroups =
                sup13.subgroup_size_control == vk::TRUE && sup13.compute_full_subgroups == vk::TRUE;
            let prio = [1.0f32];
            let qci = [vk::DeviceQueueCreateInfo::default()
                .queue_family_index(qf)
                .queue_priorities(&prio)];
            let mut f12 = vk::PhysicalDeviceVulkan12Features::default()
                .buffer_device_address(true)
                .shader_buffer_int64_atomics(true);
            let mut f13 = vk::PhysicalDeviceVulkan13Features::default()
                .dynamic_rendering(true)
                .subgroup_size_control(full_subgroups)
                .compute_full_subgroups(full_subgroups);
            let mut f2 = vk::PhysicalDeviceFeatures2::default()
                .features(vk::PhysicalDeviceFeatures::default().shader_int64(true))
                .push_next(&mut f12)
                .push_next(&mut f13);
            let dexts = [ash::khr::swapchain::NAME.as_ptr()];
            let device = instance
                .create_device(
                    pdev,
                    &vk::DeviceCreateInfo::default()
                        .queue_create_infos(&qci)
                        .enabled_extension_names(&dexts)
                        .push_next(&mut f2),
                    None,
                )
                .map_err(vkerr("vkCreateDevice"))?;
            let queue = device.get_device_queue(qf, 0);
            let ctx = Context::borrowed(BorrowedHandles {
                entry: entry.clone(),
                instance: instance.clone(),
                physical_device: pdev,
                device: device.clone(),
                queue_family_index: qf,
                queue_index: 0,
                debug_utils: opts.validation,
                float_atomic_add: false,
                full_subgroups,
                conditional_rendering: false,
            })
            .map_err(|e| e.to_string())?;
            let scene_gpu = SceneGpu::upload(&ctx, scene).map_err(|e| e.to_string())?;
            let hr = HostRenderer::new(&ctx, FRAMES_IN_FLIGHT as u32).map_err(|e| e.to_string())?;
            let pool = device
                .create_command_pool(
                    &vk::CommandPoolCreateInfo::default()
                        .queue_family_index(qf)
                        .flags(vk::CommandPoolCreateFlags::RESET_COMMAND_BUFFER),
                    None,
                )
                .map_err(vkerr("vkCreateCommandPool"))?;
            let swapchain_loader = ash::khr::swapchain::Device::new(&instance, &device);
            let mut mesh = opts.triangles.clone();
            mesh.extend_from_slice(&opts.lines);
            // A buffer of at least one vertex (none drawn when there is no geometry).
            mesh.resize(mesh.len().max(6), 0.0);
            let mut gpu = Gpu {
                hr: ManuallyDrop::new(hr),
                scene: ManuallyDrop::new(scene_gpu),
                ctx: ManuallyDrop::new(ctx),
                opts: RenderOptions {
                    samples: opts.samples,
                    supersample: scene.supersample.max(1.0),
                },
                clear: [opts.clear[0], opts.clear[1], opts.clear[2], 1.0],
                colour_format: if opts.display_blend {
                    vk::Format::R8G8B8A8_UNORM
                } else {
                    vk::Format::R8G8B8A8_SRGB
                },
                hud: hud::Hud::new()?,
                frames: vec![],
                swapchain: vk::SwapchainKHR::null(),
                images: vec![],
                presented: vec![],
                extent: vk::Extent2D::default(),
                resized: false,
                mesh_pipeline: (vk::Pipeline::null(), vk::PipelineLayout::null()),
                line_pipeline: (vk::Pipeline::null(), vk::PipelineLayout::null()),
                blend_pipeline: (vk::Pipeline::null(), vk::PipelineLayout::null()),
                vertices: (vk::Buffer::null(), vk::DeviceMemory::null(), 0),
                triangle_vertices: (opts.triangles.len() / 6) as u32,
                line_vertices: (opts.lines.len() / 6) as u32,
                screenshot: None,
                screenshot_frame: None,
                pool,
                swapchain_loader,
                surface_loader,
                surface,
                queue,
                device,
                pdev,
                debug,
                instance,
                _entry: entry,
                device_name,
                window,
            };
            gpu.vertices = gpu.buffer(
                (mesh.len() * 4) as u64,
                vk::BufferUsageFlags::STORAGE_BUFFER,
                true,
            )?;
            let ptr = gpu
                .device
                .map_memory(
                    gpu.vertices.1,
                    0,
                    vk::WHOLE_SIZE,
                    vk::MemoryMapFlags::empty(),
                )
                .map_err(vkerr("vkMapMemory"))?;
            std::ptr::copy_nonoverlapping(
                mesh.as_ptr() as *const u8,
                ptr as *mut u8,
                mesh.len() * 4,
            );
            gpu.device.unmap_memory(gpu.vertices.1);
            gpu.mesh_pipeline = gpu.pipeline(Pass::Triangles)?;
            gpu.line_pipeline = gpu.pipeline(Pass::Lines)?;
            gpu.blend_pipeline = gpu.pipeline(Pass::Blend)?;
            gpu.create_swapchain()?;
            Ok(gpu)
        }
    }

    pub(super) fn memory_type(
        &self,
        bits: u32,
        flags: vk::MemoryPropertyFlags,
    ) -> Result<u32, String> {
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
            .ok_or_else(|| format!("no memory type with {flags:?}"))
    }

    /// A buffer with a device address; host-visible (coherent) or device-local.
    pub(super) fn buffer(
        &self,
        size: u64,
        usage: vk::BufferUsageFlags,
        host: bool,
    ) -> Result<(vk::Buffer, vk::DeviceMemory, u64), String> {
        unsafe {
            let b = self
                .device
                .create_buffer(
                    &vk::BufferCreateInfo::default()
                        .size(size)
                        .usage(usage | vk::BufferUsageFlags::SHADER_DEVICE_ADDRESS),
                    None,
                )
                .map_err(vkerr("vkCreateBuffer"))?;
            let req = self.device.get_buffer_memory_requirements(b);
            let flags = if host {
                vk::MemoryPropertyFlags::HOST_VISIBLE | vk::MemoryPropertyFlags::HOST_COHERENT
            } else {
                vk::MemoryPropertyFlags::DEVICE_LOCAL
            };
            let mut af = vk::MemoryAllocateFlagsInfo::default()
                .flags(vk::MemoryAllocateFlags::DEVICE_ADDRESS);
            let m = self
                .device
                .allocate_memory(
                    &vk::MemoryAllocateInfo::default()
                        .allocation_size(req.size)
                        .memory_type_index(self.memory_type(req.memory_type_bits, flags)?)
                        .push_next(&mut af),
                    None,
                )
                .map_err(vkerr("vkAllocateMemory"))?;
            self.device
                .bind_buffer_memory(b, m, 0)
                .map_err(vkerr("bind"))?;
            let addr = self
                .device
                .get_buffer_device_address(&vk::BufferDeviceAddressInfo::default().buffer(b));
            Ok((b, m, addr))
        }
    }

    pub(super) fn image(
        &self,
        format: vk::Format,
        usage: vk::ImageUsageFlags,
        aspect: vk::ImageAspectFlags,
    ) -> Result<(vk::Image, vk::DeviceMemory, vk::ImageView), String> {
        unsafe {
            let image = self
                .device
                .create_image(
                    &vk::ImageCreateInfo::default()
                        .image_type(vk::ImageType::TYPE_2D)
                        .format(format)
                        .extent(vk::Extent3D {
                            width: self.extent.width,
                            height: self.extent.height,
                            depth: 1,
                        })
                        .mip_levels(1)
                        .array_layers(1)
                        .samples(vk::SampleCountFlags::TYPE_1)
                        .tiling(vk::ImageTiling::OPTIMAL)
                        .usage(usage),
                    None,
                )
                .map_err(vkerr("vkCreateImage"))?;
            let req = self.device.get_image_memory_requirements(image);
            let memory = self
                .device
                .allocate_memory(
                    &vk::MemoryAllocateInfo::default()
                        .allocation_size(req.size)
                        .memory_type_index(self.memory_type(
                            req.memory_type_bits,
                            vk::MemoryPropertyFlags::DEVICE_LOCAL,
                        )?),
                    None,
                )
                .map_err(vkerr("vkAllocateMemory"))?;
            self.device
                .bind_image_memory(image, memory, 0)
                .map_err(vkerr("bind"))?;
            let view = self
                .device
                .create_image_view(
                    &vk::ImageViewCreateInfo::default()
                        .image(image)
                        .view_type(vk::ImageViewType::TYPE_2D)
                        .format(format)
                        .subresource_range(range(aspect)),
                    None,
                )
                .map_err(vkerr("vkCreateImageView"))?;
            Ok((image, memory, view))
        }
    }

    /// The geometry pipelines (colour + reverse-Z depth) or the blend pipeline (colour
    /// only, premultiplied-alpha blending).
    pub(super) fn pipeline(
        &self,
        pass: Pass,
    ) -> Result<(vk::Pipeline, vk::PipelineLayout), String> {
        let mesh = pass != Pass::Blend;
        use crate::gpu::graphics::{
            HOST_BLEND_FRAG, HOST_BLEND_VERT, HOST_MESH_FRAG, HOST_MESH_VERT,
        };
        unsafe {
            let module = |spv: &[u8]| {
                let code = ash::util::read_spv(&mut std::io::Cursor::new(spv)).unwrap();
                self.device
                    .create_shader_module(&vk::ShaderModuleCreateInfo::default().code(&code), None)
                    .map_err(vkerr("vkCreateShaderModule"))
            };
            let (vs, fs) = if mesh {
                (module(HOST_MESH_VERT)?, module(HOST_MESH_FRAG)?)
            } else {
                (module(HOST_BLEND_VERT)?, module(HOST_BLEND_FRAG)?)
            };
            let ranges = [vk::PushConstantRange {
                stage_flags: if mesh {
                    vk::ShaderStageFlags::VERTEX
                } else {
                    vk::ShaderStageFlags::FRAGMENT
                },
                offset: 0,
                size: if mesh { 72 } else { 16 },
            }];
            let layout = self
                .device
                .create_pipeline_layout(
                    &vk::PipelineLayoutCreateInfo::default().push_constant_ranges(&ranges),
                    None,
                )
                .map_err(vkerr("vkCreatePipelineLayout"))?;
            let stages = [
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::VERTEX)
                    .module(vs)
                    .name(c"main"),
                vk::PipelineShaderStageCreateInfo::default()
                    .stage(vk::ShaderStageFlags::FRAGMENT)
                    .module(fs)
                    .name(c"main"),
            ];
            let vi = vk::PipelineVertexInputStateCreateInfo::default();
            let ia = vk::PipelineInputAssemblyStateCreateInfo::default().topology(
                if pass == Pass::Lines {
                    vk::PrimitiveTopology::LINE_LIST
                } else {
                    vk::PrimitiveTopology::TRIANGLE_LIST
                },
            );
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
                .depth_test_enable(mesh)
                .depth_write_enable(mesh)
                .depth_compare_op(vk::CompareOp::GREATER);
            let blend = [vk::PipelineColorBlendAttachmentState::default()
                .blend_enable(!mesh)
                .src_color_blend_factor(vk::BlendFactor::ONE)
                .dst_color_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
                .color_blend_op(vk::BlendOp::ADD)
                .src_alpha_blend_factor(vk::BlendFactor::ONE)
                .dst_alpha_blend_factor(vk::BlendFactor::ONE_MINUS_SRC_ALPHA)
                .alpha_blend_op(vk::BlendOp::ADD)
                .color_write_mask(vk::ColorComponentFlags::RGBA)];
            let cb = vk::PipelineColorBlendStateCreateInfo::default().attachments(&blend);
            let dynamic = [vk::DynamicState::VIEWPORT, vk::DynamicState::SCISSOR];
            let dy = vk::PipelineDynamicStateCreateInfo::default().dynamic_states(&dynamic);
            let formats = [self.colour_format];
            let mut rendering = vk::PipelineRenderingCreateInfo::default()
                .color_attachment_formats(&formats)
                .depth_attachment_format(if mesh {
                    vk::Format::D32_SFLOAT
                } else {
                    vk::Format::UNDEFINED
                });
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
            let p = self
                .device
                .create_graphics_pipelines(vk::PipelineCache::null(), &[info], None)
                .map_err(|(_, e)| format!("vkCreateGraphicsPipelines: {e}"))?[0];
            self.device.destroy_shader_module(vs, None);
            self.device.destroy_shader_module(fs, None);
            Ok((p, layout))
        }
    }
}
