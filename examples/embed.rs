//! The smallest embedding: record a frame of a model into a command buffer with the
//! host's camera matrices and read the premultiplied sRGB pixels from a buffer.
//! README's "Embedding" section shows this file; `src/viewer/` (`svraster view`) is a full host
//! (its own device, swapchain, depth buffer and mesh, frames in flight).
//!
//! ```text
//! cargo run --release --example embed -- RUN/model.safetensors out.png
//! ```

use glam::{Mat4, Vec3};
use svraster::gpu::{ContextOptions, Memory};
use svraster::raster::host::{ColorFormat, ColorTarget, HostRenderer, HostTarget, HostView};
use svraster::{Context, RenderOptions, SceneGpu};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(model), Some(out)) = (args.get(1), args.get(2)) else {
        return Err("usage: embed MODEL.safetensors OUT.png".into());
    };
    // A host lends its device with Context::borrowed; here the engine makes its own.
    let ctx = Context::new(&ContextOptions {
        device: None,
        validation: false,
    })?;
    let scene = svraster::scene::checkpoint::load(model.as_ref())?;
    let gpu = SceneGpu::upload(&ctx, &scene)?;
    let mut renderer = HostRenderer::new(&ctx, 2)?; // two frames in flight

    // The host's camera: right-handed view, reverse-Z infinite projection, y flipped
    // for Vulkan's clip space.
    let (w, h) = (640u32, 480u32);
    let centre = Vec3::from(scene.center);
    let eye = centre + scene.extent * Vec3::new(1.2, -0.9, 0.8);
    let mut projection =
        Mat4::perspective_infinite_reverse_rh(50f32.to_radians(), w as f32 / h as f32, 0.01);
    projection.y_axis.y = -projection.y_axis.y;
    let view = HostView {
        view: Mat4::look_at_rh(eye, centre, Vec3::Z),
        projection,
        model: Mat4::IDENTITY,
        width: w,
        height: h,
        viewport_y_up: false,
    };
    let pixels = ctx.buffer("colour", (w * h * 4) as u64, Memory::Readback)?;
    let target = HostTarget {
        color: ColorTarget::Buffer {
            buffer: pixels.raw(),
            offset: 0,
            format: ColorFormat::Rgba8Srgb,
        },
        depth: None, // or the host's D32 depth image: rays end at its surfaces
    };
    // Each frame: prepare (outside recording: reads the slot's previous frame, grows,
    // allocates), then record into any command buffer of the queue family (a host's
    // own). A first frame can find its buffers short: render until one is complete.
    let opts = RenderOptions::default();
    for frame in 0..8 {
        renderer.prepare(frame, &gpu, &view, &opts, &target)?;
        ctx.submit_and_wait(|cmd| renderer.record(cmd, frame, &gpu, &view, &opts, &target))?;
        let stats = renderer.finished(frame).expect("just recorded");
        if stats.complete() {
            break;
        }
        eprintln!("frame {frame} incomplete ({stats:?}): growing and rendering again");
    }
    let rgba = pixels.mapped().expect("mapped")[..(w * h * 4) as usize].to_vec();
    image::RgbaImage::from_raw(w, h, rgba)
        .expect("size")
        .save(out)?;
    println!("wrote {out} (premultiplied alpha over transparent)");
    Ok(())
}
