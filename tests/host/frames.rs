use super::*;

#[test]
fn host_matrices_give_back_the_camera_and_depth_convention() {
    let mut rng = Rng(41);
    for trial in 0..40 {
        let scene = random_scene(&mut rng, 3, 0);
        let mut cam = camera_outside(&mut rng, &scene, 64 + trial, 48 + 2 * trial);
        cam.fy = cam.fx * rng.range(0.8, 1.25);
        cam.cx += rng.range(-8.0, 8.0);
        cam.cy += rng.range(-8.0, 8.0);
        cam.near = rng.range(0.05, 0.5);
        let far = [None, Some(rng.range(20.0, 200.0))][trial as usize % 2];
        let reverse = trial % 4 >= 2;
        let mut hv = host_view(&cam, far, reverse);
        // Half of the trials place the field with a model matrix (rotation, uniform
        // scale, translation) and move the view to match: the same camera.
        if trial % 3 == 0 {
            let s = rng.range(0.5, 3.0) as f32;
            let model = Mat4::from_scale_rotation_translation(
                glam::Vec3::splat(s),
                glam::Quat::from_axis_angle(glam::Vec3::new(0.3, -0.8, 0.5).normalize(), 1.1),
                glam::Vec3::new(3.0, -2.0, 7.0),
            );
            hv.view = (hv.view.as_dmat4() * model.as_dmat4().inverse()).as_mat4();
            hv.model = model;
        }
        if trial % 5 == 4 {
            // A host drawing with a negative-height viewport and a y-up projection.
            hv.projection.y_axis.y = -hv.projection.y_axis.y;
            hv.projection.z_axis.y = -hv.projection.z_axis.y;
            hv.viewport_y_up = true;
        }
        let (got, conv) = hv.camera().expect("a perspective view");
        let tol = 2e-5;
        for (a, b, what) in [
            (got.fx, cam.fx, "fx"),
            (got.fy, cam.fy, "fy"),
            (got.cx, cam.cx, "cx"),
            (got.cy, cam.cy, "cy"),
            (got.near, cam.near, "near"),
        ] {
            assert!(
                (a - b).abs() <= tol * b.abs().max(1.0),
                "trial {trial}: {what} {a} vs {b}"
            );
        }
        for r in 0..3 {
            for c in 0..4 {
                let scale = if c == 3 {
                    1.0 + cam.c2w[r][3].abs()
                } else {
                    1.0
                };
                assert!(
                    (got.c2w[r][c] - cam.c2w[r][c]).abs() <= tol * scale,
                    "trial {trial}: c2w[{r}][{c}] {} vs {}",
                    got.c2w[r][c],
                    cam.c2w[r][c]
                );
            }
        }
        assert_eq!(conv.reverse, reverse, "trial {trial}");
        match far {
            Some(f) => assert!(
                (conv.far - f).abs() <= 1e-3 * f,
                "trial {trial}: far {}",
                conv.far
            ),
            None => assert!(conv.far > 1e5, "trial {trial}: far {}", conv.far),
        }
        // The depth convention reproduces the projection's depth of world points.
        let m = hv.projection.as_dmat4() * hv.view.as_dmat4() * hv.model.as_dmat4();
        for _ in 0..10 {
            let (x, y, d) = (
                rng.range(-0.5, 0.5),
                rng.range(-0.5, 0.5),
                rng.range(0.5, 15.0),
            );
            let p = got.rotate([x * d, y * d, d]);
            let o = got.origin();
            let wp = glam::DVec4::new(o[0] + p[0], o[1] + p[1], o[2] + p[2], 1.0);
            let clip = m * wp;
            let z = clip.z / clip.w;
            let want = conv.depth_value(d, x, y);
            assert!(
                (z - want).abs() < 1e-5,
                "trial {trial}: depth value {want} vs {z}"
            );
            let back = conv.camera_depth(z, x, y);
            assert!(
                (back - d).abs() < 1e-3 * d,
                "trial {trial}: depth {back} vs {d}"
            );
        }
    }
}

#[test]
fn host_matrices_that_cannot_be_a_pinhole_are_refused() {
    let mut rng = Rng(5);
    let scene = random_scene(&mut rng, 3, 0);
    let cam = camera_outside(&mut rng, &scene, 64, 48);
    let ok = host_view(&cam, Some(100.0), false);
    // A y-up projection drawn with a normal viewport: the image would be mirrored.
    let mut mirrored = ok;
    mirrored.projection.y_axis.y = -mirrored.projection.y_axis.y;
    mirrored.projection.z_axis.y = -mirrored.projection.z_axis.y;
    let e = mirrored.camera().unwrap_err().to_string();
    assert!(e.contains("mirrors") && e.contains("viewport_y_up"), "{e}");
    let ortho = HostView {
        projection: Mat4::orthographic_rh(-1.0, 1.0, -1.0, 1.0, 0.1, 10.0),
        ..ok
    };
    let e = ortho.camera().unwrap_err().to_string();
    assert!(e.contains("orthographic"), "{e}");
    let mut skewed = ok;
    skewed.projection.y_axis.x = 0.3;
    let e = skewed.camera().unwrap_err().to_string();
    assert!(e.contains("skew"), "{e}");
    let mut nan = ok;
    nan.view.x_axis.x = f32::NAN;
    assert!(nan.camera().unwrap_err().to_string().contains("non-finite"));
}

#[test]
#[allow(clippy::needless_range_loop)]
fn host_depth_cuts_rays_and_targets_agree() {
    let host = Host::new(true);
    let (scene, cam) = scene_and_camera(7);
    let mut bg_free = scene.clone();
    bg_free.background = [0.0; 3];
    let mut frames = vec![];
    // Standard and reverse Z; and the field composited in segments of 5 entries.
    for (reverse, segments) in [(false, 0), (true, 0), (false, 5)] {
        let f = host_frame(&host, &scene, &cam, reverse, segments);
        let refs = references(&bg_free, &f.cam, &f.conv, &f.host_z);
        let uncut: Vec<RefPixel> = (0..H)
            .flat_map(|py| (0..W).map(move |px| (px, py)))
            .map(|(px, py)| {
                render_pixel_cut(
                    &bg_free,
                    &f.cam,
                    px as f64 + 0.5,
                    py as f64 + 0.5,
                    1,
                    f64::INFINITY,
                )
            })
            .collect();
        let mut covered = 0;
        let mut cut_matters = 0;
        let (mut e_rgb, mut e_depth) = (0f64, 0f64);
        let (mut field_depth, mut host_depth_kept) = (0, 0);
        let (mut e_uncut, mut e_uncut_depth, mut uncut_field, mut uncut_host) = (0f64, 0f64, 0, 0);
        for (i, r) in refs.iter().enumerate() {
            let (px, py) = (i as u32 % W, i as u32 / W);
            let (x, y) = xy(&f.cam, px, py);
            if f.host_z[i] != f.conv.clear_value() {
                covered += 1;
            }
            if (uncut[i].alpha - r.alpha).abs() > 0.05 {
                cut_matters += 1;
            }
            let g = f.f32_rgba[i];
            let lin = linear(r);
            for c in 0..3 {
                e_rgb = e_rgb.max((g[c] as f64 - lin[c]).abs());
            }
            e_rgb = e_rgb.max((g[3] as f64 - r.alpha).abs());
            // Written depth: the field's median where it is opaque enough, the host's
            // own value elsewhere.
            if r.alpha >= 0.5 + 1e-3 && !r.median_ambiguous {
                let d = f.conv.camera_depth(f.written_z[i] as f64, x, y);
                e_depth = e_depth.max((d - r.depth_median).abs() / (1.0 + r.depth_median));
                field_depth += 1;
            } else if r.alpha < 0.5 - 1e-3 {
                assert_eq!(
                    f.written_z[i], f.host_z[i],
                    "pixel {i}: host depth not kept"
                );
                host_depth_kept += 1;
            }
            // Rays not cut: the uncut reference; its mean depth written where it is
            // opaque enough and nearer than the (median-written) depth before it.
            let u = &uncut[i];
            let ul = linear(u);
            let gu = f.uncut_rgba[i];
            for c in 0..3 {
                e_uncut = e_uncut.max((gu[c] as f64 - ul[c]).abs());
            }
            e_uncut = e_uncut.max((gu[3] as f64 - u.alpha).abs());
            let before = f.conv.camera_depth(f.written_z[i] as f64, x, y);
            let after = f.conv.camera_depth(f.uncut_z[i] as f64, x, y);
            if u.alpha >= 0.5 + 1e-3 {
                let mean = u.depth / u.alpha;
                if mean < before * (1.0 - 1e-3) {
                    e_uncut_depth = e_uncut_depth.max((after - mean).abs() / (1.0 + mean));
                    uncut_field += 1;
                } else if mean > before * (1.0 + 1e-3) {
                    assert_eq!(
                        f.uncut_z[i], f.written_z[i],
                        "pixel {i}: nearer host depth lost"
                    );
                    uncut_host += 1;
                }
            } else if u.alpha < 0.5 - 1e-3 {
                assert_eq!(
                    f.uncut_z[i], f.written_z[i],
                    "pixel {i}: host depth not kept"
                );
            }
            // The other targets against the f32 one, encoded the same way.
            let clamp = |v: f32| (v as f64).clamp(0.0, 1.0);
            for c in 0..4 {
                let lin = clamp(g[c]);
                let want_srgb = if c < 3 { srgb_encode(lin) } else { lin };
                let s = f.srgb[i][c] as f64 / 255.0;
                assert!(
                    (s - want_srgb).abs() <= 0.5 / 255.0 + 1e-4,
                    "pixel {i} sRGB {c}: {s} vs {want_srgb}"
                );
                let u = f.unorm[i][c] as f64 / 255.0;
                assert!(
                    (u - lin).abs() <= 0.5 / 255.0 + 1e-4,
                    "pixel {i} UNORM {c}: {u} vs {lin}"
                );
                let h = f.f16_rgba[i][c];
                assert!(
                    (h - g[c]).abs() <= 1e-3 * g[c].abs().max(1.0),
                    "pixel {i} 16F {c}: {h} vs {}",
                    g[c]
                );
            }
        }
        println!(
            "reverse {reverse}: {covered} pixels behind the triangle, {cut_matters} changed by the \
             cut; colour error {e_rgb:.2e}; depth error {e_depth:.2e} on {field_depth} pixels, \
             host depth kept on {host_depth_kept}"
        );
        assert!(
            covered > 100 && covered < (W * H) as usize - 100,
            "{covered}"
        );
        assert!(
            cut_matters >= 20,
            "the host depth changes only {cut_matters} pixels"
        );
        assert!(e_rgb <= RGB_TOL, "colour error {e_rgb}");
        assert!(e_depth <= 1e-3, "depth error {e_depth}");
        assert!(
            field_depth >= 20 && host_depth_kept >= 20,
            "{field_depth} {host_depth_kept}"
        );
        println!(
            "  rays not cut: colour error {e_uncut:.2e}; mean depth written on {uncut_field} \
             pixels (error {e_uncut_depth:.2e}), the nearer host depth kept on {uncut_host}"
        );
        assert!(e_uncut <= RGB_TOL, "uncut colour error {e_uncut}");
        assert!(e_uncut_depth <= 1e-3, "uncut depth error {e_uncut_depth}");
        assert!(
            uncut_field >= 20 && uncut_host >= 20,
            "{uncut_field} {uncut_host}"
        );
        frames.push(f);
    }
    // Standard and reverse-Z: the same image.
    let mut diff = 0f32;
    for (a, b) in frames[0].f32_rgba.iter().zip(&frames[1].f32_rgba) {
        for c in 0..4 {
            diff = diff.max((a[c] - b[c]).abs());
        }
    }
    println!("standard vs reverse-Z: max difference {diff:.2e}");
    assert!(
        (diff as f64) <= RGB_TOL,
        "standard vs reverse-Z differ by {diff}"
    );
    // Segmented: the unsegmented image up to rounding.
    let mut diff = 0f32;
    for (a, b) in frames[0].f32_rgba.iter().zip(&frames[2].f32_rgba) {
        for c in 0..4 {
            diff = diff.max((a[c] - b[c]).abs());
        }
    }
    println!("segments of 5 vs none: max difference {diff:.2e}");
    assert!(diff <= 1e-5, "segmented host frame differs by {diff}");
    let log = host.log();
    drop(host);
    assert_host_clean(&log);
}

#[test]
fn frames_in_flight_grow_and_stay_clean() {
    let host = Host::new(true);
    let (scene, cam0) = scene_and_camera(11);
    let mut bg_free = scene.clone();
    bg_free.background = [0.0; 3];
    let ctx = host.context();
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    const FLIGHT: usize = 3;
    let mut hr = HostRenderer::new(&ctx, FLIGHT as u32).unwrap();
    let idle = host.idle_on_drop();
    // Small composite chunks: each slot's first frame is short of chunks and grows.
    hr.set_chunk_size(16);
    // Chunks split the unsegmented walk; a GPU's default segments never run short.
    hr.set_segment_entries(0);
    let npix = (W * H) as u64;
    let usage = vk::BufferUsageFlags::TRANSFER_DST;
    let cmds = host.command_buffers(FLIGHT as u32);
    let fences: Vec<vk::Fence> = (0..FLIGHT).map(|_| host.fence(true)).collect();
    let colour: Vec<HostBuffer> = (0..FLIGHT).map(|_| host.buffer(npix * 16, usage)).collect();
    let zs: Vec<HostBuffer> = (0..FLIGHT).map(|_| host.buffer(npix * 4, usage)).collect();
    let depth_usage = vk::ImageUsageFlags::DEPTH_STENCIL_ATTACHMENT
        | vk::ImageUsageFlags::TRANSFER_SRC
        | vk::ImageUsageFlags::TRANSFER_DST;
    let depths: Vec<_> = (0..FLIGHT)
        .map(|_| host.image(W, H, vk::Format::D32_SFLOAT, depth_usage))
        .collect();
    let pipeline = host.depth_pipeline(true);
    let mut views = vec![vk::ImageView::null(); FLIGHT];
    let dl = vk::ImageLayout::DEPTH_ATTACHMENT_OPTIMAL;
    let frames = 9u64;
    let mut last = None;
    let mut slot_verts: Vec<Option<HostBuffer>> = (0..FLIGHT).map(|_| None).collect();
    for i in 0..frames {
        let s = (i % FLIGHT as u64) as usize;
        // The host's per-frame fence: the slot's previous frame is done.
        host.wait(fences[s]);
        if views[s] != vk::ImageView::null() {
            unsafe { host.device.destroy_image_view(views[s], None) };
        }
        if let Some(v) = slot_verts[s].take() {
            host.destroy_buffer(v);
        }
        // The camera orbits a little each frame.
        let mut cam = cam0.clone();
        let angle = 0.02 * i as f64;
        let (sa, ca) = angle.sin_cos();
        for r in 0..3 {
            let (x, z) = (cam0.c2w[r][0], cam0.c2w[r][2]);
            cam.c2w[r][0] = ca * x - sa * z;
            cam.c2w[r][2] = sa * x + ca * z;
        }
        let hv = host_view(&cam, None, true);
        let (rcam, conv) = hv.camera().unwrap();
        let tri = triangle(&scene, &rcam);
        let verts = host.buffer(tri.len() as u64 * 4, vk::BufferUsageFlags::STORAGE_BUFFER);
        unsafe {
            std::ptr::copy_nonoverlapping(tri.as_ptr() as *const u8, verts.ptr, tri.len() * 4)
        };
        let vp = (hv.projection.as_dmat4() * hv.view.as_dmat4()).as_mat4();
        let target = HostTarget {
            color: ColorTarget::Buffer {
                buffer: colour[s].buffer,
                offset: 0,
                format: ColorFormat::Rgba32Float,
            },
            depth: Some(DepthTarget {
                image: depths[s].image,
                layout: dl,
                final_layout: dl,
                cut_rays: true,
                write: Some(DepthMode::Mean),
            }),
        };
        let report = hr
            .prepare(i, &gpu, &hv, &RenderOptions::default(), &target)
            .unwrap();
        host.submit(cmds[s], fences[s], |cmd| {
            views[s] = host.record_depth_pass(
                cmd,
                pipeline,
                depths[s].image,
                W,
                H,
                0.0,
                vp,
                host.address(&verts),
                3,
            );
            host.record_image_to_buffer(
                cmd,
                depths[s].image,
                vk::ImageAspectFlags::DEPTH,
                dl,
                W,
                H,
                &zs[s],
            );
            hr.record(cmd, i, &gpu, &hv, &RenderOptions::default(), &target)
                .unwrap();
        });
        match i {
            0..3 => assert_eq!(report.previous, None, "frame {i}"),
            3..6 => {
                let p = report.previous.unwrap();
                assert!(p.need_chunks && report.grew, "frame {i}: {report:?}");
            }
            _ => assert!(report.previous.unwrap().complete(), "frame {i}: {report:?}"),
        }
        // The vertex buffer is the host's: it lives until this slot comes round again.
        slot_verts[s] = Some(verts);
        last = Some((s, rcam, conv));
    }
    for f in &fences {
        unsafe { host.device.wait_for_fences(&[*f], true, u64::MAX).unwrap() };
    }
    let (s, rcam, conv) = last.unwrap();
    assert!(hr.finished(frames - 1).unwrap().complete());
    let host_z: Vec<f32> = zs[s].read();
    let refs = references(&bg_free, &rcam, &conv, &host_z);
    let got: Vec<f32> = colour[s].read();
    let mut e = 0f64;
    for (i, r) in refs.iter().enumerate() {
        let lin = linear(r);
        for c in 0..3 {
            e = e.max((got[4 * i + c] as f64 - lin[c]).abs());
        }
        e = e.max((got[4 * i + 3] as f64 - r.alpha).abs());
    }
    println!("last of {frames} frames in flight: colour error {e:.2e}");
    assert!(e <= RGB_TOL, "colour error {e}");
    unsafe {
        for v in views {
            host.device.destroy_image_view(v, None);
        }
        for f in fences {
            host.device.destroy_fence(f, None);
        }
        host.device.destroy_pipeline(pipeline.0, None);
        host.device.destroy_pipeline_layout(pipeline.1, None);
    }
    for b in colour
        .into_iter()
        .chain(zs)
        .chain(slot_verts.into_iter().flatten())
    {
        host.destroy_buffer(b);
    }
    for d in depths {
        host.destroy_image(d);
    }
    drop(idle);
    drop(hr);
    drop(gpu);
    assert_eq!(ctx.validation_messages(), 0);
    drop(ctx);
    let log = host.log();
    drop(host);
    assert_host_clean(&log);
}

/// `HostRenderer::set_image`: the colour target shows the depth (grey by the reference's
/// median depth where its alpha reaches 0.5, transparent elsewhere) or the normal
/// ((−n/|n|)·0.5 + 0.5 of the reference's composited density gradient, times alpha),
/// each as premultiplied linear light α·decode(v), within the colour tolerance.
#[test]
fn host_image_shows_depth_and_normals() {
    use svraster::raster::host::HostImage;
    let host = Host::new(false);
    let (scene, cam) = scene_and_camera(23);
    let ctx = host.context();
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    let mut hr = HostRenderer::new(&ctx, 2).unwrap();
    let idle = host.idle_on_drop();
    let hv = host_view(&cam, None, true);
    let (rcam, _) = hv.camera().unwrap();
    let npix = (W * H) as u64;
    let usage = vk::BufferUsageFlags::TRANSFER_DST;
    let bufs = [host.buffer(npix * 16, usage), host.buffer(npix * 16, usage)];
    // The depth range: the scene's centre ± its extent, seen from the camera.
    let dc = cam.world_to_camera(scene.center.map(|v| v as f64))[2] as f32;
    let (near, far) = (dc - 0.5 * scene.extent, dc + 0.5 * scene.extent);
    let images = [HostImage::Depth { near, far }, HostImage::Normal];
    let targets: Vec<HostTarget> = bufs
        .iter()
        .map(|b| HostTarget {
            color: ColorTarget::Buffer {
                buffer: b.buffer,
                offset: 0,
                format: ColorFormat::Rgba32Float,
            },
            depth: None,
        })
        .collect();
    let opts = RenderOptions::default();
    for (i, t) in targets.iter().enumerate() {
        hr.prepare(i as u64, &gpu, &hv, &opts, t).unwrap();
    }
    let cmd = host.command_buffers(1)[0];
    let fence = host.fence(false);
    host.submit(cmd, fence, |cmd| {
        for (i, t) in targets.iter().enumerate() {
            hr.set_image(images[i]);
            hr.record(cmd, i as u64, &gpu, &hv, &opts, t).unwrap();
        }
    });
    host.wait(fence);
    let depth: Vec<f32> = bufs[0].read();
    let normal: Vec<f32> = bufs[1].read();
    let (mut ed, mut en, mut surfaces, mut shaded) = (0f64, 0f64, 0, 0);
    for py in 0..H {
        for px in 0..W {
            let i = (py * W + px) as usize;
            let r = render_pixel(&rcam, &scene, px, py);
            // Depth: skip pixels whose alpha or median is decided at 0.5 by a hair.
            if (r.alpha - 0.5).abs() > 1e-3 && !r.median_ambiguous {
                let want = if r.alpha >= 0.5 {
                    surfaces += 1;
                    let t = ((r.depth_median - near as f64) / (far - near) as f64).clamp(0.0, 1.0);
                    let g = srgb_decode(1.0 - 0.8 * t);
                    [g, g, g, 1.0]
                } else {
                    [0.0; 4]
                };
                for c in 0..4 {
                    ed = ed.max((depth[4 * i + c] as f64 - want[c]).abs());
                }
            }
            // Normal.
            let l = r.normal.iter().map(|v| v * v).sum::<f64>().sqrt();
            if l > 1e-4 {
                shaded += 1;
                let a = r.alpha.clamp(0.0, 1.0);
                for c in 0..3 {
                    let want = a * srgb_decode(-r.normal[c] / l * 0.5 + 0.5);
                    en = en.max((normal[4 * i + c] as f64 - want).abs());
                }
                en = en.max((normal[4 * i + 3] as f64 - a).abs());
            }
        }
    }
    println!(
        "depth image: {surfaces} surface pixels, error {ed:.2e}; normal image: {shaded} \
         pixels, error {en:.2e}"
    );
    assert!(surfaces > 50 && shaded > 100, "{surfaces} {shaded}");
    assert!(ed <= RGB_TOL, "depth image error {ed}");
    assert!(en <= RGB_TOL, "normal image error {en}");
    unsafe { host.device.destroy_fence(fence, None) };
    for b in bufs {
        host.destroy_buffer(b);
    }
    drop(idle);
    drop(hr);
    drop(gpu);
    assert_eq!(ctx.validation_messages(), 0);
    drop(ctx);
    let log = host.log();
    drop(host);
    assert_host_clean(&log);
}

fn render_pixel(cam: &Camera, scene: &Scene, px: u32, py: u32) -> RefPixel {
    common::reference::render_pixel(scene, cam, px as f64 + 0.5, py as f64 + 0.5, 1)
}
