//! The two-tone excitation (29): `U_exc = a₁·sin(2πf₁t) + a₂·sin(2πf₂t)`, without calling a sine.
//!
//! Each tone is a direct digital synthesiser: a 32-bit phase accumulator advanced by an integer
//! increment per sample, and a 256-entry sine table with a second-order correction. The phase is
//! an integer, so it never drifts: after 10⁸ or 10¹² samples it is exactly `n·Δ mod 2³²`. The
//! output error is that of the table step alone, independent of how long it has run:
//! with `a` the table angle and `b < 2π/256` the remainder, `sin(a + b) = sin a·cos b +
//! cos a·sin b` with `cos b ≈ 1 − b²/2`, `sin b ≈ b(1 − b²/6)`, whose truncation error
//! `b⁴/24 < 1.5·10⁻⁸` is below f32 rounding. A recursive oscillator (a rotation per sample)
//! would cost about the same but accumulates phase error from the rounded rotation angle
//! (≈ 0.75 rad after 10⁸ samples at 20 kHz in f32) and needs amplitude renormalisation.
//!
//! The price is that a frequency is a multiple of `f_s/2³²` (0.23 mHz at 1 MHz): the
//! synthesised frequency is reported by [`Tone::frequency`], and it is the one the phase is
//! exact for.
//!
//! An envelope in [0, 1] ramps the excitation in and out (a DIVE tap switches it on only in
//! contact: a base oscillation of 1 µm near resonance would swing a free cantilever by Q·1 µm).

use crate::real::Real;

/// log2 of the table length.
const TABLE_BITS: u32 = 8;
/// Entries per period.
pub const TABLE_LEN: usize = 1 << TABLE_BITS;
/// The table holds a period and a quarter, so that `cos a = table[i + TABLE_LEN/4]`.
pub const TABLE_SIZE: usize = TABLE_LEN + TABLE_LEN / 4;

/// sin x by its Taylor series after reduction to [−π, π]; used only at compile time.
const fn sin_const(x: f64) -> f64 {
    let pi = core::f64::consts::PI;
    let mut r = x;
    while r > pi {
        r -= 2.0 * pi;
    }
    while r < -pi {
        r += 2.0 * pi;
    }
    let mut term = r;
    let mut sum = r;
    let mut n = 1;
    while n < 30 {
        term = -term * r * r / ((2 * n) as f64 * (2 * n + 1) as f64);
        sum += term;
        n += 1;
    }
    sum
}

const fn table_f64() -> [f64; TABLE_SIZE] {
    let mut t = [0.0; TABLE_SIZE];
    let mut i = 0;
    while i < TABLE_SIZE {
        t[i] = sin_const(2.0 * core::f64::consts::PI * i as f64 / TABLE_LEN as f64);
        i += 1;
    }
    t
}

const fn table_f32() -> [f32; TABLE_SIZE] {
    let d = table_f64();
    let mut t = [0.0f32; TABLE_SIZE];
    let mut i = 0;
    while i < TABLE_SIZE {
        t[i] = d[i] as f32;
        i += 1;
    }
    t
}

/// The sine table in f64.
pub static SIN_TABLE_F64: [f64; TABLE_SIZE] = table_f64();
/// The sine table in f32.
pub static SIN_TABLE_F32: [f32; TABLE_SIZE] = table_f32();

/// A number type with a sine table.
pub trait SineTable: Real + 'static {
    /// sin(2π·i/TABLE_LEN) for i in 0..TABLE_SIZE.
    fn sine_table() -> &'static [Self; TABLE_SIZE];
}

impl SineTable for f32 {
    #[inline(always)]
    fn sine_table() -> &'static [f32; TABLE_SIZE] {
        &SIN_TABLE_F32
    }
}

impl SineTable for f64 {
    #[inline(always)]
    fn sine_table() -> &'static [f64; TABLE_SIZE] {
        &SIN_TABLE_F64
    }
}

/// sin(2π·phase/2³²).
#[inline(always)]
pub fn sine<T: SineTable>(phase: u32) -> T {
    let table = T::sine_table();
    // Both indices are < TABLE_SIZE by construction (the shift leaves TABLE_BITS bits), so
    // the bounds checks are proven away.
    let i = (phase >> (32 - TABLE_BITS)) as usize;
    let s = table[i & (TABLE_LEN - 1)];
    let c = table[(i & (TABLE_LEN - 1)) + TABLE_LEN / 4];
    let frac = (phase & ((1u32 << (32 - TABLE_BITS)) - 1)) as i32;
    // b = frac · 2π/2³²; frac < 2²⁴ converts to f32 exactly.
    let b = T::from_i32(frac) * T::from_f64(2.0 * core::f64::consts::PI / 4_294_967_296.0);
    let b2 = b * b;
    let cos_b = T::ONE - b2 * T::from_f64(0.5);
    let sin_b = b * (T::ONE - b2 * T::from_f64(1.0 / 6.0));
    s * cos_b + c * sin_b
}

/// One tone of the synthesiser.
#[derive(Clone, Copy, Debug)]
pub struct Tone<T> {
    /// Phase increment per sample.
    pub increment: u32,
    /// Amplitude (internal length unit).
    pub amplitude: T,
}

impl<T: Real> Tone<T> {
    /// A tone of `frequency_hz` at `sample_rate_hz` with `amplitude`.
    pub fn new(frequency_hz: f64, sample_rate_hz: f64, amplitude: T) -> Self {
        let inc = frequency_hz / sample_rate_hz * 4_294_967_296.0;
        let inc = inc.clamp(0.0, 4_294_967_295.0);
        Self {
            increment: (inc + 0.5) as u32,
            amplitude,
        }
    }

    /// The synthesised frequency.
    pub fn frequency(&self, sample_rate_hz: f64) -> f64 {
        self.increment as f64 * sample_rate_hz / 4_294_967_296.0
    }
}

/// Constants of the two-tone excitation.
#[derive(Clone, Copy, Debug)]
pub struct ExcitationParams<T> {
    /// The tone near resonance.
    pub tone1: Tone<T>,
    /// The tone below resonance.
    pub tone2: Tone<T>,
    /// Envelope change per sample while ramping.
    pub ramp_step: T,
}

/// State of the two-tone excitation.
#[derive(Clone, Copy, Debug, Default)]
pub struct Excitation<T> {
    phase1: u32,
    phase2: u32,
    envelope: T,
    on: bool,
}

impl<T: SineTable> Excitation<T> {
    /// Ramp the envelope towards 1 (`true`) or 0 (`false`).
    #[inline(always)]
    pub fn set_on(&mut self, on: bool) {
        self.on = on;
    }

    /// Switch off at once.
    pub fn silence(&mut self) {
        self.on = false;
        self.envelope = T::ZERO;
    }

    /// The current envelope.
    pub fn envelope(&self) -> T {
        self.envelope
    }

    /// True when fully on.
    pub fn is_full(&self) -> bool {
        self.envelope >= T::ONE
    }

    /// Phases (for tests and telemetry).
    pub fn phases(&self) -> (u32, u32) {
        (self.phase1, self.phase2)
    }

    /// The next excitation sample, and advance.
    #[inline(always)]
    pub fn next(&mut self, p: &ExcitationParams<T>) -> T {
        // The phases run continuously, on or off, so the tones are coherent from tap to tap.
        self.phase1 = self.phase1.wrapping_add(p.tone1.increment);
        self.phase2 = self.phase2.wrapping_add(p.tone2.increment);
        if self.on && self.envelope == T::ONE {
            // Fully on: the ramp below would leave the envelope at 1, and 1·s = s.
            return p.tone1.amplitude * sine::<T>(self.phase1)
                + p.tone2.amplitude * sine::<T>(self.phase2);
        }
        let env = if self.on {
            self.envelope + p.ramp_step
        } else {
            self.envelope - p.ramp_step
        };
        self.envelope = env.clamp_to(T::ZERO, T::ONE);
        if self.envelope > T::ZERO {
            let s = p.tone1.amplitude * sine::<T>(self.phase1)
                + p.tone2.amplitude * sine::<T>(self.phase2);
            self.envelope * s
        } else {
            T::ZERO
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_is_accurate() {
        for (i, v) in SIN_TABLE_F64.iter().enumerate() {
            let x = 2.0 * core::f64::consts::PI * i as f64 / TABLE_LEN as f64;
            assert!((v - libm::sin(x)).abs() < 1e-15, "i={i}");
        }
    }

    #[test]
    fn sine_error_is_below_f32_rounding_everywhere() {
        let mut worst = 0.0f64;
        let mut p: u32 = 0;
        // A stride coprime with 2³² sweeps all table cells and fractions.
        for _ in 0..2_000_000 {
            p = p.wrapping_add(2_147_483_659);
            let exact = libm::sin(2.0 * core::f64::consts::PI * p as f64 / 4_294_967_296.0);
            let e32 = (sine::<f32>(p) as f64 - exact).abs();
            let e64 = (sine::<f64>(p) - exact).abs();
            assert!(e64 < 2e-8, "f64 {e64}");
            worst = worst.max(e32);
        }
        assert!(worst < 2.5e-7, "f32 worst error {worst}");
    }
}
