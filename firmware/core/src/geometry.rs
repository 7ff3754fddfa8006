//! Tip geometry and the scaling of identified aggregates to per-element values (5.2, App. A).
//!
//! The identified `c`, `k` are sums over the elements under the tip. Per-element values are
//! `c/n` and `k/n` (30)–(31), `n = |W|`. The tip is a sphere of radius R; an element at lateral
//! distance r from the apex sits under the tip surface at the *sag* `s(r) = R − √(R² − r²)`
//! above the apex, so it is indented by `δ − s(r)` when the apex is δ deep in a flat sample.
//! Summing, the force is `k₀·n·(δ − s̄)` with `s̄` the mean sag over the contact disk: an
//! aggregate model without offset (13) identifies `k = k₀·n·(δ − s̄)/δ`, which (32) corrects:
//! `k_c = (k/n)·δ/(δ − s̄)`, with `s̄ = R/3` for a fully submerged tip (A.3).
//!
//! Everything here runs outside the loop (at a tap's read-out, on the host, or in the
//! firmware's main loop): it uses square roots and loops over lattice sites.

/// Contact radius of a sphere of radius `r` whose apex is `delta` deep in a flat sample.
pub fn contact_radius(r: f64, delta: f64) -> f64 {
    if delta <= 0.0 {
        0.0
    } else if delta >= r {
        r
    } else {
        libm::sqrt(2.0 * r * delta - delta * delta)
    }
}

/// Mean sag `s̄` of the sphere over its contact disk at depth `delta` (continuous limit).
///
/// `s̄ = R − 2/(3a²)·(R³ − (R − δ)³)` for δ < R (a² = 2Rδ − δ²), and R/3 for δ ≥ R.
pub fn mean_sag(r: f64, delta: f64) -> f64 {
    if delta <= 0.0 {
        return 0.0;
    }
    let d = if delta > r { r } else { delta };
    let a2 = 2.0 * r * d - d * d;
    let rd = r - d;
    r - 2.0 / (3.0 * a2) * (r * r * r - rd * rd * rd)
}

/// The lateral lattice of the element bed (the sample model's resolution).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lattice {
    /// Pitch along x (m).
    pub pitch_x: f64,
    /// Pitch along y (m).
    pub pitch_y: f64,
    /// x of element (0, 0) (m).
    pub origin_x: f64,
    /// y of element (0, 0) (m).
    pub origin_y: f64,
}

/// The lattice sites under a disk: how many, and their mean sag under a sphere.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// Number of sites with r < radius.
    pub count: u32,
    /// Mean of R − √(R² − r²) over those sites (m).
    pub mean_sag: f64,
}

impl Lattice {
    /// A square lattice of pitch `pitch` with element (0, 0) at `(origin, origin)`.
    pub fn square(pitch: f64, origin: f64) -> Self {
        Self {
            pitch_x: pitch,
            pitch_y: pitch,
            origin_x: origin,
            origin_y: origin,
        }
    }

    /// Sites strictly inside the disk of `radius` around (x, y), and their mean sag under a
    /// sphere of radius `tip_radius` (radius ≤ tip_radius).
    pub fn footprint(&self, x: f64, y: f64, radius: f64, tip_radius: f64) -> Footprint {
        let mut count = 0u32;
        let mut sag = 0.0;
        if !(radius > 0.0) || !(self.pitch_x > 0.0) || !(self.pitch_y > 0.0) {
            return Footprint {
                count: 0,
                mean_sag: 0.0,
            };
        }
        let i0 = libm::floor((x - radius - self.origin_x) / self.pitch_x) as i64;
        let i1 = libm::ceil((x + radius - self.origin_x) / self.pitch_x) as i64;
        let j0 = libm::floor((y - radius - self.origin_y) / self.pitch_y) as i64;
        let j1 = libm::ceil((y + radius - self.origin_y) / self.pitch_y) as i64;
        let r2max = radius * radius;
        let mut i = i0;
        while i <= i1 {
            let dx = self.origin_x + i as f64 * self.pitch_x - x;
            let mut j = j0;
            while j <= j1 {
                let dy = self.origin_y + j as f64 * self.pitch_y - y;
                let r2 = dx * dx + dy * dy;
                if r2 < r2max {
                    count += 1;
                    sag += tip_radius - libm::sqrt((tip_radius * tip_radius - r2).max(0.0));
                }
                j += 1;
            }
            i += 1;
        }
        let mean_sag = if count > 0 { sag / count as f64 } else { 0.0 };
        Footprint { count, mean_sag }
    }
}

/// How many elements are under the tip, and their mean sag, for the scaling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ElementCount {
    /// Continuous limit: n = π a²/(pitch_x·pitch_y), s̄ from [`mean_sag`].
    Continuous {
        /// Area per element (m²).
        element_area: f64,
    },
    /// Exact count of lattice sites under the tip at its lateral position.
    Lattice(Lattice),
}

impl ElementCount {
    /// `(n, s̄)` for a tip of radius `r` at (x, y), `delta` deep in a locally flat sample.
    pub fn at(&self, x: f64, y: f64, r: f64, delta: f64) -> (f64, f64) {
        let a = contact_radius(r, delta);
        match self {
            ElementCount::Continuous { element_area } => (
                core::f64::consts::PI * a * a / element_area,
                mean_sag(r, delta),
            ),
            ElementCount::Lattice(l) => {
                let f = l.footprint(x, y, a, r);
                (f.count as f64, f.mean_sag)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mean_sag_limits() {
        let r = 300e-9;
        assert!((mean_sag(r, r) - r / 3.0).abs() < 1e-18);
        assert!((mean_sag(r, 2.0 * r) - r / 3.0).abs() < 1e-18);
        // Shallow: the cap is nearly a paraboloid, s̄ ≈ δ/2.
        assert!((mean_sag(r, 1e-9) / 0.5e-9 - 1.0).abs() < 2e-3);
        // 150 nm under a 300 nm sphere: 66.67 nm.
        assert!((mean_sag(r, 150e-9) - 66.6667e-9).abs() < 1e-12);
    }

    #[test]
    fn lattice_footprint_counts() {
        let l = Lattice::square(100e-9, 50e-9);
        // On a site: 25 sites strictly inside r < 300 nm (r = 300 nm excluded).
        assert_eq!(l.footprint(50e-9, 50e-9, 300e-9, 300e-9).count, 25);
        // Centred between four sites: 32.
        assert_eq!(l.footprint(100e-9, 100e-9, 300e-9, 300e-9).count, 32);
        // Averaged over positions it approaches π R²/p² = 28.27 and s̄ → R/3.
        let (mut n, mut s) = (0.0, 0.0);
        let m = 40;
        for i in 0..m {
            for j in 0..m {
                let f = l.footprint(i as f64 * 2.5e-9, j as f64 * 2.5e-9, 300e-9, 300e-9);
                n += f.count as f64;
                s += f.mean_sag * f.count as f64;
            }
        }
        let nm = n / (m * m) as f64;
        assert!((nm / 28.274 - 1.0).abs() < 0.01, "mean count {nm}");
        assert!((s / n / 100e-9 - 1.0).abs() < 0.02, "mean sag {}", s / n);
    }
}
