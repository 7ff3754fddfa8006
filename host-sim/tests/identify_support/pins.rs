//! Pinning the figures the README quotes: a figure is written as the README writes it (a
//! string, so its last digit is known), and a measured value matches it when it lies within
//!
//!   max(half a unit of the quoted last digit, 3 standard errors from the recording's noise).
//!
//! The first term says the README's rounding is right; the second lets a re-measure move a
//! figure by what the noise makes indistinguishable, and no further. The standard errors are
//! computed by each test from the noise the tools measure; this module knows no physics.

/// Half a unit of the last digit of a quoted figure ("24" → 0.5, "2.1" → 0.05,
/// "0.030" → 0.0005, "−5.3" → 0.05, "0" → 0).
/// A quoted "0" is a value at its bound (a damping clamped at zero): no digit to round, so
/// only the noise's tolerance applies.
pub fn half_unit(quoted: &str) -> f64 {
    let t = quoted.trim();
    if t == "0" {
        return 0.0;
    }
    let decimals = t.split_once('.').map_or(0, |(_, f)| f.len());
    0.5 * 10f64.powi(-(decimals as i32))
}

/// A quoted figure as a number ("−" accepted for the minus sign).
pub fn value(quoted: &str) -> f64 {
    quoted
        .trim()
        .replace('−', "-")
        .parse()
        .unwrap_or_else(|_| panic!("quoted figure {quoted:?} is not a number"))
}

/// Collects the comparisons of one test, so that a failure lists every figure that moved.
#[derive(Default)]
pub struct Pins {
    lines: Vec<String>,
    failures: usize,
}

impl Pins {
    /// Compares `measured` (in the quoted figure's unit) with `quoted`, given the measured
    /// value's standard error `se` from the noise (same unit).
    pub fn check(&mut self, what: &str, quoted: &str, measured: f64, se: f64) {
        let tol = half_unit(quoted).max(3.0 * se);
        let ok = (measured - value(quoted)).abs() <= tol;
        self.failures += usize::from(!ok);
        self.lines.push(format!(
            "{} {what}: README {quoted}, measured {measured:.4} (tolerance ±{tol:.3}: half a \
             digit {:.3}, 3 SE from the noise {:.3})",
            if ok { "  ok  " } else { "MOVED " },
            half_unit(quoted),
            3.0 * se
        ));
    }

    /// An exact expectation (a name, a count).
    pub fn equal(&mut self, what: &str, quoted: &str, measured: &str) {
        let ok = quoted == measured;
        self.failures += usize::from(!ok);
        self.lines.push(format!(
            "{} {what}: README {quoted}, measured {measured}",
            if ok { "  ok  " } else { "MOVED " }
        ));
    }

    /// Prints every comparison and fails if any figure moved.
    pub fn finish(self, name: &str) {
        for l in &self.lines {
            println!("{name}: {l}");
        }
        assert_eq!(
            self.failures, 0,
            "{name}: {} figure(s) quoted in README.md moved beyond their tolerance (MOVED \
             lines above): re-measure and update the expected table and README.md together",
            self.failures
        );
    }
}
