//! The input check's steady path (two good samples in a row: no loads and stores of the
//! state it knows, no division by 1) gives the general path's results bit for bit: `Guard`
//! against the general path alone (`Reference`, the check as it was before the steady path),
//! on a wandering tip with spikes, full-scale and NaN readings, reprimes and a changing
//! `spike`, in f32, f64 and Q31.32.
use visco_core::fixed::Q32;
use visco_core::guard::{FaultBits, Guard};
use visco_core::Real;

#[derive(Default, Clone, Copy)]
struct Reference<T> {
    z_good: T,
    velocity: T,
    predicted: T,
    elapsed: T,
    reach: T,
    known: u8,
    hold: u32,
}
impl<T: Real> Reference<T> {
    fn input(
        &mut self,
        spike: T,
        hold: u32,
        d: T,
        u: T,
        d_max: T,
        flags: &FaultBits,
    ) -> (T, bool, u32) {
        let z = u - d;
        let in_range = d.abs_lt(d_max);
        self.predicted += self.velocity;
        let jump = z - self.predicted;
        let plausible = self.known < 2 || jump.abs_lt(self.reach);
        if in_range && plausible {
            self.velocity = if self.known == 0 {
                T::ZERO
            } else if !T::CHEAP_DIV && self.elapsed == T::ONE {
                z - self.z_good
            } else {
                (z - self.z_good) / self.elapsed
            };
            self.elapsed = T::ONE;
            self.z_good = z;
            self.predicted = z;
            self.reach = spike;
            self.known = if self.known > 0 { 2 } else { 1 };
            let ok = self.hold == 0;
            if !ok {
                self.hold -= 1;
            }
            return (d, ok, 0);
        }
        let f = if !in_range {
            if d.is_finite() {
                flags.saturated
            } else {
                flags.invalid
            }
        } else {
            flags.spike
        };
        self.hold = hold;
        self.reach += spike + self.velocity.abs();
        self.elapsed += T::ONE;
        (u - self.z_good, false, f)
    }
}

fn run<T: Real + PartialEq + core::fmt::Debug>(to_bits: fn(T) -> u64) {
    let flags = FaultBits {
        invalid: 1,
        saturated: 2,
        spike: 4,
    };
    let mut seed = 12345u64;
    let mut rnd = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for case in 0..200 {
        let mut g: Guard<T> = Guard::default();
        let mut o: Reference<T> = Reference::default();
        let spike = T::from_f64(2.0 + 10.0 * rnd());
        let mut last_spike = spike;
        let mut pos = 0.0f64;
        let mut vel = 0.0f64;
        for k in 0..5000 {
            vel += (rnd() - 0.5) * 0.3;
            pos += vel;
            let mut d = pos.sin() * 30.0 + (rnd() - 0.5) * 2.0;
            let r = rnd();
            if r < 0.02 {
                d += 300.0 * (rnd() - 0.5);
            } else if r < 0.025 {
                d = 5000.0;
            } else if r < 0.027 {
                d = f64::NAN;
            }
            let u = (k as f64 * 0.01).cos() * 50.0;
            if rnd() < 0.003 {
                g.reprime();
                o.known = 0;
            }
            let spike_k = if rnd() < 0.01 {
                T::from_f64(3.0)
            } else {
                spike
            };
            // The contract: the steady path keeps the last `spike`.
            if spike_k != last_spike {
                g.leave_steady();
                last_spike = spike_k;
            }
            let (dt, ut) = (T::from_f64(d), T::from_f64(u));
            let a = g.input_with(spike_k, 3, dt, ut, T::from_f64(1000.0), &flags);
            let b = o.input(spike_k, 3, dt, ut, T::from_f64(1000.0), &flags);
            assert_eq!(
                (to_bits(a.d), a.ok, a.flags),
                (to_bits(b.0), b.1, b.2),
                "case {case} sample {k}"
            );
        }
    }
}

#[test]
fn steady_path_is_bit_identical_f32() {
    run::<f32>(|x| x.to_bits() as u64);
}
#[test]
fn steady_path_is_bit_identical_f64() {
    run::<f64>(|x| x.to_bits());
}
#[test]
fn steady_path_is_bit_identical_q32() {
    run::<Q32>(|x| x.0 as u64);
}
