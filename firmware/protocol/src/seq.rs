//! Counting lost frames from sequence numbers.
//!
//! Frames may arrive slightly out of order (in the firmware a loop interrupt can queue a
//! frame between the main loop taking a sequence number and sending its own frame), so a
//! gap is only *provisional* while it is within the last [`WINDOW`] sequence numbers; a late
//! frame fills its hole. A hole becomes a lost frame when it leaves the window, or when the
//! caller asks for the total. Nothing is ever dropped without being counted.

/// How far back a late frame is still accepted.
pub const WINDOW: u32 = 64;

/// What one observed sequence number meant.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqEvent {
    /// The next expected number (or the first one seen).
    InOrder,
    /// Jumped ahead: this many numbers were skipped (provisionally lost).
    Gap(u32),
    /// An earlier number that fills a provisional hole.
    Late,
    /// Seen before.
    Duplicate,
    /// Older than the window (already counted as lost) or older than the first number seen;
    /// ignored.
    Stale,
}

/// Tracks one sequence number stream.
#[derive(Clone, Copy, Debug, Default)]
pub struct SeqTracker {
    started: bool,
    highest: u32,
    /// Bit `i` set: `highest - i` was received.
    window: u64,
    /// Numbers in the window that belong to the stream (≤ 64; fewer right after the start).
    span: u32,
    lost_final: u64,
    received: u64,
    duplicates: u64,
    stale: u64,
}

impl SeqTracker {
    /// A tracker that takes the first number it sees as the start.
    pub const fn new() -> Self {
        Self {
            started: false,
            highest: 0,
            window: 0,
            span: 0,
            lost_final: 0,
            received: 0,
            duplicates: 0,
            stale: 0,
        }
    }

    /// A tracker for a stream that starts at `first` (frames before the first one received
    /// then count as lost, e.g. when the sender starts at 0).
    pub const fn starting_at(first: u32) -> Self {
        let mut t = Self::new();
        t.started = true;
        t.highest = first.wrapping_sub(1);
        t.window = 1; // the virtual "previous" number counts as received
        t.span = 1;
        t
    }

    /// Records one received sequence number.
    pub fn observe(&mut self, seq: u32) -> SeqEvent {
        if !self.started {
            self.started = true;
            self.highest = seq;
            self.window = 1;
            self.span = 1;
            self.received += 1;
            return SeqEvent::InOrder;
        }
        let d = seq.wrapping_sub(self.highest) as i32;
        if d > 0 {
            let d = d as u32;
            // Holes that leave the window are final losses.
            let leaving = if d >= 64 {
                self.window
            } else {
                self.window >> (64 - d)
            };
            let leaving_span = self
                .span
                .saturating_add(d)
                .saturating_sub(64)
                .min(self.span);
            let holes_leaving = leaving_span - leaving.count_ones().min(leaving_span);
            self.lost_final += holes_leaving as u64;
            if d > 64 {
                // Numbers skipped that never even entered the window.
                self.lost_final += (d - 64) as u64;
            }
            self.window = if d >= 64 { 1 } else { (self.window << d) | 1 };
            self.span = self.span.saturating_add(d).min(64);
            self.highest = seq;
            self.received += 1;
            if d == 1 {
                SeqEvent::InOrder
            } else {
                SeqEvent::Gap(d - 1)
            }
        } else if d == 0 {
            self.duplicates += 1;
            SeqEvent::Duplicate
        } else {
            let age = d.unsigned_abs();
            if age < self.span {
                let bit = 1u64 << age;
                if self.window & bit != 0 {
                    self.duplicates += 1;
                    SeqEvent::Duplicate
                } else {
                    self.window |= bit;
                    self.received += 1;
                    SeqEvent::Late
                }
            } else {
                self.stale += 1;
                SeqEvent::Stale
            }
        }
    }

    /// Frames lost so far, including the holes still inside the window.
    pub fn lost(&self) -> u64 {
        let mask = if self.span >= 64 {
            u64::MAX
        } else {
            (1u64 << self.span) - 1
        };
        let holes = self.span - (self.window & mask).count_ones().min(self.span);
        self.lost_final + holes as u64
    }
    /// Distinct frames received.
    pub fn received(&self) -> u64 {
        self.received
    }
    /// Frames received twice.
    pub fn duplicates(&self) -> u64 {
        self.duplicates
    }
    /// Frames that arrived after they had been counted lost.
    pub fn stale(&self) -> u64 {
        self.stale
    }
    /// The highest number received, if any.
    pub fn highest(&self) -> Option<u32> {
        (self.received > 0).then_some(self.highest)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use std::vec::Vec;

    #[test]
    fn in_order_loses_nothing() {
        let mut t = SeqTracker::starting_at(0);
        for s in 0..1000 {
            assert_eq!(t.observe(s), SeqEvent::InOrder);
        }
        assert_eq!(t.lost(), 0);
        assert_eq!(t.received(), 1000);
    }

    #[test]
    fn gaps_are_counted_and_late_frames_fill_them() {
        let mut t = SeqTracker::new();
        t.observe(10);
        assert_eq!(t.observe(13), SeqEvent::Gap(2));
        assert_eq!(t.lost(), 2);
        assert_eq!(t.observe(11), SeqEvent::Late);
        assert_eq!(t.lost(), 1);
        assert_eq!(t.observe(11), SeqEvent::Duplicate);
        for s in 14..300 {
            t.observe(s);
        }
        assert_eq!(t.lost(), 1);
        assert_eq!(t.observe(12), SeqEvent::Stale);
        assert_eq!(t.lost(), 1);
    }

    #[test]
    fn big_jump_and_wraparound() {
        let mut t = SeqTracker::new();
        t.observe(u32::MAX - 1);
        t.observe(u32::MAX);
        assert_eq!(t.observe(0), SeqEvent::InOrder);
        assert_eq!(t.observe(1000), SeqEvent::Gap(999));
        assert_eq!(t.lost(), 999);
    }

    #[test]
    fn starting_at_counts_missing_head() {
        let mut t = SeqTracker::starting_at(0);
        assert_eq!(t.observe(3), SeqEvent::Gap(3));
        assert_eq!(t.lost(), 3);
    }

    proptest! {
        /// Dropping an arbitrary subset of a stream and shuffling it locally (by less than the
        /// window) is counted exactly.
        #[test]
        fn prop_exact_loss_count(
            n in 1usize..2000,
            drops in proptest::collection::vec(any::<bool>(), 2000),
            swaps in proptest::collection::vec((0usize..2000, 1usize..8), 0..50),
        ) {
            let mut kept: Vec<u32> = (0..n as u32).filter(|&i| !drops[i as usize] || i == 0).collect();
            for (at, by) in swaps {
                if kept.len() > 1 {
                    let a = at % kept.len();
                    let b = (a + by).min(kept.len() - 1);
                    kept.swap(a, b);
                }
            }
            let mut t = SeqTracker::starting_at(0);
            for &s in &kept {
                t.observe(s);
            }
            let highest = *kept.iter().max().unwrap();
            // Every number up to the highest is either received (in time) or lost; a frame
            // that arrives after leaving the window stays lost and is counted as stale.
            prop_assert_eq!(t.lost(), highest as u64 + 1 - t.received());
            prop_assert_eq!(t.received() + t.stale(), kept.len() as u64);
            prop_assert_eq!(t.duplicates(), 0);
        }
    }
}
