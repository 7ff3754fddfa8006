//! The elements under the tip, estimated from what the instrument measures, for the scaling
//! of aggregates to per-element values (30)–(32).
//!
//! The paper scales by n = |W|, the number of elements in contact. An instrument does not see
//! W; it knows the element lattice of its sample model, the tip radius, the effective depth it
//! measured — `δ_eff = ĥ_bed − Z`, the k-weighted mean indentation of the engaged elements
//! `hᵢ − sᵢ − Z` (sᵢ = R − √(R² − rᵢ²) the sphere's sag over element i) — and the topography
//! it identified around the pixel, whose local gradient g tilts the bed under the tip.
//!
//! With a locally planar bed `hᵢ = h(axis) + g·dᵢ` (dᵢ the lateral offset of element i from the
//! tip's axis), element i is engaged when `eᵢ + H > 0`, with `eᵢ = g·dᵢ − sᵢ` and H the apex
//! depth below the plane at the axis; and the measured effective depth is then
//! `δ_eff = H + mean_W(eᵢ)`. Solving that for H gives W, hence n, the mean sag and the mean
//! height of the engaged elements `ĥ_bed + mean_W(sᵢ)`. On flat ground this is the exact
//! lattice version of Appendix A's continuum relation `δ_eff = δ − s̄(δ)`; on a slope it
//! follows the contact uphill, which is what Appendix B says the flat-surface scaling misses.

use crate::sample::Sample;

/// The estimated contact set at one tip position.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LocalContact {
    /// Number of engaged elements, averaged over the excitation's swing.
    pub n: f64,
    /// Their mean sag sᵢ (m).
    pub mean_sag_m: f64,
}

/// Offsets of the apex depth over the two tones' swing: `a₁·sin φ + a₂·sin ψ` on a 4 × 4 grid of
/// phases (the tones are incommensurate, so every pair of phases occurs).
pub fn swing(tip_amplitudes_m: [f64; 2]) -> Vec<f64> {
    let mut v = Vec::with_capacity(16);
    for i in 0..4 {
        for j in 0..4 {
            let (p, q) = (
                std::f64::consts::TAU * (i as f64 + 0.5) / 4.0,
                std::f64::consts::TAU * (j as f64 + 0.5) / 4.0,
            );
            v.push(tip_amplitudes_m[0] * p.sin() + tip_amplitudes_m[1] * q.sin());
        }
    }
    v
}

/// The identified bed around a pixel, to second order: `h(c + d) − h(c) = g·d + ½·dᵀ·H·d` about
/// the pixel's centre c.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LocalBed {
    /// Centre c (m).
    pub centre_m: [f64; 2],
    /// Gradient g = (∂h/∂x, ∂h/∂y) at c.
    pub grad: [f64; 2],
    /// Curvature H = (∂²h/∂x², ∂²h/∂x∂y, ∂²h/∂y²) at c (1/m).
    pub curv_per_m: [f64; 3],
}

/// A model of the bed's height around the tip, from what the instrument identified: only
/// height differences matter.
pub trait Bed {
    /// Height of the bed at (x, y) (m), up to a constant.
    fn height(&self, x: f64, y: f64) -> f64;
}

impl Bed for LocalBed {
    fn height(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (x - self.centre_m[0], y - self.centre_m[1]);
        let [hxx, hxy, hyy] = self.curv_per_m;
        self.grad[0] * dx
            + self.grad[1] * dy
            + 0.5 * (hxx * dx * dx + 2.0 * hxy * dx * dy + hyy * dy * dy)
    }
}

impl LocalBed {
    /// A plane through c of gradient `grad`.
    pub fn plane(centre_m: [f64; 2], grad: [f64; 2]) -> Self {
        Self {
            centre_m,
            grad,
            curv_per_m: [0.0; 3],
        }
    }
}

/// Elements under a sphere of radius `r` at (x, y): for each, `eᵢ = b(xᵢ) − b(x) − sᵢ` (the bed's
/// height relative to the sphere's surface, up to the apex depth) and its sag sᵢ.
fn offsets(
    sample: &Sample,
    x: f64,
    y: f64,
    r: f64,
    bed: &(impl Bed + ?Sized),
    e: &mut Vec<f64>,
    sag: &mut Vec<f64>,
) {
    e.clear();
    sag.clear();
    let b0 = bed.height(x, y);
    sample.for_each_within(x, y, r, |el| {
        let s = r - (r * r - el.r_m * el.r_m).max(0.0).sqrt();
        e.push(bed.height(el.x_m, el.y_m) - b0 - s);
        sag.push(s);
    });
}

/// ⟨n⟩, ⟨Σ(H + eᵢ)⟩ and ⟨Σ sᵢ⟩ of the engaged elements over the swing, at mean apex depth h.
fn moments(e: &[f64], sag: &[f64], swing: &[f64], h: f64) -> (f64, f64, f64) {
    let (mut n, mut f, mut s) = (0.0, 0.0, 0.0);
    for o in swing {
        let hh = h + o;
        for (ei, si) in e.iter().zip(sag) {
            if ei + hh > 0.0 {
                n += 1.0;
                f += ei + hh;
                s += si;
            }
        }
    }
    let k = 1.0 / swing.len() as f64;
    (n * k, f * k, s * k)
}

/// The contact of a sphere of radius `r` passing over the lateral positions `path` (one point
/// for a DIVE tap, the positions along an SVE pixel's pass) on a planar bed of gradient `grad`
/// (dh/dx, dh/dy), with measured effective depth `effective_depth_m`, the apex swinging by the
/// offsets `swing` (see [`swing`]). Only the sample's lattice positions are used, never its
/// heights or properties.
///
/// The estimator's k̂ is the slope of the force against the depth over the swing and the pass —
/// the average of Σ_W kᵢ — and the low-passed force the average of Σ_W kᵢ·(H + eᵢ); their ratio
/// is the measured effective depth. We find the mean apex depth H whose modelled ratio, averaged
/// the same way, equals the measured one (bisection) and return the averaged count there. At a
/// single position without swing the ratio is a sawtooth in H (it drops each time an element
/// engages) and its inverse ambiguous by about an element; the swing (±9 nm in SVE, ±125 nm in
/// DIVE) and the pass (one lattice pitch per SVE pixel) smooth it.
pub fn contact_for(
    sample: &Sample,
    path: &[(f64, f64)],
    r: f64,
    effective_depth_m: f64,
    grad: [f64; 2],
    swing: &[f64],
) -> LocalContact {
    let c = path.first().map_or([0.0; 2], |p| [p.0, p.1]);
    contact_on(
        sample,
        path,
        r,
        effective_depth_m,
        &LocalBed::plane(c, grad),
        swing,
    )
}

/// [`contact_for`] on a curved bed.
pub fn contact_on(
    sample: &Sample,
    path: &[(f64, f64)],
    r: f64,
    effective_depth_m: f64,
    bed: &(impl Bed + ?Sized),
    swing: &[f64],
) -> LocalContact {
    if !(effective_depth_m > 0.0) {
        return LocalContact::default();
    }
    let zero = [0.0];
    let swing = if swing.is_empty() { &zero[..] } else { swing };
    let (mut e, mut sag) = (Vec::with_capacity(64), Vec::with_capacity(64));
    let mut points: Vec<(Vec<f64>, Vec<f64>)> = Vec::with_capacity(path.len());
    for &(x, y) in path {
        offsets(sample, x, y, r, bed, &mut e, &mut sag);
        if !e.is_empty() {
            points.push((e.clone(), sag.clone()));
        }
    }
    if points.is_empty() {
        return LocalContact::default();
    }
    let averaged = |h: f64| {
        let (mut n, mut f, mut s) = (0.0, 0.0, 0.0);
        for (e, sg) in &points {
            let m = moments(e, sg, swing, h);
            n += m.0;
            f += m.1;
            s += m.2;
        }
        (n, f, s)
    };
    // 28 halvings of 4R: 2·10⁻⁶ nm, far below a lattice effect.
    let (mut lo, mut hi) = (0.0, 4.0 * r);
    for _ in 0..28 {
        let mid = 0.5 * (lo + hi);
        let (n, f, _) = averaged(mid);
        if n == 0.0 || f / n < effective_depth_m {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let (n, _, s) = averaged(0.5 * (lo + hi));
    LocalContact {
        n: n / points.len() as f64,
        mean_sag_m: if n > 0.0 { s / n } else { 0.0 },
    }
}

/// The apex depth δ with δ − s̄(δ) = `effective_m` for the continuum mean sag (Appendix A's
/// relation on a flat bed), by bisection.
pub fn continuum_apex_depth(tip_radius_m: f64, effective_m: f64) -> f64 {
    if !(effective_m > 0.0) {
        return 0.0;
    }
    let (mut lo, mut hi) = (0.0, effective_m + tip_radius_m);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if mid - visco_core::geometry::mean_sag(tip_radius_m, mid) < effective_m {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Gradient of a regular grid of heights (row-major, `nx` × `ny`, spacing `dx`, `dy`): central
/// differences inside, second-order one-sided ones at the ends (`(−3h₀ + 4h₁ − h₂)/2d`: the
/// first-order forward difference is the slope half a step inwards, off by `h''·d/2` — on the
/// cell's cap, 0.06 at 250 nm between lines, against the 0.144 that makes a footprint steep);
/// NaN neighbours are skipped (first order, or zero gradient when none).
pub fn grid_gradient(h: &[f64], nx: usize, ny: usize, dx: f64, dy: f64) -> Vec<[f64; 2]> {
    let at = |i: isize, j: isize| -> f64 {
        if i < 0 || j < 0 || i >= nx as isize || j >= ny as isize {
            f64::NAN
        } else {
            h[j as usize * nx + i as usize]
        }
    };
    let mut g = vec![[0.0; 2]; nx * ny];
    for j in 0..ny as isize {
        for i in 0..nx as isize {
            g[j as usize * nx + i as usize] = [
                derivative(|m| at(i + m, j), dx),
                derivative(|m| at(i, j + m), dy),
            ];
        }
    }
    g
}

/// d/ds of `f` at 0 from its values at integer steps of `d`: central where both neighbours are
/// finite, else second-order one-sided, else first-order one-sided, else 0.
fn derivative(f: impl Fn(isize) -> f64, d: f64) -> f64 {
    let ok = |v: &[f64]| v.iter().all(|x| x.is_finite()) && d > 0.0;
    let (m1, z, p1) = (f(-1), f(0), f(1));
    if ok(&[m1, p1]) {
        return (p1 - m1) / (2.0 * d);
    }
    for s in [1isize, -1] {
        let (a, b) = (f(s), f(2 * s));
        if ok(&[z, a, b]) {
            return s as f64 * (-3.0 * z + 4.0 * a - b) / (2.0 * d);
        }
    }
    for s in [1isize, -1] {
        let a = f(s);
        if ok(&[z, a]) {
            return s as f64 * (a - z) / d;
        }
    }
    0.0
}

/// Curvature (∂²h/∂x², ∂²h/∂x∂y, ∂²h/∂y²) of a regular grid of heights (row-major, `nx` × `ny`,
/// spacing `dx`, `dy`), from second differences over ±2 columns (±1 where the grid ends or a
/// neighbour is NaN: a wider stencil averages the identification's pixel noise) and ±1 row
/// (one-sided at the ends). Without `resolve_y` (rows farther apart than the contact is wide:
/// the rows do not see the same bed) only ∂²h/∂x² is kept. Zero where it cannot be formed.
pub fn grid_curvature(
    h: &[f64],
    nx: usize,
    ny: usize,
    dx: f64,
    dy: f64,
    resolve_y: bool,
) -> Vec<[f64; 3]> {
    let at = |i: isize, j: isize| -> f64 {
        if i < 0 || j < 0 || i >= nx as isize || j >= ny as isize {
            f64::NAN
        } else {
            h[j as usize * nx + i as usize]
        }
    };
    let d2 = |a: f64, b: f64, c: f64, d: f64| {
        let v = (a - 2.0 * b + c) / (d * d);
        if v.is_finite() {
            v
        } else {
            0.0
        }
    };
    let mut out = vec![[0.0; 3]; nx * ny];
    for j in 0..ny as isize {
        for i in 0..nx as isize {
            let mut m = 2;
            while m > 0 && !(at(i - m, j).is_finite() && at(i + m, j).is_finite()) {
                m -= 1;
            }
            let hxx = if m > 0 {
                d2(at(i - m, j), at(i, j), at(i + m, j), m as f64 * dx)
            } else {
                0.0
            };
            let (hxy, hyy) = if resolve_y {
                let hyy = if at(i, j - 1).is_finite() && at(i, j + 1).is_finite() {
                    d2(at(i, j - 1), at(i, j), at(i, j + 1), dy)
                } else if at(i, j + 2).is_finite() {
                    d2(at(i, j), at(i, j + 1), at(i, j + 2), dy)
                } else {
                    d2(at(i, j - 2), at(i, j - 1), at(i, j), dy)
                };
                // ∂/∂y of the row's ∂h/∂x (one-sided at the first and last row, as the gradient).
                let hx = |m: isize| (at(i + 1, j + m) - at(i - 1, j + m)) / (2.0 * dx);
                (derivative(hx, dy), hyy)
            } else {
                (0.0, 0.0)
            };
            out[j as usize * nx + i as usize] = [hxx, hxy, hyy];
        }
    }
    out
}

/// The largest |∇h| within `reach_x` columns and `reach_y` rows of each grid point: the slope of
/// the identified topography over a footprint.
pub fn footprint_max_slope(
    grad: &[[f64; 2]],
    nx: usize,
    ny: usize,
    reach_x: usize,
    reach_y: usize,
) -> Vec<f64> {
    let mut out = vec![0.0; nx * ny];
    for j in 0..ny {
        for i in 0..nx {
            let mut m: f64 = 0.0;
            for jj in j.saturating_sub(reach_y)..=(j + reach_y).min(ny - 1) {
                for ii in i.saturating_sub(reach_x)..=(i + reach_x).min(nx - 1) {
                    let g = grad[jj * nx + ii];
                    m = m.max(g[0].hypot(g[1]));
                }
            }
            out[j * nx + i] = m;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The true contact set of a sphere on a bed of heights `h(x, y)` with its apex at `z`: its
    /// size and Σ(hᵢ − sᵢ − z) over it.
    fn truth(s: &Sample, x: f64, y: f64, r: f64, z: f64) -> (usize, f64) {
        let (mut n, mut f) = (0usize, 0.0);
        s.for_each_within(x, y, r, |e| {
            let sag = r - (r * r - e.r_m * e.r_m).sqrt();
            if e.h_m - sag - z > 0.0 {
                n += 1;
                f += e.h_m - sag - z;
            }
        });
        (n, f)
    }

    /// A pass of 16 points over one pitch at apex depth `delta` below the bed at the axis, with
    /// the SVE swing: the time-averaged count, and the measured effective depth ⟨F⟩/⟨n⟩.
    fn pass(
        s: &Sample,
        y: f64,
        r: f64,
        bed: impl Fn(f64) -> f64,
        delta: f64,
        sw: &[f64],
    ) -> (Vec<(f64, f64)>, f64, f64) {
        let path: Vec<(f64, f64)> = (0..16)
            .map(|i| (2.5e-6 + i as f64 * 100e-9 / 16.0, y))
            .collect();
        let (mut n, mut f) = (0.0, 0.0);
        for &(x, y) in &path {
            for o in sw {
                let (ni, fi) = truth(s, x, y, r, bed(x) - delta - o);
                n += ni as f64;
                f += fi;
            }
        }
        let per = (path.len() * sw.len()) as f64;
        (path, n / per, f / n)
    }

    #[test]
    fn pass_averaged_count_is_recovered_on_flat_ground() {
        let s = Sample::flat(50, 50, 100e-9, [50e-9, 50e-9], 100e-9, 6e-7, 3.5e-3).unwrap();
        let r = 300e-9;
        let sw = swing([5e-9, 8e-9]);
        for delta in [100e-9, 150e-9, 200e-9] {
            for y in [2.5e-6, 2.52e-6, 2.55e-6] {
                let (path, n, eff) = pass(&s, y, r, |_| 100e-9, delta, &sw);
                let c = contact_for(&s, &path, r, eff, [0.0, 0.0], &sw);
                assert!(
                    (c.n / n - 1.0).abs() < 0.02,
                    "δ {delta}, y {y}: {} vs {n}",
                    c.n
                );
            }
        }
    }

    #[test]
    fn a_slope_moves_the_contact_set_and_the_estimate_follows() {
        let g = 0.4;
        let s = Sample::from_fn(50, 50, 100e-9, [0.0, 0.0], |x, _| {
            (1e-6 + g * x, 6e-7, 3.5e-3)
        })
        .unwrap();
        let r = 300e-9;
        let sw = swing([5e-9, 8e-9]);
        let (path, n, eff) = pass(&s, 2.47e-6, r, |x| 1e-6 + g * x, 150e-9, &sw);
        let tilted = contact_for(&s, &path, r, eff, [g, 0.0], &sw);
        let flat = contact_for(&s, &path, r, eff, [0.0, 0.0], &sw);
        assert!(
            (tilted.n / n - 1.0).abs() < 0.03,
            "tilted {} vs {n}",
            tilted.n
        );
        assert!(
            (tilted.n - flat.n).abs() > 0.5,
            "the slope should matter: {} vs {}",
            tilted.n,
            flat.n
        );
    }
}
