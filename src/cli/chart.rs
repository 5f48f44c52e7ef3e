//! Dependency-free PNG charts for benchmark reports: scatter/line plots with "nice" ticks,
//! an embedded 5×7 bitmap font, a legend, and atomic PNG output.
//!
//! Only `image` (for the PNG encoder and the pixel buffer) is used; all drawing (Bresenham
//! lines, filled markers, text) is done here.

use std::io::Cursor;
use std::path::Path;

use anyhow::{bail, Context as _};
use image::{Rgb, RgbImage};

/// One data point; `label` is drawn next to its marker.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub label: Option<String>,
}

impl Point {
    #[allow(dead_code)] // unlabeled points: used by the tests
    pub fn new(x: f64, y: f64) -> Self {
        Self { x, y, label: None }
    }

    pub fn labeled(x: f64, y: f64, label: impl Into<String>) -> Self {
        Self {
            x,
            y,
            label: Some(label.into()),
        }
    }
}

/// A named set of points, drawn in one colour and joined by lines in x order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    pub name: String,
    pub points: Vec<Point>,
}

impl Series {
    pub fn new(name: impl Into<String>, points: Vec<Point>) -> Self {
        Self {
            name: name.into(),
            points,
        }
    }
}

/// A scatter/line chart. Points with a non-finite coordinate (or x <= 0 when `x_log`)
/// are skipped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Logarithmic x axis (decade ticks).
    pub x_log: bool,
}

/// Pixel rectangle of the plot frame; all four edges are inclusive pixel coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub left: i32,
    pub top: i32,
    pub right: i32,
    pub bottom: i32,
}

/// An axis tick: its data value and its label.
#[derive(Clone, Debug, PartialEq)]
pub struct Tick {
    pub value: f64,
    pub label: String,
}

/// Where everything goes for one `Chart::render(width, height)`; `map` turns data
/// coordinates into the pixel where the point's marker is centred.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    pub plot: Rect,
    /// Visible x range in axis space (log10(x) when `x_log`).
    pub x_range: (f64, f64),
    pub y_range: (f64, f64),
    pub x_log: bool,
    pub x_ticks: Vec<Tick>,
    pub y_ticks: Vec<Tick>,
    /// Integer font scale (a glyph is 5·scale × 7·scale pixels).
    pub scale: i32,
}

impl Layout {
    /// Pixel of data point (x, y), or None if the point is not drawable (non-finite, or
    /// x <= 0 on a log axis).
    pub fn map(&self, x: f64, y: f64) -> Option<(i32, i32)> {
        let tx = self.axis_x(x)?;
        if !y.is_finite() {
            return None;
        }
        Some((self.map_axis_x(tx), self.map_y(y)))
    }

    /// x in axis space (log10 for a log axis).
    fn axis_x(&self, x: f64) -> Option<f64> {
        let t = if self.x_log {
            if x > 0.0 {
                x.log10()
            } else {
                return None;
            }
        } else {
            x
        };
        t.is_finite().then_some(t)
    }

    fn map_axis_x(&self, t: f64) -> i32 {
        let (lo, hi) = self.x_range;
        let f = (t.clamp(-VMAX, VMAX) - lo) / (hi - lo);
        to_px(self.plot.left as f64 + f * (self.plot.right - self.plot.left) as f64)
    }

    fn map_y(&self, y: f64) -> i32 {
        let (lo, hi) = self.y_range;
        let f = (y.clamp(-VMAX, VMAX) - lo) / (hi - lo);
        to_px(self.plot.bottom as f64 - f * (self.plot.bottom - self.plot.top) as f64)
    }
}

/// Values are clamped to ±VMAX so ranges and spans stay finite.
const VMAX: f64 = 1e300;
/// Largest image side `save_png` / `save_grid` accept.
const MAX_DIM: u32 = 16384;

fn to_px(v: f64) -> i32 {
    if v.is_nan() {
        0
    } else {
        v.round().clamp(-1e6, 1e6) as i32
    }
}

const WHITE: Rgb<u8> = Rgb([255, 255, 255]);
const BLACK: Rgb<u8> = Rgb([0, 0, 0]);
const TEXT: Rgb<u8> = Rgb([30, 30, 30]);
const POINT_LABEL: Rgb<u8> = Rgb([80, 80, 80]);
const GRID: Rgb<u8> = Rgb([222, 222, 222]);
const MINOR_GRID: Rgb<u8> = Rgb([242, 242, 242]);

/// Tableau-10 palette.
const PALETTE: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];

/// Colour of series `i` (10 distinct colours, then repeating with another marker shape).
pub fn series_color(i: usize) -> Rgb<u8> {
    Rgb(PALETTE[i % PALETTE.len()])
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Shape {
    Circle,
    Square,
    Diamond,
}

fn series_shape(i: usize) -> Shape {
    [Shape::Circle, Shape::Square, Shape::Diamond][i % 3]
}

impl Chart {
    fn valid(&self, p: &Point) -> bool {
        p.x.is_finite() && p.y.is_finite() && (!self.x_log || p.x > 0.0)
    }

    fn valid_points(&self) -> impl Iterator<Item = &Point> + '_ {
        self.series
            .iter()
            .flat_map(|s| s.points.iter())
            .filter(|p| self.valid(p))
    }

    /// Computes the plot rectangle, axis ranges and ticks for a `width`×`height` image.
    pub fn layout(&self, width: u32, height: u32) -> Layout {
        let s = font_scale(width, height);
        let (w, h) = (dim(width), dim(height));
        let ch = GLYPH_H * s;
        let adv = ADVANCE * s;
        let pad = 4 * s;
        let tick_len = 3 * s;

        let x_range = axis_range(self.valid_points().map(|p| p.x), self.x_log);
        let y_range = axis_range(self.valid_points().map(|p| p.y), false);

        let title_h = if self.title.trim().is_empty() {
            0
        } else {
            GLYPH_H * (s + 1) + pad
        };
        let top = 2 * pad + title_h;
        let legend_w = if self.series.is_empty() {
            0
        } else {
            let names = self
                .series
                .iter()
                .enumerate()
                .map(|(i, se)| text_width(&legend_name(se, i), s))
                .max()
                .unwrap_or(0);
            (legend_swatch(s) + adv + names + pad).min(w / 3)
        };
        let right_margin = 2 * pad + legend_w;
        let x_label_h = if self.x_label.trim().is_empty() {
            0
        } else {
            ch + pad
        };
        let bottom_margin = tick_len + pad + ch + pad + x_label_h;
        let plot_h = (h - top - bottom_margin).max(1);

        // As many y ticks as fit with a label height of space between them.
        let mut y_vals = Vec::new();
        for target in (2..=8).rev() {
            y_vals = nice_ticks(y_range.0, y_range.1, target);
            if y_vals.len() as i32 * ch * 2 <= plot_h {
                break;
            }
        }
        let y_ticks = label_ticks(&y_vals, false);
        let y_tick_w = y_ticks
            .iter()
            .map(|t| text_width(&t.label, s))
            .max()
            .unwrap_or(0);
        let y_label_w = if self.y_label.trim().is_empty() {
            0
        } else {
            ch + pad
        };
        let left = pad + y_label_w + y_tick_w + pad + tick_len;
        let plot_w = (w - left - right_margin).max(1);

        // As many x ticks as fit with two glyphs of space between labels.
        let mut x_ticks = Vec::new();
        for target in (2..=10).rev() {
            let vals = if self.x_log {
                log_ticks(10f64.powf(x_range.0), 10f64.powf(x_range.1), target)
            } else {
                nice_ticks(x_range.0, x_range.1, target)
            };
            x_ticks = label_ticks(&vals, self.x_log);
            let need: i32 = x_ticks
                .iter()
                .map(|t| text_width(&t.label, s) + 2 * adv)
                .sum();
            if need <= plot_w {
                break;
            }
        }

        Layout {
            plot: Rect {
                left,
                top,
                right: left + plot_w,
                bottom: top + plot_h,
            },
            x_range,
            y_range,
            x_log: self.x_log,
            x_ticks,
            y_ticks,
            scale: s,
        }
    }

    /// Renders the chart: grid, axes with tick labels, each series as a line through its
    /// points in x order with a filled marker per point and optional point labels, axis
    /// labels, title and a legend on the right. Panics only if the image buffer cannot be
    /// allocated (`save_png` checks the size first).
    pub fn render(&self, width: u32, height: u32) -> RgbImage {
        let l = self.layout(width, height);
        let mut cv = Canvas::new(width, height);
        let s = l.scale;
        let ch = GLYPH_H * s;
        let adv = ADVANCE * s;
        let pad = 4 * s;
        let tick_len = 3 * s;
        let line_w = s;
        let r = 2 * s + 1;
        let p = l.plot;

        // Minor grid (2..9 × 10^k) on a log axis spanning few decades.
        if l.x_log && l.x_range.1 - l.x_range.0 <= 8.0 {
            let (lo, hi) = l.x_range;
            for e in lo.floor() as i32..=hi.ceil() as i32 {
                for m in 2..=9 {
                    let t = e as f64 + (m as f64).log10();
                    if t > lo && t < hi {
                        cv.fill(l.map_axis_x(t), p.top, 1, p.bottom - p.top, MINOR_GRID);
                    }
                }
            }
        }
        let x_tick_px: Vec<(i32, &Tick)> = l
            .x_ticks
            .iter()
            .filter_map(|t| l.axis_x(t.value).map(|a| (l.map_axis_x(a), t)))
            .collect();
        let y_tick_px: Vec<(i32, &Tick)> =
            l.y_ticks.iter().map(|t| (l.map_y(t.value), t)).collect();
        for &(x, _) in &x_tick_px {
            cv.fill(x, p.top, 1, p.bottom - p.top, GRID);
        }
        for &(y, _) in &y_tick_px {
            cv.fill(p.left, y, p.right - p.left, 1, GRID);
        }

        // Series: lines, then point labels, then markers on top; all clipped to the frame.
        let mapped: Vec<Vec<(i32, i32, Option<&str>)>> = self
            .series
            .iter()
            .map(|se| {
                let mut pts: Vec<(f64, (i32, i32), Option<&str>)> = se
                    .points
                    .iter()
                    .filter(|pt| self.valid(pt))
                    .filter_map(|pt| l.map(pt.x, pt.y).map(|px| (pt.x, px, pt.label.as_deref())))
                    .collect();
                pts.sort_by(|a, b| a.0.total_cmp(&b.0));
                pts.into_iter()
                    .map(|(_, (x, y), lab)| (x, y, lab))
                    .collect()
            })
            .collect();
        cv.set_clip(p.left + 1, p.top + 1, p.right, p.bottom);
        for (i, pts) in mapped.iter().enumerate() {
            for w in pts.windows(2) {
                cv.line((w[0].0, w[0].1), (w[1].0, w[1].1), line_w, series_color(i));
            }
        }
        for pts in &mapped {
            for &(x, y, lab) in pts {
                let Some(lab) = lab.filter(|t| !t.is_empty()) else {
                    continue;
                };
                let tw = text_width(lab, s);
                let mut lx = x + r + 2 * s;
                if lx + tw > p.right - s && x - r - 2 * s - tw > p.left {
                    lx = x - r - 2 * s - tw;
                }
                cv.text(lx, y - ch / 2, lab, s, POINT_LABEL);
            }
        }
        for (i, pts) in mapped.iter().enumerate() {
            for &(x, y, _) in pts {
                cv.marker(x, y, r, series_shape(i), series_color(i));
            }
        }
        cv.reset_clip();

        // Frame, ticks, tick labels.
        cv.fill(p.left, p.top, p.right - p.left + 1, 1, BLACK);
        cv.fill(p.left, p.bottom, p.right - p.left + 1, 1, BLACK);
        cv.fill(p.left, p.top, 1, p.bottom - p.top + 1, BLACK);
        cv.fill(p.right, p.top, 1, p.bottom - p.top + 1, BLACK);
        for &(x, t) in &x_tick_px {
            cv.fill(x, p.bottom + 1, 1, tick_len, BLACK);
            let tw = text_width(&t.label, s);
            cv.text(x - tw / 2, p.bottom + tick_len + pad / 2, &t.label, s, TEXT);
        }
        for &(y, t) in &y_tick_px {
            cv.fill(p.left - tick_len, y, tick_len, 1, BLACK);
            let tw = text_width(&t.label, s);
            cv.text(
                p.left - tick_len - pad / 2 - tw,
                y - ch / 2,
                &t.label,
                s,
                TEXT,
            );
        }

        // Axis labels and title (centred; left/bottom-aligned when too long, clipped at
        // the image edge).
        if !self.x_label.trim().is_empty() {
            let tw = text_width(&self.x_label, s);
            let x = ((p.left + p.right) / 2 - tw / 2).max(pad);
            cv.text(
                x,
                p.bottom + tick_len + pad / 2 + ch + pad,
                &self.x_label,
                s,
                TEXT,
            );
        }
        if !self.y_label.trim().is_empty() {
            let tw = text_width(&self.y_label, s);
            let y = ((p.top + p.bottom) / 2 + tw / 2).min(p.bottom);
            cv.text_up(pad, y, &self.y_label, s, TEXT);
        }
        if !self.title.trim().is_empty() {
            let ts = s + 1;
            let tw = text_width(&self.title, ts);
            let x = ((dim(width) - tw) / 2).max(pad);
            cv.text(x, pad, &self.title, ts, TEXT);
        }

        // Legend, right of the frame.
        let lx = p.right + 2 * pad;
        let sw = legend_swatch(s);
        for (i, se) in self.series.iter().enumerate() {
            let cy = p.top + pad + i as i32 * (ch + pad) + ch / 2;
            let c = series_color(i);
            cv.line((lx, cy), (lx + sw, cy), line_w, c);
            cv.marker(lx + sw / 2, cy, r, series_shape(i), c);
            cv.text(lx + sw + adv, cy - ch / 2, &legend_name(se, i), s, TEXT);
        }
        cv.img
    }

    /// Renders and writes a PNG atomically (temporary file in the same directory, then
    /// rename).
    #[allow(dead_code)] // single charts: bench trade saves a grid
    pub fn save_png(&self, path: &Path, width: u32, height: u32) -> anyhow::Result<()> {
        check_dims(path, width, height)?;
        write_png(path, &self.render(width, height))
    }
}

/// Renders `charts` into one PNG, each in a `cell_w`×`cell_h` cell: side by side in one
/// row for up to 3 charts, otherwise 3 per row.
pub fn save_grid(charts: &[Chart], path: &Path, cell_w: u32, cell_h: u32) -> anyhow::Result<()> {
    if charts.is_empty() {
        bail!("cannot write chart grid {}: no charts", path.display());
    }
    let cols = charts.len().min(3) as u64;
    let rows = (charts.len() as u64).div_ceil(cols);
    let (w, h) = (cols * cell_w as u64, rows * cell_h as u64);
    if w > MAX_DIM as u64 || h > MAX_DIM as u64 {
        bail!(
            "cannot write chart grid {}: {w}x{h} exceeds {MAX_DIM}x{MAX_DIM}",
            path.display()
        );
    }
    check_dims(path, w as u32, h as u32)?;
    let mut img = RgbImage::from_pixel(w as u32, h as u32, WHITE);
    for (i, c) in charts.iter().enumerate() {
        let (col, row) = (i as u64 % cols, i as u64 / cols);
        let cell = c.render(cell_w, cell_h);
        image::imageops::replace(
            &mut img,
            &cell,
            (col * cell_w as u64) as i64,
            (row * cell_h as u64) as i64,
        );
    }
    write_png(path, &img)
}

fn check_dims(path: &Path, width: u32, height: u32) -> anyhow::Result<()> {
    if width == 0 || height == 0 || width > MAX_DIM || height > MAX_DIM {
        bail!(
            "cannot write chart {}: image size {width}x{height} is outside 1..={MAX_DIM}",
            path.display()
        );
    }
    Ok(())
}

fn write_png(path: &Path, img: &RgbImage) -> anyhow::Result<()> {
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
        .with_context(|| format!("cannot encode chart {}", path.display()))?;
    write_atomic(path, &bytes)
}

/// Writes `bytes` to `path` atomically ([`svraster::fsio::write_atomic`]).
fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    svraster::fsio::write_atomic(path, bytes)
        .map_err(|e| anyhow::anyhow!("cannot write chart {}: {e}", path.display()))
}

fn legend_name(se: &Series, i: usize) -> String {
    if se.name.trim().is_empty() {
        format!("series {}", i + 1)
    } else {
        se.name.clone()
    }
}

fn legend_swatch(s: i32) -> i32 {
    3 * ADVANCE * s
}

/// Integer font scale: 2 at 800×600 / 900×600, 1 below ~800 px wide.
fn font_scale(width: u32, height: u32) -> i32 {
    (width.min(height.saturating_mul(3) / 2) / 400).clamp(1, 16) as i32
}

fn dim(v: u32) -> i32 {
    v.min(1 << 20) as i32
}

/// Visible range in axis space: the finite values (log10 of the positive ones when
/// `log`), padded when all equal, plus a 5 % margin; (0, 1) when there are none.
fn axis_range(vals: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals {
        let t = if log {
            if v > 0.0 {
                v.log10()
            } else {
                continue;
            }
        } else {
            v
        };
        if t.is_finite() {
            let t = t.clamp(-VMAX, VMAX);
            lo = lo.min(t);
            hi = hi.max(t);
        }
    }
    if lo > hi {
        return (0.0, 1.0);
    }
    // All equal (relative to their size, or tiny enough to underflow tick maths): centre
    // them in a padded range.
    if hi - lo <= 1e-9 * lo.abs().max(hi.abs()) || hi - lo < 1e-200 {
        let c = 0.5 * lo + 0.5 * hi;
        let pad = if log {
            0.5
        } else if c.abs() > 1e-200 {
            0.1 * c.abs()
        } else {
            1.0
        };
        lo = c - pad;
        hi = c + pad;
    }
    let m = 0.05 * (hi - lo);
    (lo - m, hi + m)
}

/// Power of ten as the nearest f64 (exact for the ranges used here).
fn pow10(e: i32) -> f64 {
    if e >= 0 {
        10f64.powi(e)
    } else {
        1.0 / 10f64.powi(-e)
    }
}

/// Ticks at multiples of a 1-2-5 step that lie inside [lo, hi]: the smallest such step giving
/// at most `target` intervals, or a smaller one if that leaves fewer than two ticks.
pub fn nice_ticks(lo: f64, hi: f64, target: usize) -> Vec<f64> {
    if !lo.is_finite() || !hi.is_finite() {
        return Vec::new();
    }
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    if hi - lo <= 0.0 {
        return vec![lo];
    }
    let raw = (hi - lo) / target.max(1) as f64;
    // Spans that overflow or are (nearly) subnormal have no sensible decimal step.
    if !raw.is_normal() || !(1e-290..1e300).contains(&raw) {
        return vec![lo, hi];
    }
    let mut e = raw.log10().floor() as i32;
    let n = raw / pow10(e);
    let mut m = if n <= 1.0 + 1e-9 {
        1.0
    } else if n <= 2.0 + 1e-9 {
        2.0
    } else if n <= 5.0 + 1e-9 {
        5.0
    } else {
        e += 1;
        1.0
    };
    // The step can leave fewer than two multiples inside the range (0.353..0.396 with a
    // 0.05 step): go down the 1-2-5 ladder until there are two (span >= 2 steps suffices).
    let (mut k0, mut k1) = (0.0, 0.0);
    for _ in 0..12 {
        let step = m * pow10(e);
        k0 = (lo / step - 1e-9).ceil();
        k1 = (hi / step + 1e-9).floor();
        if !(k0.is_finite() && k1.is_finite()) || k1 - k0 > 1000.0 {
            return vec![lo, hi];
        }
        if k1 > k0 || step < (hi - lo) / 2.0 {
            break;
        }
        (m, e) = match m as u32 {
            5 => (2.0, e),
            2 => (1.0, e),
            _ => (5.0, e - 1),
        };
    }
    // k·m·10^e computed as an integer times/divided by an exact power of ten, so that
    // e.g. 3 × 0.2 is 0.6 and not 0.6000000000000001.
    (k0 as i64..=k1 as i64)
        .map(|k| {
            let km = k as f64 * m;
            let v = if e >= 0 {
                km * pow10(e)
            } else {
                km / pow10(-e)
            };
            if v == 0.0 {
                0.0
            } else {
                v
            }
        })
        .collect()
}

/// Ticks for a log axis over [lo, hi] (lo > 0): powers of ten (every n-th decade so that
/// there are at most `max_ticks`); if fewer than two decades fall inside, 1-2-5 × 10^k;
/// failing that, linear nice ticks.
pub fn log_ticks(lo: f64, hi: f64, max_ticks: usize) -> Vec<f64> {
    if !(lo > 0.0 && hi.is_finite() && lo.is_finite()) {
        return Vec::new();
    }
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    let in_range = |v: f64| v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9);
    let e0 = (lo.log10() - 1e-9).ceil() as i32;
    let e1 = (hi.log10() + 1e-9).floor() as i32;
    let decades = e1 - e0 + 1;
    if decades >= 2 {
        let stride = (decades as usize).div_ceil(max_ticks.max(2)).max(1);
        return (e0..=e1).step_by(stride).map(pow10).collect();
    }
    let mut v125 = Vec::new();
    for e in e0 - 1..=e1 + 1 {
        for m in [1.0, 2.0, 5.0] {
            let v = if e >= 0 { m * pow10(e) } else { m / pow10(-e) };
            if in_range(v) {
                v125.push(v);
            }
        }
    }
    if v125.len() >= 2 && v125.len() <= max_ticks.max(2) {
        return v125;
    }
    nice_ticks(lo, hi, max_ticks.clamp(2, 5))
}

/// Tick labels: on a linear axis with the decimals the tick step needs (0.0, 0.5, 1.0); on a
/// log axis each value in its shortest form (0.001, 0.01, 0.1).
fn label_ticks(vals: &[f64], log: bool) -> Vec<Tick> {
    if log {
        return vals
            .iter()
            .map(|&v| Tick {
                value: v,
                label: if (1e-4..1e7).contains(&v.abs()) {
                    format!("{v}")
                } else {
                    fmt_tick(v, v.abs())
                },
            })
            .collect();
    }
    let step = vals
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| *d > 0.0)
        .fold(f64::INFINITY, f64::min);
    vals.iter()
        .map(|&v| Tick {
            value: v,
            label: fmt_tick(v, if step.is_finite() { step } else { v.abs() }),
        })
        .collect()
}

/// Formats a tick value: plain decimals (as many as the step needs) for moderate
/// magnitudes, scientific notation for very large or very small ones.
pub fn fmt_tick(v: f64, step: f64) -> String {
    if !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if v == 0.0 && !(1e-4..1e7).contains(&step) {
        return "0".into();
    }
    if v != 0.0 && !(1e-4..1e7).contains(&a) {
        let digits = if step > 0.0 && step.is_finite() {
            (a.log10().floor() - step.log10().floor()).clamp(0.0, 6.0) as usize
        } else {
            3
        };
        let s = format!("{v:.digits$e}");
        // Trim trailing zeros of the mantissa: 1.50e7 -> 1.5e7, 1.00e7 -> 1e7.
        return match s.split_once('e') {
            Some((mant, exp)) if mant.contains('.') => {
                format!("{}e{exp}", mant.trim_end_matches('0').trim_end_matches('.'))
            }
            _ => s,
        };
    }
    let st = if step > 0.0 && step.is_finite() {
        step
    } else {
        a
    };
    let decimals = (-(st.log10() + 1e-9).floor()).clamp(0.0, 10.0) as usize;
    format!("{v:.decimals$}")
}

// ---------------------------------------------------------------------------------------
// Raster primitives.

struct Canvas {
    img: RgbImage,
    /// Half-open clip rectangle (x0, y0, x1, y1), always inside the image.
    clip: (i32, i32, i32, i32),
}

impl Canvas {
    fn new(width: u32, height: u32) -> Self {
        let mut cv = Self {
            img: RgbImage::from_pixel(width, height, WHITE),
            clip: (0, 0, 0, 0),
        };
        cv.reset_clip();
        cv
    }

    fn reset_clip(&mut self) {
        self.clip = (0, 0, dim(self.img.width()), dim(self.img.height()));
    }

    fn set_clip(&mut self, x0: i32, y0: i32, x1: i32, y1: i32) {
        let (w, h) = (dim(self.img.width()), dim(self.img.height()));
        self.clip = (
            x0.clamp(0, w),
            y0.clamp(0, h),
            x1.clamp(0, w),
            y1.clamp(0, h),
        );
    }

    /// Fills the w×h rectangle at (x, y), clipped.
    fn fill(&mut self, x: i32, y: i32, w: i32, h: i32, c: Rgb<u8>) {
        let (cx0, cy0, cx1, cy1) = self.clip;
        let (x0, y0) = (x.max(cx0), y.max(cy0));
        let (x1, y1) = (x.saturating_add(w).min(cx1), y.saturating_add(h).min(cy1));
        for yy in y0..y1 {
            for xx in x0..x1 {
                self.img.put_pixel(xx as u32, yy as u32, c);
            }
        }
    }

    /// Bresenham line with a square brush of `thick` pixels.
    fn line(&mut self, a: (i32, i32), b: (i32, i32), thick: i32, c: Rgb<u8>) {
        let lim = 1 << 20;
        let (mut x, mut y) = (a.0.clamp(-lim, lim), a.1.clamp(-lim, lim));
        let (x1, y1) = (b.0.clamp(-lim, lim), b.1.clamp(-lim, lim));
        let (dx, dy) = ((x1 - x).abs(), -(y1 - y).abs());
        let (sx, sy) = ((x1 - x).signum(), (y1 - y).signum());
        let t = thick.max(1);
        let off = (t - 1) / 2;
        let mut err = dx + dy;
        loop {
            self.fill(x - off, y - off, t, t, c);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Filled marker of radius `r` centred on (cx, cy).
    fn marker(&mut self, cx: i32, cy: i32, r: i32, shape: Shape, c: Rgb<u8>) {
        for dy in -r..=r {
            for dx in -r..=r {
                let inside = match shape {
                    Shape::Circle => dx * dx + dy * dy <= r * r + r / 2,
                    Shape::Square => dx.abs() < r && dy.abs() < r,
                    Shape::Diamond => dx.abs() + dy.abs() <= r + 1,
                };
                if inside {
                    self.fill(cx + dx, cy + dy, 1, 1, c);
                }
            }
        }
    }

    /// Left-to-right text with its top-left corner at (x, y).
    fn text(&mut self, x: i32, y: i32, s: &str, scale: i32, c: Rgb<u8>) {
        let adv = ADVANCE * scale;
        let mut cx = x;
        for ch in s.chars() {
            if cx >= self.clip.2 {
                break;
            }
            if cx + GLYPH_W * scale > self.clip.0 {
                let g = glyph(ch);
                for (row, bits) in g.iter().enumerate() {
                    for col in 0..GLYPH_W {
                        if bits & (0x10 >> col) != 0 {
                            let (px, py) = (cx + col * scale, y + row as i32 * scale);
                            self.fill(px, py, scale, scale, c);
                        }
                    }
                }
            }
            cx = cx.saturating_add(adv);
        }
    }

    /// Text rotated 90° counter-clockwise (reads bottom to top); (x, y) is the left end of
    /// the glyph tops and the bottom end of the baseline direction.
    fn text_up(&mut self, x: i32, y: i32, s: &str, scale: i32, c: Rgb<u8>) {
        let adv = ADVANCE * scale;
        let mut cy = y;
        for ch in s.chars() {
            if cy <= self.clip.1 {
                break;
            }
            if cy - GLYPH_W * scale < self.clip.3 {
                let g = glyph(ch);
                for (row, bits) in g.iter().enumerate() {
                    for col in 0..GLYPH_W {
                        if bits & (0x10 >> col) != 0 {
                            let (px, py) = (x + row as i32 * scale, cy - (col + 1) * scale);
                            self.fill(px, py, scale, scale, c);
                        }
                    }
                }
            }
            cy = cy.saturating_sub(adv);
        }
    }
}

// ---------------------------------------------------------------------------------------
// 5×7 bitmap font.

const GLYPH_W: i32 = 5;
const GLYPH_H: i32 = 7;
/// Horizontal advance per character (glyph plus one column of spacing).
const ADVANCE: i32 = 6;

/// Width in pixels of `s` drawn at `scale` (no trailing spacing).
fn text_width(s: &str, scale: i32) -> i32 {
    let n = s.chars().count().min(100_000) as i32;
    if n == 0 {
        0
    } else {
        n * ADVANCE * scale - scale
    }
}

/// The 5×7 bitmap of `c`: seven rows top to bottom, bit 4 (0x10) is the leftmost column.
/// Characters outside printable ASCII render as '?'.
pub fn glyph(c: char) -> [u8; 7] {
    let i = if (' '..='~').contains(&c) {
        c as usize - 32
    } else {
        '?' as usize - 32
    };
    FONT[i]
}

#[rustfmt::skip]
const FONT: [[u8; 7]; 95] = [
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00], // ' '
    [0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x04], // !
    [0x0A, 0x0A, 0x0A, 0x00, 0x00, 0x00, 0x00], // "
    [0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A], // #
    [0x04, 0x0F, 0x14, 0x0E, 0x05, 0x1E, 0x04], // $
    [0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03], // %
    [0x0C, 0x12, 0x14, 0x08, 0x15, 0x12, 0x0D], // &
    [0x0C, 0x04, 0x08, 0x00, 0x00, 0x00, 0x00], // '
    [0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02], // (
    [0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08], // )
    [0x00, 0x04, 0x15, 0x0E, 0x15, 0x04, 0x00], // *
    [0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00], // +
    [0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08], // ,
    [0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00], // -
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C], // .
    [0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00], // /
    [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E], // 0
    [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E], // 1
    [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F], // 2
    [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E], // 3
    [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02], // 4
    [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E], // 5
    [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E], // 6
    [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08], // 7
    [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E], // 8
    [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C], // 9
    [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00], // :
    [0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x04, 0x08], // ;
    [0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02], // <
    [0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00], // =
    [0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08], // >
    [0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04], // ?
    [0x0E, 0x11, 0x01, 0x0D, 0x15, 0x15, 0x0E], // @
    [0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11], // A
    [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E], // B
    [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E], // C
    [0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C], // D
    [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F], // E
    [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10], // F
    [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F], // G
    [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11], // H
    [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E], // I
    [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C], // J
    [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11], // K
    [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F], // L
    [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11], // M
    [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11], // N
    [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E], // O
    [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10], // P
    [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D], // Q
    [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11], // R
    [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E], // S
    [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04], // T
    [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E], // U
    [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04], // V
    [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A], // W
    [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11], // X
    [0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04], // Y
    [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F], // Z
    [0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E], // [
    [0x00, 0x10, 0x08, 0x04, 0x02, 0x01, 0x00], // \
    [0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E], // ]
    [0x04, 0x0A, 0x11, 0x00, 0x00, 0x00, 0x00], // ^
    [0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F], // _
    [0x08, 0x04, 0x02, 0x00, 0x00, 0x00, 0x00], // `
    [0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F], // a
    [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E], // b
    [0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E], // c
    [0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F], // d
    [0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E], // e
    [0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08], // f
    [0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E], // g
    [0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11], // h
    [0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E], // i
    [0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C], // j
    [0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12], // k
    [0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E], // l
    [0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11], // m
    [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11], // n
    [0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E], // o
    [0x00, 0x00, 0x1E, 0x11, 0x1E, 0x10, 0x10], // p
    [0x00, 0x00, 0x0D, 0x13, 0x0F, 0x01, 0x01], // q
    [0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10], // r
    [0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E], // s
    [0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06], // t
    [0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D], // u
    [0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04], // v
    [0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A], // w
    [0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11], // x
    [0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E], // y
    [0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F], // z
    [0x02, 0x04, 0x04, 0x08, 0x04, 0x04, 0x02], // {
    [0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04], // |
    [0x08, 0x04, 0x04, 0x02, 0x04, 0x04, 0x08], // }
    [0x00, 0x00, 0x08, 0x15, 0x02, 0x00, 0x00], // ~
];

#[cfg(test)]
mod tests {
    use super::*;

    fn approx_eq(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-12 * y.abs().max(1.0))
    }

    #[test]
    fn nice_ticks_linear() {
        let t = nice_ticks(0.13, 0.97, 5);
        assert!(approx_eq(&t, &[0.2, 0.4, 0.6, 0.8]), "{t:?}");
        // Exact decimals, not 0.6000000000000001.
        assert_eq!(t[2], 0.6);
        let t = nice_ticks(0.0, 100.0, 5);
        assert_eq!(t, vec![0.0, 20.0, 40.0, 60.0, 80.0, 100.0]);
        let t = nice_ticks(-3.0, 7.0, 5);
        assert_eq!(t, vec![-2.0, 0.0, 2.0, 4.0, 6.0]);
        assert!(t[1].is_sign_positive());
        let t = nice_ticks(1200.0, 4900.0, 4);
        assert_eq!(t, vec![2000.0, 3000.0, 4000.0]);
        // Degenerate inputs.
        assert_eq!(nice_ticks(3.0, 3.0, 5), vec![3.0]);
        assert!(nice_ticks(f64::NAN, 1.0, 5).is_empty());
        assert_eq!(nice_ticks(0.97, 0.13, 5), nice_ticks(0.13, 0.97, 5));
        // A step that would leave a single tick is refined: 0.05 -> 0.02.
        let t = nice_ticks(0.353, 0.396, 2);
        assert!(approx_eq(&t, &[0.36, 0.38]), "{t:?}");
        // Overflowing / subnormal spans terminate with the end points.
        assert_eq!(nice_ticks(-1.7e308, 1.7e308, 5), vec![-1.7e308, 1.7e308]);
        assert_eq!(nice_ticks(0.0, 5e-324, 5), vec![0.0, 5e-324]);

        // Property: 1-2-5 steps, ticks inside the range, a sensible count.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let scale = 10f64.powf(rnd() * 12.0 - 6.0);
            let lo = (rnd() - 0.5) * scale * 10.0;
            let hi = lo + rnd() * scale + scale * 1e-3;
            let target = 2 + (rnd() * 8.0) as usize;
            let t = nice_ticks(lo, hi, target);
            assert!(
                t.len() >= 2 && t.len() <= (target + 1).max(5),
                "{lo} {hi} {target}: {t:?}"
            );
            let tol = (hi - lo) * 1e-9;
            assert!(
                t.iter().all(|v| *v >= lo - tol && *v <= hi + tol),
                "{lo} {hi}: {t:?}"
            );
            if t.len() >= 2 {
                let step = t[1] - t[0];
                let e = step.log10().floor();
                let m = step / 10f64.powf(e);
                assert!(
                    [1.0, 2.0, 5.0, 10.0].iter().any(|c| (m - c).abs() < 1e-6),
                    "step {step} from {lo}..{hi}"
                );
            }
        }
    }

    #[test]
    fn log_ticks_decades() {
        assert_eq!(log_ticks(3.0, 4000.0, 10), vec![10.0, 100.0, 1000.0]);
        assert_eq!(log_ticks(1.0, 1000.0, 10), vec![1.0, 10.0, 100.0, 1000.0]);
        // Sub-unit decades are exact.
        assert_eq!(log_ticks(0.0005, 0.2, 10), vec![0.001, 0.01, 0.1]);
        // Too many decades: every other one.
        assert_eq!(log_ticks(1.0, 1e9, 5), vec![1.0, 100.0, 1e4, 1e6, 1e8]);
        // Less than a decade: 1-2-5 mantissas, else linear.
        assert_eq!(log_ticks(15.0, 90.0, 10), vec![20.0, 50.0]);
        let t = log_ticks(31.0, 39.0, 10);
        assert!(
            t.len() >= 2 && t.iter().all(|v| (31.0..=39.0).contains(v)),
            "{t:?}"
        );
        assert!(log_ticks(0.0, 10.0, 5).is_empty());
        assert!(log_ticks(-1.0, 10.0, 5).is_empty());
    }

    #[test]
    fn tick_labels() {
        assert_eq!(fmt_tick(0.2, 0.2), "0.2");
        assert_eq!(fmt_tick(0.05, 0.05), "0.05");
        assert_eq!(fmt_tick(1000.0, 1000.0), "1000");
        assert_eq!(fmt_tick(-2.0, 2.0), "-2");
        assert_eq!(fmt_tick(0.0, 0.1), "0.0");
        assert_eq!(fmt_tick(0.0, 10.0), "0");
        assert_eq!(fmt_tick(0.0, 1e-6), "0");
        assert_eq!(fmt_tick(2.5e7, 5e6), "2.5e7");
        assert_eq!(fmt_tick(3e7, 1e7), "3e7");
        assert_eq!(fmt_tick(2e-5, 1e-5), "2e-5");
        let labels = |v: &[f64], log: bool| -> Vec<String> {
            label_ticks(v, log).into_iter().map(|t| t.label).collect()
        };
        assert_eq!(labels(&[0.0, 0.5, 1.0], false), ["0.0", "0.5", "1.0"]);
        assert_eq!(labels(&[20.0, 40.0, 60.0], false), ["20", "40", "60"]);
        assert_eq!(labels(&[10.0, 100.0, 1000.0], true), ["10", "100", "1000"]);
        assert_eq!(labels(&[0.001, 0.01, 0.1], true), ["0.001", "0.01", "0.1"]);
        assert_eq!(labels(&[1e6, 1e8], true), ["1000000", "1e8"]);
        assert_eq!(labels(&[1.2, 1.4], true), ["1.2", "1.4"]);
    }

    #[test]
    fn glyphs_non_empty_and_distinct() {
        let chars: Vec<char> = ('A'..='Z')
            .chain('a'..='z')
            .chain('0'..='9')
            .chain(".-%()/:".chars())
            .collect();
        for &c in &chars {
            assert!(glyph(c).iter().any(|r| *r != 0), "glyph {c:?} is empty");
            assert!(
                glyph(c).iter().all(|r| *r < 0x20),
                "glyph {c:?} wider than 5"
            );
        }
        for (i, &a) in chars.iter().enumerate() {
            for &b in &chars[i + 1..] {
                assert_ne!(glyph(a), glyph(b), "glyphs {a:?} and {b:?} are identical");
            }
        }
        assert_eq!(glyph(' '), [0; 7]);
        assert_eq!(glyph('é'), glyph('?'));
        assert_eq!(FONT.len(), ('~' as usize) - (' ' as usize) + 1);
    }

    #[test]
    fn text_draws_glyph_bits() {
        for scale in [1, 3] {
            let mut cv = Canvas::new(40, 40);
            cv.text(2, 3, "A", scale, BLACK);
            let g = glyph('A');
            for row in 0..GLYPH_H {
                for col in 0..GLYPH_W {
                    let on = g[row as usize] & (0x10 >> col) != 0;
                    for (dx, dy) in [(0, 0), (scale - 1, scale - 1)] {
                        let p = cv.img.get_pixel(
                            (2 + col * scale + dx) as u32,
                            (3 + row * scale + dy) as u32,
                        );
                        assert_eq!(*p == BLACK, on, "scale {scale} row {row} col {col}");
                    }
                }
            }
        }
        // Rotated text: taller than wide, top of the glyph ('T' bar) on the left.
        let mut cv = Canvas::new(40, 60);
        cv.text_up(5, 50, "TT", 1, BLACK);
        let ink: Vec<(u32, u32)> = cv
            .img
            .enumerate_pixels()
            .filter(|(_, _, p)| **p == BLACK)
            .map(|(x, y, _)| (x, y))
            .collect();
        let (xmin, xmax) = (
            ink.iter().map(|p| p.0).min().unwrap(),
            ink.iter().map(|p| p.0).max().unwrap(),
        );
        let (ymin, ymax) = (
            ink.iter().map(|p| p.1).min().unwrap(),
            ink.iter().map(|p| p.1).max().unwrap(),
        );
        assert_eq!((xmin, xmax), (5, 11));
        assert_eq!((ymin, ymax), (50 - 11, 49));
        // The 'T' bar is glyph row 0: a full column of 5 pixels at x = 5 for each T.
        assert_eq!(ink.iter().filter(|p| p.0 == 5).count(), 10);
        assert_eq!(ink.iter().filter(|p| p.0 == 6).count(), 2);
    }

    fn one_series(points: Vec<Point>) -> Chart {
        Chart {
            title: "PSNR vs train time".into(),
            x_label: "train time (s)".into(),
            y_label: "PSNR (dB)".into(),
            series: vec![Series::new("ours", points)],
            x_log: false,
        }
    }

    #[test]
    fn point_lands_at_expected_pixel() {
        let chart = one_series(vec![
            Point::new(1.0, 1.0),
            Point::new(2.0, 4.0),
            Point::new(3.0, 9.0),
        ]);
        let (w, h) = (900, 600);
        let l = chart.layout(w, h);
        let img = chart.render(w, h);
        let c = series_color(0);
        let px: Vec<(i32, i32)> = chart.series[0]
            .points
            .iter()
            .map(|p| l.map(p.x, p.y).unwrap())
            .collect();
        for &(x, y) in &px {
            assert_eq!(
                *img.get_pixel(x as u32, y as u32),
                c,
                "marker at ({x}, {y})"
            );
        }
        // The mapping is linear and inside the frame: equal x spacing, y grows upwards,
        // the data range plus a 5 % margin each side spans the frame.
        let p = l.plot;
        assert!((px[1].0 - px[0].0 - (px[2].0 - px[1].0)).abs() <= 1);
        assert!(px[0].1 > px[1].1 && px[1].1 > px[2].1);
        let fw = (p.right - p.left) as f64;
        assert!(
            ((px[0].0 - p.left) as f64 - fw * 0.05 / 1.1).abs() <= 1.0,
            "{px:?} {p:?}"
        );
        assert!(
            ((p.right - px[2].0) as f64 - fw * 0.05 / 1.1).abs() <= 1.0,
            "{px:?} {p:?}"
        );
        let fh = (p.bottom - p.top) as f64;
        assert!(
            ((p.bottom - px[0].1) as f64 - fh * 0.05 / 1.1).abs() <= 1.0,
            "{px:?} {p:?}"
        );
        // Where there is no point and no line, there is no series colour: top-left and
        // bottom-right corners of the data area.
        for (x, y) in [(1.0, 9.0), (3.0, 1.0)] {
            let (qx, qy) = l.map(x, y).unwrap();
            assert_ne!(*img.get_pixel(qx as u32, qy as u32), c, "({x}, {y})");
        }
        // The frame is black, the background white, the line between points coloured.
        assert_eq!(
            *img.get_pixel(p.left as u32, ((p.top + p.bottom) / 2) as u32),
            BLACK
        );
        assert_eq!(*img.get_pixel(w - 1, h - 1), WHITE);
        let mid = ((px[0].0 + px[1].0) / 2, (px[0].1 + px[1].1) / 2);
        let near_line = (-2..=2).any(|d| *img.get_pixel(mid.0 as u32, (mid.1 + d) as u32) == c);
        assert!(near_line, "no line pixel near {mid:?}");
        // Ticks: y over 1..9 and x over 1..3, all within the visible range.
        assert!(l.y_ticks.len() >= 3 && l.x_ticks.len() >= 3);
        assert!(l
            .y_ticks
            .iter()
            .all(|t| t.value >= l.y_range.0 && t.value <= l.y_range.1));
    }

    #[test]
    fn log_axis_mapping() {
        let mut chart = one_series(vec![
            Point::labeled(3.0, 20.0, "a"),
            Point::labeled(40.0, 25.0, "b"),
            Point::labeled(4000.0, 30.0, "c"),
            Point::new(0.0, 31.0),  // skipped on a log axis
            Point::new(-5.0, 32.0), // skipped
        ]);
        chart.x_log = true;
        let l = chart.layout(900, 600);
        let vals: Vec<f64> = l.x_ticks.iter().map(|t| t.value).collect();
        assert_eq!(vals, vec![10.0, 100.0, 1000.0]);
        let x10 = l.map(10.0, 25.0).unwrap().0;
        let x100 = l.map(100.0, 25.0).unwrap().0;
        let x1000 = l.map(1000.0, 25.0).unwrap().0;
        assert!(
            (x100 - x10 - (x1000 - x100)).abs() <= 1,
            "{x10} {x100} {x1000}"
        );
        assert!(l.map(0.0, 1.0).is_none());
        // Skipped points do not widen the y range.
        assert!(l.y_range.1 < 31.0, "{:?}", l.y_range);
        let img = chart.render(900, 600);
        for p in &chart.series[0].points[..3] {
            let (x, y) = l.map(p.x, p.y).unwrap();
            assert_eq!(*img.get_pixel(x as u32, y as u32), series_color(0));
        }
    }

    #[test]
    fn distinct_series_colours() {
        for i in 0..10 {
            for j in i + 1..10 {
                assert_ne!(series_color(i), series_color(j));
            }
            assert_ne!(series_color(i), WHITE);
            assert_ne!(series_color(i), GRID);
        }
        // Each series shows up in its own colour.
        let chart = Chart {
            series: (0..6)
                .map(|i| Series::new(format!("s{i}"), vec![Point::new(i as f64, i as f64)]))
                .collect(),
            ..Default::default()
        };
        let l = chart.layout(600, 400);
        let img = chart.render(600, 400);
        for i in 0..6 {
            let (x, y) = l.map(i as f64, i as f64).unwrap();
            assert_eq!(*img.get_pixel(x as u32, y as u32), series_color(i));
        }
    }

    #[test]
    fn degenerate_inputs_render() {
        let long = "x".repeat(5000);
        let charts = vec![
            Chart::default(),
            Chart {
                series: vec![Series::default(), Series::new("", vec![])],
                ..Default::default()
            },
            one_series(vec![Point::new(5.0, 7.0)]),
            one_series(vec![Point::new(2.0, 1.0), Point::new(2.0, 3.0)]),
            one_series(vec![Point::new(1.0, 0.0), Point::new(3.0, 0.0)]),
            one_series(vec![Point::new(0.0, 0.0), Point::new(0.0, 0.0)]),
            one_series(vec![
                Point::new(f64::NAN, 1.0),
                Point::new(1.0, f64::INFINITY),
                Point::new(f64::NEG_INFINITY, 2.0),
                Point::new(2.0, 3.0),
            ]),
            one_series(vec![Point::new(f64::NAN, f64::NAN)]),
            one_series(vec![Point::new(-1e308, 1e308), Point::new(1e308, -1e308)]),
            one_series(vec![
                Point::new(1.0, 1.0),
                Point::new(1.0 + 1e-15, 1.0 + 1e-15),
            ]),
            one_series(vec![Point::new(1e-300, 5e-324), Point::new(2e-300, 0.0)]),
            Chart {
                title: long.clone(),
                x_label: long.clone(),
                y_label: long.clone(),
                series: vec![Series::new(
                    long.clone(),
                    vec![
                        Point::labeled(0.0, 0.0, long.clone()),
                        Point::labeled(1.0, 1.0, "héllo\t✓"),
                    ],
                )],
                x_log: false,
            },
            Chart {
                x_log: true,
                ..one_series(vec![Point::new(0.0, 1.0), Point::new(-2.0, 2.0)])
            },
            Chart {
                x_log: true,
                ..one_series(vec![Point::new(1e-300, 1.0), Point::new(1e300, 2.0)])
            },
            Chart {
                x_log: true,
                ..one_series(vec![Point::new(7.0, 1.0)])
            },
            Chart {
                series: (0..25)
                    .map(|i| Series::new(format!("s{i}"), vec![Point::new(i as f64, 1.0)]))
                    .collect(),
                ..Default::default()
            },
        ];
        for (i, c) in charts.iter().enumerate() {
            for (w, h) in [(900, 600), (300, 200), (40, 30), (1, 1), (0, 0), (7, 1000)] {
                let img = c.render(w, h);
                assert_eq!(img.dimensions(), (w, h), "chart {i}");
                let l = c.layout(w, h);
                assert!(
                    l.x_range.0 < l.x_range.1 && l.y_range.0 < l.y_range.1,
                    "chart {i}"
                );
                assert!(
                    l.x_range.1.is_finite() && l.y_range.1.is_finite(),
                    "chart {i}"
                );
            }
        }
        // A single point sits in the middle of the frame, also when the others are skipped
        // (they must not widen the ranges).
        let centred = |c: &Chart, x: f64, y: f64| {
            let l = c.layout(900, 600);
            let (px, py) = l.map(x, y).unwrap();
            (px - (l.plot.left + l.plot.right) / 2).abs() <= 1
                && (py - (l.plot.top + l.plot.bottom) / 2).abs() <= 1
        };
        assert!(centred(&one_series(vec![Point::new(5.0, 7.0)]), 5.0, 7.0));
        assert!(centred(&charts[6], 2.0, 3.0));
        let mut c = one_series(vec![Point::new(7.0, 1.0), Point::new(-1.0, 5.0)]);
        c.x_log = true;
        assert!(centred(&c, 7.0, 1.0));
    }

    fn temp_dir(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("svraster-chart-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn dir_names(d: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn save_png_roundtrip() {
        let d = temp_dir("png");
        let path = d.join("chart.png");
        let chart = one_series(vec![
            Point::labeled(10.0, 25.1, "16k"),
            Point::labeled(30.0, 27.9, "64k"),
            Point::labeled(90.0, 29.3, "256k"),
        ]);
        chart.save_png(&path, 900, 600).unwrap();
        // Overwrite works too.
        chart.save_png(&path, 900, 600).unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(back, chart.render(900, 600));
        assert_eq!(dir_names(&d), vec!["chart.png".to_string()]);

        // Errors name the path and leave nothing behind.
        let bad = d.join("missing-dir").join("x.png");
        let e = chart.save_png(&bad, 900, 600).unwrap_err().to_string();
        assert!(e.contains(&bad.display().to_string()), "{e}");
        let e = chart.save_png(&path, 0, 10).unwrap_err().to_string();
        assert!(e.contains("chart.png"), "{e}");
        assert_eq!(dir_names(&d), vec!["chart.png".to_string()]);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn save_grid_side_by_side() {
        let d = temp_dir("grid");
        let path = d.join("grid.png");
        let a = one_series(vec![Point::new(1.0, 20.0), Point::new(2.0, 25.0)]);
        let b = Chart {
            x_log: true,
            ..one_series(vec![Point::new(3.0, 20.0), Point::new(300.0, 25.0)])
        };
        save_grid(&[a.clone(), b.clone()], &path, 450, 300).unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(back.dimensions(), (900, 300));
        let left = image::imageops::crop_imm(&back, 0, 0, 450, 300).to_image();
        let right = image::imageops::crop_imm(&back, 450, 0, 450, 300).to_image();
        assert_eq!(left, a.render(450, 300));
        assert_eq!(right, b.render(450, 300));
        let four = vec![a.clone(); 4];
        save_grid(&four, &path, 100, 80).unwrap();
        assert_eq!(
            image::open(&path).unwrap().to_rgb8().dimensions(),
            (300, 160)
        );
        assert_eq!(dir_names(&d), vec!["grid.png".to_string()]);
        assert!(save_grid(&[], &path, 100, 100).is_err());
        assert!(save_grid(&four, &path, 10_000, 100).is_err());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
