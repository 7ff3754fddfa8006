//! Error figures of an image, as in the paper's Fig. 7: errors in percent of each property's
//! maximum (h_max = 0.3 µm, c_max = 8×10⁻⁷ N·s/m, k_max = 5×10⁻³ N/m).

use super::Props;

/// The paper's normalisation of the errors.
pub const PAPER_MAX: Props = Props {
    h_m: 0.3e-6,
    c_ns_per_m: 8e-7,
    k_n_per_m: 5e-3,
};

/// The slope (|Δh| between neighbouring elements / pitch) above which a footprint is "steep":
/// where the surface rises across the footprint's diameter 2a by more than half the apex depth
/// δ, `slope > δ/(4a)`. There the flat-sample geometry behind the element count n and the mean
/// sag no longer holds (part of the footprint is barely touched, the contact shifts uphill),
/// which is Appendix B's explanation of the larger errors at steep topography.
/// DIVE (δ = 450 nm, a = R = 300 nm): 0.375; SVE (δ = 150 nm, a = 260 nm): 0.144.
pub fn steep_slope(depth_m: f64, contact_radius_m: f64) -> f64 {
    depth_m / (4.0 * contact_radius_m)
}

/// Error statistics of one property, in percent of its maximum.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ErrorStats {
    /// RMS over all pixels.
    pub rms_pct: f64,
    /// Largest |error| over all pixels.
    pub max_pct: f64,
    /// Largest |error| over the pixels whose footprint is neither steep nor over the sample's
    /// border (see [`super::footprint_slope`]).
    pub max_not_steep_pct: f64,
    /// Mean error (bias).
    pub mean_pct: f64,
    /// Pixels counted.
    pub pixels: usize,
    /// Of which steep.
    pub steep: usize,
}

/// Error statistics of h, c and k.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImageErrors {
    /// Topography.
    pub h: ErrorStats,
    /// Damping.
    pub c: ErrorStats,
    /// Spring constant.
    pub k: ErrorStats,
}

/// Percent error of each property.
pub fn percent_errors(est: &Props, reference: &Props, max: &Props) -> [f64; 3] {
    [
        (est.h_m - reference.h_m) / max.h_m * 100.0,
        (est.c_ns_per_m - reference.c_ns_per_m) / max.c_ns_per_m * 100.0,
        (est.k_n_per_m - reference.k_n_per_m) / max.k_n_per_m * 100.0,
    ]
}

/// Statistics over `(estimate, reference, slope)` triples.
pub fn image_errors<'a>(
    items: impl Iterator<Item = (&'a Props, &'a Props, f64)>,
    max: &Props,
    steep_slope: f64,
) -> ImageErrors {
    let mut sq = [0.0f64; 3];
    let mut sum = [0.0f64; 3];
    let mut mx = [0.0f64; 3];
    let mut mx_ns = [0.0f64; 3];
    let (mut n, mut steep) = (0usize, 0usize);
    for (e, r, slope) in items {
        let err = percent_errors(e, r, max);
        if err.iter().any(|v| !v.is_finite()) {
            continue;
        }
        n += 1;
        let is_steep = slope > steep_slope;
        steep += is_steep as usize;
        for i in 0..3 {
            sq[i] += err[i] * err[i];
            sum[i] += err[i];
            mx[i] = mx[i].max(err[i].abs());
            if !is_steep {
                mx_ns[i] = mx_ns[i].max(err[i].abs());
            }
        }
    }
    let stat = |i: usize| ErrorStats {
        rms_pct: if n > 0 {
            (sq[i] / n as f64).sqrt()
        } else {
            f64::NAN
        },
        max_pct: mx[i],
        max_not_steep_pct: mx_ns[i],
        mean_pct: if n > 0 { sum[i] / n as f64 } else { f64::NAN },
        pixels: n,
        steep,
    };
    ImageErrors {
        h: stat(0),
        c: stat(1),
        k: stat(2),
    }
}
