//! Recordings for the nominal model's tests and the diagnose benchmark.
//!
//! * [`ring_down`]: the free ring-down of a damped oscillator from a nonzero initial state in
//!   closed form (f64, sharing no code with `diagnose/` or `plant/`), with Gaussian noise.
//! * [`mid_oscillation_tap`]: a DIVE tap from the project's plant (the paper's lever, a bed of
//!   discrete elements at R/20) whose two tones run from long before the recording starts: the
//!   plant is run through a pre-roll and the first part dropped, so the recording begins
//!   mid-oscillation, as an instrument's does.

#![allow(dead_code)]

use std::f64::consts::PI;
use visco::plant::{Cantilever, Plant, PlantConfig};
use visco::recording::{Metadata, Mode, Recording};
use visco::sample::Sample;

/// SplitMix64 uniform in [0, 1) and Box–Muller normals.
pub struct Rng(pub u64);
impl Rng {
    pub fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
    }
}

/// The free ring-down `M·Z̈ + C·Ż + K·Z = K·U` (U constant) from Z(0) − U = `z0_m`,
/// Ż(0) = `v0_m_per_s`, in closed form: D = U − Z plus Gaussian noise of `noise_m`. The
/// header carries `f0_header_hz` and `q_header` (the truth is f₀ = `f0_hz`, Q = `q`).
#[allow(clippy::too_many_arguments)]
pub fn ring_down(
    f0_hz: f64,
    q: f64,
    f0_header_hz: f64,
    q_header: f64,
    fs_hz: f64,
    n: usize,
    z0_m: f64,
    v0_m_per_s: f64,
    noise_m: f64,
    seed: u64,
) -> (Recording, Vec<f64>) {
    let k = 0.18;
    let w0 = 2.0 * PI * f0_hz;
    let zeta = 1.0 / (2.0 * q);
    let wd = w0 * (1.0 - zeta * zeta).sqrt();
    let a = z0_m;
    let b = (v0_m_per_s + zeta * w0 * z0_m) / wd;
    let u = 40e-9;
    let mut meta = Metadata::new(Mode::Dive, fs_hz, k, 300e-9);
    meta.cantilever_f0_hz = Some(f0_header_hz);
    meta.cantilever_q = Some(q_header);
    let mut rec = Recording::new(meta);
    let mut rng = Rng(seed);
    let mut clean = Vec::with_capacity(n);
    for i in 0..n {
        let t = i as f64 / fs_hz;
        let z = u + (-zeta * w0 * t).exp() * (a * (wd * t).cos() + b * (wd * t).sin());
        let d = u - z;
        clean.push(d);
        rec.t_s.push(t);
        rec.u_m.push(u);
        rec.d_m.push(d + noise_m * rng.normal());
    }
    (rec, clean)
}

/// A DIVE tap's protocol: free, approach, dwell, retract, free (s), depth below the surface
/// (m), and two tones (the paper's (29): near resonance and a quarter of it) running all
/// the time, pre-roll included.
#[derive(Clone, Copy, Debug)]
pub struct TapProtocol {
    pub free_s: f64,
    pub move_s: f64,
    pub dwell_s: f64,
    pub preroll_s: f64,
    pub standoff_m: f64,
    pub depth_m: f64,
    pub tone_near_m: f64,
    pub tone_low_m: f64,
    pub rate_hz: f64,
}

impl TapProtocol {
    /// A short tap: 2 + 4 + 8 + 4 + 2 ms at 500 kHz (10 000 samples) after 10 ms of pre-roll.
    pub fn short() -> Self {
        TapProtocol {
            free_s: 2e-3,
            move_s: 4e-3,
            dwell_s: 8e-3,
            preroll_s: 10e-3,
            standoff_m: 60e-9,
            depth_m: 100e-9,
            tone_near_m: 3e-9,
            tone_low_m: 10e-9,
            rate_hz: 500e3,
        }
    }
    /// A long tap: 10 + 40 + 100 + 40 + 10 ms at 500 kHz (100 000 samples).
    pub fn long() -> Self {
        TapProtocol {
            free_s: 10e-3,
            move_s: 40e-3,
            dwell_s: 100e-3,
            ..Self::short()
        }
    }
    pub fn duration_s(&self) -> f64 {
        2.0 * (self.free_s + self.move_s) + self.dwell_s
    }
    /// U at time t (s) from the recording's start (negative in the pre-roll).
    pub fn u_at(&self, t: f64, f0_hz: f64) -> f64 {
        let top = self.standoff_m;
        let bottom = -self.depth_m;
        let t1 = self.free_s;
        let t2 = t1 + self.move_s;
        let t3 = t2 + self.dwell_s;
        let t4 = t3 + self.move_s;
        // Raised-cosine ramps.
        let ramp = |s: f64| 0.5 - 0.5 * (PI * s.clamp(0.0, 1.0)).cos();
        let base = if t < t1 {
            top
        } else if t < t2 {
            top + (bottom - top) * ramp((t - t1) / self.move_s)
        } else if t < t3 {
            bottom
        } else if t < t4 {
            bottom + (top - bottom) * ramp((t - t3) / self.move_s)
        } else {
            top
        };
        let ph = 2.0 * PI * f0_hz * (t + self.preroll_s);
        base + self.tone_near_m * (0.9 * ph).sin() + self.tone_low_m * (0.25 * ph + 0.3).sin()
    }
}

/// A tap recorded from the plant mid-oscillation: (recording with noise, noise-free D (m)).
/// The bed is the plant's lattice at pitch R/20 (R = 300 nm), k_a = 3×10¹¹ N/m³,
/// c_a = 6×10⁷ N·s/m³ (the paper's cell), the grid offset under the tip `offset` (pitches).
pub fn mid_oscillation_tap(p: &TapProtocol, seed: u64, offset: [f64; 2]) -> (Recording, Vec<f64>) {
    mid_oscillation_tap_on(p, seed, offset, 20)
}

/// [`mid_oscillation_tap`] on a lattice of pitch R/`per_radius` (3: the paper's 100 nm under
/// its 300 nm tip).
pub fn mid_oscillation_tap_on(
    p: &TapProtocol,
    seed: u64,
    offset: [f64; 2],
    per_radius: usize,
) -> (Recording, Vec<f64>) {
    let lever = Cantilever::PAPER;
    let r_tip = 300e-9;
    let (k_a, c_a) = (3e11, 6e7);
    let pitch = r_tip / per_radius as f64;
    // Three pitches of margin beyond the tip radius (23 at R/20).
    let half = per_radius + 3;
    let n = 2 * half + 1;
    let origin = [
        -(half as f64 * pitch) + offset[0] * pitch,
        -(half as f64 * pitch) + offset[1] * pitch,
    ];
    let sample = Sample::flat(
        n,
        n,
        pitch,
        origin,
        0.0,
        c_a * pitch * pitch,
        k_a * pitch * pitch,
    )
    .expect("a valid bed");
    let dt = 1.0 / p.rate_hz;
    let f0 = lever.f0_hz();
    let run = |noise: bool| -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let mut cfg = PlantConfig::paper();
        cfg.cantilever = lever;
        cfg.tip_radius_m = r_tip;
        cfg.time_step_s = dt;
        cfg.travel_z.min_m = -4e-6;
        cfg.travel_z.max_m = 4e-6;
        cfg.dac_z.enabled = false;
        cfg.adc_deflection.min_m = -2.5e-6;
        cfg.adc_deflection.max_m = 2.5e-6;
        cfg.thermal_noise = noise;
        if !noise {
            cfg.adc_deflection.enabled = false;
        }
        let mut plant = Plant::new(cfg, sample.clone(), seed).expect("a valid plant");
        plant.set_time_step(dt).expect("a valid step");
        let pre = (p.preroll_s / dt).round() as usize;
        let steps = (p.duration_s() / dt).round() as usize;
        plant.settle(p.u_at(-(pre as f64) * dt, f0), 0.0, 0.0);
        let (mut t_out, mut u_out, mut d_out) = (Vec::new(), Vec::new(), Vec::new());
        for j in 1..=pre + steps {
            let t = (j as f64 - pre as f64) * dt;
            let u = p.u_at(t, f0);
            let d = plant.step(u, 0.0, 0.0);
            if j > pre {
                t_out.push(t);
                u_out.push(u);
                d_out.push(d);
            }
        }
        (t_out, u_out, d_out)
    };
    let (t, u, d) = run(true);
    let (_, _, clean) = run(false);
    let mut meta = Metadata::new(Mode::Dive, p.rate_hz, lever.k_n_per_m, r_tip);
    meta.cantilever_f0_hz = Some(f0);
    meta.cantilever_q = Some(lever.q());
    let mut rec = Recording::new(meta);
    rec.t_s = t;
    rec.u_m = u;
    rec.d_m = d;
    (rec, clean)
}

/// RMS of a − b over every other block of two samples starting with the second (the
/// diagnosis's held-out half), m.
pub fn held_out_rms(a: &[f64], b: &[f64]) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for i in 0..a.len().min(b.len()) {
        if (i / 2) % 2 == 1 {
            s += (a[i] - b[i]).powi(2);
            n += 1;
        }
    }
    (s / n.max(1) as f64).sqrt()
}
