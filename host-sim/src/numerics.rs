//! One-dimensional minimisation shared by identify and diagnose: golden-section search over
//! a bracket, and a grid scan refined by it.
//!
//! Hand-written (30 lines) rather than argmin's `GoldenSectionSearch`: that one starts from a
//! caller's interior estimate and stops on a tolerance, so it would not visit the points
//! diagnose's findings were pinned with (its Brent, tried for issue 15, moved them past the
//! pins); this is the textbook search, one new evaluation per iteration.

/// Golden ratio conjugate (√5 − 1)/2: the fraction of the bracket each reduction keeps.
const INV_PHI: f64 = 0.618_033_988_749_894_8;

/// The outcome of [`golden_section`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Golden {
    /// The best point evaluated and its value.
    pub x: f64,
    pub f: f64,
    /// The bracket after the last reduction (its width is `INV_PHI^iterations` of the first).
    pub bracket: (f64, f64),
    /// Evaluations of the function: `iterations + 1` (none for an empty bracket or none
    /// asked).
    pub evaluations: usize,
}

/// Golden-section search for a minimum of `f` on `[lo, hi]`: `iterations` reductions of the
/// bracket by `INV_PHI` each. The two interior points of the first bracket are evaluated,
/// then one new point per reduction (the other interior point is the kept one of the
/// previous bracket, reused), except after the last: `iterations + 1` evaluations, the same
/// points a search evaluating both interior points afresh each time visits (up to rounding)
/// in half the evaluations. Ties keep the upper part of the bracket. Non-finite values count
/// as worse than any finite one.
pub fn golden_section(
    lo: f64,
    hi: f64,
    iterations: usize,
    mut f: impl FnMut(f64) -> f64,
) -> Golden {
    let (mut a, mut b) = (lo, hi);
    let mut out = Golden {
        x: f64::NAN,
        f: f64::INFINITY,
        bracket: (a, b),
        evaluations: 0,
    };
    if !(b > a) || iterations == 0 {
        return out;
    }
    // NaN compares as +∞, so that `f1 < f2` below and the best point stay well defined.
    let mut eval = |x: f64, out: &mut Golden| -> f64 {
        let v = f(x);
        let v = if v.is_nan() { f64::INFINITY } else { v };
        out.evaluations += 1;
        if v < out.f || out.x.is_nan() {
            (out.x, out.f) = (x, v);
        }
        v
    };
    let (mut x1, mut x2) = (b - INV_PHI * (b - a), a + INV_PHI * (b - a));
    let (mut f1, mut f2) = (eval(x1, &mut out), eval(x2, &mut out));
    for i in 0..iterations {
        let last = i + 1 == iterations;
        if f1 < f2 {
            b = x2;
            if !last {
                (x2, f2) = (x1, f1);
                x1 = b - INV_PHI * (b - a);
                f1 = eval(x1, &mut out);
            }
        } else {
            a = x1;
            if !last {
                (x1, f1) = (x2, f2);
                x2 = a + INV_PHI * (b - a);
                f2 = eval(x2, &mut out);
            }
        }
    }
    out.bracket = (a, b);
    out
}

/// Minimum of `f` on `[lo, hi]`: a grid of `grid` intervals, then golden section between
/// the best grid point's neighbours (robust to a few local minima); the final bracket's
/// midpoint if it is no worse than the best grid point, else that point. 40 reductions leave
/// 0.618⁴⁰ ≈ 4·10⁻⁹ of the two grid intervals.
pub fn minimize(f: impl Fn(f64) -> f64, lo: f64, hi: f64, grid: usize) -> f64 {
    let grid = grid.max(1);
    let xs: Vec<f64> = (0..=grid)
        .map(|j| lo + (hi - lo) * j as f64 / grid as f64)
        .collect();
    let mut best = (f64::INFINITY, 0usize);
    for (j, &x) in xs.iter().enumerate() {
        let v = f(x);
        if v < best.0 {
            best = (v, j);
        }
    }
    let (a, b) = (xs[best.1.saturating_sub(1)], xs[(best.1 + 1).min(grid)]);
    let g = golden_section(a, b, 40, &f);
    let x = 0.5 * (g.bracket.0 + g.bracket.1);
    if f(x) <= best.0 {
        x
    } else {
        xs[best.1]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn golden_section_evaluates_once_per_reduction_and_brackets_the_minimum() {
        // A smooth asymmetric function with its minimum at x* = ln 3 (e^x − 3x).
        let x_star = 3f64.ln();
        for n in [1usize, 2, 5, 20, 40] {
            let mut seen = 0usize;
            let g = golden_section(-1.0, 4.0, n, |x| {
                seen += 1;
                x.exp() - 3.0 * x
            });
            assert_eq!(g.evaluations, n + 1, "n = {n}");
            assert_eq!(seen, n + 1, "n = {n}");
            // The bracket shrinks by the golden ratio each reduction (5 wide at the start)…
            let width = g.bracket.1 - g.bracket.0;
            let expected = 5.0 * INV_PHI.powi(n as i32);
            // (to the rounding of the ends, ~10⁻¹⁶ of the first bracket per reduction)
            assert!(
                (width - expected).abs() < 1e-14,
                "n = {n}: {width} vs {expected}"
            );
            // …and keeps the minimum of a unimodal function.
            assert!(
                g.bracket.0 <= x_star && x_star <= g.bracket.1,
                "n = {n}: {:?}",
                g.bracket
            );
            // The best point evaluated is the interior point the last reduction kept, so
            // within the last bracket's width of x* (f is unimodal).
            assert!((g.x - x_star).abs() <= width, "n = {n}: x {}", g.x);
        }
        // 40 reductions: x* to the bracket's width, 5·0.618⁴⁰ ≈ 2.2·10⁻⁸, and the value to
        // second order (f'' = 3 there: 3/2·(2.2·10⁻⁸)² ≈ 7·10⁻¹⁶ above f(x*), within the
        // rounding of f ≈ 0.3).
        let g = golden_section(-1.0, 4.0, 40, |x| x.exp() - 3.0 * x);
        assert!((g.x - x_star).abs() <= 5.0 * INV_PHI.powi(40), "{}", g.x);
        assert!((g.f - (3.0 - 3.0 * x_star)).abs() < 1e-14, "{}", g.f);
    }

    #[test]
    fn golden_section_visits_the_points_of_the_two_point_search() {
        // The search it replaced evaluated both interior points of every bracket; the points
        // this one evaluates are those, each once (to rounding).
        let f = |x: f64| (x - 0.3).abs() + 0.1 * (5.0 * x).sin();
        let (lo, hi, n) = (-2.0f64, 1.5f64, 12usize);
        let mut old = Vec::new();
        let (mut a, mut b) = (lo, hi);
        for _ in 0..n {
            let x1 = b - INV_PHI * (b - a);
            let x2 = a + INV_PHI * (b - a);
            old.push(x1);
            old.push(x2);
            if f(x1) < f(x2) {
                b = x2;
            } else {
                a = x1;
            }
        }
        let mut new = Vec::new();
        let g = golden_section(lo, hi, n, |x| {
            new.push(x);
            f(x)
        });
        for x in &old {
            assert!(new.iter().any(|y| (x - y).abs() < 1e-12), "{x} not visited");
        }
        assert_eq!(new.len(), n + 1);
        assert!((g.bracket.0 - a).abs() < 1e-12 && (g.bracket.1 - b).abs() < 1e-12);
    }

    #[test]
    fn golden_section_on_an_empty_bracket_or_nan_values() {
        let g = golden_section(1.0, 1.0, 10, |_| 0.0);
        assert_eq!(g.evaluations, 0);
        assert!(g.x.is_nan());
        // A function that is NaN right of 0.5: the search goes left, to the minimum at 0.2.
        let g = golden_section(0.0, 1.0, 30, |x| {
            if x > 0.5 {
                f64::NAN
            } else {
                (x - 0.2) * (x - 0.2)
            }
        });
        assert!((g.x - 0.2).abs() < 1e-5, "{}", g.x);
    }

    #[test]
    fn minimize_finds_the_global_minimum_among_local_ones() {
        // Local minima near every integer (the cosine's wells); the parabola centred on 2.3
        // makes the well near 2 the global one, 7.6·10⁻⁴ right of 2 (its pull over the
        // well's curvature 4π²: 0.03/39.5).
        let f = |x: f64| 0.05 * (x - 2.3) * (x - 2.3) - (2.0 * std::f64::consts::PI * x).cos();
        let x = minimize(f, -5.0, 8.0, 52);
        // The global minimum: f'(x) = 0.1(x − 2.3) + 2π sin 2πx = 0 near x = 2.
        let root = {
            let (mut lo, mut hi) = (1.9f64, 2.1f64);
            let df = |x: f64| {
                0.1 * (x - 2.3)
                    + 2.0 * std::f64::consts::PI * (2.0 * std::f64::consts::PI * x).sin()
            };
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if df(mid) > 0.0 {
                    hi = mid;
                } else {
                    lo = mid;
                }
            }
            0.5 * (lo + hi)
        };
        // Grid step 0.25: the bracket is 0.5 wide, cut to 0.5·0.618⁴⁰ ≈ 2·10⁻⁹.
        assert!((x - root).abs() < 5e-9, "{x} vs {root}");
    }
}
