//! The frame-mean background (`Scene::background_frame_mean`, SVRaster's background for
//! captures that are neither white nor black): behind every pixel the frame's own mean
//! composited colour m = (1/N) Σ C, at render resolution.

use super::*;

/// Against the f64 reference: random scenes seen from outside and inside, K = 1..3,
/// sizes with one partial sum and with several (4 096 pixels per workgroup, the last one
/// partly filled), and supersampled frames (the mean taken at render resolution, then
/// downsampled). The frames must differ from the same scene over its constant colour.
#[test]
fn frame_mean_background_matches_reference() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut total = Errors::default();
    let mut moved = 0.0f64;
    for seed in 0..4u64 {
        let mut rng = Rng(4400 + seed);
        let k = 1 + (seed % 3) as u32;
        let mut scene = random_scene(&mut rng, [4, 8, 16, 10][seed as usize], (seed % 4) as u32);
        scene.background = [0.9, 0.1, 0.5];
        scene.background_frame_mean = true;
        let (w, h) = [(45, 31), (97, 61), (64, 64), (130, 37)][seed as usize];
        for (ci, cam) in [
            camera_outside(&mut rng, &scene, w, h),
            camera_inside(&mut rng, &scene, w, h),
        ]
        .iter()
        .enumerate()
        {
            let what = format!("seed {seed} K {k} {w}×{h} camera {ci}");
            let img = render(&mut r, &ctx, &scene, cam, k);
            let refs = reference::render(&scene, cam, k as usize);
            let e = compare(&img, &refs, &what);
            assert_within(&e, &what);
            total = total.max(e);
            let mut plain = scene.clone();
            plain.background_frame_mean = false;
            let other = render(&mut r, &ctx, &plain, cam, k);
            for p in 0..img.rgb.len() {
                for c in 0..3 {
                    moved = moved.max((img.rgb[p][c] - other.rgb[p][c]).abs() as f64);
                }
            }
        }
    }
    assert!(
        moved > 0.1,
        "the frame mean changed no pixel by 0.1 ({moved})"
    );
    // Supersampled: the mean over the render-resolution frame.
    let mut rng = Rng(4450);
    let mut scene = random_scene(&mut rng, 8, 2);
    scene.background_frame_mean = true;
    let cam = camera_outside(&mut rng, &scene, 30, 22);
    let gpu = SceneGpu::upload(&ctx, &scene).unwrap();
    for ss in [1.5f32, 2.0] {
        let opts = RenderOptions {
            samples: 1,
            supersample: ss,
        };
        let (img, st) = r.render(&gpu, &cam, &opts).unwrap();
        let (rw, rh) = (st.render_width, st.render_height);
        let hi = reference::render(&scene, &cam.resized(rw, rh), 1);
        let refs = super::reference_downsample(&hi, rw, rh, 30, 22);
        let e = compare(&img, &refs, "frame mean, supersampled");
        assert_within(&e, &format!("frame mean, supersample {ss}"));
        total = total.max(e);
    }
    println!("frame-mean background against the reference: {total:?}; largest change from the constant colour {moved:.3}");
    finish(&ctx);
}

/// A large frame (more than 256 partial sums, so the total's loop wraps): the frame-mean
/// image is the black-background image plus T·m, with m the f64 mean of the
/// black-background colours, on every pixel and channel.
#[test]
#[allow(clippy::needless_range_loop)]
fn frame_mean_of_a_large_frame_is_the_mean_colour() {
    let ctx = context();
    let mut r = Renderer::new(&ctx).unwrap();
    let mut rng = Rng(4460);
    let mut scene = random_scene(&mut rng, 6, 1);
    scene.background = [0.0; 3];
    let (w, h) = (1201, 901);
    let cam = camera_outside(&mut rng, &scene, w, h);
    assert!((w * h).div_ceil(4096) > 256);
    let black = render(&mut r, &ctx, &scene, &cam, 1);
    scene.background_frame_mean = true;
    let img = render(&mut r, &ctx, &scene, &cam, 1);
    let n = black.rgb.len() as f64;
    let m: [f64; 3] =
        std::array::from_fn(|c| black.rgb.iter().map(|p| p[c] as f64).sum::<f64>() / n);
    let covered = black.alpha.iter().filter(|&&a| a > 0.5).count();
    assert!(
        covered > 1000 && covered + 1000 < black.alpha.len(),
        "the view should show the scene and the background: {covered} covered pixels"
    );
    let mut worst = 0.0f64;
    for p in 0..img.rgb.len() {
        let t = 1.0 - black.alpha[p] as f64;
        for c in 0..3 {
            let want = black.rgb[p][c] as f64 + t * m[c];
            worst = worst.max((img.rgb[p][c] as f64 - want).abs());
        }
        assert_eq!(img.alpha[p], black.alpha[p]);
    }
    println!("{w}×{h}: mean colour {m:.4?}, worst difference {worst:.2e}");
    assert!(worst < 2e-5, "worst difference {worst:e} from C + T·m");
    finish(&ctx);
}
