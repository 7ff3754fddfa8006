//! Spectra of residuals: a radix-2 FFT, Welch's averaged periodogram (Hann window, half
//! overlap) and, beside the average, the largest periodogram of any segment — a transient
//! line (a mode ringing after a touch) shows there before averaging dilutes it.

use std::f64::consts::PI;

/// In-place complex FFT of length 2ⁿ (forward, no scaling).
pub fn fft(re: &mut [f64], im: &mut [f64]) {
    let n = re.len();
    debug_assert!(n.is_power_of_two() && im.len() == n);
    let mut j = 0;
    for i in 1..n {
        let mut bit = n >> 1;
        while j & bit != 0 {
            j ^= bit;
            bit >>= 1;
        }
        j |= bit;
        if i < j {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut len = 2;
    while len <= n {
        let ang = -2.0 * PI / len as f64;
        let (wr, wi) = (ang.cos(), ang.sin());
        for start in (0..n).step_by(len) {
            let (mut cr, mut ci) = (1.0, 0.0);
            for k in 0..len / 2 {
                let a = start + k;
                let b = a + len / 2;
                let tr = re[b] * cr - im[b] * ci;
                let ti = re[b] * ci + im[b] * cr;
                re[b] = re[a] - tr;
                im[b] = im[a] - ti;
                re[a] += tr;
                im[a] += ti;
                let nr = cr * wr - ci * wi;
                ci = cr * wi + ci * wr;
                cr = nr;
            }
        }
        len <<= 1;
    }
}

/// A one-sided spectrum: frequencies (Hz), the averaged power spectral density (unit²/Hz),
/// the largest single-segment density, and the number of segments averaged.
#[derive(Clone, Debug, Default)]
pub struct Spectrum {
    pub f_hz: Vec<f64>,
    pub psd: Vec<f64>,
    pub psd_max: Vec<f64>,
    pub segments: usize,
}

impl Spectrum {
    /// Welch's estimate of `x` sampled at `fs` with segments of `seg` samples (a power of
    /// two, shortened to the data).
    pub fn welch(x: &[f64], fs: f64, seg: usize) -> Spectrum {
        let mut seg = seg.next_power_of_two();
        while seg > 16 && seg > x.len() {
            seg /= 2;
        }
        if x.len() < seg || seg < 16 {
            return Spectrum::default();
        }
        let win: Vec<f64> = (0..seg)
            .map(|i| 0.5 - 0.5 * (2.0 * PI * i as f64 / seg as f64).cos())
            .collect();
        let u: f64 = win.iter().map(|w| w * w).sum::<f64>();
        let half = seg / 2 + 1;
        let mut psd = vec![0.0; half];
        let mut psd_max = vec![0.0f64; half];
        let mut count = 0;
        let step = seg / 2;
        let mut start = 0;
        let (mut re, mut im) = (vec![0.0; seg], vec![0.0; seg]);
        while start + seg <= x.len() {
            let mean = x[start..start + seg].iter().sum::<f64>() / seg as f64;
            for i in 0..seg {
                re[i] = (x[start + i] - mean) * win[i];
                im[i] = 0.0;
            }
            fft(&mut re, &mut im);
            for k in 0..half {
                let mut p = (re[k] * re[k] + im[k] * im[k]) / (fs * u);
                if k != 0 && k != seg / 2 {
                    p *= 2.0;
                }
                psd[k] += p;
                psd_max[k] = psd_max[k].max(p);
            }
            count += 1;
            start += step;
        }
        for p in &mut psd {
            *p /= count as f64;
        }
        Spectrum {
            f_hz: (0..half).map(|k| k as f64 * fs / seg as f64).collect(),
            psd,
            psd_max,
            segments: count,
        }
    }

    /// Index of the bin nearest `f`.
    pub fn bin(&self, f: f64) -> Option<usize> {
        if self.f_hz.len() < 2 {
            return None;
        }
        let df = self.f_hz[1] - self.f_hz[0];
        let k = (f / df).round();
        (k >= 0.0 && (k as usize) < self.f_hz.len()).then_some(k as usize)
    }

    /// Median of the averaged density over ±`half` bins around `k` (excluding ±1 bin).
    pub fn local_floor(&self, k: usize, half: usize) -> f64 {
        let lo = k.saturating_sub(half);
        let hi = (k + half + 1).min(self.psd.len());
        let mut v: Vec<f64> = (lo..hi)
            .filter(|&j| j + 1 < k || j > k + 1)
            .map(|j| self.psd[j])
            .collect();
        if v.is_empty() {
            return f64::NAN;
        }
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    }

    /// Local maxima of the largest-segment density between `f_lo` and `f_hi`, as a ratio to
    /// the local floor of the average, strongest first.
    pub fn transient_peaks(&self, f_lo: f64, f_hi: f64, count: usize) -> Vec<(f64, f64)> {
        let mut out = Vec::new();
        for k in 1..self.psd_max.len().saturating_sub(1) {
            let f = self.f_hz[k];
            if f < f_lo || f > f_hi {
                continue;
            }
            if self.psd_max[k] >= self.psd_max[k - 1] && self.psd_max[k] >= self.psd_max[k + 1] {
                let floor = self.local_floor(k, 12);
                if floor > 0.0 {
                    out.push((f, self.psd_max[k] / floor));
                }
            }
        }
        out.sort_by(|a, b| b.1.total_cmp(&a.1));
        out.truncate(count);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sine_shows_at_its_frequency_with_its_power() {
        let fs = 1000.0;
        let n = 8192;
        let x: Vec<f64> = (0..n)
            .map(|i| 2.0 * (2.0 * PI * 125.0 * i as f64 / fs).sin())
            .collect();
        let s = Spectrum::welch(&x, fs, 256);
        let k = s.bin(125.0).unwrap();
        let peak = (0..s.psd.len())
            .max_by(|&a, &b| s.psd[a].total_cmp(&s.psd[b]))
            .unwrap();
        assert_eq!(peak, k);
        // Power of the sine (A²/2 = 2) is the density summed over the line's bins.
        let df = s.f_hz[1];
        let p: f64 = s.psd[k - 3..=k + 3].iter().sum::<f64>() * df;
        assert!((p - 2.0).abs() < 0.02, "{p}");
    }
}
