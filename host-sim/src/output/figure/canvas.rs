//! A small anti-aliased RGB rasteriser: rectangles, polylines (solid or dashed), circles and
//! text (DejaVu Sans through ab_glyph), then PNG. Coordinates are canvas pixels, y down,
//! pixel `(i, j)` covering `[i, i+1] × [j, j+1]`.

use std::sync::OnceLock;

use ab_glyph::{Font, FontRef, GlyphId, PxScale, ScaleFont};

use super::colormap::Rgb;

/// DejaVu Sans, embedded by the `dejavu` crate (so no system font is needed).
fn font() -> &'static FontRef<'static> {
    static FONT: OnceLock<FontRef<'static>> = OnceLock::new();
    FONT.get_or_init(|| {
        FontRef::try_from_slice(dejavu::sans::regular()).expect("the embedded DejaVu Sans parses")
    })
}

/// True when the embedded font has a glyph for `c` (else it draws a box).
pub(crate) fn has_glyph(c: char) -> bool {
    font().glyph_id(c).0 != 0
}

/// The Unicode subscript of a letter or digit, if there is one.
fn subscript_char(c: char) -> Option<char> {
    Some(match c {
        '0'..='9' => char::from_u32('₀' as u32 + (c as u32 - '0' as u32))?,
        'a' => 'ₐ',
        'e' => 'ₑ',
        'h' => 'ₕ',
        'i' => 'ᵢ',
        'j' => 'ⱼ',
        'k' => 'ₖ',
        'l' => 'ₗ',
        'm' => 'ₘ',
        'n' => 'ₙ',
        'o' => 'ₒ',
        'p' => 'ₚ',
        'r' => 'ᵣ',
        's' => 'ₛ',
        't' => 'ₜ',
        'u' => 'ᵤ',
        'v' => 'ᵥ',
        'x' => 'ₓ',
        _ => return None,
    })
}

/// Turns short TeX-like subscripts into Unicode ones: `F_k` → `Fₖ`, `h_max` → `hₘₐₓ`,
/// `k_c,D`... A `_` is converted when the run of letters or digits after it is 1 to 3
/// characters long, ends the word, and every character has a subscript glyph in the font;
/// anything else (`h_dive.csv`) is left as written.
pub(crate) fn subscripts(text: &str) -> String {
    let chars: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut k = 0;
    while k < chars.len() {
        if chars[k] == '_' && k > 0 {
            let run: Vec<char> = chars[k + 1..]
                .iter()
                .copied()
                .take_while(|c| c.is_ascii_alphanumeric())
                .collect();
            let subs: Option<Vec<char>> = run
                .iter()
                .map(|&c| subscript_char(c).filter(|&s| has_glyph(s)))
                .collect();
            if let (1..=3, Some(subs)) = (run.len(), subs) {
                out.extend(subs);
                k += 1 + run.len();
                continue;
            }
        }
        out.push(chars[k]);
        k += 1;
    }
    out
}

/// A text style: size is the line height in pixels (ascent − descent).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct TextStyle {
    pub size: f32,
    pub color: Rgb,
}

impl TextStyle {
    pub fn new(size: f32) -> Self {
        TextStyle {
            size,
            color: [0, 0, 0],
        }
    }
    fn font(&self) -> &'static FontRef<'static> {
        font()
    }
    /// Height of a capital letter, px (for centring labels on ticks).
    pub fn cap_height(&self) -> f64 {
        let f = self.font().as_scaled(PxScale::from(self.size));
        f.outline_glyph(f.scaled_glyph('H'))
            .map(|g| g.px_bounds().height() as f64)
            .unwrap_or(0.63 * self.size as f64)
    }
    /// Line height, px.
    pub fn line_height(&self) -> f64 {
        self.size as f64
    }
    /// Advance width of `text` as [`Canvas::text`] draws it, px.
    pub fn width(&self, text: &str) -> f64 {
        let text = &subscripts(text);
        let f = self.font().as_scaled(PxScale::from(self.size));
        let mut x = 0.0f32;
        let mut prev: Option<GlyphId> = None;
        for c in text.chars() {
            let id = f.glyph_id(c);
            if let Some(p) = prev {
                x += f.kern(p, id);
            }
            x += f.h_advance(id);
            prev = Some(id);
        }
        x as f64
    }
}

/// Horizontal anchor of a text (along its reading direction).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum HAlign {
    Left,
    Center,
    Right,
}

/// Vertical anchor of a text (across its reading direction).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum VAlign {
    /// The top of the line box (ascent).
    Top,
    /// The middle of the capital letters: labels centred on a tick.
    Middle,
    /// The bottom of the line box (descent).
    Bottom,
}

/// A rectangle in canvas pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rect {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl Rect {
    pub fn new(x0: f64, y0: f64, x1: f64, y1: f64) -> Self {
        Rect { x0, y0, x1, y1 }
    }
    pub fn w(&self) -> f64 {
        self.x1 - self.x0
    }
    pub fn h(&self) -> f64 {
        self.y1 - self.y0
    }
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0 && x <= self.x1 && y >= self.y0 && y <= self.y1
    }
    pub fn grow(&self, d: f64) -> Rect {
        Rect::new(self.x0 - d, self.y0 - d, self.x1 + d, self.y1 + d)
    }
    pub fn intersects(&self, o: &Rect) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }
}

/// An RGB image being drawn.
pub(crate) struct Canvas {
    pub w: u32,
    pub h: u32,
    px: Vec<u8>,
}

impl Canvas {
    pub fn new(w: u32, h: u32, bg: Rgb) -> Self {
        let mut px = Vec::with_capacity((w * h * 3) as usize);
        for _ in 0..w * h {
            px.extend_from_slice(&bg);
        }
        Canvas { w, h, px }
    }

    /// Raw RGB bytes, row by row from the top.
    #[cfg(test)]
    pub fn pixels(&self) -> &[u8] {
        &self.px
    }

    /// Sets a pixel (no blending).
    pub fn put(&mut self, x: i64, y: i64, c: Rgb) {
        if x >= 0 && y >= 0 && (x as u32) < self.w && (y as u32) < self.h {
            let k = ((y as u32 * self.w + x as u32) * 3) as usize;
            self.px[k..k + 3].copy_from_slice(&c);
        }
    }

    /// Blends `c` over a pixel with opacity `a` in [0, 1].
    pub fn blend(&mut self, x: i64, y: i64, c: Rgb, a: f64) {
        if a <= 0.0 || x < 0 || y < 0 || x as u32 >= self.w || y as u32 >= self.h {
            return;
        }
        let a = a.min(1.0);
        let k = ((y as u32 * self.w + x as u32) * 3) as usize;
        for (dst, &src) in self.px[k..k + 3].iter_mut().zip(&c) {
            let old = *dst as f64;
            *dst = (old + (src as f64 - old) * a).round() as u8;
        }
    }

    /// Fills a rectangle with anti-aliased fractional edges.
    pub fn fill_rect(&mut self, r: Rect, c: Rgb, alpha: f64) {
        let (xa, xb) = (r.x0.max(0.0), r.x1.min(self.w as f64));
        let (ya, yb) = (r.y0.max(0.0), r.y1.min(self.h as f64));
        if xa >= xb || ya >= yb {
            return;
        }
        for y in ya.floor() as i64..yb.ceil() as i64 {
            let cy = (yb.min(y as f64 + 1.0) - ya.max(y as f64)).max(0.0);
            for x in xa.floor() as i64..xb.ceil() as i64 {
                let cx = (xb.min(x as f64 + 1.0) - xa.max(x as f64)).max(0.0);
                self.blend(x, y, c, cx * cy * alpha);
            }
        }
    }

    /// Outlines a rectangle with a line of `width` px centred on its edges.
    pub fn stroke_rect(&mut self, r: Rect, width: f64, c: Rgb) {
        let h = width / 2.0;
        self.fill_rect(Rect::new(r.x0 - h, r.y0 - h, r.x1 + h, r.y0 + h), c, 1.0);
        self.fill_rect(Rect::new(r.x0 - h, r.y1 - h, r.x1 + h, r.y1 + h), c, 1.0);
        self.fill_rect(Rect::new(r.x0 - h, r.y0 + h, r.x0 + h, r.y1 - h), c, 1.0);
        self.fill_rect(Rect::new(r.x1 - h, r.y0 + h, r.x1 + h, r.y1 - h), c, 1.0);
    }

    /// Draws a polyline of `width` px, anti-aliased, clipped to `clip`; NaN points break it.
    /// `dash` = (on, off) lengths in px for a dashed line.
    pub fn polyline(
        &mut self,
        pts: &[(f64, f64)],
        width: f64,
        c: Rgb,
        dash: Option<(f64, f64)>,
        clip: Rect,
    ) {
        let clip = Rect::new(
            clip.x0.max(0.0),
            clip.y0.max(0.0),
            clip.x1.min(self.w as f64),
            clip.y1.min(self.h as f64),
        );
        if clip.w() <= 0.0 || clip.h() <= 0.0 {
            return;
        }
        let mut cov = Coverage::new(clip);
        let mut phase = 0.0;
        for seg in pts.windows(2) {
            let (a, b) = (seg[0], seg[1]);
            if !(a.0.is_finite() && a.1.is_finite() && b.0.is_finite() && b.1.is_finite()) {
                phase = 0.0;
                continue;
            }
            let len = (b.0 - a.0).hypot(b.1 - a.1);
            match dash {
                None => cov.segment(a, b, width),
                Some((on, off)) => {
                    // Walk the segment, emitting the "on" parts of the dash pattern.
                    let period = on + off;
                    let mut s = 0.0;
                    while s < len {
                        let p = (phase + s) % period;
                        let step = if p < on { on - p } else { period - p };
                        let e = (s + step).min(len);
                        if p < on {
                            let t0 = s / len;
                            let t1 = e / len;
                            let pa = (a.0 + (b.0 - a.0) * t0, a.1 + (b.1 - a.1) * t0);
                            let pb = (a.0 + (b.0 - a.0) * t1, a.1 + (b.1 - a.1) * t1);
                            cov.segment(pa, pb, width);
                        }
                        s = e;
                    }
                    phase = (phase + len) % period;
                }
            }
        }
        cov.paint(self, c);
    }

    /// A filled and/or outlined circle, anti-aliased.
    pub fn circle(
        &mut self,
        cx: f64,
        cy: f64,
        r: f64,
        fill: Option<Rgb>,
        stroke: Option<(Rgb, f64)>,
    ) {
        let sw = stroke.map(|s| s.1).unwrap_or(0.0);
        let ro = r + sw / 2.0 + 1.0;
        for y in (cy - ro).floor() as i64..=(cy + ro).ceil() as i64 {
            for x in (cx - ro).floor() as i64..=(cx + ro).ceil() as i64 {
                let d = (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy);
                if let Some(f) = fill {
                    self.blend(x, y, f, (r + 0.5 - d).clamp(0.0, 1.0));
                }
                if let Some((sc, w)) = stroke {
                    let a = (w / 2.0 + 0.5 - (d - r).abs()).clamp(0.0, 1.0);
                    self.blend(x, y, sc, a);
                }
            }
        }
    }

    /// Draws `text` anchored at `(x, y)`; `rotate` turns it 90° counter-clockwise (reading
    /// upwards, for a y-axis title), the anchors then apply along and across the text.
    /// Returns the box the text covers.
    #[allow(clippy::too_many_arguments)]
    pub fn text(
        &mut self,
        text: &str,
        x: f64,
        y: f64,
        style: TextStyle,
        h: HAlign,
        v: VAlign,
        rotate: bool,
    ) -> Rect {
        let text = &subscripts(text);
        let font = style.font();
        let sf = font.as_scaled(PxScale::from(style.size));
        let ascent = sf.ascent() as f64;
        let line_h = (sf.ascent() - sf.descent()) as f64;
        let width = style.width(text);
        let (bw, bh) = (width.ceil() as usize + 2, line_h.ceil() as usize + 2);
        // Rasterise horizontally into an alpha box whose top-left is the line box's top-left.
        let mut alpha = vec![0f32; bw * bh];
        let mut pen = 0.0f32;
        let mut prev: Option<GlyphId> = None;
        for ch in text.chars() {
            let id = sf.glyph_id(ch);
            if let Some(p) = prev {
                pen += sf.kern(p, id);
            }
            let g = id.with_scale_and_position(
                PxScale::from(style.size),
                ab_glyph::point(pen + 1.0, ascent as f32 + 1.0),
            );
            if let Some(og) = font.outline_glyph(g) {
                let b = og.px_bounds();
                og.draw(|gx, gy, c| {
                    let px = b.min.x as i64 + gx as i64;
                    let py = b.min.y as i64 + gy as i64;
                    if px >= 0 && py >= 0 && (px as usize) < bw && (py as usize) < bh {
                        let a = &mut alpha[py as usize * bw + px as usize];
                        *a = (*a + c).min(1.0);
                    }
                });
            }
            pen += sf.h_advance(id);
            prev = Some(id);
        }
        // Anchor offsets inside the box (along u = reading direction, v = down the glyphs).
        let u0 = 1.0
            + match h {
                HAlign::Left => 0.0,
                HAlign::Center => width / 2.0,
                HAlign::Right => width,
            };
        let v0 = 1.0
            + match v {
                VAlign::Top => 0.0,
                VAlign::Middle => ascent - style.cap_height() / 2.0,
                VAlign::Bottom => line_h,
            };
        let (ox, oy) = (x.round(), y.round());
        let (u0, v0) = (u0.round(), v0.round());
        for vv in 0..bh {
            for uu in 0..bw {
                let a = alpha[vv * bw + uu] as f64;
                if a <= 0.0 {
                    continue;
                }
                let (du, dv) = (uu as f64 - u0, vv as f64 - v0);
                let (cx, cy) = if rotate {
                    (ox + dv, oy - du - 1.0)
                } else {
                    (ox + du, oy + dv)
                };
                self.blend(cx as i64, cy as i64, style.color, a);
            }
        }
        let (du0, du1) = (1.0 - u0, 1.0 + width - u0);
        let (dv0, dv1) = (1.0 - v0, 1.0 + line_h - v0);
        if rotate {
            Rect::new(ox + dv0, oy - du1, ox + dv1, oy - du0)
        } else {
            Rect::new(ox + du0, oy + dv0, ox + du1, oy + dv1)
        }
    }

    /// The PNG encoding of the canvas (8-bit RGB).
    pub fn to_png(&self) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.w, self.h);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Balanced);
            let mut w = enc.write_header().map_err(|e| e.to_string())?;
            w.write_image_data(&self.px).map_err(|e| e.to_string())?;
            w.finish().map_err(|e| e.to_string())?;
        }
        Ok(out)
    }
}

/// Per-pixel coverage of one stroked shape, so overlapping segments of the same polyline do
/// not darken their joints; painted once at the end.
struct Coverage {
    clip: Rect,
    x0: i64,
    y0: i64,
    w: usize,
    h: usize,
    cov: Vec<f32>,
}

impl Coverage {
    fn new(clip: Rect) -> Self {
        let x0 = clip.x0.floor() as i64;
        let y0 = clip.y0.floor() as i64;
        let w = (clip.x1.ceil() as i64 - x0).max(0) as usize;
        let h = (clip.y1.ceil() as i64 - y0).max(0) as usize;
        Coverage {
            clip,
            x0,
            y0,
            w,
            h,
            cov: vec![0.0; w * h],
        }
    }

    fn segment(&mut self, a: (f64, f64), b: (f64, f64), width: f64) {
        let r = width / 2.0;
        let Some((a, b)) = clip_segment(a, b, self.clip.grow(r + 1.0)) else {
            return;
        };
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let l2 = dx * dx + dy * dy;
        let thin = width.min(1.0);
        let xa = ((a.0.min(b.0) - r - 1.0).floor() as i64).max(self.x0);
        let xb = ((a.0.max(b.0) + r + 1.0).ceil() as i64).min(self.x0 + self.w as i64);
        let ya = ((a.1.min(b.1) - r - 1.0).floor() as i64).max(self.y0);
        let yb = ((a.1.max(b.1) + r + 1.0).ceil() as i64).min(self.y0 + self.h as i64);
        for y in ya..yb {
            for x in xa..xb {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                if !self.clip.contains(px, py) {
                    continue;
                }
                let t = if l2 > 0.0 {
                    (((px - a.0) * dx + (py - a.1) * dy) / l2).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let d = (px - a.0 - t * dx).hypot(py - a.1 - t * dy);
                let c = ((r.max(0.5) + 0.5 - d).clamp(0.0, 1.0) * thin) as f32;
                let k = (y - self.y0) as usize * self.w + (x - self.x0) as usize;
                if c > self.cov[k] {
                    self.cov[k] = c;
                }
            }
        }
    }

    fn paint(&self, canvas: &mut Canvas, c: Rgb) {
        for j in 0..self.h {
            for i in 0..self.w {
                let a = self.cov[j * self.w + i];
                if a > 0.0 {
                    canvas.blend(self.x0 + i as i64, self.y0 + j as i64, c, a as f64);
                }
            }
        }
    }
}

/// Liang–Barsky clipping of segment `a–b` to `r`.
fn clip_segment(a: (f64, f64), b: (f64, f64), r: Rect) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [
        (-dx, a.0 - r.x0),
        (dx, r.x1 - a.0),
        (-dy, a.1 - r.y0),
        (dy, r.y1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
        }
    }
    (t0 <= t1).then_some((
        (a.0 + t0 * dx, a.1 + t0 * dy),
        (a.0 + t1 * dx, a.1 + t1 * dy),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_drawn_and_measured() {
        let mut c = Canvas::new(200, 60, [255, 255, 255]);
        let st = TextStyle::new(20.0);
        let w = st.width("x (µm) ×10⁻⁷");
        assert!(w > 80.0 && w < 200.0, "{w}");
        let r = c.text(
            "x (µm) ×10⁻⁷",
            100.0,
            30.0,
            st,
            HAlign::Center,
            VAlign::Middle,
            false,
        );
        assert!((r.w() - w).abs() < 1.0);
        assert!(c.pixels().iter().any(|&p| p < 100));
    }

    #[test]
    fn subscript_markup() {
        assert_eq!(subscripts("F_k (nN)"), "Fₖ (nN)");
        assert_eq!(subscripts("% of h_max"), "% of hₘₐₓ");
        assert_eq!(subscripts("h_dive.csv"), "h_dive.csv");
        assert_eq!(subscripts("_x"), "_x");
    }

    #[test]
    fn clipping() {
        let r = Rect::new(0.0, 0.0, 10.0, 10.0);
        assert_eq!(
            clip_segment((-5.0, 5.0), (15.0, 5.0), r),
            Some(((0.0, 5.0), (10.0, 5.0)))
        );
        assert_eq!(clip_segment((-5.0, -5.0), (-1.0, 20.0), r), None);
    }
}
