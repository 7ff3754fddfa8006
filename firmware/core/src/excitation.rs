//! The two-tone excitation (29): `U_exc = a₁·sin(2πf₁t) + a₂·sin(2πf₂t)`, without calling a sine.
//!
//! Each tone is a second-order recursive oscillator, `y ← 2cos Δ·y − y₋₁` (the Chebyshev
//! recursion of sin: one product and one difference per sample, against four products and
//! two sums for a rotating phasor and ~17 operations and two table loads for a corrected
//! table read), on the amplitude-scaled tone itself, and set again from an exact integer
//! phase every [`RESYNC`] samples. (In floating point; the fixed-point type reads the table at
//! every sample, see [`SineTable::RECURSIVE`].)
//!
//! **The phase is exact, and the oscillator never strays far from it.** A 32-bit phase
//! accumulator advanced by an integer increment per sample is what defines the tone: after
//! 10⁸ or 10¹² samples it is exactly `n·Δ mod 2³²`. The accumulator is advanced once per chunk
//! of [`RESYNC`] samples (by `RESYNC·Δ`, exact in integers), and at each chunk's first sample
//! the oscillator is set from it — `a·sin θ` of that sample and of the one before — by the
//! sine table below (a 256-entry table with a second-order correction: `sin(a + b) = sin a·cos
//! b + cos a·sin b` with `cos b ≈ 1 − b²/2`, `sin b ≈ b(1 − b²/6)`, truncation
//! `b⁴/24 < 1.5·10⁻⁸`, below f32 rounding). In between, the recursion runs on the rounded
//! `2cos Δ`. Its errors are not damped: an error `e` made at one sample reappears
//! `n` samples later as `e·sin((n+1)Δ)/sin Δ`, so each is amplified by up to `1/sin Δ` (the
//! price of the one product: the recursion is ill-conditioned at low frequency). Per
//! sample the product and the difference round (≤ 3u·a with u = 2⁻²⁴: |2cos Δ·y| ≤ 2a) and the
//! rounded constant is off by ≤ u (≤ u·a on the product); the two starting values by ≤ 6u·a
//! each (the table read's four roundings, its truncation, the amplitude's product). So
//! after `j` recursions the tone is off by at most `(12 + 4j)·u·a / sin Δ`, for the chunk's
//! last `j = RESYNC − 1 = 31`: `136·u·a / sin Δ`; the next chunk starts exact again, so the
//! error is bounded for ever, however long the excitation runs (a free-running recursion
//! would drift and need its amplitude renormalised). For the paper's DIVE tones at 1 MHz
//! (1 µm at f₀ ≈ 19.7 kHz, sin Δ = 0.12; 70 nm at f₀/4, sin Δ = 0.031) that is 66 pm and
//! 18 pm, below the U DAC's step (6 µm/2¹⁶ = 92 pm); at the demo's 500 kHz half that.
//! Why that is enough: the identification uses U as applied (the DAC's value, whatever the
//! tones were), so the tones only have to be persistently exciting and at their frequencies.
//! (The rotating phasor it replaced was off by ≤ 8·10⁻⁶ of the amplitude, 8 pm on the 1 µm
//! tone, for ~18 instructions more per loop interrupt: `cargo xtask bench`.)
//! `excitation_long_run` checks the bound sample by sample over 10⁸ samples.
//!
//! The price of the integer phase is that a frequency is a multiple of `f_s/2³²` (0.23 mHz at
//! 1 MHz): the synthesised frequency is reported by [`Tone::frequency`], and it is the one the
//! phase is exact for.
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
    /// Tones from the recursive oscillator (true), or from the table at every sample (false).
    /// Floating point: the recursion's product is cheaper than a corrected table read.
    /// Fixed point (Q31.32) keeps the table: there the table read's products are by
    /// constants or by operands the compiler knows to be small (their partial products fold
    /// away), while the recursion's are general 64 × 64-bit products (and its error grows
    /// like 1/sin Δ, where Q31.32's table read is within 2⁻³³); measured on the Cortex-M3
    /// (`cargo xtask bench --m3 --fixed`) with the rotating phasors before it, those cost
    /// ~190 instructions more per sample.
    const RECURSIVE: bool = true;
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

/// Samples per chunk: the oscillators are set from the integer phases at every chunk's first
/// sample and run by the recursion for the other `RESYNC − 1`. 32: the setting (four table
/// reads, ~100 instructions) costs ~3 per sample, and the recursion's error stays below
/// `136·u·a/sin Δ` (module docs); the error grows linearly with the chunk, the setting's
/// share falls as its inverse.
pub const RESYNC: u32 = 32;

/// What identifies a chunk of tones: the excitation's chunk count, the integer phases of
/// the chunk's first sample and the tones' increments and amplitudes. The chunk's values are
/// a function of these alone ([`fill_chunk`]), so a chunk precomputed for an equal key holds
/// exactly the values the loop's own recursion would give.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChunkKey<T> {
    /// The excitation's chunk count (one per chunk, from 1 in a new core; wraps).
    pub chunk: u32,
    /// Phases of the chunk's first sample.
    pub first: [u32; 2],
    /// The tones' increments.
    pub inc: [u32; 2],
    /// The tones' amplitudes.
    pub amp: [T; 2],
}

/// One chunk of tones precomputed by the estimator task (issue 14, round 7): what the loop
/// reads, one value per sample, instead of running the oscillators itself.
#[derive(Clone, Copy, Debug)]
pub struct ToneChunk<T> {
    /// The chunk it is for.
    pub key: ChunkKey<T>,
    /// `a₁·sin θ₁ + a₂·sin θ₂` of the chunk's samples, last first: `values[l]` is the sample
    /// after which `l` rotations are left (the chunk's first sample at `RESYNC − 1`), so the
    /// loop indexes it by its count.
    pub values: [T; RESYNC as usize],
}

impl<T: Real> ToneChunk<T> {
    /// An empty chunk (its key matches no chunk: count 0 is never a chunk's).
    pub const fn new(zero: T) -> Self {
        Self {
            key: ChunkKey {
                chunk: 0,
                first: [0, 0],
                inc: [0, 0],
                amp: [zero, zero],
            },
            values: [zero; RESYNC as usize],
        }
    }
}

/// Where the excitation finds precomputed chunks of tones (the firmware's queue from the
/// estimator task); the default has none, and the loop runs its oscillators (the host's
/// in-line step, the tests). The values are the same either way ([`fill_chunk`]).
pub trait ToneSource<T> {
    /// At a chunk's first sample: take the chunk for `key` if one is ready (true), else the
    /// loop computes this chunk itself.
    #[inline(always)]
    fn take_tones(&mut self, _key: &ChunkKey<T>) -> bool {
        false
    }
    /// The taken chunk's value after which `left` rotations are left (`left < RESYNC`).
    #[inline(always)]
    fn tone(&self, _left: u32) -> T
    where
        T: Real,
    {
        T::ZERO
    }
}

/// No precomputed chunks: the excitation runs its oscillators (tests, callers without a task).
#[derive(Clone, Copy, Debug, Default)]
pub struct NoTones;
impl<T> ToneSource<T> for NoTones {}

/// The tones of the chunk `key` into `out` (last sample first, see [`ToneChunk::values`]),
/// by the very operations of the loop's [`Excitation`]: the oscillators set from the table
/// at the first sample, then the recursion (floating point), or the table at every sample
/// (`SineTable::RECURSIVE` false); the same values bit for bit.
pub fn fill_chunk<T: SineTable>(
    p: &ExcitationParams<T>,
    key: &ChunkKey<T>,
    out: &mut [T; RESYNC as usize],
) {
    let [f1, f2] = key.first;
    let (i1, i2) = (p.tone1.increment, p.tone2.increment);
    if T::RECURSIVE {
        let mut o1 = oscillator(f1, i1, p.tone1.amplitude);
        let mut o2 = oscillator(f2, i2, p.tone2.amplitude);
        let (c1, c2) = (p.tone1.twice_cos, p.tone2.twice_cos);
        let mut l = RESYNC as usize - 1;
        if let Some(v) = out.get_mut(l) {
            *v = o1[0] + o2[0];
        }
        while l > 0 {
            l -= 1;
            o1 = recur(o1, c1);
            o2 = recur(o2, c2);
            if let Some(v) = out.get_mut(l) {
                *v = o1[0] + o2[0];
            }
        }
    } else {
        let (mut ph1, mut ph2) = (f1, f2);
        for v in out.iter_mut().rev() {
            *v = p.tone1.amplitude * sine::<T>(ph1) + p.tone2.amplitude * sine::<T>(ph2);
            ph1 = ph1.wrapping_add(i1);
            ph2 = ph2.wrapping_add(i2);
        }
    }
}

/// One tone of the synthesiser.
#[derive(Clone, Copy, Debug)]
pub struct Tone<T> {
    /// Phase increment per sample.
    pub increment: u32,
    /// Amplitude (internal length unit).
    pub amplitude: T,
    /// `2cos Δ` of the increment's angle `Δ = 2π·increment/2³²` (computed in f64, rounded
    /// once): the recursion's constant.
    pub twice_cos: T,
}

impl<T: Real> Tone<T> {
    /// A tone of `frequency_hz` at `sample_rate_hz` with `amplitude`.
    pub fn new(frequency_hz: f64, sample_rate_hz: f64, amplitude: T) -> Self {
        let inc = frequency_hz / sample_rate_hz * 4_294_967_296.0;
        let inc = inc.clamp(0.0, 4_294_967_295.0);
        let increment = (inc + 0.5) as u32;
        // The angle of the integer increment, not of the request: the recursion then follows
        // the exact phase the chunks are set from.
        let delta = 2.0 * core::f64::consts::PI * increment as f64 / 4_294_967_296.0;
        Self {
            increment,
            amplitude,
            twice_cos: T::from_f64(2.0 * libm::cos(delta)),
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

/// One step of the recursion: `[y, y₋₁]` → `[2cos Δ·y − y₋₁, y]`.
#[inline(always)]
fn recur<T: Real>(y: [T; 2], twice_cos: T) -> [T; 2] {
    [twice_cos * y[0] - y[1], y[0]]
}

/// `[a·sin θ, a·sin(θ − Δ)]` of the integer phase `phase` and increment `inc` (2³² = one
/// turn), from the table: a tone's oscillator at that sample.
#[inline(always)]
fn oscillator<T: SineTable>(phase: u32, inc: u32, a: T) -> [T; 2] {
    [a * sine::<T>(phase), a * sine::<T>(phase.wrapping_sub(inc))]
}

/// State of the two-tone excitation.
#[derive(Clone, Copy, Debug, Default)]
pub struct Excitation<T> {
    /// The two tones' oscillators, `[a·sin θ, a·sin(θ − Δ)]` at the latest sample (while the
    /// loop runs them: not while it reads a precomputed chunk, [`TABLE`]).
    osc1: [T; 2],
    osc2: [T; 2],
    /// Integer phases of the current chunk's last sample (of the latest sample when `left` is 0).
    phase1: u32,
    phase2: u32,
    /// Bits 0–29: the rotations left in the current chunk (0: the next sample starts a
    /// chunk); bit 30 ([`TABLE`]): the current chunk's values are read from a precomputed
    /// chunk ([`ToneSource`]); bit 31 ([`FULL`]): `on` and the envelope at 1, kept with
    /// them. One word, so that the usual sample (fully on, inside a chunk) is one
    /// comparison, `> FULL | TABLE` (or, for a chunk the loop runs itself, a second one),
    /// and its decrement the count's.
    left_full: u32,
    /// The current chunk's count ([`ChunkKey::chunk`]): one per chunk, from 1.
    chunk: u32,
    envelope: T,
    on: bool,
    /// The status word's bits held from sample to sample: `EXCITING` (the envelope above
    /// zero), kept here with the envelope, and the owner's own ([`Self::held_mut`]: the
    /// controller's phase bits and `RECORD_READY`), so that a step ORs them all in with one
    /// load (issue 14, round 18: `EXCITING` took a load and an OR of its own per sample).
    held: u32,
}

/// The status word's bit for a sounding excitation ([`Excitation::held`]).
const EXCITING: u32 = crate::controller::status::EXCITING;

/// [`Excitation::left_full`]'s bit for "fully on".
const FULL: u32 = 1 << 31;
/// [`Excitation::left_full`]'s bit for "the current chunk is precomputed".
const TABLE: u32 = 1 << 30;
/// [`Excitation::left_full`]'s count.
const LEFT: u32 = TABLE - 1;

/// Where the next chunks start, for the estimator task to compute them ahead
/// ([`Excitation::ahead`]): the current chunk's count and the phases of its last sample, the
/// rotations left in it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ahead {
    /// The current chunk's count.
    pub chunk: u32,
    /// The phases of the current chunk's last sample.
    pub phase: [u32; 2],
    /// Samples left in the current chunk (the next chunk starts after them).
    pub left: u32,
}

impl Ahead {
    /// The key of the chunk `m + 1` chunks after the current one, for the tones of `p`; it
    /// starts `left + m·RESYNC` samples from now.
    #[inline(always)]
    pub fn key<T: Real>(&self, m: u32, p: &ExcitationParams<T>) -> ChunkKey<T> {
        let (i1, i2) = (p.tone1.increment, p.tone2.increment);
        let step = 1 + m * RESYNC;
        ChunkKey {
            chunk: self.chunk.wrapping_add(1 + m),
            first: [
                self.phase[0].wrapping_add(step.wrapping_mul(i1)),
                self.phase[1].wrapping_add(step.wrapping_mul(i2)),
            ],
            inc: [i1, i2],
            amp: [p.tone1.amplitude, p.tone2.amplitude],
        }
    }
}

impl<T: SineTable> Excitation<T> {
    /// Rotations left in the current chunk.
    #[inline(always)]
    fn left(&self) -> u32 {
        self.left_full & LEFT
    }

    /// Fully on: `on` and the envelope at 1.
    #[inline(always)]
    fn full(&self) -> bool {
        self.left_full & FULL != 0
    }

    #[inline(always)]
    fn set_full(&mut self, full: bool) {
        self.left_full = (self.left_full & !FULL) | if full { FULL } else { 0 };
    }

    /// Ramp the envelope towards 1 (`true`) or 0 (`false`).
    #[inline(always)]
    pub fn set_on(&mut self, on: bool) {
        self.on = on;
        self.set_full(on && self.envelope == T::ONE);
    }

    /// Switch off at once.
    pub fn silence(&mut self) {
        self.on = false;
        self.envelope = T::ZERO;
        self.set_full(false);
        self.held &= !EXCITING;
    }

    /// The current envelope.
    pub fn envelope(&self) -> T {
        self.envelope
    }

    /// True when the envelope is above zero (`envelope() > 0`, without the comparison).
    #[inline(always)]
    pub fn sounding(&self) -> bool {
        self.held & EXCITING != 0
    }

    /// The status bits held ([`Self::held`]'s field): `EXCITING` while sounding, and the
    /// owner's.
    #[inline(always)]
    pub(crate) fn held(&self) -> u32 {
        self.held
    }

    /// The owner's status bits held with `EXCITING` (the owner must leave `EXCITING` as it is).
    #[inline(always)]
    pub(crate) fn held_mut(&mut self) -> &mut u32 {
        &mut self.held
    }

    /// True when fully on.
    pub fn is_full(&self) -> bool {
        self.envelope >= T::ONE
    }

    /// Where the next chunks start (the block header's, for the estimator task).
    #[inline(always)]
    pub fn ahead(&self) -> Ahead {
        Ahead {
            chunk: self.chunk,
            phase: [self.phase1, self.phase2],
            left: self.left(),
        }
    }

    /// Integer phases of the latest sample, for the tones of `p` (for tests and telemetry).
    pub fn phases(&self, p: &ExcitationParams<T>) -> (u32, u32) {
        (
            self.phase1
                .wrapping_sub(self.left().wrapping_mul(p.tone1.increment)),
            self.phase2
                .wrapping_sub(self.left().wrapping_mul(p.tone2.increment)),
        )
    }

    /// The two tones `a·sin θ` at the latest sample, before the envelope (for tests; zero for
    /// a type that reads the table at every sample, `SineTable::RECURSIVE` false; stale while
    /// a precomputed chunk is read).
    pub fn tone_values(&self) -> (T, T) {
        (self.osc1[0], self.osc2[0])
    }

    /// True while the current chunk is read from a precomputed one (for tests).
    pub fn reading_chunk(&self) -> bool {
        self.left_full & TABLE != 0
    }

    /// A chunk's first sample: the chunk from `src` if it has it, else both oscillators set
    /// from the exact integer phases (or, `RECURSIVE` false, the table read); the sample's
    /// tones. Out of line: once per [`RESYNC`] samples, and its table reads would crowd the
    /// per-sample path.
    #[inline(never)]
    fn start_chunk(&mut self, p: &ExcitationParams<T>, src: &mut impl ToneSource<T>) -> T {
        // The phases of this sample; then those of the chunk's last, RESYNC − 1 samples on.
        let (i1, i2) = (p.tone1.increment, p.tone2.increment);
        let first1 = self.phase1.wrapping_add(i1);
        let first2 = self.phase2.wrapping_add(i2);
        self.chunk = self.chunk.wrapping_add(1);
        self.phase1 = first1.wrapping_add((RESYNC - 1).wrapping_mul(i1));
        self.phase2 = first2.wrapping_add((RESYNC - 1).wrapping_mul(i2));
        let key = ChunkKey {
            chunk: self.chunk,
            first: [first1, first2],
            inc: [i1, i2],
            amp: [p.tone1.amplitude, p.tone2.amplitude],
        };
        if src.take_tones(&key) {
            self.left_full = (self.left_full & FULL) | TABLE | (RESYNC - 1);
            return src.tone(RESYNC - 1);
        }
        self.left_full = (self.left_full & FULL) | (RESYNC - 1);
        if !T::RECURSIVE {
            return p.tone1.amplitude * sine::<T>(first1) + p.tone2.amplitude * sine::<T>(first2);
        }
        self.osc1 = oscillator(first1, i1, p.tone1.amplitude);
        self.osc2 = oscillator(first2, i2, p.tone2.amplitude);
        self.osc1[0] + self.osc2[0]
    }

    /// Both tones advanced one sample: `a₁·sin θ₁ + a₂·sin θ₂`.
    #[inline(always)]
    fn tones(&mut self, p: &ExcitationParams<T>, src: &mut impl ToneSource<T>) -> T {
        if self.left() == 0 {
            return self.start_chunk(p, src);
        }
        self.left_full -= 1;
        if self.left_full & TABLE != 0 {
            return src.tone(self.left());
        }
        if !T::RECURSIVE {
            // The table at this sample's phases (`left` samples before the chunk's last).
            let (ph1, ph2) = self.phases(p);
            return p.tone1.amplitude * sine::<T>(ph1) + p.tone2.amplitude * sine::<T>(ph2);
        }
        self.osc1 = recur(self.osc1, p.tone1.twice_cos);
        self.osc2 = recur(self.osc2, p.tone2.twice_cos);
        self.osc1[0] + self.osc2[0]
    }

    /// The next excitation sample, and advance; the chunks precomputed by `src` when it has
    /// them.
    #[inline(always)]
    pub fn next(&mut self, p: &ExcitationParams<T>, src: &mut impl ToneSource<T>) -> T {
        // The usual samples, fully on inside a chunk: the path below's operations, its tests
        // in one comparison (a precomputed chunk: one load) or two (the recursion).
        let lf = self.left_full;
        if lf > FULL | TABLE {
            let l = lf - 1;
            self.left_full = l;
            return src.tone(l & LEFT);
        }
        if T::RECURSIVE && lf.wrapping_sub(FULL + 1) < LEFT {
            self.left_full = lf - 1;
            self.osc1 = recur(self.osc1, p.tone1.twice_cos);
            self.osc2 = recur(self.osc2, p.tone2.twice_cos);
            return self.osc1[0] + self.osc2[0];
        }
        // The phases run continuously, on or off, so the tones are coherent from tap to tap.
        let s = self.tones(p, src);
        if self.full() {
            // Fully on: the ramp below would leave the envelope at 1, and 1·s = s.
            return s;
        }
        let env = if self.on {
            self.envelope + p.ramp_step
        } else {
            self.envelope - p.ramp_step
        };
        self.envelope = env.clamp_to(T::ZERO, T::ONE);
        self.set_full(self.on && self.envelope == T::ONE);
        let sounding = self.envelope > T::ZERO;
        self.held = (self.held & !EXCITING) | if sounding { EXCITING } else { 0 };
        if sounding {
            self.envelope * s
        } else {
            T::ZERO
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source that has every chunk, computed when asked (the task's `fill_chunk`).
    struct Always<T>(ToneChunk<T>, ExcitationParams<T>);
    impl<T: SineTable> ToneSource<T> for Always<T> {
        fn take_tones(&mut self, key: &ChunkKey<T>) -> bool {
            // Every other chunk, so that both kinds follow each other.
            if key.chunk % 3 == 1 {
                return false;
            }
            self.0.key = *key;
            fill_chunk(&self.1, key, &mut self.0.values);
            true
        }
        fn tone(&self, left: u32) -> T {
            self.0.values[left as usize]
        }
    }

    fn same_with_chunks<T: SineTable>() {
        let fs = 1e6;
        let p = ExcitationParams {
            tone1: Tone::new(19_700.0, fs, T::from_f64(1000.0)),
            tone2: Tone::new(19_700.0 / 4.0, fs, T::from_f64(70.0)),
            ramp_step: T::from_f64(1.0 / 300.0),
        };
        let mut a = Excitation::<T>::default();
        let mut b = Excitation::<T>::default();
        let mut src = Always(ToneChunk::new(T::ZERO), p);
        for i in 0..20_000u32 {
            // On, off and on again, with ramps: every path.
            if i % 5_000 == 17 {
                let on = (i / 5_000) % 2 == 0;
                a.set_on(on);
                b.set_on(on);
            }
            let (x, y) = (a.next(&p, &mut NoTones), b.next(&p, &mut src));
            assert!(x == y, "sample {i}: {:?} against {:?}", x, y);
            assert_eq!(a.phases(&p), b.phases(&p));
        }
    }

    #[test]
    fn precomputed_chunks_give_the_same_values() {
        same_with_chunks::<f32>();
        same_with_chunks::<f64>();
        same_with_chunks::<crate::fixed::Q32>();
    }

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
