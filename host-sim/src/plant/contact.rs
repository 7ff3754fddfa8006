//! The elements under the tip, sorted by engagement height, with prefix sums.
//!
//! Element i engages when the tip apex Z goes below `t_i = h_i − R + √(R² − r_i²)` (`r_i < R`).
//! Sorted by `t` descending, the active set is a prefix of length n = #{t_i > Z} and the contact
//! force is `F = S_kt[n] − S_k[n]·Z − S_c[n]·Ż` with prefix sums of k, c and k·t.
//!
//! The candidates are the elements within `R + margin` of a centre; while the tip stays within
//! `margin` of it they are the only ones that can come under the tip, so a lateral move only
//! recomputes their thresholds and re-sorts a nearly sorted list (insertion sort, O(m)), and
//! the candidate list is rebuilt from the lattice only when the tip leaves the margin.
//!
//! Each prefix also carries a Zobrist hash of its member set (XOR of per-element 64-bit keys),
//! so the plant can tell whether the set behind a cached `Φ` for that n is still the same after
//! a lateral move; the order within a prefix does not matter.

use crate::sample::Sample;

/// Internal units: nm, nN/nm, nN·µs/nm.
#[derive(Clone, Debug, Default)]
pub struct Footprint {
    /// Candidate elements (global index, position, rest height, k, c).
    idx: Vec<u32>,
    x: Vec<f64>,
    y: Vec<f64>,
    h: Vec<f64>,
    k: Vec<f64>,
    c: Vec<f64>,
    /// Centre of the candidate disc and its margin.
    centre: [f64; 2],
    margin: f64,
    /// Permutation of the candidates, by threshold descending; the first `len` are under the
    /// tip (`r < R`).
    order: Vec<u32>,
    /// Threshold per candidate (−∞ when not under the tip).
    t_cand: Vec<f64>,
    /// Sorted thresholds `t[0] ≥ t[1] ≥ … ≥ t[len−1]`.
    pub t: Vec<f64>,
    /// Prefix sums, length `len + 1`.
    pub s_k: Vec<f64>,
    pub s_c: Vec<f64>,
    pub s_kt: Vec<f64>,
    pub hash: Vec<u64>,
    pub len: usize,
    /// Tip position of the last threshold computation.
    pub at: [f64; 2],
    built: bool,
}

#[inline]
fn zobrist(index: u32) -> u64 {
    // SplitMix64 finaliser of the element index: distinct, well-mixed 64-bit keys.
    let mut z = (index as u64)
        .wrapping_add(1)
        .wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A sample in internal units, kept by the plant.
#[derive(Clone, Debug)]
pub struct SampleNm {
    pub sample: Sample,
    pub h_nm: Vec<f64>,
    pub k: Vec<f64>,
    pub c: Vec<f64>,
}

impl SampleNm {
    pub fn new(sample: Sample) -> Self {
        use visco_core::units::{DAMPING, LENGTH, STIFFNESS};
        let h_nm = sample.h_m().iter().map(|v| v / LENGTH).collect();
        let k = sample.k_n_per_m().iter().map(|v| v / STIFFNESS).collect();
        let c = sample.c_n_s_per_m().iter().map(|v| v / DAMPING).collect();
        SampleNm { sample, h_nm, k, c }
    }
}

impl Footprint {
    /// Gather the candidates around `(x, y)` (nm) for a tip of radius `r` (nm).
    fn rebuild(&mut self, s: &SampleNm, x: f64, y: f64, r: f64) {
        use visco_core::units::LENGTH;
        self.margin = (0.5 * s.sample.pitch_m() / LENGTH).max(0.05 * r);
        self.centre = [x, y];
        self.idx.clear();
        self.x.clear();
        self.y.clear();
        self.h.clear();
        self.k.clear();
        self.c.clear();
        let reach_m = (r + self.margin) * LENGTH;
        s.sample
            .for_each_within(x * LENGTH, y * LENGTH, reach_m, |e| {
                self.idx.push(e.index as u32);
                self.x.push(e.x_m / LENGTH);
                self.y.push(e.y_m / LENGTH);
                self.h.push(s.h_nm[e.index]);
                self.k.push(s.k[e.index]);
                self.c.push(s.c[e.index]);
            });
        let m = self.idx.len();
        self.order.clear();
        self.order.extend(0..m as u32);
        self.t_cand.resize(m, f64::NEG_INFINITY);
        self.t.resize(m, 0.0);
        for v in [&mut self.s_k, &mut self.s_c, &mut self.s_kt] {
            v.resize(m + 1, 0.0);
        }
        self.hash.resize(m + 1, 0);
    }

    /// Recompute the thresholds and prefix sums for the tip axis at `(x, y)` (nm).
    pub fn update(&mut self, s: &SampleNm, x: f64, y: f64, r: f64) {
        let off = [x - self.centre[0], y - self.centre[1]];
        if !self.built || off[0] * off[0] + off[1] * off[1] > self.margin * self.margin {
            self.rebuild(s, x, y, r);
            self.built = true;
        }
        self.at = [x, y];
        let r2 = r * r;
        for j in 0..self.idx.len() {
            let dx = self.x[j] - x;
            let dy = self.y[j] - y;
            let q = r2 - (dx * dx + dy * dy);
            self.t_cand[j] = if q > 0.0 {
                self.h[j] - r + q.sqrt()
            } else {
                f64::NEG_INFINITY
            };
        }
        // Insertion sort of the previous order: O(m) when little moved.
        let t = &self.t_cand;
        let ord = &mut self.order;
        for a in 1..ord.len() {
            let key = ord[a];
            let tk = t[key as usize];
            let mut b = a;
            while b > 0 && t[ord[b - 1] as usize] < tk {
                ord[b] = ord[b - 1];
                b -= 1;
            }
            ord[b] = key;
        }
        let mut len = 0;
        let (mut sk, mut sc, mut skt, mut hs) = (0.0, 0.0, 0.0, 0u64);
        for (n, &o) in self.order.iter().enumerate() {
            let o = o as usize;
            let tt = self.t_cand[o];
            if tt == f64::NEG_INFINITY {
                break;
            }
            self.t[n] = tt;
            sk += self.k[o];
            sc += self.c[o];
            skt += self.k[o] * tt;
            hs ^= zobrist(self.idx[o]);
            self.s_k[n + 1] = sk;
            self.s_c[n + 1] = sc;
            self.s_kt[n + 1] = skt;
            self.hash[n + 1] = hs;
            len = n + 1;
        }
        self.len = len;
    }

    /// Number of elements engaged at tip height `z`: `#{t_i > z}`.
    #[inline]
    pub fn count_above(&self, z: f64) -> usize {
        self.t[..self.len].partition_point(|&t| t > z)
    }

    /// Global sample indices of the first `n` (engaged) elements.
    pub fn active_indices(&self, n: usize) -> impl Iterator<Item = usize> + '_ {
        self.order[..n.min(self.len)]
            .iter()
            .map(|&o| self.idx[o as usize] as usize)
    }

    /// The largest number of elements that can be under the tip at once (for cache sizing).
    pub fn capacity(&self) -> usize {
        self.idx.len()
    }
}
