//! Embedding in a host engine (src/raster/host/): the host's matrices give back the
//! pinhole camera and depth convention; a host with its own device, depth pass and
//! command buffers gets the field cut at its depth, premultiplied, in its formats, with
//! its depth written (colour as premultiplied linear light: α·srgb_decode(C/α) of the
//! reference's composited C and α); standard and reverse-Z agree; frames in flight are clean under
//! synchronisation validation and grow without device loss.
//!
//! Stated bounds: colour and alpha within 1e-3 of the f64 reference cut at the host's
//! depth, as the raster tests (the kernel converts the host's depth value to a camera
//! depth in f32: about 1e-6 relative at the test's near plane, times densities up to
//! 0.6 and the step scale of 100, well inside the bound; measured: ~3e-6); written depth
//! within 1e-3·(1 + d) of the reference median depth; 8-bit targets within half a step
//! (plus 1e-4) of the float target's value encoded the same way; 16F within 1e-3
//! relative.

use crate::common;

use ash::vk;
use common::host::{assert_host_clean, Host, HostBuffer};
use common::reference::{render_pixel_cut, RefPixel};
use common::{camera_outside, random_scene, Rng};
use glam::Mat4;
use svraster::data::Camera;
use svraster::raster::host::{
    matrices_for, ColorFormat, ColorTarget, DepthConvention, DepthMode, DepthTarget, HostRenderer,
    HostTarget, HostView,
};
use svraster::raster::RenderOptions;
use svraster::scene::{Scene, SceneGpu};

const W: u32 = 40;
const H: u32 = 32;
const RGB_TOL: f64 = 1e-3;

fn host_view(cam: &Camera, far: Option<f64>, reverse: bool) -> HostView {
    let (view, projection) = matrices_for(cam, far, reverse);
    HostView {
        view,
        projection,
        model: Mat4::IDENTITY,
        width: cam.width,
        height: cam.height,
        viewport_y_up: false,
    }
}

/// Pixel centre (u, v) → camera-space (x', y').
fn xy(cam: &Camera, px: u32, py: u32) -> (f64, f64) {
    let d = cam.camera_dir(px as f64 + 0.5, py as f64 + 0.5);
    (d[0], d[1])
}

/// A scene of moderate densities (the host-depth conversion's f32 error stays far
/// below the tolerance) and a camera with a near plane of 0.3.
fn scene_and_camera(seed: u64) -> (Scene, Camera) {
    let mut rng = Rng(seed);
    let mut scene = random_scene(&mut rng, 5, 2);
    for g in scene.geo.iter_mut() {
        *g = rng.range(-6.0, 0.5) as f32;
    }
    scene.background = [0.9, 0.2, 0.5];
    let mut cam = camera_outside(&mut rng, &scene, W, H);
    cam.near = 0.3;
    (scene, cam)
}

/// A triangle through the front half of the scene: it covers the upper left half of
/// the view, tilted in depth.
fn triangle(scene: &Scene, cam: &Camera) -> Vec<f32> {
    let dc = cam.world_to_camera(scene.center.map(|v| v as f64))[2];
    let e = scene.extent as f64;
    let o = cam.origin();
    let (xm, ym) = (cam.cx / cam.fx, cam.cy / cam.fy);
    [
        (-3.0 * xm, -3.0 * ym, dc - 0.3 * e),
        (3.0 * xm, -3.0 * ym, dc - 0.1 * e),
        (-3.0 * xm, 3.0 * ym, dc),
    ]
    .iter()
    .flat_map(|&(x, y, d)| {
        let p = cam.rotate([x * d, y * d, d]);
        [
            (o[0] + p[0]) as f32,
            (o[1] + p[1]) as f32,
            (o[2] + p[2]) as f32,
            1.0,
            1.0,
            1.0,
        ]
    })
    .collect()
}

/// References of every pixel, each ray cut at the camera depth of the host's value.
fn references(
    scene: &Scene,
    cam: &Camera,
    conv: &DepthConvention,
    host_z: &[f32],
) -> Vec<RefPixel> {
    let mut out = vec![];
    for py in 0..cam.height {
        for px in 0..cam.width {
            let (x, y) = xy(cam, px, py);
            let far = conv.camera_depth(host_z[(py * cam.width + px) as usize] as f64, x, y);
            out.push(render_pixel_cut(
                scene,
                cam,
                px as f64 + 0.5,
                py as f64 + 0.5,
                1,
                far,
            ));
        }
    }
    out
}

fn srgb_decode(x: f64) -> f64 {
    if x <= 0.04045 {
        x / 12.92
    } else {
        ((x + 0.055) / 1.055).powf(2.4)
    }
}

/// The host's premultiplied linear light of a reference pixel: α·decode(C/α).
fn linear(r: &RefPixel) -> [f64; 3] {
    std::array::from_fn(|c| {
        if r.alpha > 0.0 {
            r.alpha * srgb_decode((r.rgb[c] / r.alpha).max(0.0))
        } else {
            0.0
        }
    })
}

fn srgb_encode(x: f64) -> f64 {
    if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let man = (h & 0x3ff) as f32;
    sign * match exp {
        0 => man * 2f32.powi(-24),
        31 => f32::INFINITY,
        _ => (1.0 + man / 1024.0) * 2f32.powi(exp - 15),
    }
}

struct Frame {
    host_z: Vec<f32>,
    written_z: Vec<f32>,
    /// The depth after a further frame that writes (mean depth) without cutting.
    uncut_z: Vec<f32>,
    /// Premultiplied rgba per pixel from each target, decoded to floats.
    f32_rgba: Vec<[f32; 4]>,
    srgb: Vec<[u8; 4]>,
    unorm: Vec<[u8; 4]>,
    f16_rgba: Vec<[f32; 4]>,
    /// The frame whose rays are not cut (host depth only written).
    uncut_rgba: Vec<[f32; 4]>,
    conv: DepthConvention,
    cam: Camera,
}

/// Offset of the 16F pixels in their buffer (a target at a non-zero offset).
const F16_OFFSET: u64 = 256;

/// One host submission: the host's depth pass, a copy of its depth, the field recorded
/// into five targets — f32 buffer, sRGB image (from UNDEFINED), UNORM image (from
/// GENERAL) and 16F buffer at an offset, all cut at the host's depth, the last one also
/// writing the median depth; then an f32 buffer with rays not cut, writing the mean
/// depth — and read-backs.
/// `segments`: entries per segment of the field's composite (0: off).
fn host_frame(host: &Host, scene: &Scene, cam: &Camera, reverse: bool, segments: u32) -> Frame {
    let ctx = host.context();
    let gpu = SceneGpu::upload(&ctx, scene).unwrap();
    let hv = host_view(cam, if reverse { None } else { Some(100.0) }, reverse);
    let (rcam, conv) = hv.camera().unwrap();
    let mut hr = HostRenderer::new(&ctx, 5).unwrap();
    let _idle = host.idle_on_drop();
    hr.set_segment_entries(segments);
    let npix = (W * H) as u64;
    let tri = triangle(scene, &rcam);
    let verts = host.buffer(tri.len() as u64 * 4, vk::BufferUsageFlags::STORAGE_BUFFER);
    unsafe { std::ptr::copy_nonoverlapping(tri.as_ptr() as *const u8, verts.ptr, tri.len() * 4) };
    let usage = vk::BufferUsageFlags::TRANSFER_DST;
    let host_z = host.buffer(npix * 4, usage);
    let written_z = host.buffer(npix * 4, usage);
    let uncut_z = host.buffer(npix * 4, usage);
    let f32_buf = host.buffer(npix * 16, usage);
    let uncut_buf = host.buffer(npix * 16, usage);
    let f16_buf = host.buffer(F16_OFFSET + npix * 8, usage);
    let srgb_buf = host.buffer(npix * 4, usage);
    let unorm_buf = host.buffer(npix * 4, usage);
    let depth = host.image(
        W,
        H,
        vk::Format::D32_SFLOAT,
        vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
            | vk::ImageUsageFlags::TRANSFER_SRC
            | vk::ImageUsageFlags::TRANSFER_DST,
    );
    let colour_usage = vk::ImageUsageFlags::TRANSFER_DST | vk::ImageUsageFlags::TRANSFER_SRC;
    let srgb = host.image(W, H, vk::Format::R8G8B8A8_SRGB, colour_usage);
    let unorm = host.image(W, H, vk::Format::R8G8B8A8_UNORM, colour_usage);
    let pipeline = host.depth_pipeline(reverse);
    let vp = (hv.projection.as_dmat4() * hv.view.as_dmat4()).as_mat4();
    let cmd = host.command_buffers(1)[0];
    let fence = host.fence(false);
    let opts = RenderOptions::default();
    let dl = vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL;
    let depth_target = |cut_rays, write| {
        Some(DepthTarget {
            image: depth.image,
            layout: dl,
            final_layout: dl,
            cut_rays,
            write,
        })
    };
    let targets = [
        HostTarget {
            color: ColorTarget::Buffer {
                buffer: f32_buf.buffer,
                offset: 0,
                format: ColorFormat::Rgba32Float,
            },
            depth: depth_target(true, None),
        },
        HostTarget {
            color: ColorTarget::Image {
                image: srgb.image,
                format: ColorFormat::Rgba8Srgb,
                layout: vk::ImageLayout::UNDEFINED,
                final_layout: vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            },
            depth: depth_target(true, None),
        },
        HostTarget {
            color: ColorTarget::Image {
                image: unorm.image,
                format: ColorFormat::Rgba8Unorm,
                layout: vk::ImageLayout::GENERAL,
                final_layout: vk::ImageLayout::GENERAL,
            },
            depth: depth_target(true, None),
        },
        HostTarget {
            color: ColorTarget::Buffer {
                buffer: f16_buf.buffer,
                offset: F16_OFFSET,
                format: ColorFormat::Rgba16Float,
            },
            depth: depth_target(true, Some(DepthMode::Median)),
        },
        HostTarget {
            color: ColorTarget::Buffer {
                buffer: uncut_buf.buffer,
                offset: 0,
                format: ColorFormat::Rgba32Float,
            },
            depth: depth_target(false, Some(DepthMode::Mean)),
        },
    ];
    // Prepared before recording (prepare may use the queue; record only records).
    for (i, t) in targets.iter().enumerate() {
        let report = hr.prepare(i as u64, &gpu, &hv, &opts, t).unwrap();
        assert_eq!(report.previous, None);
    }
    let mut att_view = vk::ImageView::null();
    host.submit(cmd, fence, |cmd| {
        att_view = host.record_depth_pass(
            cmd,
            pipeline,
            depth.image,
            W,
            H,
            if reverse { 0.0 } else { 1.0 },
            vp,
            host.address(&verts),
            3,
        );
        host.record_image_to_buffer(
            cmd,
            depth.image,
            vk::ImageAspectFlags::DEPTH,
            dl,
            W,
            H,
            &host_z,
        );
        // The UNORM image is left in GENERAL by the host before the field is recorded.
        host.transition(
            cmd,
            unorm.image,
            vk::ImageLayout::UNDEFINED,
            vk::ImageLayout::GENERAL,
        );
        for (i, t) in targets.iter().enumerate() {
            hr.record(cmd, i as u64, &gpu, &hv, &opts, t).unwrap();
            if i == 3 {
                host.record_image_to_buffer(
                    cmd,
                    depth.image,
                    vk::ImageAspectFlags::DEPTH,
                    dl,
                    W,
                    H,
                    &written_z,
                );
            }
        }
        host.record_image_to_buffer(
            cmd,
            depth.image,
            vk::ImageAspectFlags::DEPTH,
            dl,
            W,
            H,
            &uncut_z,
        );
        host.record_image_to_buffer(
            cmd,
            srgb.image,
            vk::ImageAspectFlags::COLOR,
            vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
            W,
            H,
            &srgb_buf,
        );
        host.record_image_to_buffer(
            cmd,
            unorm.image,
            vk::ImageAspectFlags::COLOR,
            vk::ImageLayout::GENERAL,
            W,
            H,
            &unorm_buf,
        );
    });
    host.wait(fence);
    for i in 0..5 {
        let s = hr.finished(i).expect("recorded");
        assert!(s.complete(), "frame {i}: {s:?}");
        assert!(
            segments == 0 || s.max_tile_entries > 3 * segments,
            "frame {i}: the longest list ({}) must span several segments of {segments}",
            s.max_tile_entries
        );
    }
    let rgba = |b: &HostBuffer| -> Vec<[f32; 4]> {
        b.read::<f32>()
            .chunks(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect()
    };
    let bytes4 = |b: &HostBuffer| -> Vec<[u8; 4]> {
        b.read::<u8>()
            .chunks(4)
            .map(|c| [c[0], c[1], c[2], c[3]])
            .collect()
    };
    let halves: Vec<u16> = f16_buf.read();
    let frame = Frame {
        host_z: host_z.read(),
        written_z: written_z.read(),
        uncut_z: uncut_z.read(),
        f32_rgba: rgba(&f32_buf),
        srgb: bytes4(&srgb_buf),
        unorm: bytes4(&unorm_buf),
        f16_rgba: halves[(F16_OFFSET / 2) as usize..]
            .chunks(4)
            .map(|c| std::array::from_fn(|k| f16_to_f32(c[k])))
            .collect(),
        uncut_rgba: rgba(&uncut_buf),
        conv,
        cam: rcam,
    };
    unsafe {
        host.device.destroy_fence(fence, None);
        host.device.destroy_pipeline(pipeline.0, None);
        host.device.destroy_pipeline_layout(pipeline.1, None);
        host.device.destroy_image_view(att_view, None);
    }
    for b in [
        verts, host_z, written_z, uncut_z, f32_buf, uncut_buf, f16_buf, srgb_buf, unorm_buf,
    ] {
        host.destroy_buffer(b);
    }
    for i in [depth, srgb, unorm] {
        host.destroy_image(i);
    }
    drop(hr);
    drop(gpu);
    assert_eq!(ctx.validation_messages(), 0);
    frame
}

mod frames;
