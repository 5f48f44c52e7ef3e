//! A windowed viewer (feature `viewer`): a small host engine that embeds the radiance
//! field through [`HostRenderer`] — `svraster view` and `examples/viewer.rs` are built
//! on it, and its code is the reference for embedding the field in an engine.
//!
//! It owns the Vulkan instance, device, swapchain and frames in flight; draws geometry
//! of its own (triangles and lines: the example's grid and cube, `svraster view`'s
//! training-camera frusta) with its own graphics pipelines and reverse-Z depth buffer;
//! lets [`HostRenderer`] record the field into the same command buffer (the rays stop
//! at the host's depth, the field writes its depth back); blends the premultiplied field
//! over its colour in a fullscreen pass, then a text overlay (frame time, mode, keys)
//! the same way.
//!
//! Controls: left drag orbits around the pivot (the point the view looks at), right
//! drag pans, the wheel moves to and from the pivot; W/A/S/D/Q/E fly. `]` / `[` jump to
//! the next / previous camera of [`ViewerOptions::cameras`] (its pose and field of
//! view), R returns to the start view; M cycles colour / depth / normal, K the samples
//! per voxel (1–3), H the SH degree, C shows or hides the geometry (the frusta), Tab the
//! overlay; Esc quits. With [`ViewerOptions::screenshot`] the viewer renders
//! [`ViewerOptions::frames`] frames, writes the last as a PNG and returns.

use std::mem::ManuallyDrop;
use std::path::{Path, PathBuf};
use std::time::Instant;

use ash::vk;
use glam::Mat4;
use raw_window_handle::{HasDisplayHandle, HasWindowHandle};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, EventLoop};
use winit::keyboard::{Key, NamedKey};
use winit::window::{Window, WindowId};

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{BorrowedHandles, Context, Timestamps};
use crate::raster::host::{
    matrices_for, ColorFormat, ColorTarget, DepthMode, DepthTarget, HostImage, HostRenderer,
    HostTarget, HostView,
};
use crate::raster::RenderOptions;
use crate::scene::{Scene, SceneGpu};

mod frame;
mod hud;
mod nav;
mod setup;

use nav::Nav;
pub use nav::{frusta_lines, horizontal_axes, orbit_view};

/// What the field's pixels show.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ViewMode {
    #[default]
    Colour,
    /// Grey by depth (near = bright) over the scene centre's depth ± half its extent.
    Depth,
    /// The outward normal as colour (`svraster render --normal`).
    Normal,
}

impl ViewMode {
    pub fn name(self) -> &'static str {
        match self {
            ViewMode::Colour => "colour",
            ViewMode::Depth => "depth",
            ViewMode::Normal => "normal",
        }
    }

    fn next(self) -> ViewMode {
        match self {
            ViewMode::Colour => ViewMode::Depth,
            ViewMode::Depth => ViewMode::Normal,
            ViewMode::Normal => ViewMode::Colour,
        }
    }
}

/// How to open the viewer.
#[derive(Clone, Debug)]
pub struct ViewerOptions {
    /// The window title's first words.
    pub title: String,
    /// The window's inner size in pixels.
    pub width: u32,
    pub height: u32,
    /// Render [`ViewerOptions::frames`] frames, write the last one here (PNG) and return.
    pub screenshot: Option<PathBuf>,
    pub frames: u32,
    /// Samples per voxel segment (1–3) at the start.
    pub samples: u32,
    pub mode: ViewMode,
    /// The Khronos validation layer (also on with `SVRASTER_VALIDATION=1`); its
    /// messages are printed and counted in [`ViewerReport::validation_messages`].
    pub validation: bool,
    /// The host's own geometry in the field's coordinates, 6 floats per vertex (position,
    /// linear colour): a triangle list and a line list.
    pub triangles: Vec<f32>,
    pub lines: Vec<f32>,
    pub draw_field: bool,
    pub draw_geometry: bool,
    /// Composite in display values (sRGB-encoded, as `svraster render` composites the
    /// field over a background: the picture is the render's) instead of in linear light
    /// (as a host engine composites lit geometry). The clear colour and the geometry's
    /// colours are in the same space.
    pub display_blend: bool,
    /// The clear colour behind everything.
    pub clear: [f32; 3],
    /// The scene's up axis (orbiting turns about it; flying up and down follows it).
    pub up: [f64; 3],
    /// The start view (its field of view is kept at any window size: the intrinsics
    /// scale with the window's height, the principal point with its size).
    pub start: Camera,
    /// Cameras to jump between (`]`, `[`): a dataset's training views.
    pub cameras: Vec<Camera>,
    /// The camera of [`ViewerOptions::cameras`] the start view is, if any.
    pub start_index: Option<usize>,
    /// Show the text overlay (frame time, mode, keys).
    pub hud: bool,
}

/// What a viewer session measured (displayed as one line: frames, size, device, median
/// frame and field times).
#[derive(Clone, Debug, Default)]
pub struct ViewerReport {
    pub frames: u64,
    pub width: u32,
    pub height: u32,
    /// Median time between presented frames (ms).
    pub median_frame_ms: f64,
    /// Median GPU time of the field's commands (timestamps, ms).
    pub median_field_ms: f64,
    pub device: String,
    pub validation_messages: u64,
}

impl std::fmt::Display for ViewerReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} frames of {}×{} on {}: median frame {:.1} ms, field {:.1} ms (GPU timestamps)",
            self.frames,
            self.width,
            self.height,
            self.device,
            self.median_frame_ms,
            self.median_field_ms
        )
    }
}

/// Opens the window and runs until it is closed (or, with a screenshot, until it is
/// written). Fails with a message naming what is missing when there is no window
/// system, no device that can present, or the screenshot cannot be written.
pub fn run(scene: &Scene, opts: ViewerOptions) -> Result<ViewerReport> {
    if !(1..=3).contains(&opts.samples) {
        return Err(Error::Invalid("samples must be 1, 2 or 3".into()));
    }
    if opts.width == 0 || opts.height == 0 {
        return Err(Error::Invalid(
            "the window size must be at least 1×1".into(),
        ));
    }
    let event_loop = EventLoop::new().map_err(|e| {
        Error::Viewer(format!(
            "no window system ({e}): run under a display, or headless under a virtual one \
             (`xvfb-run -a svraster view … --screenshot out.png`)"
        ))
    })?;
    VALIDATION.store(0, std::sync::atomic::Ordering::SeqCst);
    let validation = opts.validation
        || std::env::var("SVRASTER_VALIDATION").is_ok_and(|v| !v.is_empty() && v != "0");
    let mut app = App {
        nav: Nav::new(&opts.start, opts.up, scene),
        camera_index: opts.start_index,
        opts: ViewerOptions { validation, ..opts },
        scene: scene.clone(),
        gpu: None,
        error: None,
        frame: 0,
        frame_ms: vec![],
        field_ms: vec![],
        last: Instant::now(),
        drag: None,
        cursor: (0.0, 0.0),
        report: ViewerReport::default(),
    };
    event_loop
        .run_app(&mut app)
        .map_err(|e| Error::Viewer(format!("event loop: {e}")))?;
    let gpu = app.gpu.take();
    drop(gpu);
    if let Some(e) = app.error {
        return Err(Error::Viewer(e));
    }
    app.report.frames = app.frame;
    app.report.median_frame_ms = median(&app.frame_ms);
    app.report.median_field_ms = median(&app.field_ms);
    app.report.validation_messages = VALIDATION.load(std::sync::atomic::Ordering::SeqCst);
    Ok(app.report)
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    s.get(s.len() / 2).copied().unwrap_or(0.0)
}

/// The last 30 values' median (the overlay's running frame time).
fn recent_median(v: &[f64]) -> f64 {
    let s: Vec<f64> = v.iter().rev().take(30).copied().collect();
    median(&s)
}

static VALIDATION: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

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
    opts: ViewerOptions,
    scene: Scene,
    nav: Nav,
    /// The camera of `opts.cameras` last jumped to.
    camera_index: Option<usize>,
    gpu: Option<Gpu>,
    error: Option<String>,
    frame: u64,
    frame_ms: Vec<f64>,
    field_ms: Vec<f64>,
    last: Instant,
    drag: Option<MouseButton>,
    cursor: (f64, f64),
    report: ViewerReport,
}

impl App {
    fn jump(&mut self, step: isize) {
        let n = self.opts.cameras.len();
        if n == 0 {
            return;
        }
        let i = match self.camera_index {
            None if step > 0 => 0,
            None => n - 1,
            Some(i) => (i as isize + step).rem_euclid(n as isize) as usize,
        };
        self.nav.jump(&self.opts.cameras[i]);
        self.camera_index = Some(i);
    }

    fn key(&mut self, el: &ActiveEventLoop, key: Key) {
        let Some(gpu) = self.gpu.as_mut() else {
            return;
        };
        match key.as_ref() {
            Key::Named(NamedKey::Escape) => el.exit(),
            Key::Named(NamedKey::Tab) => self.opts.hud = !self.opts.hud,
            Key::Character(c) => match c.to_lowercase().as_str() {
                "k" => gpu.opts.samples = gpu.opts.samples % 3 + 1,
                "h" => gpu.scene.sh_degree = (gpu.scene.sh_degree + 1) % (self.scene.sh_degree + 1),
                "m" => self.opts.mode = self.opts.mode.next(),
                "c" => self.opts.draw_geometry = !self.opts.draw_geometry,
                "w" => self.nav.fly(1.0, 0.0, 0.0),
                "s" => self.nav.fly(-1.0, 0.0, 0.0),
                "a" => self.nav.fly(0.0, -1.0, 0.0),
                "d" => self.nav.fly(0.0, 1.0, 0.0),
                "q" => self.nav.fly(0.0, 0.0, -1.0),
                "e" => self.nav.fly(0.0, 0.0, 1.0),
                "r" => {
                    self.nav.jump(&self.opts.start);
                    self.camera_index = self.opts.start_index;
                }
                "]" => self.jump(1),
                "[" => self.jump(-1),
                _ => {}
            },
            _ => {}
        }
    }

    /// The overlay's lines.
    fn hud_text(&self, gpu: &Gpu) -> Vec<String> {
        let frame = recent_median(&self.frame_ms);
        let fps = if frame > 0.0 { 1e3 / frame } else { 0.0 };
        let cam = match self.camera_index {
            Some(i) => format!("camera {}/{}", i + 1, self.opts.cameras.len()),
            None if self.opts.cameras.is_empty() => "free view".into(),
            None => format!("free view ({} cameras: ] [)", self.opts.cameras.len()),
        };
        vec![
            format!(
                "{frame:.1} ms/frame ({fps:.0} fps) · field {:.1} ms GPU · {}×{}",
                recent_median(&self.field_ms),
                gpu.extent.width,
                gpu.extent.height
            ),
            format!(
                "{} · SH {} · {} sample{} · {}",
                self.opts.mode.name(),
                gpu.scene.sh_degree,
                gpu.opts.samples,
                if gpu.opts.samples == 1 { "" } else { "s" },
                cam
            ),
            "drag orbit/pan · wheel · WASDQE · ] [ cameras · R reset · M mode · H SH · K samples · C frusta · Tab".into(),
        ]
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, el: &ActiveEventLoop) {
        if self.gpu.is_some() {
            return;
        }
        let attrs = Window::default_attributes()
            .with_title(self.opts.title.clone())
            .with_inner_size(winit::dpi::PhysicalSize::new(
                self.opts.width,
                self.opts.height,
            ))
            .with_resizable(self.opts.screenshot.is_none());
        let made = el
            .create_window(attrs)
            .map_err(|e| format!("cannot open a window: {e}"))
            .and_then(|w| Gpu::new(w, &self.scene, &self.opts));
        match made {
            Ok(g) => {
                g.window.request_redraw();
                self.report.device = g.device_name.clone();
                self.gpu = Some(g);
            }
            Err(e) => {
                self.error = Some(e);
                el.exit();
            }
        }
    }

    fn window_event(&mut self, el: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        if self.gpu.is_none() {
            return;
        }
        match event {
            WindowEvent::CloseRequested => el.exit(),
            WindowEvent::Resized(_) => {
                let gpu = self.gpu.as_mut().expect("checked");
                gpu.resized = true;
                gpu.window.request_redraw();
            }
            WindowEvent::KeyboardInput { event, .. } if event.state == ElementState::Pressed => {
                self.key(el, event.logical_key);
            }
            WindowEvent::MouseInput { state, button, .. } => {
                self.drag = (state == ElementState::Pressed).then_some(button);
            }
            WindowEvent::CursorMoved { position, .. } => {
                let (dx, dy) = (position.x - self.cursor.0, position.y - self.cursor.1);
                self.cursor = (position.x, position.y);
                match self.drag {
                    Some(MouseButton::Left) => self.nav.orbit(-0.005 * dx, -0.005 * dy),
                    Some(MouseButton::Right) => self.nav.pan(dx, dy),
                    _ => {}
                }
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let d = match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(y),
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.nav.zoom(0.9f64.powf(d));
            }
            WindowEvent::RedrawRequested => self.redraw(el),
            _ => {}
        }
    }
}

impl App {
    fn redraw(&mut self, el: &ActiveEventLoop) {
        let last_frame =
            self.opts.screenshot.is_some() && self.frame + 1 >= self.opts.frames as u64;
        let hud = if self.opts.hud {
            let gpu = self.gpu.as_ref().expect("drawn with a device");
            Some(self.hud_text(gpu))
        } else {
            None
        };
        let gpu = self.gpu.as_mut().expect("drawn with a device");
        let view = FrameView {
            nav: &self.nav,
            mode: self.opts.mode,
            draw_field: self.opts.draw_field,
            draw_geometry: self.opts.draw_geometry,
            hud: hud.as_deref(),
        };
        match gpu.draw(self.frame, &view, last_frame) {
            Ok(Some(field)) => self.field_ms.push(field),
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
        gpu.window.set_title(&format!(
            "{} — {:.1} ms/frame, field {:.1} ms (GPU), {}",
            self.opts.title,
            recent_median(&self.frame_ms),
            recent_median(&self.field_ms),
            self.opts.mode.name()
        ));
        if last_frame {
            let path = self.opts.screenshot.clone().expect("checked");
            self.report.width = gpu.extent.width;
            self.report.height = gpu.extent.height;
            if let Err(e) = gpu.save_screenshot(&path) {
                self.error = Some(e);
            }
            el.exit();
            return;
        }
        // Minimised: wait for the next resize instead of spinning.
        if gpu.extent.width > 0 && gpu.extent.height > 0 {
            gpu.window.request_redraw();
        }
    }
}

/// What one frame draws.
struct FrameView<'a> {
    nav: &'a Nav,
    mode: ViewMode,
    draw_field: bool,
    draw_geometry: bool,
    hud: Option<&'a [String]>,
}

const FRAMES_IN_FLIGHT: usize = 2;

/// Per frame in flight.
struct FrameRes {
    cmd: vk::CommandBuffer,
    fence: vk::Fence,
    acquired: vk::Semaphore,
    colour: (vk::Image, vk::DeviceMemory, vk::ImageView),
    depth: (vk::Image, vk::DeviceMemory, vk::ImageView),
    field: (vk::Buffer, vk::DeviceMemory, u64),
    /// The overlay's premultiplied RGBA16F pixels (host-visible), its size.
    hud: (vk::Buffer, vk::DeviceMemory, u64),
    hud_size: (u32, u32),
    timestamps: Timestamps,
    pending: bool,
}

struct Gpu {
    // The engine's objects: dropped by hand (Drop for Gpu) before the device they borrow.
    hr: ManuallyDrop<HostRenderer>,
    scene: ManuallyDrop<SceneGpu>,
    ctx: ManuallyDrop<Context>,
    opts: RenderOptions,
    clear: [f32; 4],
    /// The colour attachment's format: sRGB (blending in linear light) or UNORM
    /// (blending in display values; [`ViewerOptions::display_blend`]).
    colour_format: vk::Format,
    hud: hud::Hud,
    frames: Vec<FrameRes>,
    swapchain: vk::SwapchainKHR,
    images: Vec<vk::Image>,
    presented: Vec<vk::Semaphore>,
    extent: vk::Extent2D,
    resized: bool,
    mesh_pipeline: (vk::Pipeline, vk::PipelineLayout),
    line_pipeline: (vk::Pipeline, vk::PipelineLayout),
    blend_pipeline: (vk::Pipeline, vk::PipelineLayout),
    vertices: (vk::Buffer, vk::DeviceMemory, u64),
    triangle_vertices: u32,
    line_vertices: u32,
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
            for (p, l) in [self.mesh_pipeline, self.line_pipeline, self.blend_pipeline] {
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
