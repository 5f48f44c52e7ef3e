//! SSIM as reported and as trained (f64 CPU reference, clear rather than fast): the
//! `ssim()` of 3D Gaussian Splatting / SVRaster. Per RGB channel, an 11×11 Gaussian window
//! (σ = 1.5, normalised to sum 1) applied as a convolution with **zero padding** of 5 and
//! no renormalisation at the borders; `C1 = 0.01²`, `C2 = 0.03²`; the SSIM is the mean of
//! the SSIM map over all `3·H·W` values. [`ssim_grad`] is its gradient (the reference of
//! the GPU loss in [`crate::train::ssim`], whose module notes derive it).

/// Side of the Gaussian window.
pub const WINDOW: usize = 11;
/// Standard deviation of the Gaussian window in pixels.
pub const SIGMA: f64 = 1.5;
/// `C1 = (0.01 · L)²` with dynamic range `L = 1`.
pub const C1: f64 = 0.01 * 0.01;
/// `C2 = (0.03 · L)²` with dynamic range `L = 1`.
pub const C2: f64 = 0.03 * 0.03;

const HALF: isize = (WINDOW / 2) as isize;

/// The normalised 1-D Gaussian window (`exp(−(i−5)²/(2σ²))`, sum 1) in f64.
pub fn gaussian_window() -> [f64; WINDOW] {
    let mut g = [0.0; WINDOW];
    for (i, v) in g.iter_mut().enumerate() {
        let d = i as f64 - HALF as f64;
        *v = (-(d * d) / (2.0 * SIGMA * SIGMA)).exp();
    }
    let sum: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= sum);
    g
}

/// Zero-padded separable 11×11 Gaussian blur of one `w`×`h` plane (row-major), in f64.
fn blur(src: &[f64], w: usize, h: usize, g: &[f64; WINDOW]) -> Vec<f64> {
    let mut tmp = vec![0.0; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut acc = 0.0;
            for (t, gt) in g.iter().enumerate() {
                let j = c as isize + t as isize - HALF;
                if (0..w as isize).contains(&j) {
                    acc += gt * src[r * w + j as usize];
                }
            }
            tmp[r * w + c] = acc;
        }
    }
    let mut out = vec![0.0; w * h];
    for r in 0..h {
        for c in 0..w {
            let mut acc = 0.0;
            for (t, gt) in g.iter().enumerate() {
                let i = r as isize + t as isize - HALF;
                if (0..h as isize).contains(&i) {
                    acc += gt * tmp[i as usize * w + c];
                }
            }
            out[r * w + c] = acc;
        }
    }
    out
}

/// Per-pixel SSIM map value and its partials `(S, ∂S/∂μx, ∂S/∂Exx, ∂S/∂Exy)` from the
/// blurred statistics `μx, μy, Exx = G∗x², Eyy = G∗y², Exy = G∗xy`.
fn ssim_terms(mx: f64, my: f64, exx: f64, eyy: f64, exy: f64) -> (f64, f64, f64, f64) {
    let sxx = exx - mx * mx;
    let syy = eyy - my * my;
    let sxy = exy - mx * my;
    let l = 2.0 * mx * my + C1;
    let cs = 2.0 * sxy + C2;
    let d1 = mx * mx + my * my + C1;
    let d2 = sxx + syy + C2;
    let s = l * cs / (d1 * d2);
    let a = 2.0 * my * (cs - l) / (d1 * d2) + 2.0 * mx * s * (1.0 / d2 - 1.0 / d1);
    let b = -s / d2;
    let cm = 2.0 * l / (d1 * d2);
    (s, a, b, cm)
}

/// One channel of a pair: its x and y planes and the blurred statistics planes.
struct Channel {
    x: Vec<f64>,
    y: Vec<f64>,
    mx: Vec<f64>,
    my: Vec<f64>,
    exx: Vec<f64>,
    eyy: Vec<f64>,
    exy: Vec<f64>,
}

impl Channel {
    fn new(
        x: &[[f32; 3]],
        y: &[[f32; 3]],
        c: usize,
        w: usize,
        h: usize,
        g: &[f64; WINDOW],
    ) -> Self {
        let xs: Vec<f64> = x.iter().map(|p| p[c] as f64).collect();
        let ys: Vec<f64> = y.iter().map(|p| p[c] as f64).collect();
        let blur_of = |f: fn(f64, f64) -> f64| -> Vec<f64> {
            let plane: Vec<f64> = xs.iter().zip(&ys).map(|(&a, &b)| f(a, b)).collect();
            blur(&plane, w, h, g)
        };
        let (mx, my) = (blur_of(|a, _| a), blur_of(|_, b| b));
        let (exx, eyy, exy) = (
            blur_of(|a, _| a * a),
            blur_of(|_, b| b * b),
            blur_of(|a, b| a * b),
        );
        Channel {
            x: xs,
            y: ys,
            mx,
            my,
            exx,
            eyy,
            exy,
        }
    }

    /// `(S, A, B, Cm)` at every pixel.
    fn terms(&self) -> impl Iterator<Item = (f64, f64, f64, f64)> + '_ {
        (0..self.x.len()).map(|p| {
            ssim_terms(
                self.mx[p],
                self.my[p],
                self.exx[p],
                self.eyy[p],
                self.exy[p],
            )
        })
    }
}

fn check_cpu_dims(x: &[[f32; 3]], y: &[[f32; 3]], width: usize, height: usize) {
    assert!(width > 0 && height > 0, "SSIM of an empty image");
    assert_eq!(x.len(), width * height, "x is not width×height");
    assert_eq!(y.len(), width * height, "y is not width×height");
}

/// f64 reference (clear, not fast): mean SSIM of two interleaved RGB images
/// (`width`×`height`, row-major). Separable, O(H·W·11). Panics if the sizes do not match
/// or are zero.
pub fn ssim(x: &[[f32; 3]], y: &[[f32; 3]], width: usize, height: usize) -> f64 {
    ssim_margin(x, y, width, height, 0)
}

/// The window centres counted with `margin` (those at least `margin` pixels from every
/// border; every pixel when the image is too small for any): (margin used, count per
/// channel).
fn centres(width: usize, height: usize, margin: usize) -> (usize, usize) {
    if width <= 2 * margin || height <= 2 * margin {
        return (0, width * height);
    }
    (margin, (width - 2 * margin) * (height - 2 * margin))
}

fn inside(p: usize, width: usize, height: usize, margin: usize) -> bool {
    let (row, col) = (p / width, p % width);
    row >= margin && row + margin < height && col >= margin && col + margin < width
}

/// [`ssim`] averaged over the window centres at least `margin` pixels from every border:
/// 5 is "valid" SSIM (SVRaster's `fused_ssim(..., padding="valid")`; the GPU's
/// `Ssim::set_valid`), 0 every pixel.
pub fn ssim_margin(
    x: &[[f32; 3]],
    y: &[[f32; 3]],
    width: usize,
    height: usize,
    margin: usize,
) -> f64 {
    check_cpu_dims(x, y, width, height);
    let (margin, n) = centres(width, height, margin);
    let g = gaussian_window();
    let sum: f64 = (0..3)
        .map(|c| {
            Channel::new(x, y, c, width, height, &g)
                .terms()
                .enumerate()
                .filter(|(p, _)| inside(*p, width, height, margin))
                .map(|(_, t)| t.0)
                .sum::<f64>()
        })
        .sum();
    sum / (3 * n) as f64
}

/// f64 reference gradient d(mean SSIM)/dx, interleaved like x. Separable, O(H·W·11).
/// Panics if the sizes do not match or are zero.
pub fn ssim_grad(x: &[[f32; 3]], y: &[[f32; 3]], width: usize, height: usize) -> Vec<[f64; 3]> {
    ssim_grad_margin(x, y, width, height, 0)
}

/// The gradient of [`ssim_margin`].
pub fn ssim_grad_margin(
    x: &[[f32; 3]],
    y: &[[f32; 3]],
    width: usize,
    height: usize,
    margin: usize,
) -> Vec<[f64; 3]> {
    check_cpu_dims(x, y, width, height);
    let (margin, count) = centres(width, height, margin);
    let g = gaussian_window();
    let n = width * height;
    let inv_m = 1.0 / (3 * count) as f64;
    let mut out = vec![[0.0; 3]; n];
    for c in 0..3 {
        let ch = Channel::new(x, y, c, width, height, &g);
        let terms: Vec<_> = ch
            .terms()
            .enumerate()
            .map(|(p, t)| {
                if inside(p, width, height, margin) {
                    t
                } else {
                    (0.0, 0.0, 0.0, 0.0)
                }
            })
            .collect();
        let blur_of = |f: fn(&(f64, f64, f64, f64)) -> f64| -> Vec<f64> {
            let plane: Vec<f64> = terms.iter().map(f).collect();
            blur(&plane, width, height, &g)
        };
        let (ga, gb, gc) = (blur_of(|t| t.1), blur_of(|t| t.2), blur_of(|t| t.3));
        for (p, o) in out.iter_mut().enumerate() {
            o[c] = inv_m * (ga[p] + 2.0 * ch.x[p] * gb[p] + ch.y[p] * gc[p]);
        }
    }
    out
}
