//! Image-quality metrics and model evaluation: the numbers every report quotes (the CLI's
//! `eval`, `demo` and `bench trade`, and the tests) come from here, computed one way.
//!
//! - [`psnr`]: on [0, 1] RGB, both images clamped first (as when saved to 8-bit PNG).
//! - [`ssim::ssim`]: the 3DGS/SVRaster SSIM (11×11 Gaussian, σ 1.5) in f64, on clamped
//!   images.
//! - [`evaluate`]: renders every frame of a dataset split and reports their means and,
//!   when asked, the median frame time.

pub mod ssim;

use std::time::Instant;

use crate::data::Dataset;
use crate::error::{Error, Result};
use crate::gpu::Context;
use crate::raster::{RenderOptions, Renderer};
use crate::scene::Scene;
use crate::scene::SceneGpu;

/// PSNR in dB of `a` against `b` on [0, 1] RGB (values clamped as when saved to PNG;
/// +inf for identical images). Panics if the lengths differ.
pub fn psnr(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    assert_eq!(a.len(), b.len(), "PSNR of images of different sizes");
    let mut se = 0.0f64;
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            let d = f64::from(x[c].clamp(0.0, 1.0)) - f64::from(y[c].clamp(0.0, 1.0));
            se += d * d;
        }
    }
    let mse = se / (3 * a.len().max(1)) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        -10.0 * mse.log10()
    }
}

/// Median of a slice (mean of the two middle values for an even length; NaN when empty).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let m = s.len() / 2;
    if s.len() % 2 == 1 {
        s[m]
    } else {
        0.5 * (s[m - 1] + s[m])
    }
}

/// Result of [`evaluate`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct EvalReport {
    /// Mean over the views.
    pub psnr: f64,
    pub ssim: f64,
    pub views: usize,
    /// Median render time per frame: frames queued behind each other, image read-back
    /// included, scoring excluded (after a warm-up frame); `None` when not timed.
    pub ms_per_frame: Option<f64>,
    pub split: String,
    /// Largest frame width and height (the frames' own where `sizes_differ`).
    pub width: u32,
    pub height: u32,
    /// Whether the frames differ in size (a capture with several cameras).
    pub sizes_differ: bool,
    pub voxels: usize,
    /// The supersampling the views were rendered with.
    pub supersample: f32,
    /// Per view: name, PSNR, SSIM.
    pub per_view: Vec<(String, f64, f64)>,
}

/// Whether [`evaluate`] measures the frame time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timing {
    /// The views are rendered twice: once queued back to back for the frame time
    /// (nothing done on the frames, so scoring on the host, which shares a CPU device's
    /// cores, does not slow it), once for the scores.
    Measured,
    /// Only the scores (the held-out curve during training): each view rendered once.
    Skipped,
}

/// Renders every frame of `ds` with `scene` and compares it with the photo: mean
/// [`psnr`] and [`ssim::ssim`], and with [`Timing::Measured`] the median frame time.
/// `progress` is called after each view with (views done, views in all, the view's
/// name, its PSNR, its SSIM).
pub fn evaluate(
    ctx: &Context,
    scene: &Scene,
    ds: &Dataset,
    opts: &RenderOptions,
    timing: Timing,
    mut progress: impl FnMut(usize, usize, &str, f64, f64),
) -> Result<EvalReport> {
    if ds.frames.is_empty() {
        return Err(Error::Invalid(format!(
            "split `{}` has no frames to evaluate",
            ds.split
        )));
    }
    let gpu = SceneGpu::upload(ctx, scene)?;
    let mut r = Renderer::new(ctx)?;
    // Warm up (pipelines, buffer growth) on the first view.
    r.render_to_device(&gpu, &ds.frames[0].camera, opts, None)?;
    let clamp = |v: &[[f32; 3]]| -> Vec<[f32; 3]> {
        v.iter().map(|c| c.map(|x| x.clamp(0.0, 1.0))).collect()
    };
    let cams: Vec<_> = ds.frames.iter().map(|f| f.camera.clone()).collect();
    // Frame time: frames queued behind each other (Renderer::render_each), the time
    // between consecutive frames handed over with nothing done on them — the render
    // throughput, image read-back included, scoring excluded.
    let mut times = Vec::new();
    if timing == Timing::Measured {
        let mut t = Instant::now();
        r.render_each(&gpu, &cams, opts, |_, _, _| {
            times.push(t.elapsed().as_secs_f64() * 1e3);
            t = Instant::now();
            Ok(())
        })?;
    }
    // Scoring (on the host, while the next frame renders).
    let mut per_view = Vec::new();
    r.render_each(&gpu, &cams, opts, |i, img, _| {
        let f = &ds.frames[i];
        let p = psnr(&img.rgb, &f.rgb);
        let s = ssim::ssim(
            &clamp(&img.rgb),
            &clamp(&f.rgb),
            f.camera.width as usize,
            f.camera.height as usize,
        );
        progress(i + 1, ds.frames.len(), &f.name, p, s);
        per_view.push((f.name.clone(), p, s));
        Ok(())
    })?;
    let n = per_view.len() as f64;
    Ok(EvalReport {
        psnr: per_view.iter().map(|v| v.1).sum::<f64>() / n,
        ssim: per_view.iter().map(|v| v.2).sum::<f64>() / n,
        views: per_view.len(),
        ms_per_frame: (timing == Timing::Measured).then(|| median(&times)),
        split: ds.split.clone(),
        width: ds.width,
        height: ds.height,
        sizes_differ: !ds.uniform_size(),
        voxels: scene.num_voxels(),
        supersample: opts.supersample,
        per_view,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_clamps_both_images_and_matches_the_definition() {
        let a = vec![[0.5f32; 3]; 4];
        let b = vec![[0.6f32; 3]; 4];
        // MSE 0.01 → 20 dB (f32 inputs: 0.6 − 0.5 is 0.1 to ~1e-8).
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-5, "{}", psnr(&a, &b));
        assert_eq!(psnr(&a, &a), f64::INFINITY);
        // Out-of-range values count as saved to PNG: 1.7 is 1, −0.2 is 0.
        let hi = vec![[1.7f32, -0.2, 0.5]; 4];
        let clamped = vec![[1.0f32, 0.0, 0.5]; 4];
        assert_eq!(psnr(&hi, &clamped), f64::INFINITY);
        assert_eq!(psnr(&clamped, &hi), f64::INFINITY);
    }

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(&[]).is_nan());
    }
}
