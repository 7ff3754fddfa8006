//! Least squares for the model's parameters: Levenberg–Marquardt on scaled parameters with
//! box bounds, the Jacobian by forward differences of whole simulations.
//!
//! A parameter is searched in a scaled coordinate `x = value/scale` (or `ln(value)/scale` for
//! positive quantities spanning decades, such as a bed stiffness or a relaxation time), so
//! that one unit of x is a comparable change for every parameter and the finite-difference
//! step can be the same. Bounds are kept by clamping each trial point (projected LM); a
//! parameter pinned at a bound keeps its column, so the step is still solved jointly.

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
    /// Residual evaluations (simulations).
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
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions {
            max_iterations: 30,
            tolerance: 1e-7,
            step: 1e-4,
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
        // Normal equations JᵀJ δ = −Jᵀr.
        let mut jtj = vec![vec![0.0; np]; np];
        let mut jtr = vec![0.0; np];
        for a in 0..np {
            jtr[a] = jac[a].iter().zip(&r).map(|(j, rr)| j * rr).sum();
            for b in a..np {
                let s: f64 = jac[a].iter().zip(&jac[b]).map(|(x, y)| x * y).sum();
                jtj[a][b] = s;
                jtj[b][a] = s;
            }
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut m = jtj.clone();
            for (a, row) in m.iter_mut().enumerate() {
                row[a] += lambda * (jtj[a][a] + 1e-12 * (1.0 + jtj[a][a]));
            }
            let rhs: Vec<f64> = jtr.iter().map(|v| -v).collect();
            let Some(delta) = solve(m, rhs) else {
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
    }
    LmResult {
        ssr: cost,
        iterations,
        evaluations,
        converged,
    }
}

/// Solves the symmetric system by Gaussian elimination with partial pivoting.
pub fn solve(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        if !(a[piv][col].abs() > 1e-300) {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for row in col + 1..n {
            let f = a[row][col] / a[col][col];
            if f != 0.0 {
                let (top, bottom) = a.split_at_mut(row);
                for (x, &y) in bottom[0][col..n].iter_mut().zip(&top[col][col..n]) {
                    *x -= f * y;
                }
                b[row] -= f * b[col];
            }
        }
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|k| a[i][k] * x[k]).sum();
        x[i] = (b[i] - s) / a[i][i];
        if !x[i].is_finite() {
            return None;
        }
    }
    Some(x)
}

/// Linear least squares `min ‖y − X·β‖` by the normal equations with a tiny ridge; columns
/// given as vectors. `nonneg[j]` keeps β_j ≥ 0 (active-set: a negative one is dropped and the
/// rest re-solved). Returns β and the residual sum of squares.
pub fn linear_least_squares(cols: &[Vec<f64>], y: &[f64], nonneg: &[bool]) -> (Vec<f64>, f64) {
    let p = cols.len();
    let mut active: Vec<bool> = vec![true; p];
    loop {
        let idx: Vec<usize> = (0..p).filter(|&j| active[j]).collect();
        let q = idx.len();
        let mut beta = vec![0.0; p];
        if q > 0 {
            let mut m = vec![vec![0.0; q]; q];
            let mut rhs = vec![0.0; q];
            for a in 0..q {
                rhs[a] = cols[idx[a]].iter().zip(y).map(|(x, v)| x * v).sum();
                for b in a..q {
                    let s: f64 = cols[idx[a]]
                        .iter()
                        .zip(&cols[idx[b]])
                        .map(|(x, z)| x * z)
                        .sum();
                    m[a][b] = s;
                    m[b][a] = s;
                }
            }
            for (a, row) in m.iter_mut().enumerate() {
                row[a] += 1e-12 * row[a].abs() + 1e-300;
            }
            if let Some(sol) = solve(m, rhs) {
                for (a, &j) in idx.iter().enumerate() {
                    beta[j] = sol[a];
                }
            }
        }
        let bad = (0..p).find(|&j| active[j] && nonneg[j] && beta[j] < 0.0);
        match bad {
            Some(j) => active[j] = false,
            None => {
                let mut s = 0.0;
                for (i, v) in y.iter().enumerate() {
                    let mut e = *v;
                    for j in 0..p {
                        if beta[j] != 0.0 {
                            e -= beta[j] * cols[j][i];
                        }
                    }
                    s += e * e;
                }
                return (beta, s);
            }
        }
    }
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
}
