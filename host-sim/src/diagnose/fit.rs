//! Least squares for the model's parameters: Levenberg–Marquardt on scaled parameters with
//! box bounds, the Jacobian by forward differences of whole simulations.
//!
//! A parameter is searched in a scaled coordinate `x = value/scale` (or `ln(value)/scale` for
//! positive quantities spanning decades, such as a bed stiffness or a relaxation time), so
//! that one unit of x is a comparable change for every parameter and the finite-difference
//! step can be the same. Bounds are kept by clamping each trial point (projected LM); a
//! parameter pinned at a bound keeps its column, so the step is still solved jointly.
//!
//! Every linear solve is a Householder QR (nalgebra) of the least-squares matrix itself, not
//! of its normal equations: the columns span many decades (a bed stiffness in nN/nm³ beside a
//! height in nm), and forming `JᵀJ` would square that condition number.

use nalgebra::{DMatrix, DVector};

/// One parameter of a fit.
#[derive(Clone, Debug, PartialEq)]
pub struct Param {
    /// Name (with its unit) for reports.
    pub name: String,
    /// Current value.
    pub value: f64,
    /// Bounds (inclusive).
    pub lo: f64,
    pub hi: f64,
    /// Typical change: one unit of the scaled coordinate.
    pub scale: f64,
    /// Searched as `ln(value)` (value > 0).
    pub log: bool,
    /// Held fixed.
    pub fixed: bool,
}

impl Param {
    /// A linear parameter.
    pub fn linear(name: impl Into<String>, value: f64, lo: f64, hi: f64, scale: f64) -> Self {
        Param {
            name: name.into(),
            value: value.clamp(lo, hi),
            lo,
            hi,
            scale: scale.abs().max(1e-300),
            log: false,
            fixed: false,
        }
    }
    /// A positive parameter searched in `ln`, `scale` in e-folds.
    pub fn logarithmic(name: impl Into<String>, value: f64, lo: f64, hi: f64) -> Self {
        Param {
            name: name.into(),
            value: value.clamp(lo, hi),
            lo,
            hi,
            scale: 1.0,
            log: true,
            fixed: false,
        }
    }
    /// The same, held fixed.
    pub fn fixed(mut self) -> Self {
        self.fixed = true;
        self
    }
    fn to_x(&self, v: f64) -> f64 {
        if self.log {
            v.max(1e-300).ln() / self.scale
        } else {
            v / self.scale
        }
    }
    fn value_at(&self, x: f64) -> f64 {
        let v = if self.log {
            (x * self.scale).exp()
        } else {
            x * self.scale
        };
        v.clamp(self.lo, self.hi)
    }
}

/// The outcome of [`levenberg_marquardt`].
#[derive(Clone, Debug)]
pub struct LmResult {
    /// Sum of squared residuals at the end.
    pub ssr: f64,
    /// Iterations done.
    pub iterations: usize,
    /// Residual evaluations (each a simulation unless the caller reuses one).
    pub evaluations: usize,
    /// Whether it stopped on the tolerance (not the iteration cap).
    pub converged: bool,
}

/// Options of [`levenberg_marquardt`].
#[derive(Clone, Copy, Debug)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the SSR by less than this fraction.
    pub tolerance: f64,
    /// Finite-difference step in the scaled coordinate.
    pub step: f64,
    /// `(n, bar)`: stop after `n` iterations when the SSR is still at or above `bar` (a start
    /// that has not beaten what the caller already has is not worth the rest).
    pub give_up: Option<(usize, f64)>,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 30,
            tolerance: 1e-7,
            step: 1e-4,
            give_up: None,
        }
    }
}

/// Sum of squares.
pub fn ssr(r: &[f64]) -> f64 {
    r.iter().map(|x| x * x).sum()
}

/// Minimises `Σ r²` of `residuals(values)` over the free parameters, updating `params`.
/// `residuals` returns `None` where the model cannot be evaluated (a step there is refused).
pub fn levenberg_marquardt(
    params: &mut [Param],
    opts: &LmOptions,
    mut residuals: impl FnMut(&[f64]) -> Option<Vec<f64>>,
) -> LmResult {
    let free: Vec<usize> = (0..params.len()).filter(|&i| !params[i].fixed).collect();
    let values = |ps: &[Param]| ps.iter().map(|p| p.value).collect::<Vec<f64>>();
    let mut evaluations = 1;
    let Some(mut r) = residuals(&values(params)) else {
        return LmResult {
            ssr: f64::INFINITY,
            iterations: 0,
            evaluations,
            converged: false,
        };
    };
    let mut cost = ssr(&r);
    let np = free.len();
    if np == 0 || r.is_empty() {
        return LmResult {
            ssr: cost,
            iterations: 0,
            evaluations,
            converged: true,
        };
    }
    let mut lambda = 1e-3;
    let mut converged = false;
    let mut iterations = 0;
    while iterations < opts.max_iterations {
        iterations += 1;
        // Jacobian of the residuals in the scaled coordinates.
        let mut jac: Vec<Vec<f64>> = Vec::with_capacity(np);
        for &i in &free {
            let p = &params[i];
            let x0 = p.to_x(p.value);
            // Step away from the nearer bound so the probe stays inside.
            let mut h = opts.step;
            let mut probe = p.value_at(x0 + h);
            if probe == p.value {
                h = -h;
                probe = p.value_at(x0 + h);
            }
            let mut trial = values(params);
            trial[i] = probe;
            evaluations += 1;
            let col = match residuals(&trial) {
                Some(rp) => {
                    let hx = p.to_x(probe) - x0;
                    if hx == 0.0 {
                        vec![0.0; r.len()]
                    } else {
                        rp.iter().zip(&r).map(|(a, b)| (a - b) / hx).collect()
                    }
                }
                None => vec![0.0; r.len()],
            };
            jac.push(col);
        }
        // The damped step minimises ‖Jδ + r‖² + λ·Σ d_k δ_k² with d_k = ‖J_k‖² (+1e-12 so a
        // column that does not move the residual stays bounded): the normal equations
        // (JᵀJ + λD)δ = −Jᵀr, solved without forming JᵀJ. J = QR once per Jacobian; then per
        // λ only the small stacked system [R; √(λD)] δ ≈ [−Qᵀr; 0] (MINPACK's lmpar idea).
        let n = r.len();
        let j = DMatrix::from_fn(n, np, |i, k| jac[k][i]);
        let d: Vec<f64> = (0..np)
            .map(|k| {
                let dk = j.column(k).norm_squared();
                dk + 1e-12 * (1.0 + dk)
            })
            .collect();
        let qr = j.qr();
        let r_factor = qr.r();
        let mut qtr = DVector::from_column_slice(&r);
        qr.q_tr_mul(&mut qtr);
        let rows = r_factor.nrows();
        let mut improved = false;
        for _ in 0..12 {
            let mut a = DMatrix::zeros(rows + np, np);
            a.rows_mut(0, rows).copy_from(&r_factor);
            let mut rhs = DVector::zeros(rows + np);
            for i in 0..rows {
                rhs[i] = -qtr[i];
            }
            for (k, dk) in d.iter().enumerate() {
                a[(rows + k, k)] = (lambda * dk).sqrt();
            }
            let Some(delta) = qr_least_squares(a, rhs) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial_params = params.to_vec();
            for (k, &i) in free.iter().enumerate() {
                let p = &trial_params[i];
                let v = p.value_at(p.to_x(p.value) + delta[k]);
                trial_params[i].value = v;
            }
            evaluations += 1;
            if let Some(rt) = residuals(&values(&trial_params)) {
                let ct = ssr(&rt);
                if ct < cost {
                    let gain = (cost - ct) / cost.max(1e-300);
                    params.clone_from_slice(&trial_params);
                    r = rt;
                    cost = ct;
                    lambda = (lambda * 0.3).max(1e-9);
                    improved = true;
                    if gain < opts.tolerance {
                        converged = true;
                    }
                    break;
                }
            }
            lambda *= 10.0;
        }
        if !improved {
            converged = true;
            break;
        }
        if converged {
            break;
        }
        if opts
            .give_up
            .is_some_and(|(n, bar)| iterations >= n && cost >= bar)
        {
            break;
        }
    }
    LmResult {
        ssr: cost,
        iterations,
        evaluations,
        converged,
    }
}

/// Least squares `min ‖b − A·x‖` of a tall matrix by Householder QR; `None` when `A` has fewer
/// rows than columns, a zero on R's diagonal (a column that the others repeat exactly) or a
/// result that is not finite.
fn qr_least_squares(a: DMatrix<f64>, mut b: DVector<f64>) -> Option<DVector<f64>> {
    let p = a.ncols();
    if a.nrows() < p {
        return None;
    }
    let qr = a.qr();
    qr.q_tr_mul(&mut b);
    let x = qr.r().solve_upper_triangular(&b.rows(0, p))?;
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Ridge of the linear least squares, relative to each column's squared norm: 1e-12, as the
/// normal-equation solver this replaced had. It only matters for columns that nearly repeat
/// one another (an effect's amplitude column beside a calibration's), which it keeps bounded.
const RIDGE: f64 = 1e-12;

/// Linear least squares `min ‖y − X·β‖` with `β_j ≥ 0` where `nonneg[j]`; columns given as
/// vectors. Returns β and the residual sum of squares `‖y − X·β‖²`. The general form of
/// [`LeastSquaresBase::solve`], with no base columns.
pub fn linear_least_squares(cols: &[Vec<f64>], y: &[f64], nonneg: &[bool]) -> (Vec<f64>, f64) {
    LeastSquaresBase::new(&[], y).solve(cols, nonneg)
}

/// Columns of a linear least-squares problem factored once, to which problems add a few
/// columns of their own: a screen's base Jacobian (a dozen columns of 100 000 rows), beside
/// which each of ~100 grid points brings one or two amplitude columns. The base's Householder
/// QR (nalgebra) is taken once; a problem then costs its own columns' projections on the
/// base's Q and a QR of what is left of them, not a QR of every column (measured: most of a
/// diagnosis's linear algebra was the screens' repeated QRs of the same Jacobian).
///
/// Every column is scaled to unit norm (so a column's scale does not matter) and given its
/// [`RIDGE`] row. With Q = [Q₁ Q₂] orthonormal over the columns' span and R the combined
/// triangle, `‖y − A·x‖² = ‖Qᵀy − R·x‖² + ‖y⊥‖²` (y⊥: what no column reaches), so the
/// active-set iterations run on the small triangle alone.
pub struct LeastSquaresBase {
    y: Vec<f64>,
    /// Each base column's norm; a zero or non-finite column takes no part (β = 0).
    norms: Vec<f64>,
    /// Indices of the base columns that take part.
    usable: Vec<usize>,
    /// Thin Q of the usable unit-norm base columns over the data rows and their ridge rows
    /// (row m + k for the k-th usable column).
    q: DMatrix<f64>,
    /// R of the same.
    r: DMatrix<f64>,
    /// Q₁ᵀy.
    g: DVector<f64>,
    /// y − Q₁Q₁ᵀy over the same rows.
    y_perp: DVector<f64>,
}

/// Euclidean norm.
fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

impl LeastSquaresBase {
    /// Factors the base columns `cols` (each as long as `y`; their coefficients are not
    /// constrained) for data `y`.
    pub fn new(cols: &[Vec<f64>], y: &[f64]) -> Self {
        let m = y.len();
        let norms: Vec<f64> = cols.iter().map(|c| norm(c)).collect();
        let usable: Vec<usize> = (0..cols.len())
            .filter(|&j| norms[j].is_finite() && norms[j] > 0.0)
            .collect();
        let p = usable.len();
        let a = DMatrix::from_fn(m + p, p, |i, k| {
            let j = usable[k];
            if i < m {
                cols[j].get(i).copied().unwrap_or(0.0) / norms[j]
            } else if i - m == k {
                RIDGE.sqrt()
            } else {
                0.0
            }
        });
        let mut yb = DVector::zeros(m + p);
        yb.rows_mut(0, m).copy_from_slice(y);
        let (q, r) = if p > 0 {
            let qr = a.qr();
            (qr.q(), qr.r())
        } else {
            (DMatrix::zeros(m, 0), DMatrix::zeros(0, 0))
        };
        let g = q.tr_mul(&yb);
        let y_perp = &yb - &q * &g;
        LeastSquaresBase {
            y: y.to_vec(),
            norms,
            usable,
            q,
            r,
            g,
            y_perp,
        }
    }

    /// The data y.
    pub fn y(&self) -> &[f64] {
        &self.y
    }

    /// The number of base columns.
    pub fn columns(&self) -> usize {
        self.norms.len()
    }

    /// `min ‖y − [X_base X]·β‖` with `β_j ≥ 0` where `nonneg[j]` for the added columns `cols`
    /// (the base's coefficients are free): β over the base's columns then these, and the
    /// residual sum of squares over the data rows.
    ///
    /// Lawson and Hanson's active-set NNLS (Solving Least Squares Problems, 1974, ch. 23),
    /// generalised to columns without a constraint (always in the passive set): a constrained
    /// coefficient enters when the gradient asks for it and leaves when an interpolation step
    /// brings it to zero, and can come back later — the true constrained optimum, not the
    /// "drop the first negative and re-solve" approximation. Each subproblem is a QR of the
    /// combined triangle's passive columns.
    pub fn solve(&self, cols: &[Vec<f64>], nonneg: &[bool]) -> (Vec<f64>, f64) {
        debug_assert_eq!(nonneg.len(), cols.len(), "one flag per added column");
        let m = self.y.len();
        let (nb, pb) = (self.norms.len(), self.usable.len());
        let rows_b = m + pb;
        let extra_norms: Vec<f64> = cols.iter().map(|c| norm(c)).collect();
        let extra: Vec<usize> = (0..cols.len())
            .filter(|&j| extra_norms[j].is_finite() && extra_norms[j] > 0.0)
            .collect();
        let pe = extra.len();
        let p = pb + pe;
        // The added columns less their projections on Q₁ (twice where the first pass removed
        // most of a column, Daniel–Gragg–Kaufman–Stewart's test), over the data rows, the
        // base's ridge rows and then their own ridge rows.
        let mut b = DMatrix::zeros(rows_b + pe, pe);
        let mut c = DMatrix::zeros(pb, pe);
        for (k, &j) in extra.iter().enumerate() {
            let mut a = DVector::zeros(rows_b);
            for (i, v) in cols[j].iter().take(m).enumerate() {
                a[i] = v / extra_norms[j];
            }
            if pb > 0 {
                let before = a.norm();
                let mut ck = self.q.tr_mul(&a);
                a -= &self.q * &ck;
                if a.norm() < std::f64::consts::FRAC_1_SQRT_2 * before {
                    let again = self.q.tr_mul(&a);
                    a -= &self.q * &again;
                    ck += again;
                }
                c.set_column(k, &ck);
            }
            b.view_mut((0, k), (rows_b, 1)).copy_from(&a);
            b[(rows_b + k, k)] = RIDGE.sqrt();
        }
        let (g2, r2, rest) = if pe > 0 {
            let qr = b.qr();
            let q2 = qr.q();
            let mut yp = DVector::zeros(rows_b + pe);
            yp.rows_mut(0, rows_b).copy_from(&self.y_perp);
            let g2 = q2.tr_mul(&yp);
            let rest = (&yp - &q2 * &g2).norm_squared();
            (g2, qr.r(), rest)
        } else {
            (
                DVector::zeros(0),
                DMatrix::zeros(0, 0),
                self.y_perp.norm_squared(),
            )
        };
        // The combined triangle [R₁ C; 0 R₂] and Qᵀy.
        let mut r = DMatrix::zeros(p, p);
        r.view_mut((0, 0), (pb, pb)).copy_from(&self.r);
        r.view_mut((0, pb), (pb, pe)).copy_from(&c);
        r.view_mut((pb, pb), (pe, pe)).copy_from(&r2);
        let mut g = DVector::zeros(p);
        g.rows_mut(0, pb).copy_from(&self.g);
        g.rows_mut(pb, pe).copy_from(&g2);
        let constrained: Vec<bool> = (0..p)
            .map(|k| k >= pb && nonneg.get(extra[k - pb]).copied().unwrap_or(false))
            .collect();
        // A gradient component below this is rounding: 10·ε·max(m, p)·‖y‖ (scipy's nnls uses
        // the same form of tolerance).
        let tol = 10.0 * f64::EPSILON * (m.max(nb + cols.len()) as f64) * norm(&self.y);
        let x = active_set(&r, &g, &constrained, tol);
        // ‖y − A·x‖² less the ridge rows' share.
        let fit = (&g - &r * &x).norm_squared() + rest - RIDGE * x.norm_squared();
        let mut beta = vec![0.0; nb + cols.len()];
        for (k, &j) in self.usable.iter().enumerate() {
            beta[j] = x[k] / self.norms[j];
        }
        for (k, &j) in extra.iter().enumerate() {
            beta[nb + j] = x[pb + k] / extra_norms[j];
        }
        (beta, fit.max(0.0))
    }
}

/// The active-set iterations of [`LeastSquaresBase::solve`] on the triangle `r` and `g` =
/// Qᵀy: x minimising `‖g − R·x‖` with `x_k ≥ 0` where `constrained[k]`.
fn active_set(r: &DMatrix<f64>, g: &DVector<f64>, constrained: &[bool], tol: f64) -> DVector<f64> {
    let p = r.ncols();
    // Solve on the passive set `set`, zeros elsewhere.
    let solve_on = |set: &[usize]| -> Option<Vec<f64>> {
        let mut x = vec![0.0; p];
        if set.is_empty() {
            return Some(x);
        }
        let z = qr_least_squares(r.select_columns(set.iter()), g.clone())?;
        for (k, &j) in set.iter().enumerate() {
            x[j] = z[k];
        }
        Some(x)
    };
    // Start: every unconstrained column passive, every constrained one at zero (feasible).
    let mut passive: Vec<usize> = (0..p).filter(|&j| !constrained[j]).collect();
    let mut x = solve_on(&passive).unwrap_or_else(|| vec![0.0; p]);
    // Coefficients that entered and were refused at once (a step of zero length): not offered
    // again until x moves, so the loop cannot cycle on a degenerate column.
    let mut refused = vec![false; p];
    // Each outer step adds one coefficient; Lawson and Hanson bound it by 3p in practice.
    for _ in 0..3 * p + 3 {
        // The gradient Aᵀ(y − A·x) = Rᵀ(Qᵀy − R·x).
        let w = r.tr_mul(&(g - r * DVector::from_column_slice(&x)));
        let enter = (0..p)
            .filter(|&j| constrained[j] && !refused[j] && !passive.contains(&j))
            .max_by(|&i, &j| w[i].total_cmp(&w[j]));
        let Some(t) = enter.filter(|&t| w[t] > tol) else {
            break;
        };
        passive.push(t);
        // Inner loop: at most every constrained coefficient leaves once.
        let mut moved = false;
        for _ in 0..=p {
            let Some(z) = solve_on(&passive) else {
                passive.retain(|&j| j != t);
                refused[t] = true;
                break;
            };
            let blocking: Vec<usize> = passive
                .iter()
                .copied()
                .filter(|&j| constrained[j] && z[j] <= 0.0)
                .collect();
            if blocking.is_empty() {
                moved = true;
                x = z;
                break;
            }
            // Step from x towards z as far as feasibility allows, then release every
            // constrained coefficient that reached zero.
            let (mut alpha, mut first) = (f64::INFINITY, blocking[0]);
            for &j in &blocking {
                let s = x[j] / (x[j] - z[j]);
                if s < alpha {
                    (alpha, first) = (s, j);
                }
            }
            let alpha = alpha.clamp(0.0, 1.0);
            for &j in &passive {
                x[j] += alpha * (z[j] - x[j]);
            }
            if alpha > 0.0 {
                moved = true;
            }
            x[first] = 0.0;
            passive.retain(|&j| !(constrained[j] && (j == first || x[j] <= 0.0)));
            for j in 0..p {
                if !passive.contains(&j) && constrained[j] {
                    x[j] = 0.0;
                }
            }
        }
        if moved {
            refused.iter_mut().for_each(|r| *r = false);
        } else if !passive.contains(&t) {
            refused[t] = true;
        }
    }
    DVector::from_vec(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A decaying exponential's amplitude, rate and offset from exact data, with the rate
    /// searched in ln and an offset bound that is not active.
    #[test]
    fn fits_an_exponential() {
        let t: Vec<f64> = (0..200).map(|i| i as f64 * 0.01).collect();
        let truth = [2.5, 3.0, -0.4];
        let y: Vec<f64> = t
            .iter()
            .map(|&x| truth[0] * (-truth[1] * x).exp() + truth[2])
            .collect();
        let mut ps = vec![
            Param::linear("a", 1.0, -10.0, 10.0, 1.0),
            Param::logarithmic("k", 0.5, 1e-3, 1e3),
            Param::linear("c", 0.0, -1.0, 1.0, 0.1),
        ];
        let res = levenberg_marquardt(&mut ps, &LmOptions::default(), |v| {
            Some(
                t.iter()
                    .zip(&y)
                    .map(|(&x, &yy)| yy - (v[0] * (-v[1] * x).exp() + v[2]))
                    .collect(),
            )
        });
        assert!(res.ssr < 1e-16, "{res:?}");
        for (p, tv) in ps.iter().zip(truth) {
            assert!(
                (p.value - tv).abs() < 1e-6,
                "{} = {} (truth {tv})",
                p.name,
                p.value
            );
        }
    }

    /// `give_up` stops a fit that has not reached its bar after the given iterations, and
    /// leaves one that reaches it on the same path as without the option.
    #[test]
    fn gives_up_only_above_the_bar() {
        let t: Vec<f64> = (0..200).map(|i| i as f64 * 0.01).collect();
        let y: Vec<f64> = t.iter().map(|&x| 2.5 * (-3.0 * x).exp() - 0.4).collect();
        let fit = |give_up: Option<(usize, f64)>| {
            let mut ps = vec![
                Param::linear("a", 1.0, -10.0, 10.0, 1.0),
                Param::logarithmic("k", 0.5, 1e-3, 1e3),
                Param::linear("c", 0.0, -1.0, 1.0, 0.1),
            ];
            let opts = LmOptions {
                give_up,
                ..LmOptions::default()
            };
            let res = levenberg_marquardt(&mut ps, &opts, |v| {
                Some(
                    t.iter()
                        .zip(&y)
                        .map(|(&x, &yy)| yy - (v[0] * (-v[1] * x).exp() + v[2]))
                        .collect(),
                )
            });
            (res, ps[1].value)
        };
        let (free, k_free) = fit(None);
        assert!(free.iterations > 2, "{free:?}");
        // A bar no fit reaches: two iterations, then it stops, well short of the optimum.
        let (stopped, _) = fit(Some((2, 0.0)));
        assert_eq!(stopped.iterations, 2, "{stopped:?}");
        assert!(
            stopped.ssr > 1e3 * free.ssr.max(1e-30),
            "{stopped:?} vs {free:?}"
        );
        // A bar every iterate is below: bit for bit the free fit.
        let (kept, k_kept) = fit(Some((2, f64::INFINITY)));
        assert_eq!(kept.evaluations, free.evaluations);
        assert_eq!(k_kept.to_bits(), k_free.to_bits());
    }

    /// A bound holds: the best value outside it ends on the bound.
    #[test]
    fn respects_bounds() {
        let mut ps = vec![Param::linear("a", 0.5, 0.0, 1.0, 1.0)];
        let res = levenberg_marquardt(&mut ps, &LmOptions::default(), |v| Some(vec![v[0] - 3.0]));
        assert_eq!(ps[0].value, 1.0);
        assert!((res.ssr - 4.0).abs() < 1e-12);
    }

    #[test]
    fn nonnegative_least_squares_drops_a_negative_coefficient() {
        let x1: Vec<f64> = (0..50).map(|i| i as f64).collect();
        let x2: Vec<f64> = (0..50).map(|i| ((i as f64) * 0.3).sin()).collect();
        let y: Vec<f64> = x1.iter().zip(&x2).map(|(a, b)| 2.0 * a - 0.7 * b).collect();
        let (b, s) = linear_least_squares(&[x1.clone(), x2.clone()], &y, &[false, false]);
        assert!((b[0] - 2.0).abs() < 1e-9 && (b[1] + 0.7).abs() < 1e-9 && s < 1e-12);
        let (b, s) = linear_least_squares(&[x1, x2], &y, &[false, true]);
        assert_eq!(b[1], 0.0);
        assert!(s > 1.0);
    }

    /// A problem where "drop the first negative coefficient and re-solve" (the solver this
    /// replaced) ends at β = 0 with SSR 63, while the constrained optimum keeps the first
    /// coefficient: every unconstrained coefficient is negative (−0.41, −0.55, −1.34).
    /// Reference: scipy 1.17.1 `scipy.optimize.nnls` (β, and `rnorm²`) and, with a fourth,
    /// unconstrained column, `lsq_linear(method="bvls", tol=1e-15)`, printed with `%.17e`.
    /// Tolerance 1e-10 relative: the 1e-12 ridge moves β by ~1e-12·κ², κ ≈ 4 here.
    #[test]
    #[allow(clippy::excessive_precision)] // scipy's values as printed, digit for digit
    fn nonnegative_least_squares_matches_scipy_where_dropping_the_first_negative_fails() {
        #[rustfmt::skip]
        let rows: [[f64; 3]; 6] = [
            [3.0, 2.0, -3.0], [-1.0, 4.0, -5.0], [-5.0, 5.0, -1.0],
            [1.0, 2.0, 0.0], [-4.0, 3.0, 0.0], [1.0, -5.0, 5.0],
        ];
        let y = [3.0, 4.0, 3.0, -3.0, -2.0, -4.0];
        let cols: Vec<Vec<f64>> = (0..3)
            .map(|j| rows.iter().map(|r| r[j]).collect())
            .collect();
        let close = |got: f64, want: f64| (got - want).abs() <= 1e-10 * want.abs().max(1e-300);
        let (b, s) = linear_least_squares(&cols, &y, &[true; 3]);
        let want = [3.25888324873096435e-01, 6.91370558375634436e-01, 0.0];
        for (g, w) in b.iter().zip(want) {
            assert!(close(*g, w) || (w == 0.0 && *g == 0.0), "{b:?} vs {want:?}");
        }
        assert!(close(s, 3.48213197969543202e+01), "SSR {s}");
        // The same with an unconstrained alternating column: it stays in the solution.
        let mut cols4 = cols.clone();
        cols4.push(
            (0..6)
                .map(|i| if i % 2 == 0 { 1.0 } else { -1.0 })
                .collect(),
        );
        let (b, s) = linear_least_squares(&cols4, &y, &[true, true, true, false]);
        let want = [
            3.77525074163017449e-01,
            6.45783302726373298e-01,
            0.0,
            6.38437632433959790e-01,
        ];
        for (g, w) in b.iter().zip(want) {
            assert!(close(*g, w) || (w == 0.0 && *g == 0.0), "{b:?} vs {want:?}");
        }
        assert!(close(s, 3.28684136177426183e+01), "SSR {s}");
    }

    /// A factored base with columns added (a screen's path) gives what the same columns
    /// solved together give: 100 random problems of 400 rows, seven base columns (a zero one
    /// first, then six spanning four decades) and three added ones (a zero one, first; a
    /// non-negative one whose constraint binds in every other problem; an unconstrained one
    /// 1e-4 from the base's span in relative terms). β agrees to 1e-7 of the larger of its
    /// value and its column's scale ‖y‖/‖X_j‖ (the near-repeated column's coefficient and
    /// those that compensate it carry ε·κ²), the SSR to 1e-9 relative and to the data's own
    /// sum of squares at β, the zero columns' β are 0, and the added coefficients meet the
    /// Karush–Kuhn–Tucker conditions.
    #[test]
    fn a_factored_base_with_columns_added_solves_as_one() {
        let mut rng = crate::plant::rng::NormalRng::new(9);
        let m = 400;
        for case in 0..100 {
            let mut base: Vec<Vec<f64>> = vec![vec![0.0; m]];
            for j in 0..6 {
                base.push(
                    (0..m)
                        .map(|_| rng.normal() * 10f64.powi(j % 5 - 2))
                        .collect(),
                );
            }
            let mut extra: Vec<Vec<f64>> = vec![vec![0.0; m]];
            extra.push((0..m).map(|_| rng.normal() * 3.0).collect());
            // The last added column: two of the base's columns plus a 1e-4 part of its own.
            extra.push(
                (0..m)
                    .map(|i| base[1][i] * 40.0 - base[2][i] * 0.3 + 1e-4 * rng.normal())
                    .collect(),
            );
            let sign = if case % 2 == 0 { -0.8 } else { 0.8 };
            let y: Vec<f64> = (0..m)
                .map(|i| rng.normal() + 0.5 * base[3][i] + sign * extra[1][i])
                .collect();
            let nonneg = [false, true, false];
            let (split, s_split) = LeastSquaresBase::new(&base, &y).solve(&extra, &nonneg);
            let all: Vec<Vec<f64>> = base.iter().chain(&extra).cloned().collect();
            let flags: Vec<bool> = [false; 7].iter().chain(&nonneg).copied().collect();
            let (whole, s_whole) = linear_least_squares(&all, &y, &flags);
            assert!(
                (s_split - s_whole).abs() <= 1e-9 * s_whole,
                "case {case}: SSR {s_split} vs {s_whole}"
            );
            let y_norm = norm(&y);
            for (j, col) in all.iter().enumerate() {
                let scale = if norm(col) > 0.0 {
                    y_norm / norm(col)
                } else {
                    0.0
                };
                assert!(
                    (split[j] - whole[j]).abs() <= 1e-7 * scale.max(whole[j].abs()),
                    "case {case}: β_{j} {} vs {}",
                    split[j],
                    whole[j]
                );
            }
            assert!(split[0] == 0.0 && split[7] == 0.0, "case {case}: {split:?}");
            let resid: Vec<f64> = (0..m)
                .map(|i| y[i] - all.iter().zip(&split).map(|(c, b)| b * c[i]).sum::<f64>())
                .collect();
            let direct: f64 = resid.iter().map(|r| r * r).sum();
            assert!(
                (s_split - direct).abs() <= 1e-9 * direct,
                "case {case}: SSR {s_split} vs the data's {direct}"
            );
            let grad = |col: &[f64]| col.iter().zip(&resid).map(|(a, r)| a * r).sum::<f64>();
            let tol = |col: &[f64]| 1e-6 * norm(col) * y_norm;
            let (b, g) = (split[8], grad(&extra[1]));
            assert!(b >= 0.0, "case {case}: β {b}");
            if b > 0.0 {
                assert!(
                    g.abs() <= tol(&extra[1]),
                    "case {case}: gradient {g:e} at β {b}"
                );
            } else {
                assert!(
                    g <= tol(&extra[1]),
                    "case {case}: gradient {g:e} would raise β"
                );
            }
            // Where the constraint binds (the data want a negative coefficient) β is 0.
            if sign > 0.0 {
                assert!(b > 0.0, "case {case}: β {b}");
            } else {
                assert_eq!(b, 0.0, "case {case}");
            }
            let g = grad(&extra[2]);
            assert!(g.abs() <= tol(&extra[2]), "case {case}: gradient {g:e}");
        }
    }

    /// 200 random problems (columns spanning four decades, most with some unconstrained
    /// coefficients negative): the result satisfies the Karush–Kuhn–Tucker conditions, which
    /// characterise the constrained optimum: β ≥ 0, and the gradient Xᵀ(y − Xβ) is zero
    /// where β > 0 and not positive where β = 0 (to rounding, 1e-9 of ‖X_j‖·‖y‖). Dropping
    /// the first negative coefficient for good fails the second condition wherever that
    /// coefficient belonged in the solution.
    #[test]
    fn nonnegative_least_squares_meets_the_optimality_conditions() {
        let mut rng = crate::plant::rng::NormalRng::new(5);
        for _ in 0..200 {
            let (m, p) = (12, 5);
            let cols: Vec<Vec<f64>> = (0..p)
                .map(|j| {
                    (0..m)
                        .map(|_| rng.normal() * 10f64.powi(j as i32 - 2))
                        .collect()
                })
                .collect();
            let y: Vec<f64> = (0..m).map(|_| rng.normal()).collect();
            let (b, _) = linear_least_squares(&cols, &y, &[true; 5]);
            let y_norm = y.iter().map(|v| v * v).sum::<f64>().sqrt();
            for j in 0..p {
                assert!(b[j] >= 0.0, "{b:?}");
                let resid: Vec<f64> = (0..m)
                    .map(|i| y[i] - (0..p).map(|k| b[k] * cols[k][i]).sum::<f64>())
                    .collect();
                let c_norm = cols[j].iter().map(|v| v * v).sum::<f64>().sqrt();
                let g: f64 = cols[j].iter().zip(&resid).map(|(a, r)| a * r).sum::<f64>();
                let scale = 1e-9 * c_norm * y_norm;
                if b[j] > 0.0 {
                    assert!(g.abs() <= scale, "gradient {g:e} at a positive β_{j}");
                } else {
                    assert!(g <= scale, "gradient {g:e} would raise β_{j} from 0");
                }
            }
        }
    }
}
