//! A small windowed host engine that embeds the radiance field (`raster::host`).
//!
//! It owns the Vulkan instance, device, swapchain and frames in flight, draws a mesh of
//! its own (a ground grid and a cube) with its own graphics pipeline and reverse-Z depth
//! buffer, then lets [`HostRenderer`] record the field into the same command buffer: the
//! rays stop at the host's depth, the field writes its own depth back, and the host
//! blends the premultiplied field over its colour in a fullscreen pass.
//!
//! ```text
//! cargo run --release --example viewer -- RUN_OR_MODEL [--width 800 --height 600]
//!     [--screenshot out.png --frames N] [--up z|y|-y] [--no-mesh] [--no-field]
//! ```
//! Mouse: left drag orbits, right drag pans, wheel zooms. Keys: W/A/S/D/Q/E fly,
//! K cycles samples per voxel (1–3), H cycles the SH degree, Esc quits. The title shows
//! the frame time and the field's GPU time (timestamps). With `--screenshot` the viewer
//! renders `--frames` frames, writes the last as a PNG, prints the timings and exits.

use std::mem::ManuallyDrop;
use std::path::{Path, PathBuf};
use std::time::Instant;

use ash::vk;
use clap::Parser;
use glam::{Mat4, Vec3};
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use svraster::gpu::{BorrowedHandles, Context, Timestamps};
use svraster::raster::host::{
    ColorFormat, ColorTarget, DepthMode, DepthTarget, HostRenderer, HostTarget, HostView,
};
use svraster::raster::RenderOptions;
use svraster::scene::{Scene, SceneGpu};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

#[derive(Parser, Debug, Clone)]
#[command(about = "Windowed host engine embedding a trained sparse-voxel model")]
struct Args {
    /// A `.safetensors` model or a run directory holding `model.safetensors`.
    model: PathBuf,
    #[arg(long, default_value_t = 800)]
    width: u32,
    #[arg(long, default_value_t = 600)]
    height: u32,
    /// Render `--frames` frames, write the last one here (PNG) and exit.
    #[arg(long)]
    screenshot: Option<PathBuf>,
    #[arg(long, default_value_t = 10)]
    frames: u32,
    /// The model's up axis: z (Blender, the demo), y or -y (COLMAP captures).
    #[arg(long, default_value = "z")]
    up: String,
    /// Orbit angles of the starting view (degrees) and its distance (model extents).
    #[arg(long, default_value_t = 30.0)]
    azimuth: f32,
    #[arg(long, default_value_t = 25.0)]
    elevation: f32,
    #[arg(long, default_value_t = 1.6)]
    distance: f32,
    /// Samples per voxel segment (1–3).
    #[arg(long, default_value_t = 1)]
    samples: u32,
    /// Do not draw the host's mesh (grid and cube).
    #[arg(long)]
    no_mesh: bool,
    /// Do not draw the radiance field.
    #[arg(long)]
    no_field: bool,
    /// Enable the Khronos validation layer (messages are printed and counted; the
    /// process exits with status 2 if any was reported).
    #[arg(long)]
    validation: bool,
}

const FRAMES_IN_FLIGHT: usize = 2;
/// The host composites in linear light: an sRGB colour attachment (the field arrives as
/// premultiplied linear light and the blend happens before the encoding).
const COLOUR_FORMAT: vk::Format = vk::Format::R8G8B8A8_SRGB;
/// The host's clear colour (linear).
const CLEAR: [f32; 4] = [0.013, 0.015, 0.022, 1.0];

fn model_path(p: &Path) -> PathBuf {
    if p.is_dir() {
        p.join("model.safetensors")
    } else {
        p.to_path_buf()
    }
}

fn main() {
    let args = Args::parse();
    let path = model_path(&args.model);
    let scene = match svraster::scene::checkpoint::load(&path) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("error: cannot load the model {}: {e}", path.display());
            std::process::exit(1);
        }
    };
    if !(1..=3).contains(&args.samples) {
        eprintln!("error: --samples must be 1, 2 or 3");
        std::process::exit(1);
    }
    let event_loop = match EventLoop::new() {
        Ok(l) => l,
        Err(e) => {
            eprintln!(
                "error: no window system ({e}). Run under a display, or headless with \
                 `xvfb-run -a cargo run --release --example viewer -- …`"
            );
            std::process::exit(1);
        }
    };
    let mut app = App {
        camera: Orbit::new(&scene, &args),
        args,
        scene,
        gpu: None,
        error: None,
        frame: 0,
        frame_ms: vec![],
        field_ms: vec![],
        last: Instant::now(),
        drag: None,
        cursor: (0.0, 0.0),
    };
    if let Err(e) = event_loop.run_app(&mut app) {
        eprintln!("error: event loop: {e}");
        std::process::exit(1);
    }
    if let Some(e) = app.error {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
    let messages = validation_messages();
    if messages > 0 {
        eprintln!("error: {messages} validation messages");
        std::process::exit(2);
    }
}

/// An orbit camera around a target, with the model's up axis.
struct Orbit {
    target: Vec3,
    up: Vec3,
    yaw: f32,
    pitch: f32,
    dist: f32,
    extent: f32,
}

impl Orbit {
    fn new(scene: &Scene, args: &Args) -> Orbit {
        let up = match args.up.as_str() {
            "y" => Vec3::Y,
            "-y" => Vec3::NEG_Y,
            _ => Vec3::Z,
        };
        Orbit {
            target: Vec3::from(scene.center),
            up,
            yaw: args.azimuth.to_radians(),
            pitch: args.elevation.to_radians(),
            dist: args.distance * scene.extent,
            extent: scene.extent,
        }
    }

    /// Two horizontal axes and up.
    fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let a = if self.up.x.abs() < 0.9 {
            Vec3::X
        } else {
            Vec3::Y
        };
        let e1 = (a - self.up * a.dot(self.up)).normalize();
        let e2 = self.up.cross(e1);
        (e1, e2, self.up)
    }

    fn eye(&self) -> Vec3 {
        let (e1, e2, up) = self.basis();
        let (sp, cp) = self.pitch.sin_cos();
        let (sy, cy) = self.yaw.sin_cos();
        self.target + self.dist * (cp * (cy * e1 + sy * e2) + sp * up)
    }

    fn view(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye(), self.target, self.up)
    }

    /// Reverse-Z, infinite far plane, Vulkan's y down.
    fn projection(&self, w: u32, h: u32) -> Mat4 {
        let mut p = Mat4::perspective_infinite_reverse_rh(
            50f32.to_radians(),
            w as f32 / h as f32,
            0.01 * self.extent,
        );
        p.y_axis.y = -p.y_axis.y;
        p
    }

    fn fly(&mut self, forward: f32, right: f32, lift: f32) {
        let f = (self.target - self.eye()).normalize();
        let r = f.cross(self.up).normalize();
        let step = 0.05 * self.extent;
        self.target += step * (forward * f + right * r + lift * self.up);
    }
}

/// The host's own geometry: a ground grid below the model and a cube beside its centre
/// (6 floats per vertex: position, colour).
fn host_mesh(scene: &Scene, up: Vec3) -> Vec<f32> {
    let c = Vec3::from(scene.center);
    let e = scene.extent;
    let a = if up.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let e1 = (a - up * a.dot(up)).normalize();
    let e2 = up.cross(e1);
    let mut v = vec![];
    let mut quad = |p: [Vec3; 4], col: Vec3| {
        for i in [0, 1, 2, 0, 2, 3] {
            v.extend_from_slice(&[p[i].x, p[i].y, p[i].z, col.x, col.y, col.z]);
        }
    };
    // Grid: 17 lines each way over twice the extent, at the bottom of the main region.
    let base = c - 0.5 * e * up;
    let half = e;
    let w = e / 300.0;
    for k in 0..=16 {
        let s = -half + 2.0 * half * k as f32 / 16.0;
        let col = Vec3::splat(0.55);
        for (u, t) in [(e1, e2), (e2, e1)] {
            let p0 = base + s * u - half * t;
            let p1 = base + s * u + half * t;
            quad([p0 - w * u, p0 + w * u, p1 + w * u, p1 - w * u], col);
        }
    }
    // Cube: a quarter of the extent, beside the centre, shaded per face.
    let h = 0.125 * e;
    let cc = c + 0.2 * e * e1 - 0.2 * e * e2;
    let axes = [e1, e2, up];
    for (fi, n) in axes.iter().enumerate() {
        for sign in [-1.0f32, 1.0] {
            let nn = *n * sign;
            let (t1, t2) = (axes[(fi + 1) % 3], axes[(fi + 2) % 3]);
            let f = cc + h * nn;
            let shade = 0.55 + 0.4 * nn.dot(up).max(0.0) + 0.1 * (fi as f32);
            let col = Vec3::new(0.05, 0.2, 0.8) * shade;
            quad(
                [
                    f - h * t1 - h * t2,
                    f + h * t1 - h * t2,
                    f + h * t1 + h * t2,
                    f - h * t1 + h * t2,
                ],
                col,
            );
        }
    }
    v
}

static VALIDATION: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

fn validation_messages() -> u64 {
    VALIDATION.load(std::sync::atomic::Ordering::SeqCst)
}

unsafe extern "system" fn debug_callback(
    severity: vk::DebugUtilsMessageSeverityFlagsEXT,
    _ty: vk::DebugUtilsMessageTypeFlagsEXT,
    data: *const vk::DebugUtilsMessengerCallbackDataEXT<'_>,
    _user: *mut std::ffi::c_void,
) -> vk::Bool32 {
    if severity.intersects(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING
            | vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
    ) {
        VALIDATION.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let msg = std::ffi::CStr::from_ptr((*data).p_message).to_string_lossy();
        eprintln!("[validation] {msg}");
    }
    vk::FALSE
}

struct App {
    args: Args,
    scene: Scene,
    camera: Orbit,
    gpu: Option<Gpu>,
    error: Option<String>,
    frame: u64,
    frame_ms: Vec<f64>,
    field_ms: Vec<f64>,
    last: Instant,
    drag: Option<MouseButton>,
    cursor: (f64, f64),
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.gpu.is_some() {
            return;
        }
        let attrs = Window::default_attributes()
            .with_title("svraster viewer")
            .with_inner_size(winit::dpi::PhysicalSize::new(
                self.args.width,
                self.args.height,
            ))
            .with_resizable(self.args.screenshot.is_none());
        let made = el
            .create_window(attrs)
            .map_err(|e| format!("cannot open a window: {e}"))
            .and_then(|w| Gpu::new(w, &self.scene, &self.args));
        match made {
            Ok(g) => {
                g.window.request_redraw();
                self.gpu = Some(g);
            }
            Err(e) => {
                self.error = Some(e);
                el.exit();
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(gpu) = self.gpu.as_mut() else {
            return;
        };
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(_) => {
                gpu.resized = true;
                gpu.window.request_redraw();
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                match event.logical_key.as_ref() {
                    Key::Named(NamedKey::Escape) => el.exit(),
                    Key::Character("k") => {
                        gpu.opts.samples = gpu.opts.samples % 3 + 1;
                    }
                    Key::Character("h") => {
                        gpu.scene.sh_degree =
                            (gpu.scene.sh_degree + 1) % (self.scene.sh_degree + 1);
                    }
                    Key::Character("w") => self.camera.fly(1.0, 0.0, 0.0),
                    Key::Character("s") => self.camera.fly(-1.0, 0.0, 0.0),
                    Key::Character("a") => self.camera.fly(0.0, -1.0, 0.0),
                    Key::Character("d") => self.camera.fly(0.0, 1.0, 0.0),
                    Key::Character("q") => self.camera.fly(0.0, 0.0, -1.0),
                    Key::Character("e") => self.camera.fly(0.0, 0.0, 1.0),
                    _ => {}
                }
            }
            WindowEvent::MouseInput { state, button, .. } => {
                self.drag = (state == ElementState::Pressed).then_some(button);
            }
            WindowEvent::CursorMoved { position, .. } => {
                let (dx, dy) = (position.x - self.cursor.0, position.y - self.cursor.1);
                self.cursor = (position.x, position.y);
                match self.drag {
                    Some(MouseButton::Left) => {
                        self.camera.yaw -= 0.005 * dx as f32;
                        self.camera.pitch =
                            (self.camera.pitch + 0.005 * dy as f32).clamp(-1.5, 1.5);
                    }
                    Some(MouseButton::Right) => {
                        self.camera.fly(0.0, -0.05 * dx as f32, 0.05 * dy as f32);
                    }
                    _ => {}
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let d = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.camera.dist *= 0.9f32.powf(d);
            }
            WindowEvent::RedrawRequested => {
                let last_frame = self
                    .args
                    .screenshot
                    .as_ref()
                    .is_some_and(|_| self.frame + 1 >= self.args.frames as u64);
                match gpu.draw(self.frame, &self.camera, &self.args, last_frame) {
                    Ok(Some(field)) => {
                        self.field_ms.push(field);
                    }
                    Ok(None) => {}
                    Err(e) => {
                        self.error = Some(e);
                        el.exit();
                        return;
                    }
                }
                let now = Instant::now();
                if self.frame > 0 {
                    self.frame_ms.push((now - self.last).as_secs_f64() * 1e3);
                }
                self.last = now;
                self.frame += 1;
                let med = |v: &[f64]| {
                    let mut s: Vec<f64> = v.iter().rev().take(30).copied().collect();
                    s.sort_by(f64::total_cmp);
                    s.get(s.len() / 2).copied().unwrap_or(0.0)
                };
                gpu.window.set_title(&format!(
                    "svraster viewer — frame {:.1} ms, field {:.1} ms (GPU), K={}, SH {}",
                    med(&self.frame_ms),
                    med(&self.field_ms),
                    gpu.opts.samples,
                    gpu.scene.sh_degree
                ));
                if last_frame {
                    let path = self.args.screenshot.clone().unwrap();
                    match gpu.save_screenshot(&path) {
                        Ok(()) => {
                            let all = |v: &[f64]| {
                                let mut s = v.to_vec();
                                s.sort_by(f64::total_cmp);
                                s.get(s.len() / 2).copied().unwrap_or(0.0)
                            };
                            println!(
                                "{} frames of {}×{} on {}: median frame {:.1} ms, median field {:.1} ms (GPU timestamps); screenshot {}",
                                self.frame,
                                gpu.extent.width,
                                gpu.extent.height,
                                gpu.device_name,
                                all(&self.frame_ms),
                                all(&self.field_ms),
                                path.display()
                            );
                        }
                        Err(e) => self.error = Some(e),
                    }
                    el.exit();
                    return;
                }
                // Minimised: wait for the next resize instead of spinning.
                if gpu.extent.width > 0 && gpu.extent.height > 0 {
                    gpu.window.request_redraw();
                }
            }
            _ => {}
        }
    }
}

/// Per frame in flight.
struct FrameRes {
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    acquired: vk::Semaphore,
    colour: (vk::Image, vk::DeviceMemory, vk::ImageView),
    depth: (vk::Image, vk::DeviceMemory, vk::ImageView),
    field: (vk::Buffer, vk::DeviceMemory, u64),
    timestamps: Timestamps,
    pending: bool,
}

struct Gpu {
    // The engine's objects: dropped by hand (Drop for Gpu) before the device they borrow.
    hr: ManuallyDrop<HostRenderer>,
    scene: ManuallyDrop<SceneGpu>,
    ctx: ManuallyDrop<Context>,
    opts: RenderOptions,
    frames: Vec<FrameRes>,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    presented: Vec<vk::Semaphore>,
    extent: vk::Extent2D,
    resized: bool,
    mesh_pipeline: (vk::Pipeline, vk::PipelineLayout),
    blend_pipeline: (vk::Pipeline, vk::PipelineLayout),
    vertices: (vk::Buffer, vk::DeviceMemory, u64),
    vertex_count: u32,
    screenshot: Option<(vk::Buffer, vk::DeviceMemory)>,
    screenshot_frame: Option<usize>,
    pool: vk::CommandPool,
    swapchain_loader: ash::khr::swapchain::Device,
    surface_loader: ash::khr::surface::Instance,
    surface: vk::SurfaceKHR,
    queue: vk::Queue,
    device: ash::Device,
    pdev: vk::PhysicalDevice,
    debug: Option<(ash::ext::debug_utils::Instance, vk::DebugUtilsMessengerEXT)>,
    instance: ash::Instance,
    _entry: ash::Entry,
    device_name: String,
    window: Window,
}

fn vkerr(call: &str) -> impl Fn(vk::Result) -> String + '_ {
    move |e| format!("{call}: {e}")
}

impl Gpu {
    fn new(window: Window, scene: &Scene, args: &Args) -> Result<Gpu, String> {
        unsafe {
            let entry = ash::Entry::load().map_err(|e| format!("no Vulkan loader: {e}"))?;
            let display = window.display_handle().map_err(|e| e.to_string())?.as_raw();
            let win = window.window_handle().map_err(|e| e.to_string())?.as_raw();
            let mut exts = ash_window::enumerate_required_extensions(display)
                .map_err(vkerr("surface extensions"))?
                .to_vec();
            let mut layers = vec![];
            if args.validation {
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
            let debug = if args.validation {
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
                debug_utils: args.validation,
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
            let mesh = host_mesh(scene, Orbit::new(scene, args).up);
            let mut gpu = Gpu {
                hr: ManuallyDrop::new(hr),
                scene: ManuallyDrop::new(scene_gpu),
                ctx: ManuallyDrop::new(ctx),
                opts: RenderOptions {
                    samples: args.samples,
                    supersample: 1.0,
                },
                frames: vec![],
                swapchain: vk::SwapchainKHR::null(),
                images: vec![],
                presented: vec![],
                extent: vk::Extent2D::default(),
                resized: false,
                mesh_pipeline: (vk::Pipeline::null(), vk::PipelineLayout::null()),
                blend_pipeline: (vk::Pipeline::null(), vk::PipelineLayout::null()),
                vertices: (vk::Buffer::null(), vk::DeviceMemory::null(), 0),
                vertex_count: (mesh.len() / 6) as u32,
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
            gpu.mesh_pipeline = gpu.pipeline(true)?;
            gpu.blend_pipeline = gpu.pipeline(false)?;
            gpu.create_swapchain()?;
            Ok(gpu)
        }
    }

    fn memory_type(&self, bits: u32, flags: vk::MemoryPropertyFlags) -> Result<u32, String> {
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
    fn buffer(
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

    fn image(
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

    /// The mesh pipeline (colour + reverse-Z depth) or the blend pipeline (colour only,
    /// premultiplied-alpha blending).
    fn pipeline(&self, mesh: bool) -> Result<(vk::Pipeline, vk::PipelineLayout), String> {
        use svraster::gpu::graphics::{
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
                size: if mesh { 72 } else { 12 },
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
            let formats = [COLOUR_FORMAT];
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

    /// (Re)creates the swapchain and the per-frame images at the window's size.
    fn create_swapchain(&mut self) -> Result<(), String> {
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
            // An sRGB swapchain: the blit from the sRGB attachment keeps the encoding.
            let format = formats
                .iter()
                .find(|f| {
                    matches!(
                        f.format,
                        vk::Format::B8G8R8A8_SRGB | vk::Format::R8G8B8A8_SRGB
                    )
                })
                .or_else(|| {
                    eprintln!(
                        "warning: no sRGB swapchain format: the picture is shown too dark \
                         (the screenshot is right)"
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
                    COLOUR_FORMAT,
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
                    timestamps: Timestamps::new(&self.ctx, 4).map_err(|e| e.to_string())?,
                    pending: false,
                });
            }
            self.resized = false;
            Ok(())
        }
    }

    fn destroy_frames(&mut self) {
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
                self.device.destroy_buffer(f.field.0, None);
                self.device.free_memory(f.field.1, None);
            }
        }
    }

    /// Records and submits one frame; returns the field's GPU time (ms) of the frame
    /// that last used this slot, once known.
    fn draw(
        &mut self,
        frame: u64,
        cam: &Orbit,
        args: &Args,
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
            let view = cam.view();
            let proj = cam.projection(w, h);
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
            if !args.no_field {
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
                    color: vk::ClearColorValue { float32: CLEAR },
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
            if !args.no_mesh {
                dev.cmd_bind_pipeline(cmd, vk::PipelineBindPoint::GRAPHICS, self.mesh_pipeline.0);
                dev.cmd_set_viewport(cmd, 0, &[viewport]);
                dev.cmd_set_scissor(cmd, 0, &[area]);
                let mut push = [0u8; 72];
                push[..64].copy_from_slice(bytemuck::bytes_of(&(proj * view).to_cols_array()));
                push[64..].copy_from_slice(&self.vertices.2.to_le_bytes());
                dev.cmd_push_constants(
                    cmd,
                    self.mesh_pipeline.1,
                    vk::ShaderStageFlags::VERTEX,
                    0,
                    &push,
                );
                dev.cmd_draw(cmd, self.vertex_count, 1, 0, 0);
            }
            dev.cmd_end_rendering(cmd);
            f.timestamps.mark(cmd, "mesh");
            // 2. The field, cut at the host's depth, writing its depth back.
            if !args.no_field {
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
            if !args.no_field {
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
                dev.cmd_set_scissor(cmd, 0, &[area]);
                let mut push = [0u8; 12];
                push[..8].copy_from_slice(&f.field.2.to_le_bytes());
                push[8..].copy_from_slice(&w.to_le_bytes());
                dev.cmd_push_constants(
                    cmd,
                    self.blend_pipeline.1,
                    vk::ShaderStageFlags::FRAGMENT,
                    0,
                    &push,
                );
                dev.cmd_draw(cmd, 3, 1, 0, 0);
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
    fn save_screenshot(&mut self, path: &Path) -> Result<(), String> {
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
            svraster::fsio::write_atomic(path, &png).map_err(|e| e.to_string())
        }
    }
}

use image::ImageEncoder as _;

impl Drop for Gpu {
    fn drop(&mut self) {
        unsafe {
            let _ = self.device.device_wait_idle();
            self.destroy_frames();
            // The engine's renderer, scene and context (its allocator frees its memory)
            // go before the device they borrow.
            ManuallyDrop::drop(&mut self.hr);
            ManuallyDrop::drop(&mut self.scene);
            ManuallyDrop::drop(&mut self.ctx);
            if let Some((b, m)) = self.screenshot.take() {
                self.device.destroy_buffer(b, None);
                self.device.free_memory(m, None);
            }
            for s in self.presented.drain(..) {
                self.device.destroy_semaphore(s, None);
            }
            for (p, l) in [self.mesh_pipeline, self.blend_pipeline] {
                self.device.destroy_pipeline(p, None);
                self.device.destroy_pipeline_layout(l, None);
            }
            self.device.destroy_buffer(self.vertices.0, None);
            self.device.free_memory(self.vertices.1, None);
            self.device.destroy_command_pool(self.pool, None);
            self.swapchain_loader
                .destroy_swapchain(self.swapchain, None);
            self.device.destroy_device(None);
            self.surface_loader.destroy_surface(self.surface, None);
            if let Some((du, m)) = self.debug.take() {
                du.destroy_debug_utils_messenger(m, None);
            }
            self.instance.destroy_instance(None);
        }
    }
}

fn range(aspect: vk::ImageAspectFlags) -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: aspect,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    }
}

#[allow(clippy::too_many_arguments)]
fn image_barrier(
    dev: &ash::Device,
    cmd: vk::CommandBuffer,
    image: vk::Image,
    aspect: vk::ImageAspectFlags,
    old: vk::ImageLayout,
    new: vk::ImageLayout,
    src_stage: vk::PipelineStageFlags,
    src: vk::AccessFlags,
    dst_stage: vk::PipelineStageFlags,
    dst: vk::AccessFlags,
) {
    let b = [vk::ImageMemoryBarrier::default()
        .src_access_mask(src)
        .dst_access_mask(dst)
        .old_layout(old)
        .new_layout(new)
        .src_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .dst_queue_family_index(vk::QUEUE_FAMILY_IGNORED)
        .image(image)
        .subresource_range(range(aspect))];
    unsafe {
        dev.cmd_pipeline_barrier(
            cmd,
            src_stage,
            dst_stage,
            vk::DependencyFlags::empty(),
            &[],
            &[],
            &b,
        )
    };
}
