//! Tick placement (1–2–5 steps, decades on log axes), tick-label formatting and the choice of
//! a display unit for SI values (nm, µm, ×10⁻⁷ N·s/m).

/// A physical quantity on an axis or colour bar: a symbol or name and its SI unit. Values are
/// always given in SI; the figure picks the display unit (see [`display_unit`]).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Quantity {
    /// Symbol or name: `"x"`, `"h"`, `"c"`, `"error"`, `"F"`, `"δ"`.
    pub name: String,
    /// SI unit: `"m"`, `"s"`, `"N"`, `"N·s/m"`, `"N/m"`, `"%"`, or empty.
    pub unit: String,
}

impl Quantity {
    /// A quantity `name` in `unit`.
    pub fn new(name: impl Into<String>, unit: impl Into<String>) -> Self {
        Quantity {
            name: name.into(),
            unit: unit.into(),
        }
    }
}

/// How values are shown: divide by `factor`, label with `label` (e.g. `1e-9`, `"nm"`).
#[derive(Debug, Clone, PartialEq)]
pub struct DisplayUnit {
    /// SI value / factor = displayed number.
    pub factor: f64,
    /// The unit text shown in parentheses after the name, e.g. `nm` or `×10⁻⁷ N·s/m`.
    pub label: String,
}

impl DisplayUnit {
    /// The axis title `name (label)`, or just `name` for a dimensionless quantity shown as is.
    pub fn title(&self, name: &str) -> String {
        if self.label.is_empty() {
            name.to_string()
        } else {
            format!("{name} ({})", self.label)
        }
    }
}

/// Superscript form of an integer: `-7` → `⁻⁷`.
pub fn superscript(n: i32) -> String {
    n.to_string()
        .chars()
        .map(|c| match c {
            '-' => '⁻',
            '0' => '⁰',
            '1' => '¹',
            '2' => '²',
            '3' => '³',
            '4' => '⁴',
            '5' => '⁵',
            '6' => '⁶',
            '7' => '⁷',
            '8' => '⁸',
            '9' => '⁹',
            c => c,
        })
        .collect()
}

/// Picks how to show values of `unit` whose magnitude reaches `max_abs`:
/// - `m`, `s`, `N`, `Pa`, `V`, `Hz`: an SI prefix that puts `max_abs` in [1, 1000)
///   (0.3 µm → nm; 5 µm → µm; 15 nN → nN);
/// - other units (`N·s/m`, `N/m`, ...): the paper's style, a power of ten taken out,
///   `×10ⁿ unit` with n = ⌊log₁₀ max_abs⌋ (8×10⁻⁷ N·s/m → `×10⁻⁷ N·s/m`), unless the
///   values are already between 0.1 and 1000;
/// - `%` and dimensionless: as is.
pub fn display_unit(unit: &str, max_abs: f64) -> DisplayUnit {
    let as_is = DisplayUnit {
        factor: 1.0,
        label: unit.to_string(),
    };
    if !(max_abs.is_finite() && max_abs > 0.0) {
        return as_is;
    }
    let e = max_abs.log10().floor() as i32;
    match unit {
        "%" | "" => {
            if (-2..4).contains(&e) || unit == "%" {
                as_is
            } else {
                DisplayUnit {
                    factor: 10f64.powi(e),
                    label: format!("×10{}", superscript(e)),
                }
            }
        }
        "m" | "s" | "N" | "Pa" | "V" | "Hz" | "A" | "J" | "W" => {
            const PREFIXES: [(i32, &str); 9] = [
                (-18, "a"),
                (-15, "f"),
                (-12, "p"),
                (-9, "n"),
                (-6, "µ"),
                (-3, "m"),
                (0, ""),
                (3, "k"),
                (6, "M"),
            ];
            let p = e.div_euclid(3) * 3;
            let p = p.clamp(-18, 6);
            let name = PREFIXES.iter().find(|(q, _)| *q == p).unwrap().1;
            DisplayUnit {
                factor: 10f64.powi(p),
                label: format!("{name}{unit}"),
            }
        }
        _ => {
            if (-1..3).contains(&e) {
                as_is
            } else {
                DisplayUnit {
                    factor: 10f64.powi(e),
                    label: format!("×10{} {unit}", superscript(e)),
                }
            }
        }
    }
}

/// Ticks of one axis: positions (in displayed units) and their labels.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Ticks {
    pub major: Vec<f64>,
    pub labels: Vec<String>,
    pub minor: Vec<f64>,
}

/// A "nice" step (1, 2 or 5 × 10ⁿ) giving at most about `max_ticks` ticks over `span`.
pub(crate) fn nice_step(span: f64, max_ticks: usize) -> f64 {
    let raw = span / max_ticks.max(1) as f64;
    let mag = 10f64.powf(raw.log10().floor());
    for m in [1.0, 2.0, 5.0, 10.0] {
        if m * mag >= raw * (1.0 - 1e-9) {
            return m * mag;
        }
    }
    10.0 * mag
}

/// Linear ticks over `[lo, hi]` with a 1–2–5 step, the finest step that gives at most
/// `max_ticks` ticks inside the range, labelled with the fewest decimals the step needs, with
/// a true minus.
pub(crate) fn linear_ticks(lo: f64, hi: f64, max_ticks: usize) -> Ticks {
    let count = |step: f64| {
        ((hi / step + 1e-9).floor() - (lo / step - 1e-9).ceil() + 1.0).max(0.0) as usize
    };
    let mut step = nice_step(hi - lo, max_ticks);
    // nice_step is conservative; try the next finer 1-2-5 steps while they still fit.
    for _ in 0..2 {
        let m = (step / 10f64.powf(step.log10().floor())).round();
        let finer = step * if m == 5.0 { 0.4 } else { 0.5 };
        if count(finer) <= max_ticks && count(finer) >= 2 {
            step = finer;
        } else {
            break;
        }
    }
    let eps = step * 1e-9;
    let first = (lo / step - 1e-9).ceil() as i64;
    let last = (hi / step + 1e-9).floor() as i64;
    let major: Vec<f64> = (first..=last)
        .map(|k| {
            let v = k as f64 * step;
            if v.abs() < eps {
                0.0
            } else {
                v
            }
        })
        .collect();
    let decimals = (-step.log10().floor()).max(0.0) as usize;
    let labels = major.iter().map(|&v| format_number(v, decimals)).collect();
    // Minor ticks: 5 per major step for a 1 or 5 step, 4 for a 2 step.
    let m = (step / 10f64.powf(step.log10().floor())).round();
    let sub = if m == 2.0 { 4 } else { 5 };
    let mstep = step / sub as f64;
    let mfirst = (lo / mstep - 1e-9).ceil() as i64;
    let mlast = (hi / mstep + 1e-9).floor() as i64;
    let minor = (mfirst..=mlast)
        .map(|k| k as f64 * mstep)
        .filter(|v| major.iter().all(|m| (m - v).abs() > mstep * 1e-6))
        .collect();
    Ticks {
        major,
        labels,
        minor,
    }
}

/// Log ticks over `[lo, hi]` (both > 0): every decade labelled `10ⁿ` (or every 2nd, 3rd...
/// decade when there are many), minor ticks at 2–9 × 10ⁿ. Where the range spans less than a
/// decade, falls back to 1–2–5 labels inside it.
pub(crate) fn log_ticks(lo: f64, hi: f64) -> Ticks {
    let (a, b) = (lo.log10(), hi.log10());
    let (d0, d1) = ((a - 1e-9).ceil() as i32, (b + 1e-9).floor() as i32);
    let mut minor = Vec::new();
    for d in (a.floor() as i32)..=(b.ceil() as i32) {
        for m in 2..10 {
            let v = m as f64 * 10f64.powi(d);
            if v >= lo && v <= hi {
                minor.push(v);
            }
        }
    }
    if d1 - d0 < 1 {
        // Less than two decade ticks: label 1, 2, 5 × 10ⁿ inside the range.
        let mut major = Vec::new();
        for d in (a.floor() as i32)..=(b.ceil() as i32) {
            for m in [1.0, 2.0, 5.0] {
                let v = m * 10f64.powi(d);
                if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                    major.push(v);
                }
            }
        }
        let labels = major
            .iter()
            .map(|&v| {
                let dec = (-v.log10().floor()).max(0.0) as usize;
                format_number(v, dec)
            })
            .collect();
        minor.retain(|v| major.iter().all(|m| (m - v).abs() > 1e-9 * v));
        return Ticks {
            major,
            labels,
            minor,
        };
    }
    let every = ((d1 - d0) as usize / 6 + 1) as i32;
    let major: Vec<f64> = (d0..=d1)
        .filter(|d| (d - d0) % every == 0)
        .map(|d| 10f64.powi(d))
        .collect();
    let labels = major
        .iter()
        .map(|&v| {
            let d = v.log10().round() as i32;
            match d {
                0 => "1".to_string(),
                1 => "10".to_string(),
                _ => format!("10{}", superscript(d)),
            }
        })
        .collect();
    if every > 1 {
        minor.clear();
    }
    Ticks {
        major,
        labels,
        minor,
    }
}

/// `v` with `decimals` digits after the point and a typographic minus (U+2212).
pub(crate) fn format_number(v: f64, decimals: usize) -> String {
    let s = format!("{:.*}", decimals, v);
    let s = if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    };
    s.replace('-', "−")
}

/// A value with 3 significant digits in the paper's style: `1.60×10⁻³`, `1.72`, `15.0`.
pub fn format_significant(v: f64, digits: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return format_number(v, 0);
    }
    let e = v.abs().log10().floor() as i32;
    if (-2..4).contains(&e) {
        let dec = (digits as i32 - 1 - e).max(0) as usize;
        format_number(v, dec)
    } else {
        let m = v / 10f64.powi(e);
        format!(
            "{}×10{}",
            format_number(m, digits.saturating_sub(1)),
            superscript(e)
        )
    }
}

/// Widens a degenerate or NaN range into something drawable.
pub(crate) fn sane_range(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi > lo {
        return (lo, hi);
    }
    let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.05 };
    (lo - d, hi + d)
}

/// Extends `[lo, hi]` outward to the nearest ticks of a 1–2–5 step, the way the y range of a
/// line plot is chosen, so the frame starts and ends on a labelled tick.
pub(crate) fn round_out(lo: f64, hi: f64, max_ticks: usize) -> (f64, f64) {
    let (lo, hi) = sane_range(lo, hi);
    let step = nice_step(hi - lo, max_ticks);
    let a = (lo / step + 1e-9).floor() * step;
    let b = (hi / step - 1e-9).ceil() * step;
    (a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_1_2_5() {
        assert_eq!(nice_step(5.0, 6), 1.0);
        assert_eq!(nice_step(0.3, 6), 0.05);
        assert_eq!(nice_step(8.0, 5), 2.0);
        let t = linear_ticks(0.0, 5.0, 6);
        assert_eq!(t.labels, ["0", "1", "2", "3", "4", "5"]);
        let t = linear_ticks(-5.0, 5.0, 6);
        assert_eq!(t.labels, ["−4", "−2", "0", "2", "4"]);
        let t = linear_ticks(4.0, 8.0, 6);
        assert_eq!(t.labels, ["4", "5", "6", "7", "8"]);
        let t = linear_ticks(0.0, 0.3, 6);
        assert_eq!(
            t.labels,
            ["0.00", "0.05", "0.10", "0.15", "0.20", "0.25", "0.30"]
        );
    }

    #[test]
    fn display_units() {
        assert_eq!(display_unit("m", 3e-7).label, "nm");
        assert_eq!(display_unit("m", 5e-6).label, "µm");
        assert_eq!(display_unit("N·s/m", 8e-7).label, "×10⁻⁷ N·s/m");
        assert_eq!(display_unit("N/m", 5e-3).label, "×10⁻³ N/m");
        assert_eq!(display_unit("%", 4.0).label, "%");
        assert_eq!(display_unit("N", 1.5e-8).label, "nN");
        assert_eq!(display_unit("m", 3e-7).title("h"), "h (nm)");
    }

    #[test]
    fn log_decades() {
        let t = log_ticks(1e-9, 1e-6);
        assert_eq!(t.labels, ["10⁻⁹", "10⁻⁸", "10⁻⁷", "10⁻⁶"]);
        let t = log_ticks(20.0, 80.0);
        assert_eq!(t.labels, ["20", "50"]);
    }

    #[test]
    fn numbers() {
        assert_eq!(format_number(-0.0, 1), "0.0");
        assert_eq!(format_significant(1.6e-3, 3), "1.60×10⁻³");
        assert_eq!(format_significant(1.7234, 3), "1.72");
        assert_eq!(round_out(0.3, 9.7, 6), (0.0, 10.0));
    }
}
