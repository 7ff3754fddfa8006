//! Internal units.
//!
//! The public API speaks SI. Inside, lengths are in nanometres, forces in nanonewtons and time
//! in microseconds, so the numbers the f32 loop works with are of order 10⁻³…10³ instead of
//! 10⁻¹¹…10⁻⁶: sums of terms of very different size (a 1 µm piezo offset and a 10 pm tip
//! motion) then keep f32's 24-bit mantissa for the signal. Derived units:
//!
//! | quantity | internal unit | SI value of one internal unit |
//! | --- | --- | --- |
//! | length | nm | 1e-9 m |
//! | time | µs | 1e-6 s |
//! | force | nN | 1e-9 N |
//! | stiffness | nN/nm | 1 N/m (the same number) |
//! | damping | nN·µs/nm | 1e-6 N·s/m |
//! | mass | nN·µs²/nm | 1e-12 kg |
//! | rate | 1/µs | 1e6 1/s |

/// Metres per internal length unit.
pub const LENGTH: f64 = 1e-9;
/// Seconds per internal time unit.
pub const TIME: f64 = 1e-6;
/// Newtons per internal force unit.
pub const FORCE: f64 = 1e-9;
/// N/m per internal stiffness unit.
pub const STIFFNESS: f64 = FORCE / LENGTH;
/// N·s/m per internal damping unit.
pub const DAMPING: f64 = FORCE * TIME / LENGTH;
/// kg per internal mass unit.
pub const MASS: f64 = FORCE * TIME * TIME / LENGTH;
