//! The embedded default sample: a deterministic cell phantom in the paper's ranges (section 5.1:
//! 5 µm × 5 µm, 50 × 50 elements, h up to 0.3 µm, c in 4–8 ×10⁻⁷ N·s/m, k in 2–5 ×10⁻³ N/m).
//!
//! It is a closed-form function of (x, y) with fixed parameters (no random numbers), so every
//! run, test and figure sees the same cell. Features at several length scales, so that the
//! identification's resolution and its errors at steep topography (Appendix B) can be seen:
//!
//! | feature | size | h | c | k |
//! | --- | --- | --- | --- | --- |
//! | substrate | whole field | ≈ 3–5 nm ripple | low (4.2) | high (4.8) |
//! | cell body | ≈ 3.7 µm, lobed outline | dome `√(1−ρ²)`, **vertical tangent at the edge**: a ≈ 60 nm step between neighbouring elements | 5–6 | 2.4 → 3.2 towards the cortex |
//! | nucleus | 1.5 × 1.1 µm ellipse | +0.11 µm cap | ≈ 7.2 | ≈ 3.6 |
//! | nucleoli | 2 × ≈ 0.3 µm | — | up to 8 | down to 2.8 |
//! | stress fibres | 3 lines, σ = 60 nm | +12 nm | +0.3 | +1.2 |
//! | vesicles | 6 bumps, 150–250 nm | +15–25 nm | +1.0 | −0.4 |
//! | cortex texture | 0.45 × 0.55 µm period | — | — | ±0.15 |
//!
//! (c in 10⁻⁷ N·s/m, k in 10⁻³ N/m.) Heights are scaled so the highest element is exactly
//! 0.3 µm; c and k are clamped to the paper's ranges.

use super::Sample;

const N: usize = 50;
const PITCH_M: f64 = 100e-9;
const ORIGIN_M: f64 = 50e-9;
const H_MAX_M: f64 = 0.3e-6;

fn smooth_bump(d2: f64, r: f64) -> f64 {
    // A C¹ bump of radius r: (1 − d²/r²)² inside, 0 outside.
    let q = 1.0 - d2 / (r * r);
    if q > 0.0 {
        q * q
    } else {
        0.0
    }
}

/// Raw (unscaled) height in µm and c, k in the table's units, at (x, y) in µm.
fn cell(x: f64, y: f64) -> (f64, f64, f64) {
    // Cell body: lobed outline around (2.45, 2.55) µm.
    let (bx, by) = (x - 2.45, y - 2.55);
    let r = (bx * bx + by * by).sqrt();
    let th = by.atan2(bx);
    let rb = 1.85 * (1.0 + 0.07 * (3.0 * (th - 0.4)).cos() + 0.05 * (2.0 * th + 1.0).sin());
    let rho = r / rb;
    let body = (1.0 - rho * rho).max(0.0).sqrt(); // 1 at the centre, vertical tangent at ρ = 1
    let inside = ((1.0 - rho) / 0.04).clamp(0.0, 1.0); // material blend, sharp at the edge

    // Nucleus: rotated ellipse.
    let (nx, ny) = (x - 2.75, y - 2.7);
    let (ca, sa) = (0.5f64.cos(), 0.5f64.sin());
    let (u, v) = (ca * nx + sa * ny, -sa * nx + ca * ny);
    let q = (u / 0.75).powi(2) + (v / 0.55).powi(2);
    let nucleus = (1.0 - q).max(0.0).powf(0.6);
    let in_nucleus = ((1.0 - q) / 0.08).clamp(0.0, 1.0);

    // Nucleoli.
    let nucleoli = smooth_bump((x - 2.55).powi(2) + (y - 2.6).powi(2), 0.3)
        + smooth_bump((x - 3.05).powi(2) + (y - 2.95).powi(2), 0.25);

    // Stress fibres: lines a·x + b·y = d (unit normal), Gaussian cross-section.
    let fibres: f64 = [
        (0.94f64, 0.34f64, 2.2f64),
        (0.17, 0.985, 1.6),
        (-0.6, 0.8, 0.55),
    ]
    .iter()
    .map(|&(a, b, d)| {
        let dist = a * x + b * y - d;
        (-0.5 * (dist / 0.06).powi(2)).exp()
    })
    .sum::<f64>()
        * inside
        * (1.0 - in_nucleus);

    // Vesicles in the cytoplasm: (x, y, radius, height nm).
    let vesicles: f64 = [
        (1.3, 1.6, 0.2, 20.0),
        (1.0, 2.9, 0.25, 25.0),
        (1.9, 3.7, 0.15, 15.0),
        (3.6, 1.5, 0.2, 22.0),
        (3.9, 3.2, 0.18, 18.0),
        (2.2, 1.2, 0.22, 20.0),
    ]
    .iter()
    .map(|&(vx, vy, vr, vh): &(f64, f64, f64, f64)| {
        smooth_bump((x - vx).powi(2) + (y - vy).powi(2), vr) * vh / 25.0
    })
    .sum::<f64>()
        * inside;

    let substrate = 0.004
        + 0.0015
            * (2.0 * std::f64::consts::PI * x / 0.7).sin()
            * (2.0 * std::f64::consts::PI * y / 0.9).sin();
    let h = substrate + 0.19 * body + 0.11 * nucleus + 0.012 * fibres + 0.025 * vesicles;

    let texture = 0.15
        * (2.0 * std::f64::consts::PI * x / 0.45).sin()
        * (2.0 * std::f64::consts::PI * y / 0.55).cos();
    let c_cyto = 5.0 + 1.0 * body + 1.0 * vesicles + 0.3 * fibres;
    let k_cyto = 2.4 + 0.8 * rho.min(1.0).powi(2) + 1.2 * fibres - 0.4 * vesicles + texture;
    let c_nuc = 7.2 + 0.8 * nucleoli;
    let k_nuc = 3.6 - 0.8 * nucleoli;
    let c_cell = c_cyto + (c_nuc - c_cyto) * in_nucleus;
    let k_cell = k_cyto + (k_nuc - k_cyto) * in_nucleus;
    let c = 4.2 + (c_cell - 4.2) * inside;
    let k = 4.8 + (k_cell - 4.8) * inside;
    (h, c.clamp(4.0, 8.0), k.clamp(2.0, 5.0))
}

pub(super) fn cell_phantom() -> Sample {
    let mut h = Vec::with_capacity(N * N);
    let mut c = Vec::with_capacity(N * N);
    let mut k = Vec::with_capacity(N * N);
    for j in 0..N {
        for i in 0..N {
            let x_um = (ORIGIN_M + i as f64 * PITCH_M) * 1e6;
            let y_um = (ORIGIN_M + j as f64 * PITCH_M) * 1e6;
            let (hh, cc, kk) = cell(x_um, y_um);
            h.push(hh);
            c.push(cc * 1e-7);
            k.push(kk * 1e-3);
        }
    }
    let h_raw_max = h.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    for v in &mut h {
        *v *= H_MAX_M / h_raw_max;
    }
    // The arrays are built here with valid sizes and finite values.
    Sample::new(N, N, PITCH_M, [ORIGIN_M, ORIGIN_M], h, c, k)
        .expect("the embedded phantom is a valid sample")
}
