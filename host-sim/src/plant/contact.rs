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

/// A candidate element (internal units) with its current threshold.
#[derive(Clone, Copy, Debug, Default)]
struct Cand {
    /// Threshold `t` at the last update (−∞ when not under the tip).
    t: f64,
    x: f64,
    y: f64,
    h: f64,
    k: f64,
    c: f64,
    /// Zobrist key of the element.
    key: u64,
    /// Global sample index.
    idx: u32,
}

/// Internal units: nm, nN/nm, nN·µs/nm.
#[derive(Clone, Debug, Default)]
pub struct Footprint {
    /// Candidates, kept sorted by threshold descending (the order of the last update, which
    /// the next update's insertion sort starts from).
    cand: Vec<Cand>,
    /// Centre of the candidate disc and its margin.
    centre: [f64; 2],
    margin: f64,
    /// Sorted thresholds `t[0] ≥ t[1] ≥ … ≥ t[len−1]` of the elements under the tip.
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
    scratch: Vec<f64>,
    scratch2: Vec<f64>,
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
        self.cand.clear();
        let reach_m = (r + self.margin) * LENGTH;
        s.sample
            .for_each_within(x * LENGTH, y * LENGTH, reach_m, |e| {
                self.cand.push(Cand {
                    t: f64::NEG_INFINITY,
                    x: e.x_m / LENGTH,
                    y: e.y_m / LENGTH,
                    h: s.h_nm[e.index],
                    k: s.k[e.index],
                    c: s.c[e.index],
                    key: zobrist(e.index as u32),
                    idx: e.index as u32,
                });
            });
        let m = self.cand.len();
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
        // Three passes so the square roots run as one branch-free loop over a contiguous array
        // (packed sqrtpd): the scalar square root is the cost of a refresh.
        let q = &mut self.scratch;
        q.clear();
        q.extend(self.cand.iter().map(|e| {
            let dx = e.x - x;
            let dy = e.y - y;
            r2 - (dx * dx + dy * dy)
        }));
        let w = &mut self.scratch2;
        w.clear();
        w.extend(q.iter().map(|&v| v.max(0.0).sqrt()));
        for ((e, &qq), &ww) in self.cand.iter_mut().zip(q.iter()).zip(w.iter()) {
            e.t = if qq > 0.0 {
                e.h - r + ww
            } else {
                f64::NEG_INFINITY
            };
        }
        // Insertion sort from the previous order: O(m) when little moved.
        let c = &mut self.cand;
        for a in 1..c.len() {
            if c[a - 1].t >= c[a].t {
                continue;
            }
            let item = c[a];
            let mut b = a;
            while b > 0 && c[b - 1].t < item.t {
                c[b] = c[b - 1];
                b -= 1;
            }
            c[b] = item;
        }
        let mut len = 0;
        let (mut sk, mut sc, mut skt, mut hs) = (0.0, 0.0, 0.0, 0u64);
        for (n, e) in self.cand.iter().enumerate() {
            if e.t == f64::NEG_INFINITY {
                break;
            }
            self.t[n] = e.t;
            sk += e.k;
            sc += e.c;
            skt += e.k * e.t;
            hs ^= e.key;
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
        self.cand[..n.min(self.len)].iter().map(|e| e.idx as usize)
    }

    /// The largest number of elements that can be under the tip at once (for cache sizing).
    pub fn capacity(&self) -> usize {
        self.cand.len()
    }
}
