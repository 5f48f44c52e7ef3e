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
use glam::{DMat3, DQuat, DVec3, Mat4};
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
mod setup;

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

/// The view being navigated: a pose, a pivot distance along the view, and intrinsics
/// relative to the image size.
#[derive(Clone, Debug)]
struct Nav {
    /// Camera-to-world rotation (columns: right, down, forward; OpenCV axes).
    rot: DMat3,
    eye: DVec3,
    /// Distance from the eye to the pivot along the view.
    pivot: f64,
    up: DVec3,
    /// fy / height, fx / fy, cx / width, cy / height.
    fy_rel: f64,
    aspect: f64,
    cx_rel: f64,
    cy_rel: f64,
    near: f64,
    /// The scene's size: fly steps, depth range.
    extent: f64,
    centre: DVec3,
}

impl Nav {
    fn new(cam: &Camera, up: [f64; 3], scene: &Scene) -> Nav {
        let centre = DVec3::from(scene.center.map(f64::from));
        let mut n = Nav {
            rot: DMat3::IDENTITY,
            eye: DVec3::ZERO,
            pivot: 1.0,
            up: DVec3::from(up).normalize_or(DVec3::Z),
            fy_rel: 1.0,
            aspect: 1.0,
            cx_rel: 0.5,
            cy_rel: 0.5,
            near: cam.near,
            extent: f64::from(scene.extent).max(1e-6),
            centre,
        };
        n.jump(cam);
        n
    }

    /// Takes `cam`'s pose and intrinsics; the pivot is the scene centre's depth along
    /// the view (at least a tenth of the extent ahead).
    fn jump(&mut self, cam: &Camera) {
        self.rot = cam.rotation();
        self.eye = DVec3::from(cam.origin());
        self.fy_rel = cam.fy / f64::from(cam.height);
        self.aspect = cam.fx / cam.fy;
        self.cx_rel = cam.cx / f64::from(cam.width);
        self.cy_rel = cam.cy / f64::from(cam.height);
        self.near = cam.near;
        let ahead = (self.centre - self.eye).dot(self.forward());
        self.pivot = ahead.max(0.1 * self.extent);
    }

    fn forward(&self) -> DVec3 {
        self.rot.z_axis
    }

    fn camera(&self, width: u32, height: u32) -> Camera {
        let fy = self.fy_rel * f64::from(height);
        let r = self.rot;
        Camera {
            width,
            height,
            fx: fy * self.aspect,
            fy,
            cx: self.cx_rel * f64::from(width),
            cy: self.cy_rel * f64::from(height),
            c2w: std::array::from_fn(|i| [r.x_axis[i], r.y_axis[i], r.z_axis[i], self.eye[i]]),
            near: self.near,
        }
    }

    /// Turns the view about the pivot: `yaw` about the up axis, `pitch` about the view's
    /// right axis (refused where it would look straight along the up axis).
    fn orbit(&mut self, yaw: f64, pitch: f64) {
        let pivot = self.eye + self.forward() * self.pivot;
        let q = DQuat::from_axis_angle(self.rot.x_axis, pitch);
        let pitched = DMat3::from_quat(q) * self.rot;
        let q = if pitched.z_axis.dot(self.up).abs() < 0.995 {
            DQuat::from_axis_angle(self.up, yaw) * q
        } else {
            DQuat::from_axis_angle(self.up, yaw)
        };
        let m = DMat3::from_quat(q);
        self.rot = m * self.rot;
        self.eye = pivot + m * (self.eye - pivot);
    }

    /// Moves eye and pivot together, in steps of a twentieth of the extent (scaled by
    /// the pivot distance when panning with the mouse).
    fn fly(&mut self, forward: f64, right: f64, lift: f64) {
        let step = 0.05 * self.extent;
        self.eye += step * (forward * self.forward() + right * self.rot.x_axis + lift * self.up);
    }

    fn pan(&mut self, dx: f64, dy: f64) {
        let s = 0.0015 * self.pivot;
        self.eye += s * (-dx * self.rot.x_axis - dy * self.rot.y_axis);
    }

    /// Moves toward the pivot (factor < 1) or away.
    fn zoom(&mut self, factor: f64) {
        let pivot = self.eye + self.forward() * self.pivot;
        self.pivot = (self.pivot * factor).max(1e-3 * self.extent);
        self.eye = pivot - self.forward() * self.pivot;
    }

    /// The depth range of the depth view: the scene centre's depth ± half the extent.
    fn depth_range(&self) -> (f32, f32) {
        let d = (self.centre - self.eye).dot(self.forward());
        (
            (d - 0.5 * self.extent).max(0.0) as f32,
            (d + 0.5 * self.extent).max(1e-3) as f32,
        )
    }
}

/// Two horizontal unit axes (orthogonal to `up` and to each other).
pub fn horizontal_axes(up: DVec3) -> (DVec3, DVec3) {
    let a = if up.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let e1 = (a - up * a.dot(up)).normalize();
    (e1, up.cross(e1))
}

/// A view of the model from outside: `azimuth` and `elevation` (degrees) about `up`
/// around the scene's centre, `distance` extents away, a 50° vertical field of view at
/// `width` × `height`, the near plane at a hundredth of the extent.
pub fn orbit_view(
    scene: &Scene,
    up: [f64; 3],
    azimuth: f64,
    elevation: f64,
    distance: f64,
    width: u32,
    height: u32,
) -> Camera {
    let up = DVec3::from(up).normalize_or(DVec3::Z);
    let centre = DVec3::from(scene.center.map(f64::from));
    let extent = f64::from(scene.extent);
    let (e1, e2) = horizontal_axes(up);
    let (a, el) = (azimuth.to_radians(), elevation.to_radians());
    let eye =
        centre + distance * extent * (el.cos() * (a.cos() * e1 + a.sin() * e2) + el.sin() * up);
    let (w, h) = (width.max(1), height.max(1));
    let fov_x = 2.0 * (25f64.to_radians().tan() * f64::from(w) / f64::from(h)).atan();
    let mut c = Camera::look_at(eye.into(), centre.into(), up.into(), fov_x, w, h);
    c.near = 0.01 * extent;
    c
}

/// Frusta of `cams` as a line list (6 floats per vertex): apex to the four corners of
/// the image at depth `size`, the image's outline, and a tick above its top edge
/// (which way is up).
pub fn frusta_lines(cams: &[Camera], size: f64, colour: [f32; 3]) -> Vec<f32> {
    let mut v = vec![];
    for c in cams {
        let o = DVec3::from(c.origin());
        let (w, h) = (f64::from(c.width), f64::from(c.height));
        let at = |u: f64, vv: f64| {
            let d = [(u - c.cx) / c.fx * size, (vv - c.cy) / c.fy * size, size];
            o + DVec3::from(c.rotate(d))
        };
        let corners = [at(0.0, 0.0), at(w, 0.0), at(w, h), at(0.0, h)];
        let mut line = |a: DVec3, b: DVec3| {
            for p in [a, b] {
                v.extend_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
                v.extend_from_slice(&colour);
            }
        };
        for k in 0..4 {
            line(o, corners[k]);
            line(corners[k], corners[(k + 1) % 4]);
        }
        line(at(0.5 * w, 0.0), at(0.5 * w, -0.25 * h));
    }
    v
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

#[cfg(test)]
mod tests {
    use super::*;

    fn scene() -> Scene {
        crate::data::demo::voxelize(2, 1).unwrap()
    }

    fn close(a: DVec3, b: DVec3) -> bool {
        (a - b).length() < 1e-9
    }

    /// Jumping to a camera gives it back exactly at its own size, and keeps its field of
    /// view (vertical) and principal point (relative) at another size.
    #[test]
    fn jump_gives_back_the_camera() {
        let s = scene();
        let mut cam = Camera::look_at(
            [3.0, -2.0, 1.5],
            [0.1, 0.2, 0.0],
            [0.0, 0.0, 1.0],
            0.9,
            64,
            48,
        );
        cam.cx += 3.0;
        cam.fx *= 1.1;
        cam.near = 0.05;
        let nav = Nav::new(&cam, [0.0, 0.0, 1.0], &s);
        let back = nav.camera(64, 48);
        assert_eq!((back.width, back.height), (64, 48));
        for (a, b) in [
            (back.fx, cam.fx),
            (back.fy, cam.fy),
            (back.cx, cam.cx),
            (back.cy, cam.cy),
            (back.near, cam.near),
        ] {
            assert!((a - b).abs() < 1e-9, "{a} {b}");
        }
        for r in 0..3 {
            for c in 0..4 {
                assert!((back.c2w[r][c] - cam.c2w[r][c]).abs() < 1e-12);
            }
        }
        let big = nav.camera(128, 96);
        assert!(
            (big.fy / 96.0 - cam.fy / 48.0).abs() < 1e-12
                && (big.cx / 128.0 - cam.cx / 64.0).abs() < 1e-12
        );
        assert!((big.fx / big.fy - cam.fx / cam.fy).abs() < 1e-12);
    }

    /// Orbiting turns about the pivot: it stays where it is, at the same distance; a
    /// full turn about the up axis comes back; pitching stops short of the up axis; the
    /// view stays upright (its right axis horizontal).
    #[test]
    fn orbit_turns_about_the_pivot_and_stays_upright() {
        let s = scene();
        let cam = Camera::look_at(
            [2.0, -2.0, 1.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            0.9,
            64,
            48,
        );
        let mut nav = Nav::new(&cam, [0.0, 0.0, 1.0], &s);
        let pivot = nav.eye + nav.forward() * nav.pivot;
        let (eye0, rot0) = (nav.eye, nav.rot);
        for k in 0..8 {
            nav.orbit(std::f64::consts::TAU / 8.0, if k < 4 { 0.1 } else { -0.1 });
            assert!(close(nav.eye + nav.forward() * nav.pivot, pivot));
            assert!(
                (nav.rot.x_axis.dot(nav.up)).abs() < 1e-9,
                "right axis tilted"
            );
        }
        assert!(close(nav.eye, eye0) && (nav.rot - rot0).abs_diff_eq(DMat3::ZERO, 1e-9));
        for _ in 0..100 {
            nav.orbit(0.0, 0.1);
            assert!(nav.forward().dot(nav.up).abs() < 0.995);
            assert!(close(nav.eye + nav.forward() * nav.pivot, pivot));
        }
        // Zoom keeps the pivot; panning and flying move eye and pivot together.
        nav.zoom(0.5);
        assert!(close(nav.eye + nav.forward() * nav.pivot, pivot));
        let before = nav.eye;
        nav.fly(1.0, 0.0, 0.0);
        assert!(close(nav.eye - before, nav.forward() * 0.05 * nav.extent));
    }

    /// Frusta: 9 lines per camera, the apex at the camera's centre, the corners at the
    /// given depth along the view.
    #[test]
    fn frusta_lines_start_at_the_cameras() {
        let cam = Camera::look_at(
            [2.0, -2.0, 1.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            0.9,
            64,
            48,
        );
        let v = frusta_lines(&[cam.clone(), cam.clone()], 0.5, [1.0, 0.0, 0.0]);
        assert_eq!(v.len(), 2 * 9 * 2 * 6);
        let p = |i: usize| DVec3::new(v[6 * i] as f64, v[6 * i + 1] as f64, v[6 * i + 2] as f64);
        let o = DVec3::from(cam.origin());
        assert!((p(0) - o).length() < 1e-6);
        let depth = (p(1) - o).dot(DVec3::from(cam.rotate([0.0, 0.0, 1.0])));
        assert!((depth - 0.5).abs() < 1e-6, "{depth}");
    }
}
