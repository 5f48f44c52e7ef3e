//! The viewer's text overlay: lines of text rasterised on the host with `ab_glyph` from
//! a font compiled into the binary (Ubuntu Light from `epaint_default_fonts`), white
//! over a translucent black box, as premultiplied RGBA16F pixels for the blend pass.

use ab_glyph::{Font as _, FontRef, PxScale, ScaleFont as _};

/// Pixel height of a line of text.
const SIZE: f32 = 15.0;
const LINE: u32 = 19;
const MARGIN: u32 = 6;
/// The box's opacity.
const BOX_ALPHA: f32 = 0.6;

pub(super) struct Hud {
    font: FontRef<'static>,
}

impl Hud {
    pub(super) fn new() -> Result<Hud, String> {
        let font = FontRef::try_from_slice(epaint_default_fonts::UBUNTU_LIGHT)
            .map_err(|e| format!("the overlay's font: {e}"))?;
        Ok(Hud { font })
    }

    /// The overlay of `lines`, at most `max_w` × `max_h` pixels: its size and its
    /// pixels (row-major, 4 halves each: premultiplied linear rgba).
    pub(super) fn raster(&self, lines: &[String], max_w: u32, max_h: u32) -> (u32, u32, Vec<u16>) {
        let scale = PxScale::from(SIZE);
        let sf = self.font.as_scaled(scale);
        let widths: Vec<f32> = lines
            .iter()
            .map(|l| {
                let mut x = 0.0;
                let mut prev = None;
                for c in l.chars() {
                    let id = self.font.glyph_id(c);
                    if let Some(p) = prev {
                        x += sf.kern(p, id);
                    }
                    x += sf.h_advance(id);
                    prev = Some(id);
                }
                x
            })
            .collect();
        let w = (widths.iter().fold(0f32, |a, &b| a.max(b)).ceil() as u32 + 2 * MARGIN).min(max_w);
        let h = (lines.len() as u32 * LINE + 2 * MARGIN).min(max_h);
        let mut cov = vec![0f32; (w * h) as usize];
        for (i, l) in lines.iter().enumerate() {
            let mut x = MARGIN as f32;
            let y = MARGIN as f32 + i as f32 * LINE as f32 + sf.ascent();
            let mut prev = None;
            for c in l.chars() {
                let id = self.font.glyph_id(c);
                if let Some(p) = prev {
                    x += sf.kern(p, id);
                }
                let g = id.with_scale_and_position(scale, ab_glyph::point(x, y));
                x += sf.h_advance(id);
                prev = Some(id);
                let Some(o) = self.font.outline_glyph(g) else {
                    continue;
                };
                let b = o.px_bounds();
                o.draw(|gx, gy, c| {
                    let (px, py) = (b.min.x as i64 + gx as i64, b.min.y as i64 + gy as i64);
                    if px >= 0 && py >= 0 && (px as u32) < w && (py as u32) < h {
                        let k = (py as u32 * w + px as u32) as usize;
                        cov[k] = (cov[k] + c).min(1.0);
                    }
                });
            }
        }
        let mut px = Vec::with_capacity(cov.len() * 4);
        for c in cov {
            // White text over the box, premultiplied.
            let a = c + (1.0 - c) * BOX_ALPHA;
            for v in [c, c, c, a] {
                px.push(half::f16::from_f32(v).to_bits());
            }
        }
        (w, h, px)
    }
}

#[cfg(test)]
mod tests {
    /// Text is drawn inside the box: some pixels are mostly white, the box's corner is
    /// the translucent black, and a longer line makes a wider box.
    #[test]
    fn overlay_draws_text_in_a_translucent_box() {
        let hud = super::Hud::new().unwrap();
        let f = |h: u16| half::f16::from_bits(h).to_f32();
        let (w, h, px) = hud.raster(&["12.5 ms/frame".into(), "colour".into()], 1000, 1000);
        assert_eq!(px.len(), (w * h * 4) as usize);
        assert_eq!(h, 2 * super::LINE + 2 * super::MARGIN);
        assert_eq!(f(px[0]), 0.0);
        assert!((f(px[3]) - super::BOX_ALPHA).abs() < 1e-3, "{}", f(px[3]));
        let white = px.chunks(4).filter(|p| f(p[0]) > 0.5).count();
        assert!(white > 20, "{white} text pixels");
        let (w2, _, _) = hud.raster(&["12.5 ms/frame, and more".into()], 1000, 1000);
        assert!(w2 > w, "{w2} <= {w}");
        let (w3, h3, _) = hud.raster(&["12.5 ms/frame, and more".into()], 40, 10);
        assert_eq!((w3, h3), (40, 10));
    }
}
