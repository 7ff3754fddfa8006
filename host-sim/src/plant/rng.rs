//! Seeded, fast random numbers for the measurement noise: xoshiro256++ and a ziggurat normal
//! sampler.
//!
//! The plant draws one normal number per sample, 10⁸ times in a demo, so the sampler must cost a
//! few ns. Both algorithms are small enough to keep here rather than pull a crate family in:
//! - xoshiro256++ (Blackman & Vigna 2019), seeded through SplitMix64 as its authors recommend;
//! - the ziggurat of Marsaglia & Tsang (2000) in Doornik's (2005) floating-point form, 128
//!   layers: one 64-bit draw gives the layer (low 7 bits) and the uniform (high 53 bits), so the
//!   two are independent; about 98.8 % of draws take the fast path (one multiply, one compare).

/// xoshiro256++ generator.
#[derive(Clone, Debug)]
pub struct Xoshiro256pp {
    s: [u64; 4],
}

fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Xoshiro256pp {
    /// A generator whose whole stream is a function of `seed`.
    pub fn new(seed: u64) -> Self {
        let mut sm = seed;
        let s = [
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
            splitmix64(&mut sm),
        ];
        Xoshiro256pp { s }
    }

    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = (s[0].wrapping_add(s[3])).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// Uniform in the open interval (0, 1) (never 0, so its logarithm is finite).
    #[inline]
    pub fn next_open01(&mut self) -> f64 {
        ((self.next_u64() >> 11) as i64 as f64 + 0.5) * (1.0 / (1u64 << 53) as f64)
    }
}

const LAYERS: usize = 128;
/// Right edge of the base layer's rectangle and the tail start (Marsaglia & Tsang, 128 layers).
const ZIG_R: f64 = 3.442_619_855_899;
/// Area of each layer.
const ZIG_V: f64 = 9.912_563_035_262_17e-3;

/// Standard normal sampler (ziggurat) driving its own xoshiro256++ stream.
#[derive(Clone, Debug)]
pub struct NormalRng {
    rng: Xoshiro256pp,
    /// Layer right edges, `x[0] = V/f(R)` (the base layer's equivalent width), `x[1] = R`,
    /// decreasing to `x[128] = 0`.
    x: [f64; LAYERS + 1],
    /// `x[i+1]/x[i]`: a uniform `u ∈ (−1, 1)` with `|u| < ratio[i]` lies wholly under the curve.
    ratio: [f64; LAYERS],
}

impl NormalRng {
    pub fn new(seed: u64) -> Self {
        let mut x = [0.0; LAYERS + 1];
        let f_r = (-0.5 * ZIG_R * ZIG_R).exp();
        x[0] = ZIG_V / f_r;
        x[1] = ZIG_R;
        let mut f = f_r;
        for i in 2..LAYERS {
            x[i] = (-2.0 * (ZIG_V / x[i - 1] + f).ln()).sqrt();
            f = (-0.5 * x[i] * x[i]).exp();
        }
        x[LAYERS] = 0.0;
        let mut ratio = [0.0; LAYERS];
        for i in 0..LAYERS {
            ratio[i] = x[i + 1] / x[i];
        }
        NormalRng {
            rng: Xoshiro256pp::new(seed),
            x,
            ratio,
        }
    }

    /// One standard normal number.
    #[inline]
    pub fn normal(&mut self) -> f64 {
        loop {
            let bits = self.rng.next_u64();
            let i = (bits & 0x7F) as usize;
            // Uniform in (−1, 1) from the top 53 bits (via i64: one conversion instruction).
            let u = ((bits >> 11) as i64 as f64 + 0.5) * (2.0 / (1u64 << 53) as f64) - 1.0;
            if u.abs() < self.ratio[i] {
                return u * self.x[i];
            }
            if let Some(v) = self.slow(i, u) {
                return v;
            }
        }
    }

    #[cold]
    fn slow(&mut self, i: usize, u: f64) -> Option<f64> {
        if i == 0 {
            // Tail beyond R (Marsaglia 1964).
            loop {
                let x = self.rng.next_open01().ln() / ZIG_R;
                let y = self.rng.next_open01().ln();
                if -2.0 * y >= x * x {
                    return Some(if u < 0.0 { x - ZIG_R } else { ZIG_R - x });
                }
            }
        }
        let x = u * self.x[i];
        let f0 = (-0.5 * (self.x[i] * self.x[i] - x * x)).exp();
        let f1 = (-0.5 * (self.x[i + 1] * self.x[i + 1] - x * x)).exp();
        (f1 + self.rng.next_open01() * (f0 - f1) < 1.0).then_some(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_moments_and_tails() {
        let mut g = NormalRng::new(7);
        let n = 4_000_000usize;
        let (mut s1, mut s2, mut s4) = (0.0, 0.0, 0.0);
        let (mut beyond2, mut beyond_r) = (0usize, 0usize);
        for _ in 0..n {
            let v = g.normal();
            s1 += v;
            s2 += v * v;
            s4 += v * v * v * v;
            beyond2 += (v.abs() > 2.0) as usize;
            beyond_r += (v.abs() > ZIG_R) as usize;
        }
        let nf = n as f64;
        let mean = s1 / nf;
        let var = s2 / nf - mean * mean;
        let kurt = s4 / nf / (var * var);
        // Standard errors: mean 1/√n = 5e-4, variance √(2/n) = 7e-4, kurtosis √(96/n) = 5e-3.
        assert!(mean.abs() < 2.5e-3, "mean {mean}");
        assert!((var - 1.0).abs() < 3.5e-3, "variance {var}");
        assert!((kurt - 3.0).abs() < 0.025, "kurtosis {kurt}");
        // P(|x| > 2) = 0.0455003, P(|x| > 3.4426) = 5.76e-4 (exercises the tail branch).
        let p2 = beyond2 as f64 / nf;
        let pr = beyond_r as f64 / nf;
        assert!(
            (p2 - 0.045_500_3).abs() < 5.0 * (0.0455f64 / nf).sqrt(),
            "P(|x|>2) {p2}"
        );
        assert!(
            (pr - 5.76e-4).abs() < 5.0 * (5.76e-4f64 / nf).sqrt(),
            "P(|x|>R) {pr}"
        );
    }

    #[test]
    fn seeded_streams_repeat() {
        let mut a = NormalRng::new(42);
        let mut b = NormalRng::new(42);
        let mut c = NormalRng::new(43);
        let va: Vec<f64> = (0..100).map(|_| a.normal()).collect();
        let vb: Vec<f64> = (0..100).map(|_| b.normal()).collect();
        let vc: Vec<f64> = (0..100).map(|_| c.normal()).collect();
        assert_eq!(va, vb);
        assert_ne!(va, vc);
    }
}
