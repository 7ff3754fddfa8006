//! PNG figures in the style of the paper's Figs. 4–9, drawn without any system font or
//! graphics library: maps side by side with a shared colour bar ([`map_panels`]), line plots
//! in stacked panels sharing x ([`lines`]), and data with a power-law fit ([`scatter_fit`]).
//!
//! All inputs are SI values; each axis and colour bar picks its display unit itself
//! (µm and nm for lengths, `×10⁻⁷ N·s/m` for damping, `%` for errors; see
//! [`ticks::display_unit`]). Ticks fall on 1–2–5 steps. Text is DejaVu Sans, embedded.
//! Every function writes its PNG atomically and returns an [`OutputError`] naming the path.
//!
//! # How they are drawn
//! A small rasteriser of our own (`canvas.rs`): anti-aliased lines, circles and rectangles,
//! text laid out with ab_glyph (kerning, baseline-exact anchors, 90° rotation), 8-bit RGB
//! PNG through the `png` crate. plotters was tried first; with an embedded font its bitmap
//! text sat off its ticks and its lines were not anti-aliased, and the layout we need
//! (shared colour bars, stacked panels, legends that avoid the data) was easier to own.
//!
//! # Font
//! DejaVu Sans 2.37, embedded in the binary from the `dejavu` crate (the crate is
//! MIT/Apache-2.0; the font is under the Bitstream Vera licence, with the DejaVu changes in
//! the public domain: free to use, embed and redistribute, provided a modified font is
//! renamed). No system font is read, so a clean CI machine draws the same pixels. It covers
//! µ, ×, ·, δ, superscript digits and the subscripts `F_k` → `Fₖ` turns into.

mod canvas;
pub mod colormap;
pub mod ticks;

use std::path::Path;

use super::error::{write_atomic, OutputError, Result};
use super::map::Map;
use canvas::{Canvas, HAlign, Rect, TextStyle, VAlign};
pub use colormap::{Colormap, Rgb, NO_DATA};
pub use ticks::{display_unit, format_significant, DisplayUnit, Quantity};
use ticks::{linear_ticks, log_ticks, round_out, sane_range, Ticks};

const WHITE: Rgb = [255, 255, 255];
const BLACK: Rgb = [0, 0, 0];
const FRAME: Rgb = [40, 40, 40];

/// The colour-blind-safe palette (Okabe & Ito) series take in turn when they name no colour:
/// blue, vermillion, bluish green, reddish purple, orange, sky blue, yellow, black.
pub const PALETTE: [Rgb; 8] = [
    [0, 114, 178],
    [213, 94, 0],
    [0, 158, 115],
    [204, 121, 167],
    [230, 159, 0],
    [86, 180, 233],
    [240, 228, 66],
    [0, 0, 0],
];

/// Font sizes (line heights, px) at scale 1.
struct Fonts {
    title: TextStyle,
    panel: TextStyle,
    axis: TextStyle,
    tick: TextStyle,
    legend: TextStyle,
}

fn fonts(scale: f64) -> Fonts {
    let s = scale as f32;
    Fonts {
        title: TextStyle::new(21.0 * s),
        panel: TextStyle::new(17.0 * s),
        axis: TextStyle::new(16.0 * s),
        tick: TextStyle::new(14.0 * s),
        legend: TextStyle::new(14.0 * s),
    }
}

// ---------------------------------------------------------------------------------------
// Axes
// ---------------------------------------------------------------------------------------

/// One axis after layout decisions: range and ticks in displayed units.
struct Axis {
    lo: f64,
    hi: f64,
    log: bool,
    ticks: Ticks,
    title: String,
    /// SI value / factor = displayed value.
    factor: f64,
}

impl Axis {
    /// A linear axis over `[lo, hi]` (SI) of quantity `q`.
    fn linear(q: &Quantity, lo: f64, hi: f64, max_ticks: usize, du: &DisplayUnit) -> Axis {
        let (lo, hi) = (lo / du.factor, hi / du.factor);
        Axis {
            lo,
            hi,
            log: false,
            ticks: linear_ticks(lo, hi, max_ticks),
            title: du.title(&q.name),
            factor: du.factor,
        }
    }

    /// A log axis over `[lo, hi]` (SI, > 0).
    fn log(q: &Quantity, lo: f64, hi: f64, du: &DisplayUnit) -> Axis {
        let (lo, hi) = (lo / du.factor, hi / du.factor);
        Axis {
            lo,
            hi,
            log: true,
            ticks: log_ticks(lo, hi),
            title: du.title(&q.name),
            factor: du.factor,
        }
    }

    /// Position of a displayed value as a fraction of the axis (NaN for v ≤ 0 on a log axis).
    fn frac(&self, v: f64) -> f64 {
        if self.log {
            if v <= 0.0 {
                return f64::NAN;
            }
            (v.ln() - self.lo.ln()) / (self.hi.ln() - self.lo.ln())
        } else {
            (v - self.lo) / (self.hi - self.lo)
        }
    }
}

/// Which sides of a frame get tick labels.
#[derive(Clone, Copy)]
struct Labels {
    x: bool,
    y: bool,
}

/// Tick length, px.
fn tick_len(scale: f64) -> f64 {
    5.0 * scale
}

/// The style and lines of a title within `avail` px: its own size if it fits, else smaller
/// down to 60 %, else at 60 % broken at spaces into as many lines as it takes.
fn fit_title(title: &str, style: TextStyle, avail: f64) -> (TextStyle, Vec<String>) {
    let w = style.width(title);
    if w <= avail {
        return (style, vec![title.to_string()]);
    }
    let small = TextStyle {
        size: (style.size * (avail / w) as f32).max(0.6 * style.size),
        ..style
    };
    if small.width(title) <= avail {
        return (small, vec![title.to_string()]);
    }
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in title.split(' ') {
        let candidate = if line.is_empty() {
            word.to_string()
        } else {
            format!("{line} {word}")
        };
        if !line.is_empty() && small.width(&candidate) > avail {
            lines.push(std::mem::replace(&mut line, word.to_string()));
        } else {
            line = candidate;
        }
    }
    if !line.is_empty() {
        lines.push(line);
    }
    (small, lines)
}

/// Draws the frame `r`, outward ticks and (where asked) tick labels. Axis titles are drawn by
/// the caller, who knows where there is room.
fn draw_frame(c: &mut Canvas, r: Rect, xa: &Axis, ya: &Axis, labels: Labels, f: &Fonts, s: f64) {
    let tl = tick_len(s);
    let lw = (1.0 * s).max(1.0);
    for (vals, len) in [(&xa.ticks.major, tl), (&xa.ticks.minor, tl * 0.55)] {
        for &v in vals.iter() {
            let x = r.x0 + xa.frac(v) * r.w();
            if x.is_finite() && x >= r.x0 - 0.5 && x <= r.x1 + 0.5 {
                c.fill_rect(
                    Rect::new(x - lw / 2.0, r.y1, x + lw / 2.0, r.y1 + len),
                    FRAME,
                    1.0,
                );
            }
        }
    }
    for (vals, len) in [(&ya.ticks.major, tl), (&ya.ticks.minor, tl * 0.55)] {
        for &v in vals.iter() {
            let y = r.y1 - ya.frac(v) * r.h();
            if y.is_finite() && y >= r.y0 - 0.5 && y <= r.y1 + 0.5 {
                c.fill_rect(
                    Rect::new(r.x0 - len, y - lw / 2.0, r.x0, y + lw / 2.0),
                    FRAME,
                    1.0,
                );
            }
        }
    }
    c.stroke_rect(r, lw, FRAME);
    if labels.x {
        for (v, l) in xa.ticks.major.iter().zip(&xa.ticks.labels) {
            let x = r.x0 + xa.frac(*v) * r.w();
            if x.is_finite() {
                c.text(
                    l,
                    x,
                    r.y1 + tl + 3.0 * s,
                    f.tick,
                    HAlign::Center,
                    VAlign::Top,
                    false,
                );
            }
        }
    }
    if labels.y {
        for (v, l) in ya.ticks.major.iter().zip(&ya.ticks.labels) {
            let y = r.y1 - ya.frac(*v) * r.h();
            if y.is_finite() {
                c.text(
                    l,
                    r.x0 - tl - 4.0 * s,
                    y,
                    f.tick,
                    HAlign::Right,
                    VAlign::Middle,
                    false,
                );
            }
        }
    }
}

/// Width of the widest tick label.
fn max_label_width(t: &Ticks, st: &TextStyle) -> f64 {
    t.labels.iter().map(|l| st.width(l)).fold(0.0, f64::max)
}

/// Encodes and writes a canvas.
fn save(path: &Path, c: &Canvas) -> Result<()> {
    let png = c
        .to_png()
        .map_err(|e| OutputError::new(path, format!("cannot encode the PNG: {e}")))?;
    write_atomic(path, &png)
}

// ---------------------------------------------------------------------------------------
// Maps
// ---------------------------------------------------------------------------------------

/// How [`map_panels`] draws its maps.
#[derive(Debug, Clone)]
pub struct MapStyle<'a> {
    /// Title over the whole figure, e.g. "Damping coefficient c".
    pub title: Option<String>,
    /// The quantity shown, for the colour-bar title: name and SI unit (`c`, `N·s/m`). When
    /// `None`, the first map's name and unit.
    pub quantity: Option<Quantity>,
    /// Colour map. [`Colormap::Diverging`] makes the automatic range symmetric around 0.
    pub colormap: Colormap,
    /// Shared colour range (SI). `None`: the min and max over all panels (for a diverging
    /// map, ±max |v|). Values outside are drawn in the end colours.
    pub range: Option<(f64, f64)>,
    /// Display unit of the colour bar. `None`: chosen from the range ([`display_unit`]).
    pub unit: Option<DisplayUnit>,
    /// Prefix panel titles with (a), (b), (c).
    pub letters: bool,
    /// Shade the colours by the map's own slopes (light from the upper left), a 2-D relief
    /// view of a topography.
    pub relief: bool,
    /// An optional mask drawn over every panel, on its own grid: pixels whose value is 1 are
    /// hatched and outlined (e.g. "steep" pixels from [`Map::gradient_magnitude`] and
    /// [`Map::threshold`]). Its name labels it in the legend under the panels.
    pub mask: Option<&'a Map>,
    /// Width of one map panel in px at scale 1 (the height follows the map's aspect ratio).
    pub panel_px: u32,
    /// Multiplies every size (fonts, lines, panels): 2.0 for print.
    pub scale: f64,
}

impl Default for MapStyle<'_> {
    fn default() -> Self {
        MapStyle {
            title: None,
            quantity: None,
            colormap: Colormap::Viridis,
            range: None,
            unit: None,
            letters: true,
            relief: false,
            mask: None,
            panel_px: 300,
            scale: 1.0,
        }
    }
}

/// The shared colour range of `maps` for `cmap` (SI).
fn auto_range(maps: &[&Map], cmap: Colormap) -> (f64, f64) {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for m in maps {
        for &v in &m.data {
            if v.is_finite() {
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if cmap.is_diverging() {
        let a = lo.abs().max(hi.abs());
        return if a > 0.0 { (-a, a) } else { (-1.0, 1.0) };
    }
    sane_range(lo, hi)
}

/// Slope shading factor per pixel of `m` (1 = flat), light from the upper left.
fn relief_shade(m: &Map) -> Vec<f64> {
    // Vertical exaggeration from a typical slope (the 75th percentile of the non-zero
    // ones), so the relief inside a cell shows and not only its steep rim.
    let mut slopes: Vec<f64> = m
        .gradient_magnitude()
        .data
        .into_iter()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    slopes.sort_by(f64::total_cmp);
    let typical = slopes.get(slopes.len() * 3 / 4).copied().unwrap_or(0.0);
    let ex = if typical > 0.0 { 0.8 / typical } else { 1.0 };
    let gr = &m.grid;
    let (lx, ly, lz) = (-1.0f64, 1.0f64, 1.2f64);
    let ln = (lx * lx + ly * ly + lz * lz).sqrt();
    let mut out = vec![1.0; gr.len()];
    for j in 0..gr.ny {
        for i in 0..gr.nx {
            let (il, ir) = (i.saturating_sub(1), (i + 1).min(gr.nx - 1));
            let (jb, jt) = (j.saturating_sub(1), (j + 1).min(gr.ny - 1));
            let gx = if ir > il {
                (m.get(ir, j) - m.get(il, j)) / ((ir - il) as f64 * gr.dx)
            } else {
                0.0
            };
            let gy = if jt > jb {
                (m.get(i, jt) - m.get(i, jb)) / ((jt - jb) as f64 * gr.dy)
            } else {
                0.0
            };
            let (nx, ny, nz) = (-gx * ex, -gy * ex, 1.0);
            let nn = (nx * nx + ny * ny + nz * nz).sqrt();
            let lam = (nx * lx + ny * ly + nz * lz) / (nn * ln);
            let flat = lz / ln;
            let v = 0.62 + 0.38 * (lam / flat);
            out[j * gr.nx + i] = if v.is_finite() {
                v.clamp(0.35, 1.25)
            } else {
                1.0
            };
        }
    }
    out
}

/// Draws one to several maps side by side, like the paper's Figs. 4–7: each panel titled
/// (`"given"`, `"DIVE"`, `"SVE"`), axes in µm, one colour scale shared by all panels with a
/// colour bar on the right, NaN pixels grey, an optional hatched mask, and a legend row for
/// the mask and for "no data" when there is any.
///
/// ```no_run
/// # use visco::output::{map::{Grid, Map}, figure::{self, MapStyle}};
/// # let given = Map::new(Grid::over(50, 50, 0.0, 5e-6, 0.0, 5e-6), "c", "N·s/m");
/// # let dive = given.clone(); let sve = given.clone();
/// figure::map_panels(
///     "out/c.png".as_ref(),
///     &[(&given, "given"), (&dive, "DIVE"), (&sve, "SVE")],
///     &MapStyle { title: Some("Damping coefficient".into()), ..Default::default() },
/// )?;
/// # Ok::<(), visco::output::OutputError>(())
/// ```
pub fn map_panels(path: &Path, panels: &[(&Map, &str)], style: &MapStyle) -> Result<()> {
    let c = render_map_panels(panels, style).map_err(|e| OutputError::new(path, e))?;
    save(path, &c)
}

fn render_map_panels(
    panels: &[(&Map, &str)],
    style: &MapStyle,
) -> std::result::Result<Canvas, String> {
    if panels.is_empty() {
        return Err("cannot draw a map figure without maps".into());
    }
    let s = if style.scale.is_finite() && style.scale > 0.0 {
        style.scale
    } else {
        1.0
    };
    let f = fonts(s);
    let maps: Vec<&Map> = panels.iter().map(|p| p.0).collect();
    let (lo, hi) = style
        .range
        .map(|(a, b)| sane_range(a, b))
        .unwrap_or_else(|| auto_range(&maps, style.colormap));
    let q = style
        .quantity
        .clone()
        .unwrap_or_else(|| Quantity::new(maps[0].name.clone(), maps[0].unit.clone()));
    let cu = style
        .unit
        .clone()
        .unwrap_or_else(|| display_unit(&q.unit, lo.abs().max(hi.abs())));
    let cbar = Axis::linear(&q, lo, hi, 7, &cu);

    // Physical extents and axes of each panel (µm for lengths).
    let lunit = {
        let m = maps
            .iter()
            .map(|m| {
                m.grid
                    .x0
                    .abs()
                    .max(m.grid.x1().abs())
                    .max(m.grid.y0.abs())
                    .max(m.grid.y1().abs())
            })
            .fold(0.0, f64::max);
        display_unit("m", m)
    };
    let axes: Vec<(Axis, Axis)> = maps
        .iter()
        .map(|m| {
            let g = &m.grid;
            (
                Axis::linear(&Quantity::new("x", "m"), g.x0, g.x1(), 6, &lunit),
                Axis::linear(&Quantity::new("y", "m"), g.y0, g.y1(), 6, &lunit),
            )
        })
        .collect();
    let share_y = maps.iter().all(|m| {
        (m.grid.y0 - maps[0].grid.y0).abs() <= 1e-9 * m.grid.height()
            && (m.grid.y1() - maps[0].grid.y1()).abs() <= 1e-9 * m.grid.height()
    });

    // Layout.
    let pad = 12.0 * s;
    let tl = tick_len(s);
    let pw = (style.panel_px.max(60) as f64 * s).round();
    let aspect = |m: &Map| (m.grid.height() / m.grid.width()).clamp(0.1, 10.0);
    let ph = maps
        .iter()
        .map(|m| (pw * aspect(m)).round())
        .fold(0.0, f64::max);
    let ylab_w = axes
        .iter()
        .map(|(_, ya)| max_label_width(&ya.ticks, &f.tick))
        .fold(0.0, f64::max);
    let left_axis = tl + 4.0 * s + ylab_w + 8.0 * s + f.axis.line_height();
    // Panels sit close when they share y, but never so close that the last x tick label of
    // one panel touches the first of the next.
    let xlab_w = axes
        .iter()
        .map(|(xa, _)| max_label_width(&xa.ticks, &f.tick))
        .fold(0.0, f64::max);
    let gap = if share_y {
        (22.0 * s).max(xlab_w + 10.0 * s)
    } else {
        left_axis + 10.0 * s
    };
    let title_h = if style.title.is_some() {
        f.title.line_height() + 6.0 * s
    } else {
        0.0
    };
    let top = pad + title_h + f.panel.line_height() + 8.0 * s;
    let cbar_w = 18.0 * s;
    let cbar_lab = max_label_width(&cbar.ticks, &f.tick);
    let right = 26.0 * s + cbar_w + tl + 4.0 * s + cbar_lab + 10.0 * s + f.axis.line_height() + pad;
    let bottom_axis = tl + 3.0 * s + f.tick.line_height() + 6.0 * s + f.axis.line_height();
    let has_nan = maps.iter().any(|m| m.data.iter().any(|v| v.is_nan()));
    let legend_h = if has_nan || style.mask.is_some() {
        f.legend.line_height() + 10.0 * s
    } else {
        0.0
    };
    let n = maps.len() as f64;
    let x_start = pad + left_axis;
    let width = x_start + n * pw + (n - 1.0) * gap + right;
    let height = top + ph + bottom_axis + legend_h + pad;
    // Keep the figure title inside the canvas when it is wider than the panels.
    let title_w = style
        .title
        .as_ref()
        .map(|t| f.title.width(t) + 2.0 * pad)
        .unwrap_or(0.0);
    let width = width.max(title_w).ceil();
    let mut c = Canvas::new(width as u32, height.ceil() as u32, WHITE);

    if let Some(t) = &style.title {
        let cx = x_start + (n * pw + (n - 1.0) * gap) / 2.0;
        let cx = cx.clamp(title_w / 2.0, width - title_w / 2.0);
        c.text(t, cx, pad, f.title, HAlign::Center, VAlign::Top, false);
    }

    let shades: Vec<Option<Vec<f64>>> = maps
        .iter()
        .map(|m| style.relief.then(|| relief_shade(m)))
        .collect();
    for (k, ((m, name), (xa, ya))) in panels.iter().zip(&axes).enumerate() {
        let x0 = (x_start + k as f64 * (pw + gap)).round();
        let h = (pw * aspect(m)).round();
        let y0 = (top + (ph - h) / 2.0).round();
        let r = Rect::new(x0, y0, x0 + pw, y0 + h);
        paint_map(&mut c, r, m, lo, hi, style, shades[k].as_deref());
        if let Some(mask) = style.mask {
            paint_mask(&mut c, r, m, mask, s);
        }
        let show_y = k == 0 || !share_y;
        draw_frame(&mut c, r, xa, ya, Labels { x: true, y: show_y }, &f, s);
        let label = if style.letters {
            format!("({}) {}", (b'a' + (k % 26) as u8) as char, name)
        } else {
            name.to_string()
        };
        c.text(
            &label,
            r.x0 + r.w() / 2.0,
            r.y0 - 7.0 * s,
            f.panel,
            HAlign::Center,
            VAlign::Bottom,
            false,
        );
        c.text(
            &xa.title,
            r.x0 + r.w() / 2.0,
            r.y1 + tl + 3.0 * s + f.tick.line_height() + 5.0 * s,
            f.axis,
            HAlign::Center,
            VAlign::Top,
            false,
        );
        if show_y {
            c.text(
                &ya.title,
                r.x0 - left_axis,
                r.y0 + r.h() / 2.0,
                f.axis,
                HAlign::Center,
                VAlign::Top,
                true,
            );
        }
    }

    // Colour bar, as tall as the panels.
    let bx = (x_start + n * pw + (n - 1.0) * gap + 26.0 * s).round();
    let br = Rect::new(bx, top.round(), bx + cbar_w.round(), (top + ph).round());
    for py in br.y0 as i64..br.y1 as i64 {
        // First and last rows get exactly the end colours.
        let t = (br.y1 - 1.0 - py as f64) / (br.h() - 1.0).max(1.0);
        let col = style.colormap.at(t);
        c.fill_rect(
            Rect::new(br.x0, py as f64, br.x1, py as f64 + 1.0),
            col,
            1.0,
        );
    }
    let lw = s.max(1.0);
    for &v in &cbar.ticks.major {
        let y = br.y1 - cbar.frac(v) * br.h();
        c.fill_rect(
            Rect::new(br.x1, y - lw / 2.0, br.x1 + tl, y + lw / 2.0),
            FRAME,
            1.0,
        );
    }
    c.stroke_rect(br, lw, FRAME);
    for (v, l) in cbar.ticks.major.iter().zip(&cbar.ticks.labels) {
        let y = br.y1 - cbar.frac(*v) * br.h();
        c.text(
            l,
            br.x1 + tl + 4.0 * s,
            y,
            f.tick,
            HAlign::Left,
            VAlign::Middle,
            false,
        );
    }
    c.text(
        &cbar.title,
        br.x1 + tl + 4.0 * s + cbar_lab + 10.0 * s + f.axis.line_height(),
        br.y0 + br.h() / 2.0,
        f.axis,
        HAlign::Center,
        VAlign::Bottom,
        true,
    );

    // Legend row: hatched mask, grey no-data.
    if legend_h > 0.0 {
        let y = top + ph + bottom_axis + 10.0 * s;
        let bh = f.legend.cap_height() + 4.0 * s;
        let mut x = x_start;
        if let Some(mask) = style.mask {
            let r = Rect::new(x, y, x + 2.0 * bh, y + bh);
            c.fill_rect(r, WHITE, 1.0);
            hatch(&mut c, r, s, |_, _| true);
            c.stroke_rect(r, lw, FRAME);
            let name = if mask.name.is_empty() {
                "mask"
            } else {
                &mask.name
            };
            let tr = c.text(
                name,
                r.x1 + 6.0 * s,
                y + bh / 2.0,
                f.legend,
                HAlign::Left,
                VAlign::Middle,
                false,
            );
            x = tr.x1 + 24.0 * s;
        }
        if has_nan {
            let r = Rect::new(x, y, x + 2.0 * bh, y + bh);
            c.fill_rect(r, NO_DATA, 1.0);
            c.stroke_rect(r, lw, FRAME);
            c.text(
                "no data",
                r.x1 + 6.0 * s,
                y + bh / 2.0,
                f.legend,
                HAlign::Left,
                VAlign::Middle,
                false,
            );
        }
    }
    Ok(c)
}

/// Fills `r` with the map's colours, nearest pixel (no smoothing: a pixel of the map is a
/// measurement).
fn paint_map(
    c: &mut Canvas,
    r: Rect,
    m: &Map,
    lo: f64,
    hi: f64,
    style: &MapStyle,
    shade: Option<&[f64]>,
) {
    let g = &m.grid;
    for py in r.y0 as i64..r.y1 as i64 {
        let y = g.y1() - (py as f64 + 0.5 - r.y0) / r.h() * g.height();
        for px in r.x0 as i64..r.x1 as i64 {
            let x = g.x0 + (px as f64 + 0.5 - r.x0) / r.w() * g.width();
            let Some((i, j)) = g.cell_of(x, y) else {
                continue;
            };
            let v = m.get(i, j);
            let mut col = style.colormap.at((v - lo) / (hi - lo));
            if v.is_nan() {
                col = NO_DATA;
            } else if let Some(sh) = shade {
                let k = sh[j * g.nx + i];
                col = col.map(|ch| (ch as f64 * k).round().clamp(0.0, 255.0) as u8);
            }
            c.put(px, py, col);
        }
    }
}

/// Diagonal hatching over the pixels of `r` where `inside(px, py)`.
fn hatch(c: &mut Canvas, r: Rect, s: f64, inside: impl Fn(i64, i64) -> bool) {
    let period = (7.0 * s).round().max(4.0) as i64;
    let lw = s.max(1.0);
    for py in r.y0 as i64..r.y1 as i64 {
        for px in r.x0 as i64..r.x1 as i64 {
            if !inside(px, py) {
                continue;
            }
            // Distance to the nearest line x + y = k·period, along the diagonal.
            let d = ((px + py).rem_euclid(period)) as f64;
            let d = d.min(period as f64 - d) / std::f64::consts::SQRT_2;
            let a = (lw / 2.0 + 0.5 - d).clamp(0.0, 1.0);
            c.blend(px, py, BLACK, 0.75 * a);
        }
    }
}

/// Hatches and outlines the pixels of panel `r` (showing map `m`) where `mask` is 1.
fn paint_mask(c: &mut Canvas, r: Rect, m: &Map, mask: &Map, s: f64) {
    let g = &m.grid;
    let (w, h) = (r.w() as i64, r.h() as i64);
    // The mask value under each canvas pixel of the panel.
    let mut on = vec![false; (w * h) as usize];
    for py in 0..h {
        let y = g.y1() - (py as f64 + 0.5) / r.h() * g.height();
        for px in 0..w {
            let x = g.x0 + (px as f64 + 0.5) / r.w() * g.width();
            on[(py * w + px) as usize] = mask
                .grid
                .cell_of(x, y)
                .map(|(i, j)| mask.get(i, j) >= 0.5)
                .unwrap_or(false);
        }
    }
    let at =
        |px: i64, py: i64| px >= 0 && py >= 0 && px < w && py < h && on[(py * w + px) as usize];
    let (ox, oy) = (r.x0 as i64, r.y0 as i64);
    hatch(c, r, s, |px, py| at(px - ox, py - oy));
    // Outline: mask pixels with a non-mask 4-neighbour inside the panel.
    let t = (s.round() as i64).max(1);
    for py in 0..h {
        for px in 0..w {
            if !at(px, py) {
                continue;
            }
            let edge = [(-1, 0), (1, 0), (0, -1), (0, 1)].iter().any(|(dx, dy)| {
                let (qx, qy) = (px + dx * t, py + dy * t);
                qx >= 0 && qy >= 0 && qx < w && qy < h && !at(qx, qy)
            });
            if edge {
                c.blend(ox + px, oy + py, BLACK, 0.9);
            }
        }
    }
}

// ---------------------------------------------------------------------------------------
// Line plots
// ---------------------------------------------------------------------------------------

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SeriesStyle {
    /// A solid line of this width (px at scale 1).
    Line(f64),
    /// A dashed line of this width.
    Dashed(f64),
    /// Open circles of this radius.
    Markers(f64),
    /// Filled dots of this radius (for many points).
    Dots(f64),
}

/// One named series of `(x, y)` points in SI units. NaN points break a line.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text; empty for no legend entry.
    pub label: String,
    /// The points, SI.
    pub points: Vec<(f64, f64)>,
    /// Drawing style.
    pub style: SeriesStyle,
    /// Colour; `None` takes the next colour of [`PALETTE`].
    pub color: Option<Rgb>,
}

impl Series {
    /// A solid line, 1.8 px.
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
            style: SeriesStyle::Line(1.8),
            color: None,
        }
    }
    /// A dashed line, 1.8 px (e.g. the given values).
    pub fn dashed(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            style: SeriesStyle::Dashed(1.8),
            ..Series::line(label, points)
        }
    }
    /// Open circles, radius 3.5 px.
    pub fn markers(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            style: SeriesStyle::Markers(3.5),
            ..Series::line(label, points)
        }
    }
    /// The same series in colour `c`.
    pub fn with_color(mut self, c: Rgb) -> Self {
        self.color = Some(c);
        self
    }
    /// The same series drawn as `style`.
    pub fn with_style(mut self, style: SeriesStyle) -> Self {
        self.style = style;
        self
    }
}

/// One panel of a [`LinePlot`]: a y quantity and its series.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LinePanel {
    /// The y quantity (name, SI unit).
    pub y: Quantity,
    /// The series, drawn in order.
    pub series: Vec<Series>,
    /// y range (SI); `None`: the data's, rounded out to ticks.
    pub y_range: Option<(f64, f64)>,
    /// Logarithmic y axis (non-positive values are not drawn).
    pub y_log: bool,
}

/// Stacked panels sharing one x axis, like the paper's Fig. 8 (h, c, k and U along a
/// cross-section or against time). One panel is a plain x–y plot.
#[derive(Debug, Clone, PartialEq)]
pub struct LinePlot {
    /// Title over the figure.
    pub title: Option<String>,
    /// The x quantity (name, SI unit), shared by all panels.
    pub x: Quantity,
    /// x range (SI); `None`: the data's extent (scatter plots round it out to ticks).
    pub x_range: Option<(f64, f64)>,
    /// Logarithmic x axis.
    pub x_log: bool,
    /// The panels, top to bottom.
    pub panels: Vec<LinePanel>,
    /// Width of the plotting frame, px at scale 1.
    pub width: u32,
    /// Height of each panel's frame, px at scale 1.
    pub panel_height: u32,
    /// Multiplies every size: 2.0 for print.
    pub scale: f64,
}

impl Default for LinePlot {
    fn default() -> Self {
        LinePlot {
            title: None,
            x: Quantity::new("x", "m"),
            x_range: None,
            x_log: false,
            panels: Vec::new(),
            width: 640,
            panel_height: 180,
            scale: 1.0,
        }
    }
}

/// Draws a [`LinePlot`] to `path` as PNG.
pub fn lines(path: &Path, plot: &LinePlot) -> Result<()> {
    let c = render_lines(plot, false).map_err(|e| OutputError::new(path, e))?;
    save(path, &c)
}

/// Data range of a set of values (finite, and > 0 on a log axis).
fn data_range(vals: impl Iterator<Item = f64>, log: bool) -> Option<(f64, f64)> {
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    for v in vals.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    lo.is_finite().then_some((lo, hi))
}

/// A log range rounded out to whole decades (or to 1-2-5 within less than a decade).
fn log_range(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, hi) = if hi > lo {
        (lo, hi)
    } else {
        (lo / 2.0, hi * 2.0)
    };
    let a = 10f64.powf(lo.log10().floor());
    let b = 10f64.powf(hi.log10().ceil());
    if (b / a) <= 10.0 + 1e-9 {
        // Tighter: 1-2-5 bounds.
        let down = |v: f64| {
            let d = 10f64.powf(v.log10().floor());
            [5.0, 2.0, 1.0]
                .iter()
                .map(|m| m * d)
                .find(|&x| x <= v * (1.0 + 1e-12))
                .unwrap_or(d)
        };
        let up = |v: f64| {
            let d = 10f64.powf(v.log10().floor());
            [1.0, 2.0, 5.0, 10.0]
                .iter()
                .map(|m| m * d)
                .find(|&x| x >= v * (1.0 - 1e-12))
                .unwrap_or(10.0 * d)
        };
        return (down(lo), up(hi));
    }
    (a, b)
}

/// Thins a long series for drawing: per pixel column, the first, min, max and last point.
fn decimate(pts: &[(f64, f64)], to_px: impl Fn(f64) -> f64, columns: usize) -> Vec<(f64, f64)> {
    if pts.len() <= 8 * columns.max(1) {
        return pts.to_vec();
    }
    let mut out = Vec::with_capacity(4 * columns);
    let mut k = 0;
    while k < pts.len() {
        let col = to_px(pts[k].0).floor();
        let start = k;
        if !pts[k].1.is_finite() || !col.is_finite() {
            out.push(pts[k]);
            k += 1;
            continue;
        }
        let (mut imin, mut imax) = (k, k);
        while k < pts.len() && pts[k].1.is_finite() && to_px(pts[k].0).floor() == col {
            if pts[k].1 < pts[imin].1 {
                imin = k;
            }
            if pts[k].1 > pts[imax].1 {
                imax = k;
            }
            k += 1;
        }
        let mut idx = vec![start, imin, imax, k - 1];
        idx.sort_unstable();
        idx.dedup();
        out.extend(idx.into_iter().map(|i| pts[i]));
    }
    out
}

fn render_lines(plot: &LinePlot, scatter: bool) -> std::result::Result<Canvas, String> {
    if plot.panels.is_empty() {
        return Err("cannot draw a line plot without panels".into());
    }
    let s = if plot.scale.is_finite() && plot.scale > 0.0 {
        plot.scale
    } else {
        1.0
    };
    let f = fonts(s);
    let all_x = || {
        plot.panels
            .iter()
            .flat_map(|p| p.series.iter())
            .flat_map(|s| s.points.iter().map(|p| p.0))
    };
    // Each axis takes its display unit from the data (or the given range) *before* rounding
    // the range out to ticks, so 0.8×10⁻⁶ stays "×10⁻⁷" and is not promoted by the rounding.
    let (xlo, xhi, xdu) = match plot.x_range {
        Some((a, b)) => {
            let (a, b) = sane_range(a, b);
            (a, b, display_unit(&plot.x.unit, a.abs().max(b.abs())))
        }
        None => {
            let (a, b) = data_range(all_x(), plot.x_log).unwrap_or((0.0, 1.0));
            let du = display_unit(&plot.x.unit, a.abs().max(b.abs()));
            let (a, b) = if plot.x_log {
                log_range(a, b)
            } else if scatter {
                let a = if a > 0.0 && a < 0.25 * b { 0.0 } else { a };
                let (ra, rb) = round_out(a / du.factor, b / du.factor, 8);
                (ra * du.factor, rb * du.factor)
            } else {
                sane_range(a, b)
            };
            (a, b, du)
        }
    };
    if plot.x_log && (xlo.is_nan() || xlo <= 0.0) {
        return Err("a logarithmic x axis needs positive values".into());
    }
    let xa = if plot.x_log {
        Axis::log(&plot.x, xlo, xhi, &xdu)
    } else {
        Axis::linear(&plot.x, xlo, xhi, 8, &xdu)
    };
    let mut yaxes = Vec::new();
    for p in &plot.panels {
        let (lo, hi, du) = match p.y_range {
            Some((a, b)) => {
                let (a, b) = sane_range(a, b);
                (a, b, display_unit(&p.y.unit, a.abs().max(b.abs())))
            }
            None => {
                let vals = p.series.iter().flat_map(|s| {
                    s.points
                        .iter()
                        .filter(|q| q.0 >= xlo.min(xhi) && q.0 <= xhi.max(xlo))
                        .map(|q| q.1)
                });
                let (a, b) = data_range(vals, p.y_log).unwrap_or((0.0, 1.0));
                let du = display_unit(&p.y.unit, a.abs().max(b.abs()));
                if p.y_log {
                    let (a, b) = log_range(a, b);
                    (a, b, du)
                } else {
                    let (a, b) = sane_range(a, b);
                    let (ra, rb) = round_out(a / du.factor, b / du.factor, 5);
                    (ra * du.factor, rb * du.factor, du)
                }
            }
        };
        if p.y_log && (lo.is_nan() || lo <= 0.0) {
            return Err(format!(
                "panel `{}`: a logarithmic axis needs positive values",
                p.y.name
            ));
        }
        yaxes.push(if p.y_log {
            Axis::log(&p.y, lo, hi, &du)
        } else {
            Axis::linear(&p.y, lo, hi, 5, &du)
        });
    }

    // Layout.
    let pad = 12.0 * s;
    let tl = tick_len(s);
    let ylab_w = yaxes
        .iter()
        .map(|a| max_label_width(&a.ticks, &f.tick))
        .fold(0.0, f64::max);
    let left = pad + f.axis.line_height() + 8.0 * s + ylab_w + 4.0 * s + tl;
    let pw = (plot.width.max(100) as f64 * s).round();
    let ph = (plot.panel_height.max(60) as f64 * s).round();
    let vgap = 14.0 * s;
    let bottom = tl + 3.0 * s + f.tick.line_height() + 6.0 * s + f.axis.line_height() + pad;
    // Room on the right for the last x tick label hanging over the frame.
    let right = pad + max_label_width(&xa.ticks, &f.tick) / 2.0;
    let n = plot.panels.len() as f64;
    let width = (left + pw + right).ceil();
    // A long title (a file name, the findings) is set smaller to fit the canvas, down to 60 %
    // of its size, and past that broken into lines at spaces; each line is kept inside the
    // canvas, centred on the panels where it fits there.
    let (title_style, title_lines) = match &plot.title {
        Some(t) => fit_title(t, f.title, width - 2.0 * pad),
        None => (f.title, Vec::new()),
    };
    let title_h = if title_lines.is_empty() {
        0.0
    } else {
        title_lines.len() as f64 * title_style.line_height() + 10.0 * s
    };
    let top = pad + title_h + 4.0 * s;
    let height = (top + n * ph + (n - 1.0) * vgap + bottom).ceil();
    let mut c = Canvas::new(width as u32, height as u32, WHITE);
    for (i, line) in title_lines.iter().enumerate() {
        let half = title_style.width(line) / 2.0;
        let (lo, hi) = (pad + half, width - pad - half);
        // f64::clamp panics on lo > hi: a word wider than the canvas is centred on it.
        let cx = if lo <= hi {
            (left + pw / 2.0).clamp(lo, hi)
        } else {
            width / 2.0
        };
        let y = pad + i as f64 * title_style.line_height();
        c.text(line, cx, y, title_style, HAlign::Center, VAlign::Top, false);
    }
    let x0 = left.round();
    for (k, (p, ya)) in plot.panels.iter().zip(&yaxes).enumerate() {
        let y0 = (top + k as f64 * (ph + vgap)).round();
        let r = Rect::new(x0, y0, x0 + pw, y0 + ph);
        let last = k + 1 == plot.panels.len();
        let map_pt = |q: (f64, f64)| {
            (
                r.x0 + xa.frac(q.0 / xa.factor) * r.w(),
                r.y1 - ya.frac(q.1 / ya.factor) * r.h(),
            )
        };
        // Light grid at major ticks helps reading values off stacked panels.
        for &v in &ya.ticks.major {
            let y = r.y1 - ya.frac(v) * r.h();
            if y > r.y0 + 1.0 && y < r.y1 - 1.0 {
                c.fill_rect(
                    Rect::new(r.x0, y - 0.5, r.x1, y + 0.5),
                    [228, 228, 228],
                    1.0,
                );
            }
        }
        let mut palette = PALETTE.iter().cycle();
        let mut colors = Vec::new();
        let mut drawn: Vec<Vec<(f64, f64)>> = Vec::new();
        for sr in &p.series {
            let col = sr.color.unwrap_or_else(|| *palette.next().unwrap());
            colors.push(col);
            let pts: Vec<(f64, f64)> = sr.points.iter().map(|&q| map_pt(q)).collect();
            match sr.style {
                SeriesStyle::Line(w) | SeriesStyle::Dashed(w) => {
                    let pts = decimate(&pts, |x| x, pw as usize);
                    let dash =
                        matches!(sr.style, SeriesStyle::Dashed(_)).then_some((7.0 * s, 4.0 * s));
                    c.polyline(&pts, w * s, col, dash, r);
                }
                SeriesStyle::Markers(rad) => {
                    for &(x, y) in &pts {
                        if r.contains(x, y) {
                            c.circle(x, y, rad * s, Some(WHITE), Some((col, 1.3 * s)));
                        }
                    }
                }
                SeriesStyle::Dots(rad) => {
                    for &(x, y) in &pts {
                        if r.contains(x, y) {
                            c.circle(x, y, rad * s, Some(col), None);
                        }
                    }
                }
            }
            drawn.push(pts);
        }
        draw_frame(&mut c, r, &xa, ya, Labels { x: last, y: true }, &f, s);
        c.text(
            &ya.title,
            pad,
            r.y0 + r.h() / 2.0,
            f.axis,
            HAlign::Center,
            VAlign::Top,
            true,
        );
        if last {
            c.text(
                &xa.title,
                r.x0 + r.w() / 2.0,
                r.y1 + tl + 3.0 * s + f.tick.line_height() + 5.0 * s,
                f.axis,
                HAlign::Center,
                VAlign::Top,
                false,
            );
        }
        draw_legend(&mut c, r, p, &colors, &drawn, &f, s);
    }
    Ok(c)
}

/// A legend box in the corner of `r` that hides the fewest drawn points.
fn draw_legend(
    c: &mut Canvas,
    r: Rect,
    p: &LinePanel,
    colors: &[Rgb],
    drawn: &[Vec<(f64, f64)>],
    f: &Fonts,
    s: f64,
) {
    let entries: Vec<(usize, &Series)> = p
        .series
        .iter()
        .enumerate()
        .filter(|(_, sr)| !sr.label.is_empty())
        .collect();
    if entries.is_empty() {
        return;
    }
    let row = f.legend.line_height() + 2.0 * s;
    let sample = 26.0 * s;
    let tw = entries
        .iter()
        .map(|(_, sr)| f.legend.width(&sr.label))
        .fold(0.0, f64::max);
    let (bw, bh) = (
        8.0 * s + sample + 6.0 * s + tw + 8.0 * s,
        6.0 * s + row * entries.len() as f64 + 2.0 * s,
    );
    let m = 6.0 * s;
    let corners = [
        Rect::new(r.x1 - m - bw, r.y0 + m, r.x1 - m, r.y0 + m + bh),
        Rect::new(r.x0 + m, r.y0 + m, r.x0 + m + bw, r.y0 + m + bh),
        Rect::new(r.x1 - m - bw, r.y1 - m - bh, r.x1 - m, r.y1 - m),
        Rect::new(r.x0 + m, r.y1 - m - bh, r.x0 + m + bw, r.y1 - m),
    ];
    let hidden = |b: &Rect| -> usize {
        let g = b.grow(3.0 * s);
        drawn
            .iter()
            .map(|pts| {
                let mut n = pts.iter().filter(|&&(x, y)| g.contains(x, y)).count();
                // Segments crossing the box without a vertex inside count too.
                n += pts
                    .windows(2)
                    .filter(|w| {
                        let seg = Rect::new(
                            w[0].0.min(w[1].0),
                            w[0].1.min(w[1].1),
                            w[0].0.max(w[1].0),
                            w[0].1.max(w[1].1),
                        );
                        seg.intersects(&g)
                    })
                    .count();
                n
            })
            .sum()
    };
    let b = corners
        .iter()
        .copied()
        .min_by_key(hidden)
        .unwrap_or(corners[0]);
    c.fill_rect(b, WHITE, 0.9);
    c.stroke_rect(b, s.max(1.0) * 0.8, [170, 170, 170]);
    for (k, (i, sr)) in entries.iter().enumerate() {
        let cy = b.y0 + 5.0 * s + row * (k as f64 + 0.5);
        let col = colors[*i];
        let (sx0, sx1) = (b.x0 + 8.0 * s, b.x0 + 8.0 * s + sample);
        match sr.style {
            SeriesStyle::Line(w) => c.polyline(&[(sx0, cy), (sx1, cy)], w * s, col, None, b),
            SeriesStyle::Dashed(w) => c.polyline(
                &[(sx0, cy), (sx1, cy)],
                w * s,
                col,
                Some((7.0 * s, 4.0 * s)),
                b,
            ),
            SeriesStyle::Markers(rad) => c.circle(
                (sx0 + sx1) / 2.0,
                cy,
                rad * s,
                Some(WHITE),
                Some((col, 1.3 * s)),
            ),
            SeriesStyle::Dots(rad) => c.circle(
                (sx0 + sx1) / 2.0,
                cy,
                (rad * s).max(2.5 * s),
                Some(col),
                None,
            ),
        }
        c.text(
            &sr.label,
            sx1 + 6.0 * s,
            cy,
            f.legend,
            HAlign::Left,
            VAlign::Middle,
            false,
        );
    }
}

// ---------------------------------------------------------------------------------------
// Scatter + power-law fit
// ---------------------------------------------------------------------------------------

/// `y = a·x^b` in SI units (e.g. spring force in N against depth in m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PowerLaw {
    /// Prefactor, SI (`N/m^b` for a force against a depth).
    pub a: f64,
    /// Exponent (1.5 for Hertz with a sphere; the paper finds 1.72).
    pub b: f64,
}

impl PowerLaw {
    /// `a·x^b`.
    pub fn eval(&self, x: f64) -> f64 {
        self.a * x.powf(self.b)
    }

    /// The prefactor when x and y are shown in display units `xu`, `yu`:
    /// `y/yu = a' · (x/xu)^b` with `a' = a · xu^b / yu`.
    pub fn prefactor_in(&self, xu: &DisplayUnit, yu: &DisplayUnit) -> f64 {
        self.a * xu.factor.powf(self.b) / yu.factor
    }
}

/// Least-squares fit of `y = a·x^b` on log–log axes, over the points with x > 0 and y > 0.
/// Returns the law and the coefficient of determination R² of the log–log line; `None` with
/// fewer than 2 usable points or no spread in x.
pub fn fit_power_law(points: &[(f64, f64)]) -> Option<(PowerLaw, f64)> {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|(x, y)| *x > 0.0 && *y > 0.0 && x.is_finite() && y.is_finite())
        .map(|(x, y)| (x.ln(), y.ln()))
        .collect();
    let n = pts.len() as f64;
    if pts.len() < 2 {
        return None;
    }
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let syy: f64 = pts.iter().map(|p| (p.1 - my).powi(2)).sum();
    if sxx <= 0.0 {
        return None;
    }
    let b = sxy / sxx;
    let a = (my - b * mx).exp();
    let r2 = if syy > 0.0 {
        (sxy * sxy) / (sxx * syy)
    } else {
        1.0
    };
    Some((PowerLaw { a, b }, r2))
}

/// Data points with an optional power-law fit, like the paper's Fig. 9 (spring force
/// against indentation depth).
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterFit {
    /// Title over the figure.
    pub title: Option<String>,
    /// x quantity (e.g. `δ`, `m`).
    pub x: Quantity,
    /// y quantity (e.g. `F_k`, `N`).
    pub y: Quantity,
    /// The data, SI.
    pub points: Vec<(f64, f64)>,
    /// Legend text of the data (e.g. "simulation").
    pub points_label: String,
    /// The fit to draw; its legend entry shows the law in display units.
    pub fit: Option<PowerLaw>,
    /// Log–log axes (a power law is a straight line there).
    pub log_log: bool,
    /// Frame size, px at scale 1.
    pub width: u32,
    /// Frame height, px at scale 1.
    pub height: u32,
    /// Multiplies every size.
    pub scale: f64,
}

impl Default for ScatterFit {
    fn default() -> Self {
        ScatterFit {
            title: None,
            x: Quantity::new("δ", "m"),
            y: Quantity::new("F", "N"),
            points: Vec::new(),
            points_label: "data".into(),
            fit: None,
            log_log: false,
            width: 520,
            height: 380,
            scale: 1.0,
        }
    }
}

/// The legend text of a fit: `fit: F = 1.60×10⁻³·δ^1.72 (F in nN, δ in nm)`.
pub fn power_law_label(
    fit: &PowerLaw,
    x: &Quantity,
    y: &Quantity,
    xu: &DisplayUnit,
    yu: &DisplayUnit,
) -> String {
    let a = fit.prefactor_in(xu, yu);
    let units = match (xu.label.is_empty(), yu.label.is_empty()) {
        (false, false) => format!(" ({} in {}, {} in {})", y.name, yu.label, x.name, xu.label),
        _ => String::new(),
    };
    format!(
        "fit: {} = {}·{}^{}{}",
        y.name,
        format_significant(a, 3),
        x.name,
        format_significant(fit.b, 3),
        units
    )
}

/// Draws a [`ScatterFit`] to `path` as PNG.
pub fn scatter_fit(path: &Path, plot: &ScatterFit) -> Result<()> {
    let c = render_scatter_fit(plot).map_err(|e| OutputError::new(path, e))?;
    save(path, &c)
}

fn render_scatter_fit(plot: &ScatterFit) -> std::result::Result<Canvas, String> {
    let many = plot.points.len() > 300;
    let data = Series {
        label: plot.points_label.clone(),
        points: plot.points.clone(),
        style: if many {
            SeriesStyle::Dots(1.6)
        } else {
            SeriesStyle::Markers(3.2)
        },
        color: Some(PALETTE[0]),
    };
    let mut series = vec![data];
    if let Some(fit) = plot.fit {
        let (lo, hi) = data_range(plot.points.iter().map(|p| p.0), true)
            .ok_or("a power-law fit needs points with x > 0")?;
        let xmax_u = display_unit(&plot.x.unit, hi);
        let ymax = data_range(plot.points.iter().map(|p| p.1), plot.log_log)
            .map(|r| r.1.abs().max(r.0.abs()))
            .unwrap_or(1.0);
        let yu = display_unit(&plot.y.unit, ymax);
        let lo = if plot.log_log { lo } else { lo.min(hi * 1e-3) };
        let n = 200;
        let pts = (0..=n)
            .map(|k| {
                let t = k as f64 / n as f64;
                let x = if plot.log_log {
                    (lo.ln() + t * (hi.ln() - lo.ln())).exp()
                } else {
                    lo + t * (hi - lo)
                };
                (x, fit.eval(x))
            })
            .collect();
        series.push(Series {
            label: power_law_label(&fit, &plot.x, &plot.y, &xmax_u, &yu),
            points: pts,
            style: SeriesStyle::Line(2.0),
            color: Some(PALETTE[1]),
        });
    }
    let lp = LinePlot {
        title: plot.title.clone(),
        x: plot.x.clone(),
        x_range: None,
        x_log: plot.log_log,
        panels: vec![LinePanel {
            y: plot.y.clone(),
            series,
            y_range: None,
            y_log: plot.log_log,
        }],
        width: plot.width,
        panel_height: plot.height,
        scale: plot.scale,
    };
    render_lines(&lp, true)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_law_fit_recovers_exponent() {
        let pts: Vec<(f64, f64)> = (1..50)
            .map(|k| {
                let d = k as f64 * 4e-9;
                (d, 1.6e-3 * 1e-9 * (d / 1e-9).powf(1.72))
            })
            .collect();
        let (law, r2) = fit_power_law(&pts).unwrap();
        assert!((law.b - 1.72).abs() < 1e-9 && r2 > 0.999_999);
        let nm = display_unit("m", 2e-7);
        let nn = display_unit("N", 1.5e-8);
        assert!((law.prefactor_in(&nm, &nn) - 1.6e-3).abs() < 1e-12);
        let label = power_law_label(
            &law,
            &Quantity::new("δ", "m"),
            &Quantity::new("F", "N"),
            &nm,
            &nn,
        );
        assert_eq!(label, "fit: F = 1.60×10⁻³·δ^1.72 (F in nN, δ in nm)");
    }
}
