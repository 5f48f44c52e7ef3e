//! The forward rasterizer's comparison with the f64 reference (tests/common/reference.rs),
//! shared by tests/raster/ and tests/properties.rs.
//!
//! Stated bounds (max abs error per pixel, f32 GPU vs f64 reference): rgb and alpha
//! ≤ RGB_TOL, depth ≤ DEPTH_TOL·(1 + depth), normal ≤ NORMAL_TOL, median depth ≤
//! DEPTH_TOL·(1 + depth) except where the reference decides it within 1e-3 of T = 0.5.

use super::reference::RefPixel;
use svraster::data::Camera;
use svraster::raster::{Image, RenderOptions, Renderer};
use svraster::scene::{Scene, SceneGpu};

pub const RGB_TOL: f64 = 1e-3;
pub const DEPTH_TOL: f64 = 1e-3;
pub const NORMAL_TOL: f64 = 1e-3;

#[derive(Default, Debug, Clone, Copy)]
pub struct Errors {
    pub rgb: f64,
    pub alpha: f64,
    pub depth: f64,
    pub median: f64,
    pub normal: f64,
    pub median_skipped: usize,
}

impl Errors {
    pub fn max(self, o: Errors) -> Errors {
        Errors {
            rgb: self.rgb.max(o.rgb),
            alpha: self.alpha.max(o.alpha),
            depth: self.depth.max(o.depth),
            median: self.median.max(o.median),
            normal: self.normal.max(o.normal),
            median_skipped: self.median_skipped + o.median_skipped,
        }
    }
}

pub fn compare(img: &Image, refs: &[RefPixel], what: &str) -> Errors {
    assert_eq!(img.rgb.len(), refs.len(), "{what}: pixel count");
    let mut e = Errors::default();
    for (i, r) in refs.iter().enumerate() {
        for c in 0..3 {
            e.rgb = e.rgb.max((img.rgb[i][c] as f64 - r.rgb[c]).abs());
            e.normal = e.normal.max((img.normal[i][c] as f64 - r.normal[c]).abs());
        }
        e.alpha = e.alpha.max((img.alpha[i] as f64 - r.alpha).abs());
        e.depth = e
            .depth
            .max((img.depth[i] as f64 - r.depth).abs() / (1.0 + r.depth.abs()));
        if r.median_ambiguous {
            e.median_skipped += 1;
        } else {
            e.median = e.median.max(
                (img.depth_median[i] as f64 - r.depth_median).abs() / (1.0 + r.depth_median.abs()),
            );
        }
        assert!(
            img.rgb[i].iter().all(|v| v.is_finite())
                && img.alpha[i].is_finite()
                && img.depth[i].is_finite()
                && img.depth_median[i].is_finite(),
            "{what}: non-finite output at pixel {i}"
        );
    }
    e
}

/// Pixel `i` of an image as a 1×1 image.
pub fn pixel(img: &Image, i: usize) -> Image {
    Image {
        width: 1,
        height: 1,
        rgb: vec![img.rgb[i]],
        alpha: vec![img.alpha[i]],
        depth: vec![img.depth[i]],
        depth_median: vec![img.depth_median[i]],
        normal: vec![img.normal[i]],
    }
}

pub fn assert_within(e: &Errors, what: &str) {
    println!("{what}: {e:?}");
    assert!(e.rgb <= RGB_TOL, "{what}: rgb error {} > {RGB_TOL}", e.rgb);
    assert!(
        e.alpha <= RGB_TOL,
        "{what}: alpha error {} > {RGB_TOL}",
        e.alpha
    );
    assert!(
        e.depth <= DEPTH_TOL,
        "{what}: depth error {} > {DEPTH_TOL}",
        e.depth
    );
    assert!(
        e.median <= DEPTH_TOL,
        "{what}: median depth error {}",
        e.median
    );
    assert!(e.normal <= NORMAL_TOL, "{what}: normal error {}", e.normal);
}

pub fn render(
    r: &mut Renderer,
    ctx: &svraster::gpu::Context,
    scene: &Scene,
    cam: &Camera,
    k: u32,
) -> Image {
    let gpu = SceneGpu::upload(ctx, scene).expect("upload");
    let (img, stats) = r
        .render(
            &gpu,
            cam,
            &RenderOptions {
                samples: k,
                supersample: 1.0,
            },
        )
        .expect("render");
    assert!(stats.complete());
    img
}
