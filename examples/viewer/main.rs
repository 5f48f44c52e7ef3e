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

mod frame;
mod setup;

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
