//! The estimator off the fast path: the loop hands blocks of samples to an estimator task.
//!
//! With a block of N > 1 samples (`estimator.decimation`), [`crate::Controller`]'s per-sample
//! step only accumulates the block's information ([`BlockStats`]); every N samples it closes a
//! [`Block`], which the estimator task ([`EstimatorTask::run`]: the block update of
//! [`crate::estimator`] and the divergence watch) turns into a [`BlockResult`]. On the
//! firmware the task is a lower-priority interrupt fed through a lock-free queue; on the host
//! it runs in-line. Both follow the same schedule, so their results are bit-identical:
//!
//! * the block clock is the loop's sample counter: a block closes at the start of every N-th
//!   sample (the first sample of the next block), holding the samples the estimator took in
//!   the N samples before;
//! * the result of the block that closed at sample s is adopted at the start of sample s + N,
//!   before that sample uses θ̂ (at the next block's close, just before it is handed over). The
//!   task has N loop periods to finish; the loop never waits for it (a late result is
//!   adopted at the next close, and counted by the firmware).
//!
//! So θ̂ reaches the depth controller and the read-out one to two blocks after the samples
//! that made it. Restarts (a new tap or scan: θ̂₀ and P₀) and the divergence watch's restart
//! travel with the next block; results of blocks from before a restart are dropped (epoch).

use crate::controller::status;
use crate::estimator::{BlockStats, Estimator, EstimatorParams, UpdateInfo};
use crate::guard::{GuardParams, Watch};
use crate::real::Real;

/// Which estimator and constants a block is for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// DIVE, the paper's regressor: θ = [c, k].
    Dive2,
    /// DIVE, the offset regressor: θ = [c, k, k·(h − z₀)].
    Dive3,
    /// SVE, decoupled (high-passed) regressor: θ = [c, k].
    Sve2,
    /// SVE, the paper's regressor: θ = [c, k, k·(h − z₀)].
    Sve3,
}

impl Target {
    /// Two parameters (the `Estimator<T, 2>`), else three.
    #[inline(always)]
    pub fn two(self) -> bool {
        matches!(self, Target::Dive2 | Target::Sve2)
    }
}

/// The information of one block for the estimator it is for: only that estimator's sums travel
/// (36 bytes for two parameters, 60 for three in f32), so that the hand-over is one short copy.
#[derive(Clone, Copy, Debug)]
pub enum BlockData<T> {
    /// DIVE, the paper's regressor.
    Dive2(BlockStats<T, 2>),
    /// DIVE, the offset regressor.
    Dive3(BlockStats<T, 3>),
    /// SVE, decoupled.
    Sve2(BlockStats<T, 2>),
    /// SVE, the paper's regressor.
    Sve3(BlockStats<T, 3>),
}

impl<T> BlockData<T> {
    /// Which estimator the sums are for.
    #[inline(always)]
    pub fn target(&self) -> Target {
        match self {
            BlockData::Dive2(_) => Target::Dive2,
            BlockData::Dive3(_) => Target::Dive3,
            BlockData::Sve2(_) => Target::Sve2,
            BlockData::Sve3(_) => Target::Sve3,
        }
    }
}

/// One block, loop → estimator task.
#[derive(Clone, Copy, Debug)]
pub struct Block<T> {
    /// Restart the estimator at this θ̂₀ with P₀ before the block (a new tap or scan).
    pub restart: Option<[T; 3]>,
    /// Restart the divergence watch before the block.
    pub restart_watch: bool,
    /// The loop's estimation epoch when the block was closed (bumped by every restart).
    pub epoch: u32,
    /// The block's information, and which estimator it is for.
    pub data: BlockData<T>,
}

impl<T> Block<T> {
    /// Which estimator the block is for.
    #[inline(always)]
    pub fn target(&self) -> Target {
        self.data.target()
    }
}

/// One result, estimator task → loop.
#[derive(Clone, Copy, Debug)]
pub struct BlockResult<T> {
    /// Which estimator it is from.
    pub target: Target,
    /// θ̂ after the block ([c, k, 0] for two parameters).
    pub theta: [T; 3],
    /// Status bits of the update: `COV_AT_BOUND`, `PROJECTED`, `EST_RESET`, `EST_DIVERGED`.
    pub flags: u32,
    /// The block's epoch.
    pub epoch: u32,
}

/// The estimators' constants, per mode.
#[derive(Clone, Copy, Debug)]
pub struct TaskParams<T> {
    /// DIVE, two parameters.
    pub dive2: EstimatorParams<T, 2>,
    /// DIVE, three parameters.
    pub dive3: EstimatorParams<T, 3>,
    /// SVE, two parameters.
    pub sve2: EstimatorParams<T, 2>,
    /// SVE, three parameters.
    pub sve3: EstimatorParams<T, 3>,
    /// DIVE divergence watch.
    pub guard_dive: GuardParams<T>,
    /// SVE divergence watch.
    pub guard_sve: GuardParams<T>,
}

/// The estimators and their divergence watch: what the lower-priority task owns.
#[derive(Clone, Copy, Debug)]
pub struct EstimatorTask<T> {
    p: TaskParams<T>,
    est2: Estimator<T, 2>,
    est3: Estimator<T, 3>,
    watch: Watch<T>,
}

/// Status bits of an update.
pub(crate) fn est_flags(info: UpdateInfo) -> u32 {
    let mut f = 0;
    if info.at_bound {
        f |= status::COV_AT_BOUND;
    }
    if info.projected {
        f |= status::PROJECTED;
    }
    if info.reset {
        f |= status::EST_RESET;
    }
    f
}

impl<T: Real> EstimatorTask<T> {
    /// The estimators at DIVE's θ̂₀ with P₀.
    pub fn new(p: TaskParams<T>, theta0: [T; 3]) -> Self {
        Self {
            est2: Estimator::new(&p.dive2, [theta0[0], theta0[1]]),
            est3: Estimator::new(&p.dive3, theta0),
            watch: Watch::default(),
            p,
        }
    }

    /// The two-parameter estimator.
    pub fn estimator2(&self) -> &Estimator<T, 2> {
        &self.est2
    }

    /// The three-parameter estimator.
    pub fn estimator3(&self) -> &Estimator<T, 3> {
        &self.est3
    }

    /// Restart at θ̂₀ with P₀ (DIVE: the estimator in use; SVE: both).
    pub fn restart(&mut self, target: Target, th: [T; 3]) {
        let p = &self.p;
        match target {
            Target::Dive2 => self.est2.restart(&p.dive2, [th[0], th[1]]),
            Target::Dive3 => self.est3.restart(&p.dive3, th),
            Target::Sve2 | Target::Sve3 => {
                self.est3.restart(&p.sve3, th);
                self.est2.restart(&p.sve2, [th[0], th[1]]);
            }
        }
    }

    /// Restart the divergence watch.
    pub fn restart_watch(&mut self) {
        self.watch.restart();
    }

    /// θ̂ of the target's estimator ([c, k, 0] for two parameters).
    #[inline(always)]
    pub fn theta(&self, target: Target) -> [T; 3] {
        if target.two() {
            let t = self.est2.theta();
            [t[0], t[1], T::ZERO]
        } else {
            self.est3.theta()
        }
    }

    /// The divergence policy after an update: P back to P₀ (DIVE: both estimators).
    #[inline(always)]
    fn watch(&mut self, target: Target, info: UpdateInfo, e: T, w: T, block: bool) -> u32 {
        let gp = match target {
            Target::Dive2 | Target::Dive3 => &self.p.guard_dive,
            Target::Sve2 | Target::Sve3 => &self.p.guard_sve,
        };
        let diverging = if block {
            self.watch.diverging_ms(gp, info, e, w)
        } else {
            self.watch.diverging(gp, info, e, w)
        };
        if !diverging {
            return 0;
        }
        match target {
            Target::Dive2 | Target::Dive3 => {
                self.est2.reset_covariance(&self.p.dive2);
                self.est3.reset_covariance(&self.p.dive3);
            }
            Target::Sve2 => self.est2.reset_covariance(&self.p.sve2),
            Target::Sve3 => self.est3.reset_covariance(&self.p.sve3),
        }
        status::EST_DIVERGED
    }

    /// One block: restarts first, then the block update and the divergence watch.
    pub fn run(&mut self, b: &Block<T>) -> BlockResult<T> {
        let target = b.target();
        if let Some(th) = b.restart {
            self.restart(target, th);
        }
        if b.restart_watch {
            self.watch.restart();
        }
        let bi = match &b.data {
            BlockData::Dive2(s) => self.est2.update_block(&self.p.dive2, s),
            BlockData::Sve2(s) => self.est2.update_block(&self.p.sve2, s),
            BlockData::Dive3(s) => self.est3.update_block(&self.p.dive3, s),
            BlockData::Sve3(s) => self.est3.update_block(&self.p.sve3, s),
        };
        let mut flags = est_flags(bi.info);
        flags |= self.watch(target, bi.info, bi.e_ms, bi.w_ms, true);
        BlockResult {
            target,
            theta: self.theta(target),
            flags,
            epoch: b.epoch,
        }
    }

    /// One per-sample update of a two-parameter target (N = 1, the law in the loop).
    #[inline(always)]
    pub fn sample2(&mut self, target: Target, w: T, phi: &[T; 2]) -> u32 {
        let p = if target == Target::Sve2 {
            &self.p.sve2
        } else {
            &self.p.dive2
        };
        let info = self.est2.update(p, w, phi);
        let e = self.est2.last_error();
        est_flags(info) | self.watch(target, info, e, w, false)
    }

    /// One per-sample update of a three-parameter target (N = 1).
    #[inline(always)]
    pub fn sample3(&mut self, target: Target, w: T, phi: &[T; 3]) -> u32 {
        let p = if target == Target::Sve3 {
            &self.p.sve3
        } else {
            &self.p.dive3
        };
        let info = self.est3.update(p, w, phi);
        let e = self.est3.last_error();
        est_flags(info) | self.watch(target, info, e, w, false)
    }
}
