//! A lock-free single-producer single-consumer ring for `Copy` items, for handing data
//! between the loop interrupt and the main loop without critical sections.
//!
//! The queue lives in a `static`; [`Spsc::split`] hands out the one [`Producer`] and the one
//! [`Consumer`] exactly once, so the single-producer/single-consumer contract is enforced by
//! ownership rather than by comments. `push`/`pop` never block and never panic: a full queue
//! returns the item to the caller, who counts it.

use core::cell::UnsafeCell;
use core::mem::MaybeUninit;
use core::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// The ring. `N` must be a power of two (checked at compile time in [`Spsc::new`]).
pub struct Spsc<T: Copy, const N: usize> {
    slots: [UnsafeCell<MaybeUninit<T>>; N],
    /// Next slot to read (written by the consumer only).
    head: AtomicUsize,
    /// Next slot to write (written by the producer only).
    tail: AtomicUsize,
    split: AtomicBool,
}

// SAFETY: slots are written only by the unique producer before it publishes them with a
// Release store of `tail`, and read only by the unique consumer after an Acquire load of
// `tail`; the consumer releases a slot with a Release store of `head`, which the producer
// Acquire-loads before reusing it. `T: Send` because items move between contexts.
unsafe impl<T: Copy + Send, const N: usize> Sync for Spsc<T, N> {}

impl<T: Copy, const N: usize> Default for Spsc<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Copy, const N: usize> Spsc<T, N> {
    const POWER_OF_TWO: () = assert!(N.is_power_of_two() && N >= 2);

    /// An empty ring.
    pub const fn new() -> Self {
        #[allow(clippy::let_unit_value)]
        let _ = Self::POWER_OF_TWO;
        Self {
            slots: [const { UnsafeCell::new(MaybeUninit::uninit()) }; N],
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
            split: AtomicBool::new(false),
        }
    }

    /// The producer and consumer ends; `None` after the first call.
    pub fn split(&self) -> Option<(Producer<'_, T, N>, Consumer<'_, T, N>)> {
        if self.split.swap(true, Ordering::AcqRel) {
            return None;
        }
        Some((Producer { q: self }, Consumer { q: self }))
    }

    fn len_between(head: usize, tail: usize) -> usize {
        tail.wrapping_sub(head)
    }
}

/// The writing end.
pub struct Producer<'a, T: Copy, const N: usize> {
    q: &'a Spsc<T, N>,
}

/// The reading end.
pub struct Consumer<'a, T: Copy, const N: usize> {
    q: &'a Spsc<T, N>,
}

impl<T: Copy, const N: usize> Producer<'_, T, N> {
    /// Appends `v`, or gives it back when the ring is full.
    #[inline(always)]
    pub fn push(&mut self, v: T) -> Result<(), T> {
        let tail = self.q.tail.load(Ordering::Relaxed);
        let head = self.q.head.load(Ordering::Acquire);
        if Spsc::<T, N>::len_between(head, tail) >= N {
            return Err(v);
        }
        match self.q.slots.get(tail & (N - 1)) {
            Some(slot) => {
                // SAFETY: the slot is not visible to the consumer until `tail` is published.
                unsafe { (*slot.get()).write(v) };
                self.q.tail.store(tail.wrapping_add(1), Ordering::Release);
                Ok(())
            }
            None => Err(v), // unreachable: the index is masked to N - 1
        }
    }
    /// Free slots.
    #[inline(always)]
    pub fn free(&self) -> usize {
        let tail = self.q.tail.load(Ordering::Relaxed);
        let head = self.q.head.load(Ordering::Acquire);
        N - Spsc::<T, N>::len_between(head, tail).min(N)
    }
}

impl<T: Copy, const N: usize> Consumer<'_, T, N> {
    /// Takes the oldest item.
    #[inline(always)]
    pub fn pop(&mut self) -> Option<T> {
        let head = self.q.head.load(Ordering::Relaxed);
        let tail = self.q.tail.load(Ordering::Acquire);
        if head == tail {
            return None;
        }
        let slot = self.q.slots.get(head & (N - 1))?;
        // SAFETY: the producer published this slot (Acquire above) and will not touch it
        // again until `head` moves past it.
        let v = unsafe { (*slot.get()).assume_init_read() };
        self.q.head.store(head.wrapping_add(1), Ordering::Release);
        Some(v)
    }
    /// Items waiting.
    #[inline(always)]
    pub fn len(&self) -> usize {
        let head = self.q.head.load(Ordering::Relaxed);
        let tail = self.q.tail.load(Ordering::Acquire);
        Spsc::<T, N>::len_between(head, tail)
    }
    /// True when nothing is waiting.
    #[inline(always)]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fifo_full_and_wraparound() {
        let q: Spsc<u32, 4> = Spsc::new();
        let (mut p, mut c) = q.split().unwrap();
        assert!(q.split().is_none());
        for round in 0..10u32 {
            for i in 0..4 {
                p.push(round * 10 + i).unwrap();
            }
            assert_eq!(p.push(99), Err(99));
            assert_eq!(p.free(), 0);
            for i in 0..4 {
                assert_eq!(c.pop(), Some(round * 10 + i));
            }
            assert_eq!(c.pop(), None);
        }
    }

    #[test]
    fn threads() {
        static Q: Spsc<u64, 64> = Spsc::new();
        let (mut p, mut c) = Q.split().unwrap();
        let t = std::thread::spawn(move || {
            for i in 0..100_000u64 {
                let mut v = i;
                while let Err(back) = p.push(v) {
                    v = back;
                    std::hint::spin_loop();
                }
            }
        });
        let mut next = 0u64;
        while next < 100_000 {
            if let Some(v) = c.pop() {
                assert_eq!(v, next);
                next += 1;
            }
        }
        t.join().unwrap();
    }
}
