//! PNG charts for reports (`bench trade`'s trade.png, a run's training.png): `plotters`
//! lays out and draws them; its bitmap backend is wrapped to draw text with `ab_glyph`
//! and a font compiled into the binary (Ubuntu Light from `epaint_default_fonts`), so
//! charts have labels on machines without fontconfig or any installed font.

use std::path::Path;

use anyhow::Context as _;
use plotters::coord::combinators::BindKeyPoints;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters_backend::{
    text_anchor::{HPos, VPos},
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind,
};

use ab_glyph::{Font as _, FontRef, PxScale, ScaleFont as _};

/// One point; `label` is drawn beside its marker.
#[derive(Clone, Debug, PartialEq)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub label: Option<String>,
}

impl Point {
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
    /// Join the points (sorted by x) with a line; false: markers only (unrelated
    /// points, e.g. the variants of a comparison).
    pub line: bool,
}

impl Series {
    /// Markers only, no line between the points.
    pub fn scatter(name: impl Into<String>, points: Vec<Point>) -> Self {
        Self {
            line: false,
            ..Self::new(name, points)
        }
    }

    pub fn new(name: impl Into<String>, points: Vec<Point>) -> Self {
        Self {
            line: true,
            name: name.into(),
            points,
        }
    }
}

/// One panel: a line+marker chart. Points with a non-finite coordinate (or ≤ 0 on a log
/// axis) are left out.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    pub x_log: bool,
    pub y_log: bool,
    /// Draw markers (and point labels); otherwise lines only (dense curves).
    pub markers: bool,
}

/// Colour of series `i` (Tableau 10).
pub fn series_color(i: usize) -> RGBColor {
    const C: [(u8, u8, u8); 6] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
    ];
    let (r, g, b) = C[i % C.len()];
    RGBColor(r, g, b)
}

/// Draws `charts` side by side (one row, `cell_w`×`cell_h` pixels each) and writes the
/// PNG atomically.
pub fn save_row(charts: &[Chart], path: &Path, cell_w: u32, cell_h: u32) -> anyhow::Result<()> {
    anyhow::ensure!(
        !charts.is_empty(),
        "no chart to draw into {}",
        path.display()
    );
    let (w, h) = (cell_w * charts.len() as u32, cell_h);
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = TextBackend::new(&mut buf, (w, h))?.into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;
        for (chart, area) in charts
            .iter()
            .zip(root.split_evenly((1, charts.len())).iter())
        {
            draw(chart, area).with_context(|| format!("drawing \"{}\"", chart.title))?;
        }
        root.present().map_err(draw_err)?;
    }
    let img = image::RgbImage::from_raw(w, h, buf).context("chart buffer size")?;
    let mut png = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .with_context(|| format!("cannot encode {}", path.display()))?;
    Ok(svraster::fsio::write_atomic(path, &png)?)
}

/// Draws a run's training curves from its `stats.jsonl` into `png`: training PSNR, loss
/// and voxel count against iteration (adaptive steps show as steps in the voxel curve).
pub fn training_chart(stats: &Path, png: &Path) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(stats)
        .with_context(|| format!("cannot read {}", stats.display()))?;
    let (mut psnr, mut loss, mut voxels) = (Vec::new(), Vec::new(), Vec::new());
    let mut held = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let v: serde_json::Value = serde_json::from_str(line)
            .with_context(|| format!("{} line {}: not JSON", stats.display(), i + 1))?;
        if let (Some(it), Some(p)) = (v["eval"]["iter"].as_f64(), v["eval"]["psnr"].as_f64()) {
            held.push(Point::new(it, p)); // a held-out evaluation (--eval-every)
            continue;
        }
        let Some(it) = v["iter"].as_f64() else {
            continue; // an adaptive-step record
        };
        let get = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
        psnr.push(Point::new(it, get("psnr")));
        loss.push(Point::new(it, get("loss")));
        voxels.push(Point::new(it, get("voxels")));
    }
    let chart = |title: &str, y: &str, pts, y_log| Chart {
        title: title.into(),
        x_label: "iteration".into(),
        y_label: y.into(),
        series: vec![Series::new(y, pts)],
        y_log,
        ..Default::default()
    };
    let mut psnr_chart = chart("training PSNR", "PSNR (dB)", psnr, false);
    if !held.is_empty() {
        psnr_chart.title = "PSNR: training views, held-out views".into();
        psnr_chart.series[0].name = "training".into();
        psnr_chart.series.push(Series::new("held-out", held));
    }
    save_row(
        &[
            psnr_chart,
            chart("training loss", "loss", loss, true),
            chart("model size", "voxels", voxels, true),
        ],
        png,
        480,
        360,
    )
}

/// A tick label: `dec` decimals (a linear axis: [`axis_decimals`]) or, on a log axis,
/// the fewest that show the value exactly (at most 6), trailing zeros dropped; thousands
/// as k and millions as M where that loses nothing: 300, 0.01, 21.92, 25k, 1.5M.
fn tick_label(v: f64, dec: Option<usize>) -> String {
    fn shortest(v: f64, max_dec: usize) -> String {
        let d = (0..max_dec)
            .find(|&d| {
                let x = v * 10f64.powi(d as i32);
                (x - x.round()).abs() <= 1e-9 * x.abs().max(1.0)
            })
            .unwrap_or(max_dec);
        format!("{v:.d$}")
    }
    let s = match dec {
        Some(d) => {
            let s = format!("{v:.d$}");
            if s.contains('.') {
                s.trim_end_matches('0').trim_end_matches('.').to_string()
            } else {
                s
            }
        }
        None => shortest(v, 6),
    };
    let a = v.abs();
    let exact = |unit: f64| (v / unit * 10.0).round() == v / unit * 10.0;
    if a >= 1e6 && exact(1e6) {
        format!("{}M", shortest(v / 1e6, 1))
    } else if a >= 1e4 && exact(1e3) {
        format!("{}k", shortest(v / 1e3, 1))
    } else if s == "-0" {
        "0".into()
    } else {
        s
    }
}

fn draw_err<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> anyhow::Error {
    anyhow::anyhow!("chart drawing failed: {e}")
}

/// Data range of `v` on an axis (log10 space when `log`), padded by 5 % of its span or
/// 0.05 % of its magnitude, whichever is larger (differences in the 7th digit are not
/// blown up to fill the panel); a single value 0 gets ±1, a single value on a log axis
/// ×/÷ 2.
fn range(v: impl Iterator<Item = f64>, log: bool) -> Option<(f64, f64)> {
    let (lo, hi) = v
        .filter(|x| x.is_finite() && (!log || *x > 0.0))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        });
    if lo > hi {
        return None;
    }
    Some(if log {
        let (l, h) = (lo.log10(), hi.log10());
        let pad = ((h - l) * 0.05).max(if h > l { 0.0 } else { 0.3 });
        (10f64.powf(l - pad), 10f64.powf(h + pad))
    } else {
        let pad = ((hi - lo) * 0.05).max(5e-4 * lo.abs().max(hi.abs()));
        let pad = if pad > 0.0 { pad } else { 1.0 };
        (lo - pad, hi + pad)
    })
}

/// Labelled ticks of a log axis over `lo..hi`: m·10^k inside it for m in 1, 2, 5 — all
/// of 1..9 when that gives fewer than 3 (a short run's loss or voxel count spans less
/// than a decade: plotters' own log ticks labelled one value or none), round values
/// evenly spaced within a fraction of a decade, and powers of ten (at most 8) over many.
fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    let within = |ms: &[f64]| -> Vec<f64> {
        if !(lo > 0.0 && hi >= lo && hi.is_finite()) {
            return Vec::new();
        }
        let (k0, k1) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
        (k0..=k1)
            .flat_map(|k| ms.iter().map(move |m| m * 10f64.powi(k)))
            .filter(|v| *v >= lo * (1.0 - 1e-12) && *v <= hi * (1.0 + 1e-12))
            .collect()
    };
    let t = within(&[1.0, 2.0, 5.0]);
    if t.len() > 8 {
        // Powers of ten, every other (or third, …) one over many decades.
        let t = within(&[1.0]);
        let every = t.len().div_ceil(8).max(1);
        return t.into_iter().step_by(every).collect();
    }
    if t.len() >= 3 {
        return t;
    }
    let t = within(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
    if t.len() >= 3 || hi <= lo || hi.is_nan() {
        return t;
    }
    // Less than a fraction of a decade: evenly spaced round values (3 to 8 of them).
    let raw = (hi - lo) / 4.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|st| (hi - lo) / st <= 8.0)
        .unwrap_or(10.0 * mag);
    let first = (lo / step).ceil() as i64;
    (first..)
        .map(|i| i as f64 * step)
        .take_while(|v| *v <= hi)
        .collect()
}

/// Decimals that tell apart the ~6 ticks of a linear axis over `lo..hi`.
fn axis_decimals(lo: f64, hi: f64) -> usize {
    let step = (hi - lo) / 6.0;
    ((-step.log10()).ceil() + 1.0).clamp(0.0, 10.0) as usize
}

fn draw<DB: DrawingBackend>(c: &Chart, area: &DrawingArea<DB, Shift>) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let pts = || c.series.iter().flat_map(|s| s.points.iter());
    let ok = |p: &Point| {
        p.x.is_finite() && p.y.is_finite() && (!c.x_log || p.x > 0.0) && (!c.y_log || p.y > 0.0)
    };
    let (x0, mut x1) = range(pts().filter(|p| ok(p)).map(|p| p.x), c.x_log).unwrap_or((0.0, 1.0));
    if pts().any(|p| p.label.is_some()) {
        // Room for the label of the rightmost point (drawn to its right).
        x1 = if c.x_log {
            x1 * (x1 / x0).powf(0.12)
        } else {
            x1 + 0.12 * (x1 - x0)
        };
    }
    let (y0, y1) = range(pts().filter(|p| ok(p)).map(|p| p.y), c.y_log).unwrap_or((0.0, 1.0));
    let xd = (!c.x_log).then(|| axis_decimals(x0, x1));
    let yd = (!c.y_log).then(|| axis_decimals(y0, y1));
    let mut b = ChartBuilder::on(area);
    b.caption(&c.title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(80);
    // The four axis combinations are four coordinate types in plotters.
    macro_rules! body {
        ($chart:expr) => {{
            let mut ch = $chart;
            ch.configure_mesh()
                .x_desc(c.x_label.as_str())
                .y_desc(c.y_label.as_str())
                .x_labels(6)
                .y_labels(6)
                .x_label_formatter(&|v| tick_label(*v, xd))
                .y_label_formatter(&|v| tick_label(*v, yd))
                .light_line_style(RGBColor(235, 235, 235))
                .label_style(("sans-serif", 14))
                .axis_desc_style(("sans-serif", 15))
                .draw()
                .map_err(draw_err)?;
            for (i, s) in c.series.iter().enumerate() {
                let color = series_color(i);
                let mut p: Vec<&Point> = s.points.iter().filter(|p| ok(p)).collect();
                p.sort_by(|a, b| a.x.total_cmp(&b.x));
                let line = LineSeries::new(
                    p.iter().map(|p| (p.x, p.y)).filter(|_| s.line),
                    Color::stroke_width(&color, 2),
                );
                let joined = s.line;
                ch.draw_series(line)
                    .map_err(draw_err)?
                    .label(s.name.as_str())
                    .legend(move |(x, y)| {
                        if joined {
                            PathElement::new(
                                vec![(x, y), (x + 18, y)],
                                Color::stroke_width(&color, 2),
                            )
                            .into_dyn()
                        } else {
                            Circle::new((x + 9, y), 4, color.filled()).into_dyn()
                        }
                    });
                if c.markers {
                    ch.draw_series(p.iter().map(|p| {
                        EmptyElement::at((p.x, p.y))
                            + Circle::new((0, 0), 4, color.filled())
                            + Text::new(
                                p.label.clone().unwrap_or_default(),
                                (6, -16),
                                ("sans-serif", 13),
                            )
                    }))
                    .map_err(draw_err)?;
                }
            }
            if c.series.len() > 1 {
                ch.configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK.mix(0.4))
                    .label_font(("sans-serif", 14))
                    .position(SeriesLabelPosition::LowerRight)
                    .draw()
                    .map_err(draw_err)?;
            }
        }};
    }
    let (xk, yk) = (log_ticks(x0, x1), log_ticks(y0, y1));
    match (c.x_log, c.y_log) {
        (false, false) => body!(b.build_cartesian_2d(x0..x1, y0..y1).map_err(draw_err)?),
        (true, false) => body!(b
            .build_cartesian_2d((x0..x1).log_scale().with_key_points(xk), y0..y1)
            .map_err(draw_err)?),
        (false, true) => body!(b
            .build_cartesian_2d(x0..x1, (y0..y1).log_scale().with_key_points(yk))
            .map_err(draw_err)?),
        (true, true) => body!(b
            .build_cartesian_2d(
                (x0..x1).log_scale().with_key_points(xk),
                (y0..y1).log_scale().with_key_points(yk)
            )
            .map_err(draw_err)?),
    }
    Ok(())
}

/// `plotters`' RGB bitmap backend with text drawn by `ab_glyph` from the embedded font.
struct TextBackend<'a> {
    inner: BitMapBackend<'a>,
    font: FontRef<'static>,
}

impl<'a> TextBackend<'a> {
    fn new(buf: &'a mut [u8], size: (u32, u32)) -> anyhow::Result<Self> {
        let font = FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT)
            .context("the embedded chart font does not parse")?;
        Ok(Self {
            inner: BitMapBackend::with_buffer(buf, size),
            font,
        })
    }

    /// Lays `text` out on one line at `size` px: each glyph's outline and the text's
    /// advance width and line height.
    fn layout(&self, text: &str, size: f64) -> (Vec<ab_glyph::OutlinedGlyph>, f32, f32) {
        let scale = PxScale::from(size as f32);
        let sf = self.font.as_scaled(scale);
        let mut x = 0.0f32;
        let mut prev = None;
        let mut out = Vec::new();
        for ch in text.chars() {
            let id = sf.glyph_id(ch);
            if let Some(p) = prev {
                x += sf.kern(p, id);
            }
            let g = id.with_scale_and_position(scale, ab_glyph::point(x, sf.ascent()));
            x += sf.h_advance(id);
            prev = Some(id);
            if let Some(o) = self.font.outline_glyph(g) {
                out.push(o);
            }
        }
        (out, x, sf.ascent() - sf.descent())
    }
}

impl DrawingBackend for TextBackend<'_> {
    type ErrorType = <BitMapBackend<'static> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }
    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.ensure_prepared()
    }
    fn present(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.present()
    }
    fn draw_pixel(
        &mut self,
        p: BackendCoord,
        c: BackendColor,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_pixel(p, c)
    }
    fn draw_line<S: BackendStyle>(
        &mut self,
        a: BackendCoord,
        b: BackendCoord,
        s: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_line(a, b, s)
    }
    fn draw_rect<S: BackendStyle>(
        &mut self,
        a: BackendCoord,
        b: BackendCoord,
        s: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_rect(a, b, s, fill)
    }
    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        s: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_path(path, s)
    }
    fn draw_circle<S: BackendStyle>(
        &mut self,
        c: BackendCoord,
        r: u32,
        s: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_circle(c, r, s, fill)
    }
    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        s: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.fill_polygon(vert, s)
    }
    fn blit_bitmap(
        &mut self,
        pos: BackendCoord,
        size: (u32, u32),
        src: &[u8],
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.blit_bitmap(pos, size, src)
    }

    fn estimate_text_size<T: BackendTextStyle>(
        &self,
        text: &str,
        style: &T,
    ) -> Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        let (_, w, h) = self.layout(text, style.size());
        Ok((w.ceil() as u32, h.ceil() as u32))
    }

    fn draw_text<T: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &T,
        pos: BackendCoord,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        let color = style.color();
        if color.alpha == 0.0 {
            return Ok(());
        }
        let (glyphs, w, h) = self.layout(text, style.size());
        let dx = match style.anchor().h_pos {
            HPos::Left => 0.0,
            HPos::Right => -w,
            HPos::Center => -w / 2.0,
        };
        let dy = match style.anchor().v_pos {
            VPos::Top => 0.0,
            VPos::Center => -h / 2.0,
            VPos::Bottom => -h,
        };
        let trans = style.transform();
        let (sw, sh) = self.get_size();
        for g in glyphs {
            let b = g.px_bounds();
            let mut err = Ok(());
            g.draw(|gx, gy, cov| {
                if cov <= 0.0 || err.is_err() {
                    return;
                }
                let x = (b.min.x + gx as f32 + dx).round() as i32;
                let y = (b.min.y + gy as f32 + dy).round() as i32;
                let (x, y) = trans.transform(x, y);
                let (x, y) = (pos.0 + x, pos.1 + y);
                if x >= 0 && y >= 0 && x < sw as i32 && y < sh as i32 {
                    let c = BackendColor {
                        alpha: color.alpha * f64::from(cov.min(1.0)),
                        rgb: color.rgb,
                    };
                    err = self.inner.draw_pixel((x, y), c);
                }
            });
            err?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(path: &Path) -> image::RgbImage {
        image::open(path).unwrap().to_rgb8()
    }

    fn count(img: &image::RgbImage, f: impl Fn(&image::Rgb<u8>) -> bool) -> usize {
        img.pixels().filter(|p| f(p)).count()
    }

    #[test]
    fn draws_series_text_and_skips_bad_points() {
        let dir = tempfile::Builder::new()
            .prefix("svraster-plot-")
            .tempdir()
            .unwrap();
        let chart = Chart {
            title: "quality vs size".into(),
            x_label: "voxels".into(),
            y_label: "PSNR (dB)".into(),
            series: vec![
                Series::new(
                    "adaptive",
                    vec![
                        Point::labeled(1e3, 20.0, "a"),
                        Point::labeled(1e5, 30.0, "b"),
                        Point::new(f64::NAN, 25.0),
                        Point::new(-1.0, 25.0), // not drawable on a log axis
                    ],
                ),
                Series::new("uniform", vec![Point::new(3e4, 22.0)]),
            ],
            x_log: true,
            y_log: false,
            markers: true,
        };
        let p = dir.path().join("c.png");
        save_row(&[chart.clone(), chart.clone()], &p, 400, 300).unwrap();
        let img = decode(&p);
        assert_eq!((img.width(), img.height()), (800, 300));
        let c0 = series_color(0);
        let c1 = series_color(1);
        let is = |c: RGBColor| move |p: &image::Rgb<u8>| p.0 == [c.0, c.1, c.2];
        // Both series are drawn, in both panels.
        let (left, right) = (
            image::imageops::crop_imm(&img, 0, 0, 400, 300).to_image(),
            image::imageops::crop_imm(&img, 400, 0, 400, 300).to_image(),
        );
        for half in [&left, &right] {
            assert!(count(half, is(c0)) > 50, "series 0 missing");
            assert!(count(half, is(c1)) > 20, "series 1 missing");
        }
        // Text is drawn by the embedded font: dark anti-aliased pixels above the plot
        // (the title) where nothing else is drawn.
        let title = image::imageops::crop_imm(&left, 0, 0, 400, 30).to_image();
        let dark = count(&title, |p| p.0.iter().all(|&v| v < 128));
        let grey = count(&title, |p| p.0.iter().all(|&v| v > 128 && v < 250));
        assert!(
            dark > 30 && grey > 30,
            "title not rendered: {dark} dark, {grey} grey"
        );

        // Nothing drawable: still a chart (axes), not an error.
        let empty = Chart {
            title: "empty".into(),
            series: vec![Series::new("none", vec![Point::new(f64::NAN, 1.0)])],
            ..Default::default()
        };
        save_row(&[empty], &p, 300, 200).unwrap();
        assert_eq!(decode(&p).dimensions(), (300, 200));
        dir.close().unwrap();
    }

    #[test]
    fn tick_labels_are_short_and_tell_ticks_apart() {
        let log = [
            (300.0, "300"),
            (25_000.0, "25k"),
            (262_144.0, "262144"),
            (1_500_000.0, "1.5M"),
            (0.1 + 0.2, "0.3"),
            (0.01, "0.01"),
        ];
        for (v, want) in log {
            assert_eq!(tick_label(v, None), want, "{v}");
        }
        // Linear axes: as many decimals as the span needs.
        let d = axis_decimals(20.0, 32.0); // 2 dB steps
        assert_eq!(d, 1);
        assert_eq!(tick_label(21.0, Some(d)), "21");
        assert_eq!(tick_label(21.900000000000002, Some(d)), "21.9");
        let d = axis_decimals(21.89304, 21.89305); // a 1e-5 span
        assert_eq!(tick_label(21.8930421, Some(d)), "21.8930421");
        assert_ne!(
            tick_label(21.8930421, Some(d)),
            tick_label(21.8930422, Some(d))
        );
        assert_eq!(tick_label(-0.00001, Some(axis_decimals(-1.0, 1.0))), "0");
        assert_eq!(tick_label(20000.0, Some(0)), "20k");
    }

    #[test]
    fn log_axes_get_three_to_eight_labelled_ticks_at_any_span() {
        use super::log_ticks;
        // A short run's voxels and loss, a long run's loss, a near-flat count, a
        // flat one (range pads it by 0.3 decades), eight decades.
        for (lo, hi) in [
            (2519.0, 32768.0),
            (0.0025, 0.15),
            (0.0008, 0.2),
            (2900.0, 3100.0),
            (511.9, 512.1),
            (256.0, 1024.0),
            (1.0, 1e8),
        ] {
            let (lo, hi) = super::range([lo, hi].into_iter(), true).unwrap();
            let t = log_ticks(lo, hi);
            assert!((3..=8).contains(&t.len()), "{lo}..{hi}: {t:?}");
            assert!(t.iter().all(|v| *v >= lo && *v <= hi), "{lo}..{hi}: {t:?}");
            assert!(t.windows(2).all(|w| w[0] < w[1]), "{t:?}");
        }
    }

    #[test]
    fn ranges_pad_and_handle_single_values() {
        assert_eq!(range([2.0, 4.0].into_iter(), false), Some((1.9, 4.1)));
        assert_eq!(range([0.0].into_iter(), false), Some((-1.0, 1.0)));
        // Values equal to 7 digits: a 0.05 % pad, not a panel filled by the 7th digit.
        let (lo, hi) = range([21.893041, 21.893042].into_iter(), false).unwrap();
        assert!((hi - lo - 2.0 * 5e-4 * 21.893042).abs() < 1e-4, "{lo} {hi}");
        let (lo, hi) = range([100.0].into_iter(), true).unwrap();
        assert!((lo - 10f64.powf(1.7)).abs() < 1e-9 && (hi - 10f64.powf(2.3)).abs() < 1e-6);
        assert_eq!(range([f64::NAN, -1.0].into_iter(), true), None);
    }
}
