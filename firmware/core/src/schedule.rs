//! The estimator off the fast path: the loop hands blocks of samples to an estimator task.
//!
//! With a block of N > 1 samples (`estimator.decimation`), [`crate::Controller`]'s per-sample
//! step hands every sample of a running mode to a [`SampleSink`] as its raw regressor inputs
//! (Z, U, the reference and what the sample is for: [`Sample`]); the prefilters, the
//! regressor and the SVE high-passes run in the task ([`EstimatorTask::feed`]), not in the
//! loop. Every N samples the step closes a [`Block`] (a header: restarts, epoch, target, how
//! many samples), which the estimator task ([`EstimatorTask::run`]: the samples through the
//! filters, the block sums [`BlockStats`] over the estimating ones, the block update of
//! [`crate::estimator`] and the divergence watch) turns into a [`BlockResult`]. On the firmware the task is a lower-priority interrupt handed each
//! block whole (its header and samples in a buffer passed through a lock-free queue) and runs
//! it in passes on the buffer ([`EstimatorTask::run_in_place`]); on the host it runs in-line,
//! on the block's samples staged as the firmware's buffer holds them ([`Staged`]) and by the
//! same pass (issue 14, round 12: DIVE's grouped prefilters take their groups from the
//! block's own samples, known only at its close; until then the host added each sample to
//! the block sums as it came, [`BlockSums`]). Both follow the same schedule and add the same
//! samples in the same order, so their results are bit-identical:
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
use crate::estimator::{BlockInfo, BlockStats, Estimator, EstimatorParams, UpdateInfo};
use crate::excitation::{
    fill_chunk, Ahead, ChunkKey, ExcitationParams, SineTable, ToneSource, RESYNC,
};
use crate::guard::{GuardParams, Watch};
use crate::prefilter::{Filtered, HighPass, GROUP};
use crate::real::Real;
use crate::regressor::{w_of, GroupParams, Regressor, RegressorParams};

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

/// One loop sample, loop → estimator task: the raw inputs of the regressor, from which the
/// task forms `w` and `φ` itself (the prefilters, the regressor and the SVE high-passes run
/// in the task, not in the loop interrupt), and what to do with them ([`SAMPLE_EST`],
/// [`SAMPLE_HP`], [`SAMPLE_HP_REST`]). The loop hands over every sample while a mode runs,
/// so the task's filters see an unbroken signal; it adds to the block sums only those
/// flagged [`SAMPLE_EST`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample<T> {
    /// Z = U − D, the tip position sampled now (internal units).
    pub z: T,
    /// U held over the period ending now (the DAC value output one step ago).
    pub u: T,
    /// The regressor's reference: the contact height h (DIVE, the paper's regressor) or z₀
    /// (DIVE offset, SVE); `φ = [−s·Z/Λ, r − Z/Λ, 1]`.
    pub r: T,
    /// [`SAMPLE_EST`] | [`SAMPLE_HP`] | [`SAMPLE_HP_REST`].
    pub flags: u32,
}

/// [`Sample::flags`]: an estimating sample, its `w` and `φ` go into the block sums.
pub const SAMPLE_EST: u32 = 1;
/// [`Sample::flags`]: `w` and `φ` through the SVE high-passes (the decoupled regressor),
/// which run on every such sample, estimating or not.
pub const SAMPLE_HP: u32 = 2;
/// [`Sample::flags`]: the high-passes set at rest at this sample's `w` and `φ` (the SVE
/// contact); never estimating.
pub const SAMPLE_HP_REST: u32 = 4;

/// Where the loop puts its estimating samples while blocks are in use (N > 1): on the
/// firmware the producer end of a queue to the estimator task, on the host
/// ([`crate::Controller::step_internal`]) the in-line task's block sums. Closures
/// `FnMut(Sample<T>)` are sinks.
/// The sink is also where the excitation finds chunks of tones precomputed by the task
/// ([`ToneSource`]; a closure has none).
pub trait SampleSink<T>: ToneSource<T> {
    /// One sample of the block being accumulated, in order.
    fn push(&mut self, s: Sample<T>);
}

impl<T, F: FnMut(Sample<T>)> SampleSink<T> for F {
    #[inline(always)]
    fn push(&mut self, s: Sample<T>) {
        self(s)
    }
}

impl<T, F: FnMut(Sample<T>)> ToneSource<T> for F {}

/// One block header, loop → estimator task. The block's samples travel apart, in order,
/// through a [`SampleSink`]: the header says how many of the samples waiting belong to this
/// block, after how many to discard.
#[derive(Clone, Copy, Debug)]
pub struct Block<T> {
    /// Restart the estimator at this θ̂₀ with P₀ before the block (a new tap or scan).
    pub restart: Option<[T; 3]>,
    /// Restart the divergence watch before the block.
    pub restart_watch: bool,
    /// The loop's estimation epoch when the block was closed (bumped by every restart).
    pub epoch: u32,
    /// Which estimator the block is for.
    pub target: Target,
    /// Samples handed over before this block's own that are to be discarded: taken before a
    /// restart (the block sums started again there), or, on the firmware, queued for a block
    /// that was lost.
    pub skip: u32,
    /// The block's samples, following the discarded ones. Zero only on the firmware, for a
    /// block whose samples did not all fit the queue: its restarts still apply, θ̂ does not
    /// move.
    pub samples: u32,
    /// The chunks of tones the task computes ahead with this block.
    pub tones: ToneAhead,
}

/// The chunks of tones the estimator task computes ahead with a block (issue 14, round 7):
/// those starting N to 2N − 1 samples after the block's close (N samples: the task's
/// deadline, as for its result), so that over the blocks every chunk is asked for once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ToneAhead {
    /// Where the next chunks start, at the block's close.
    pub at: Ahead,
    /// The block length N.
    pub n: u32,
    /// The tones: 0 none, [`TONES_DIVE`], [`TONES_SVE`].
    pub which: u32,
}

impl ToneAhead {
    /// No chunks.
    pub const NONE: Self = Self {
        at: Ahead {
            chunk: 0,
            phase: [0, 0],
            left: 0,
        },
        n: 0,
        which: 0,
    };
}

/// [`ToneAhead::which`]: DIVE's tones.
pub const TONES_DIVE: u32 = 1;
/// [`ToneAhead::which`]: SVE's tones.
pub const TONES_SVE: u32 = 2;

impl<T> Block<T> {
    /// Which estimator the block is for.
    #[inline(always)]
    pub fn target(&self) -> Target {
        self.target
    }
}

/// A block's sums for either estimator: what [`EstimatorTask::run`] forms from the samples,
/// and what the host's [`crate::Controller::step_internal`] adds its samples to as they come.
#[derive(Clone, Copy, Debug)]
pub struct BlockSums<T> {
    /// Two parameters.
    pub s2: BlockStats<T, 2>,
    /// Three parameters.
    pub s3: BlockStats<T, 3>,
    /// Estimating samples added.
    pub n: u32,
    /// The block's samples seen (estimating or not): the next one's place in the block.
    pub seen: u32,
}

impl<T: Real> Default for BlockSums<T> {
    fn default() -> Self {
        Self {
            s2: BlockStats::default(),
            s3: BlockStats::default(),
            n: 0,
            seen: 0,
        }
    }
}

impl<T: Real> Default for Sample<T> {
    fn default() -> Self {
        Self {
            z: T::ZERO,
            u: T::ZERO,
            r: T::ZERO,
            flags: 0,
        }
    }
}

impl<T: Real> BlockSums<T> {
    /// One estimating sample (`w`, `φ` as [`EstimatorTask::feed`] gives them) of a block for
    /// `target`, with the task's constants `acc` ([`EstimatorTask::acc`]).
    #[inline(always)]
    pub fn add(&mut self, target: Target, acc: (T, T), w: T, phi: &[T; 3]) {
        if target.two() {
            self.s2.add(acc.0, acc.1, w, &[phi[0], phi[1]]);
        } else {
            self.s3.add(acc.0, acc.1, w, phi);
        }
        self.n = self.n.wrapping_add(1);
    }

    /// Empty again.
    #[inline(always)]
    pub fn clear(&mut self) {
        self.s2.clear();
        self.s3.clear();
        self.n = 0;
        self.seen = 0;
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
    /// The block had estimating samples and θ̂ was updated; else (a block of samples that
    /// only fed the filters, or one that only restarts) the loop has nothing to adopt.
    pub updated: bool,
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
    /// DIVE: 1/T and α/T of the loop period, a block sample's weight T/m² ([`BlockStats::add`]).
    pub acc_dive: (T, T),
    /// SVE: 1/T and α/T.
    pub acc_sve: (T, T),
    /// The regressor: the cantilever and the prefilters.
    pub reg: RegressorParams<T>,
    /// The SVE high-passes' pole factor.
    pub highpass: T,
    /// DIVE's tones (the chunks computed ahead).
    pub exc_dive: ExcitationParams<T>,
    /// SVE's tones.
    pub exc_sve: ExcitationParams<T>,
    /// DIVE: every `mask + 1`-th sample of a block into the sums (`EstimatorConfig::stride`).
    pub stride_mask_dive: u32,
    /// SVE: the same.
    pub stride_mask_sve: u32,
}

/// The estimators and their divergence watch: what the lower-priority task owns.
#[derive(Clone, Copy, Debug)]
pub struct EstimatorTask<T> {
    p: TaskParams<T>,
    est2: Estimator<T, 2>,
    est3: Estimator<T, 3>,
    watch: Watch<T>,
    /// The prefilters of Z and U (every sample the loop hands over).
    reg: Regressor<T>,
    /// The SVE high-passes of w, φ₁, φ₂ (decoupled regressor).
    hp: [HighPass<T>; 3],
    /// The prefilters four samples at a time (DIVE at 1 MHz); last, so that the fields
    /// above keep their offsets.
    groups: GroupParams<T>,
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

/// [`EstimatorTask::feed`] on filter states passed apart, so that a block's loop
/// ([`EstimatorTask::run`]) can keep them in locals: in the task's memory, the queue's atomics
/// between two samples would make every sample load and store them.
#[inline(always)]
fn feed_filters<T: Real>(
    p: &TaskParams<T>,
    reg: &mut Regressor<T>,
    hp: &mut [HighPass<T>; 3],
    x: &Sample<T>,
) -> Option<(T, [T; 3])> {
    reg.update(&p.reg, x.u, x.z);
    if x.flags == 0 {
        return None;
    }
    let w = reg.w(&p.reg);
    let phi = reg.phi_sve(x.r);
    if x.flags & SAMPLE_HP_REST != 0 {
        *hp = [
            HighPass::at_rest(w),
            HighPass::at_rest(phi[0]),
            HighPass::at_rest(phi[1]),
        ];
        return None;
    }
    let (w, phi) = if x.flags & SAMPLE_HP != 0 {
        let a = p.highpass;
        let wh = hp[0].update(a, w);
        (
            wh,
            [hp[1].update(a, phi[0]), hp[2].update(a, phi[1]), phi[2]],
        )
    } else {
        (w, phi)
    };
    (x.flags & SAMPLE_EST != 0).then_some((w, phi))
}

/// The SVE high-passes' part of [`feed_filters`] on a slot that holds a flagged sample's `w`,
/// `φ₁`, `φ₂` ([`EstimatorTask::run_in_place`]): set at rest ([`SAMPLE_HP_REST`]), or through
/// them ([`SAMPLE_HP`]), or not; `w` and `φ₁`, `φ₂` when it is an estimating one.
#[inline(always)]
fn high_pass<T: Real>(a: T, hp: &mut [HighPass<T>; 3], x: &Sample<T>) -> Option<(T, [T; 2])> {
    if x.flags & SAMPLE_HP_REST != 0 {
        *hp = [
            HighPass::at_rest(x.z),
            HighPass::at_rest(x.u),
            HighPass::at_rest(x.r),
        ];
        return None;
    }
    let v = if x.flags & SAMPLE_HP != 0 {
        (
            hp[0].update(a, x.z),
            [hp[1].update(a, x.u), hp[2].update(a, x.r)],
        )
    } else {
        (x.z, [x.u, x.r])
    };
    (x.flags & SAMPLE_EST != 0).then_some(v)
}

/// The prefilters' part of [`EstimatorTask::run_in_place`] on one slot: the sample through
/// the filters, and, when its flags meet `want`, its `w`, `φ₁`, `φ₂` over its `z`, `u`, `r`
/// (the same operations as [`feed_filters`]). Returns its flags.
#[inline(always)]
fn prefilter_slot<T: Real>(
    p: &RegressorParams<T>,
    reg: &mut Regressor<T>,
    x: &mut Sample<T>,
    want: u32,
) -> u32 {
    reg.update(p, x.u, x.z);
    if x.flags & want != 0 {
        let w = reg.w(p);
        let phi = reg.phi_sve(x.r);
        (x.z, x.u, x.r) = (w, phi[0], phi[1]);
    }
    x.flags
}

/// The prefilters over a block's own samples with the sums' stride `S`: in groups of `S`
/// (the last one shorter), the first of each group at the stride's place (its `w` and `φ`
/// when flagged at all), the others only when the high-passes want them. Returns the
/// samples' flags, or-ed, and with a stride of 1 and-ed (else 0).
#[inline(always)]
fn prefilter_strided<T: Real, const S: usize>(
    p: &RegressorParams<T>,
    reg: &mut Regressor<T>,
    own: &mut [Sample<T>],
) -> (u32, u32) {
    let mut f = 0;
    // Every sample's flags and-ed (stride 1 and 2: SVE's usual block at 500 kHz and 1 MHz,
    // which the uniform pass takes; DIVE's stride 4 does without).
    let mut all = if S <= 2 { u32::MAX } else { 0 };
    // One slot at place `i` of its group: the first at the stride's place, the others for
    // the high-passes only.
    let mut slot = |i: usize, x: &mut Sample<T>| {
        let want = if i == 0 {
            u32::MAX
        } else {
            SAMPLE_HP | SAMPLE_HP_REST
        };
        let flags = prefilter_slot(p, reg, x, want);
        f |= flags;
        if S <= 2 {
            all &= flags;
        }
    };
    let mut groups = own.chunks_exact_mut(S);
    for g in groups.by_ref() {
        for (i, x) in g.iter_mut().enumerate() {
            slot(i, x);
        }
    }
    // (Empty with a stride of 1.)
    for (i, x) in groups.into_remainder().iter_mut().enumerate() {
        slot(i, x);
    }
    (f, all)
}

/// The most samples one block hands over (`estimator.decimation` ≤ 64; those to discard
/// before a restart and the block's own are one window of the sample clock): the firmware's
/// block buffers and the host's staged block ([`crate::Controller::step_internal`]).
pub const BLOCK_MAX: usize = 64;

/// The host's copy of the firmware's staged block buffer (issue 14, round 12): the samples
/// handed over since the last header, run by the same pass as the firmware's
/// ([`EstimatorTask::run_in_place`]) when the header comes, so that the grouped prefilters,
/// whose groups follow the block's own samples, take the same groups on both (a sample's
/// place among them is known only at the close: a restart later in the block makes it one
/// of the discarded). A sample beyond [`BLOCK_MAX`] is lost and its block only feeds the
/// filters, as the firmware's link does.
#[derive(Clone, Copy, Debug)]
pub struct Staged<T> {
    n: u32,
    lost: u32,
    samples: [Sample<T>; BLOCK_MAX],
}

impl<T: Real> Default for Staged<T> {
    fn default() -> Self {
        Self {
            n: 0,
            lost: 0,
            samples: [Sample::default(); BLOCK_MAX],
        }
    }
}

impl<T: Real> Staged<T> {
    /// One sample handed over, in order.
    #[inline(always)]
    pub fn push(&mut self, s: Sample<T>) {
        match self.samples.get_mut(self.n as usize) {
            Some(slot) => {
                *slot = s;
                self.n += 1;
            }
            None => self.lost = self.lost.wrapping_add(1),
        }
    }

    /// The block `b` closed: its samples (those staged) through `task`, the buffer empty
    /// again.
    #[inline(always)]
    pub fn run(&mut self, task: &mut EstimatorTask<T>, mut b: Block<T>) -> BlockResult<T> {
        if core::mem::take(&mut self.lost) != 0 {
            b.skip = self.n;
            b.samples = 0;
        }
        let n = core::mem::take(&mut self.n) as usize;
        let staged = match self.samples.get_mut(..n) {
            Some(s) => s,
            None => &mut [],
        };
        task.run_in_place(&b, staged)
    }
}

/// Whether a block for `target` with the sums' stride mask `mask` takes the grouped pass
/// ([`prefilter_grouped`]) when its first own sample estimates: DIVE at a stride of
/// [`GROUP`] (1 MHz).
#[inline(always)]
fn grouped(target: Target, mask: u32) -> bool {
    matches!(target, Target::Dive2 | Target::Dive3) && mask as usize + 1 == GROUP
}

/// One group's `w` and `φ₁`, `φ₂` from the Z filter's outputs `z` (after the group), the U
/// filter's `ux`, `udx` and the reference `r`: [`Regressor::w`] and [`Regressor::phi_sve`]'s
/// operations.
#[inline(always)]
fn group_read<T: Real>(p: &RegressorParams<T>, z: &Filtered<T>, ux: T, udx: T, r: T) -> [T; 3] {
    [w_of(p, z, ux, udx), -z.dx, r - z.x]
}

/// The prefilters over a DIVE block's own samples at the sums' stride of [`GROUP`] (issue
/// 14, round 12): in groups of four from the first, each advanced in one step
/// ([`Regressor::z_group`], [`Regressor::u_group`]), the last of each group the one the sums
/// read (`w`, `φ₁`, `φ₂` over its `z`, `u`, `r`, whatever its flags: DIVE's are only
/// [`SAMPLE_EST`] or none, and no test per group); a shorter last group per sample, unread.
/// Two passes, the Z filter's then the U filter's, so that each one's coefficients (19 and
/// 12) stay in the FPU's 32 registers; the Z pass leaves Z/Λ and s·Z/Λ in the group's first
/// two `z` (read already), its third `z` the sample s²·Z/Λ needs. Own samples run no
/// high-passes (the loop flags none in a DIVE block: SVE's restart comes before its first
/// flagged sample).
#[inline(always)]
fn prefilter_grouped<T: Real>(
    p: &RegressorParams<T>,
    q: &GroupParams<T>,
    reg: &mut Regressor<T>,
    own: &mut [Sample<T>],
) {
    let mut groups = own.chunks_exact_mut(GROUP);
    for g in groups.by_ref() {
        let [a, b, c, d] = g else { continue };
        reg.z_group(q, [a.z, b.z, c.z, d.z]);
        (a.z, b.z) = (reg.z_x(), reg.z_dx());
    }
    for x in groups.into_remainder() {
        reg.update_z(p, x.z);
    }
    let mut groups = own.chunks_exact_mut(GROUP);
    for g in groups.by_ref() {
        let [a, b, c, d] = g else { continue };
        let (ux, udx) = reg.u_group(q, [a.u, b.u, c.u, d.u]);
        let z = p.z_filtered(c.z, a.z, b.z);
        [d.z, d.u, d.r] = group_read(p, &z, ux, udx, d.r);
    }
    for x in groups.into_remainder() {
        reg.update_u(p, x.u);
    }
}

impl<T: Real> EstimatorTask<T> {
    /// The estimators at DIVE's θ̂₀ with P₀, the prefilters at rest with the tip and the
    /// base at `u0`.
    pub fn new(p: TaskParams<T>, groups: GroupParams<T>, theta0: [T; 3], u0: T) -> Self {
        Self {
            groups,
            est2: Estimator::new(&p.dive2, [theta0[0], theta0[1]]),
            est3: Estimator::new(&p.dive3, theta0),
            watch: Watch::default(),
            reg: Regressor::at_rest(u0, u0),
            hp: [HighPass::default(); 3],
            p,
        }
    }

    /// One sample through the prefilters (and, flagged, the high-passes): its `w` and `φ`
    /// when it is an estimating one ([`SAMPLE_EST`]). The operations of the loop's former
    /// per-sample regressor, in its order.
    #[inline(always)]
    pub fn feed(&mut self, x: &Sample<T>) -> Option<(T, [T; 3])> {
        feed_filters(&self.p, &mut self.reg, &mut self.hp, x)
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

    /// 1/T and α/T of the target's mode: [`BlockStats::add`]'s constants.
    #[inline(always)]
    pub fn acc(&self, target: Target) -> (T, T) {
        match target {
            Target::Dive2 | Target::Dive3 => self.p.acc_dive,
            Target::Sve2 | Target::Sve3 => self.p.acc_sve,
        }
    }

    /// The stride of the information sums less one (a mask: the stride is a power of two):
    /// the block's sample `j` (from 0, its own samples) goes into the sums when `j & mask` is 0
    /// — but in DIVE's blocks at a stride of [`GROUP`] when it is `mask`, the last of each
    /// group of the grouped prefilters (issue 14, round 12).
    #[inline(always)]
    pub fn stride_mask(&self, target: Target) -> u32 {
        match target {
            Target::Dive2 | Target::Dive3 => self.p.stride_mask_dive,
            Target::Sve2 | Target::Sve3 => self.p.stride_mask_sve,
        }
    }

    /// One block (the reference form; the firmware runs [`Self::run_in_place`]): `samples`
    /// yields the samples handed over for it in order, first the `b.skip` to
    /// discard (they only feed the filters), then the block's `b.samples` (the estimating
    /// ones also into the block sums); at most `b.skip + b.samples` are taken. Then the
    /// restarts, the block update (when the block had an estimating sample) and the
    /// divergence watch. The sums are formed here, in registers, sample by sample as the loop
    /// handed them over: the same operations in the same order as [`Self::feed`] and
    /// [`BlockSums::add`] on the host.
    #[inline(always)]
    pub fn run(
        &mut self,
        b: &Block<T>,
        samples: impl Iterator<Item = Sample<T>>,
    ) -> BlockResult<T> {
        let mut samples = samples.take(b.skip.wrapping_add(b.samples) as usize);
        let target = b.target;
        let (ip, ai) = self.acc(target);
        let mask = self.stride_mask(target);
        let p = &self.p;
        let mut n = 0u32;
        // The filters in locals for the block (see `feed_filters`).
        let (mut reg, mut hp) = (self.reg, self.hp);
        for x in samples.by_ref().take(b.skip as usize) {
            feed_filters(p, &mut reg, &mut hp, &x);
        }
        let mut samples = samples.peekable();
        if grouped(target, mask) && samples.peek().is_some_and(|x| x.flags & SAMPLE_EST != 0) {
            // `run_in_place_grouped` in one pass: the same group steps and reads.
            let mut sums = BlockSums::<T>::default();
            let mut g = [Sample::default(); GROUP];
            let mut k = 0;
            for x in samples {
                if let Some(slot) = g.get_mut(k) {
                    *slot = x;
                }
                k += 1;
                if k == GROUP {
                    k = 0;
                    let [a, b1, c, d] = g;
                    reg.z_group(&self.groups, [a.z, b1.z, c.z, d.z]);
                    let z = p.reg.z_filtered(c.z, reg.z_x(), reg.z_dx());
                    let (ux, udx) = reg.u_group(&self.groups, [a.u, b1.u, c.u, d.u]);
                    let [w, f0, f1] = group_read(&p.reg, &z, ux, udx, d.r);
                    if d.flags & SAMPLE_EST != 0 {
                        sums.add(target, (ip, ai), w, &[f0, f1, T::ONE]);
                    }
                }
            }
            for x in g.iter().take(k) {
                reg.update(&p.reg, x.u, x.z);
            }
            (self.reg, self.hp) = (reg, hp);
            self.restarts(b);
            let bi = (sums.n != 0).then(|| {
                if target.two() {
                    self.update2(target, &sums.s2)
                } else {
                    self.update3(target, &sums.s3)
                }
            });
            return self.finish(b, bi);
        }
        if target.two() {
            let mut s = BlockStats::<T, 2>::default();
            for (j, x) in samples.enumerate() {
                if let Some((w, phi)) = feed_filters(p, &mut reg, &mut hp, &x) {
                    if j as u32 & mask == 0 {
                        s.add(ip, ai, w, &[phi[0], phi[1]]);
                        n += 1;
                    }
                }
            }
            (self.reg, self.hp) = (reg, hp);
            // A copy for the update, which takes the sums by reference: the loop's own stay
            // in registers (passed by reference themselves, they are kept in memory and
            // loaded and stored every sample).
            let s = core::hint::black_box(s);
            self.restarts(b);
            let bi = (n != 0).then(|| self.update2(target, &s));
            self.finish(b, bi)
        } else {
            let mut s = BlockStats::<T, 3>::default();
            for (j, x) in samples.enumerate() {
                if let Some((w, phi)) = feed_filters(p, &mut reg, &mut hp, &x) {
                    if j as u32 & mask == 0 {
                        s.add(ip, ai, w, &phi);
                        n += 1;
                    }
                }
            }
            (self.reg, self.hp) = (reg, hp);
            let s = core::hint::black_box(s);
            self.restarts(b);
            let bi = (n != 0).then(|| self.update3(target, &s));
            self.finish(b, bi)
        }
    }

    /// [`Self::run`] on a block's samples in a buffer the task owns (the firmware's block
    /// buffers, `samples` the `skip` to discard, then the block's own): the same operations
    /// in the same order for every value, so the same result bit for bit, in two passes that
    /// each keep their state in registers: the prefilters over every sample, their states in
    /// locals across the block, each flagged sample's `w` and `φ` written over its own slot
    /// (`z`, `u`, `r` ← `w`, `φ₁`, `φ₂`; `φ₃` is 1); then over the slots the SVE high-passes,
    /// when a sample asks for them, and the block sums of the block's estimating ones. In one
    /// pass the filters, the high-passes, the sums and their constants outnumber the FPU's 32
    /// registers and spill (three parameters: the filter states were kept in memory instead,
    /// loaded and stored every sample); the high-passes with the sums fit.
    ///
    /// The passes are out of line: as arguments, `&mut self` and the buffer are known apart;
    /// inlined into the estimator interrupt, which takes the buffer out of a queue, the
    /// compiler could not tell, and would order every sample's loads after the previous
    /// sample's stores. The choice between them is inlined into the caller (issue 14, round
    /// 13): as a function of its own it saved the per-sample pass's registers before its
    /// test, and DIVE's grouped blocks paid two calls (measured: 5 instructions a SVE block,
    /// 12 a DIVE read-out block).
    #[inline(always)]
    pub fn run_in_place(&mut self, b: &Block<T>, samples: &mut [Sample<T>]) -> BlockResult<T> {
        // DIVE's estimating blocks at 1 MHz (by their first own sample: a per-block test);
        // the approach's and retract's blocks, and those before a mode's first restart (SVE's
        // approach among them: SVE's results do not move), per sample.
        if grouped(b.target, self.stride_mask(b.target))
            && samples
                .get(b.skip as usize)
                .is_some_and(|x| x.flags & SAMPLE_EST != 0)
        {
            return self.run_in_place_grouped(b, samples);
        }
        self.run_in_place_strided(b, samples)
    }

    /// [`Self::run_in_place`] per sample, the sums at their stride (every block but DIVE's
    /// grouped ones).
    #[inline(never)]
    fn run_in_place_strided(&mut self, b: &Block<T>, samples: &mut [Sample<T>]) -> BlockResult<T> {
        let take = b.skip.wrapping_add(b.samples) as usize;
        let samples = match samples.get_mut(..take) {
            Some(s) => s,
            None => samples,
        };
        let skip = b.skip as usize;
        let target = b.target;
        let (ip, ai) = self.acc(target);
        let mask = self.stride_mask(target);
        // At least 1 (`step_by` of 0 would panic; the mask is below 8).
        let stride = (mask as usize).wrapping_add(1).max(1);
        let p = &self.p;
        // The prefilters: every sample; a flagged one's w, φ₁, φ₂ over its slot.
        // Only the slots a later pass reads get their w and φ: those the high-passes take
        // (every sample flagged for them), and the estimating ones at the stride's places of
        // the block's own samples (the sums take no other). The filters run on every sample.
        let mut reg = self.reg;
        let mut hp_flags = 0;
        // (All of them the head when the header's skip exceeds them, as below.)
        let len = samples.len();
        let (head, own) = match samples.split_at_mut_checked(skip.min(len)) {
            Some(parts) => parts,
            None => (&mut [][..], &mut [][..]),
        };
        for x in head.iter_mut() {
            hp_flags |= prefilter_slot(&p.reg, &mut reg, x, SAMPLE_HP | SAMPLE_HP_REST);
        }
        let (own_flags, all_flags) = match stride {
            2 => prefilter_strided::<T, 2>(&p.reg, &mut reg, own),
            4 => prefilter_strided::<T, 4>(&p.reg, &mut reg, own),
            // Every sample (stride 1; 8 takes the w and φ of all, as before).
            _ => prefilter_strided::<T, 1>(&p.reg, &mut reg, own),
        };
        hp_flags |= own_flags;
        // Every own sample through the high-passes into the sums (SVE's usual block, stride
        // 1): the pass below without a test per sample.
        let uniform = mask <= 1
            && own_flags & SAMPLE_HP_REST == 0
            && all_flags & (SAMPLE_HP | SAMPLE_EST) == SAMPLE_HP | SAMPLE_EST;
        self.reg = reg;
        let samples: &[Sample<T>] = samples;
        // The SVE high-passes (only when a sample asks for them), in order over the slots, the
        // block's own estimating ones then into the sums: the high-passes' states and the
        // sums fit the registers together.
        let hp_on = hp_flags & (SAMPLE_HP | SAMPLE_HP_REST) != 0;
        let a = p.highpass;
        let (head, own) = match (samples.get(..skip), samples.get(skip..)) {
            (Some(h), Some(o)) => (h, o),
            _ => (samples, &[][..]),
        };
        let mut n = 0u32;
        if target.two() {
            let mut s = BlockStats::<T, 2>::default();
            if hp_on {
                let mut hp = self.hp;
                for x in head {
                    high_pass(a, &mut hp, x);
                }
                if uniform {
                    // Every sample through the high-passes and into the sums (their operations
                    // in `high_pass`'s order, without its tests).
                    // Two samples a turn: the filters' old and new states in alternating
                    // registers, not moved over every sample.
                    // At stride 2 (SVE at 1 MHz) the second of a pair only through the
                    // high-passes.
                    let mut pairs = own.chunks_exact(2);
                    if mask == 0 {
                        for pair in pairs.by_ref() {
                            for x in pair {
                                let w = hp[0].update(a, x.z);
                                let phi = [hp[1].update(a, x.u), hp[2].update(a, x.r)];
                                s.add(ip, ai, w, &phi);
                            }
                        }
                        n = (own.len() & !1) as u32;
                    } else {
                        for pair in pairs.by_ref() {
                            let [x, y] = pair else { continue };
                            let w = hp[0].update(a, x.z);
                            let phi = [hp[1].update(a, x.u), hp[2].update(a, x.r)];
                            s.add(ip, ai, w, &phi);
                            hp[0].update(a, y.z);
                            hp[1].update(a, y.u);
                            hp[2].update(a, y.r);
                        }
                        n = (own.len() / 2) as u32;
                    }
                    for x in pairs.remainder() {
                        let w = hp[0].update(a, x.z);
                        let phi = [hp[1].update(a, x.u), hp[2].update(a, x.r)];
                        s.add(ip, ai, w, &phi);
                        n += 1;
                    }
                } else if mask == 0 {
                    // Every sample (the loop without the stride's test).
                    for x in own {
                        if let Some((w, phi)) = high_pass(a, &mut hp, x) {
                            s.add(ip, ai, w, &phi);
                            n += 1;
                        }
                    }
                } else {
                    for (j, x) in own.iter().enumerate() {
                        if let Some((w, phi)) = high_pass(a, &mut hp, x) {
                            if j as u32 & mask == 0 {
                                s.add(ip, ai, w, &phi);
                                n += 1;
                            }
                        }
                    }
                }
                self.hp = hp;
            } else {
                for x in own.iter().step_by(stride) {
                    if x.flags & SAMPLE_EST != 0 {
                        s.add(ip, ai, x.z, &[x.u, x.r]);
                        n += 1;
                    }
                }
            }
            // A copy for the update (see `run`).
            let s = core::hint::black_box(s);
            self.restarts(b);
            let bi = (n != 0).then(|| self.update2(target, &s));
            self.finish(b, bi)
        } else {
            let mut s = BlockStats::<T, 3>::default();
            if hp_on {
                let mut hp = self.hp;
                for x in head {
                    high_pass(a, &mut hp, x);
                }
                if mask == 0 {
                    // Every sample (the loop without the stride's test).
                    for x in own {
                        if let Some((w, phi)) = high_pass(a, &mut hp, x) {
                            s.add(ip, ai, w, &[phi[0], phi[1], T::ONE]);
                            n += 1;
                        }
                    }
                } else {
                    for (j, x) in own.iter().enumerate() {
                        if let Some((w, phi)) = high_pass(a, &mut hp, x) {
                            if j as u32 & mask == 0 {
                                s.add(ip, ai, w, &[phi[0], phi[1], T::ONE]);
                                n += 1;
                            }
                        }
                    }
                }
                self.hp = hp;
            } else {
                for x in own.iter().step_by(stride) {
                    if x.flags & SAMPLE_EST != 0 {
                        s.add(ip, ai, x.z, &[x.u, x.r, T::ONE]);
                        n += 1;
                    }
                }
            }
            let s = core::hint::black_box(s);
            self.restarts(b);
            let bi = (n != 0).then(|| self.update3(target, &s));
            self.finish(b, bi)
        }
    }

    /// [`Self::run_in_place`] for a DIVE block at a stride of [`GROUP`] (issue 14, round
    /// 12): the discarded samples per sample as there, the block's own in groups of four
    /// ([`prefilter_grouped`]), the last of each group into the sums when estimating. No
    /// test of a sample's flags in the filters' passes. Out of line, as `run_in_place`, and
    /// apart from it: its registers and stack are its own, the other blocks' code unchanged.
    #[inline(never)]
    fn run_in_place_grouped(&mut self, b: &Block<T>, samples: &mut [Sample<T>]) -> BlockResult<T> {
        let take = b.skip.wrapping_add(b.samples) as usize;
        let samples = match samples.get_mut(..take) {
            Some(s) => s,
            None => samples,
        };
        let target = b.target;
        let (ip, ai) = self.acc(target);
        let p = &self.p;
        let skip = (b.skip as usize).min(samples.len());
        let (head, own) = match samples.split_at_mut_checked(skip) {
            Some(parts) => parts,
            None => (&mut [][..], &mut [][..]),
        };
        let mut reg = self.reg;
        let mut hp_flags = 0;
        for x in head.iter_mut() {
            hp_flags |= prefilter_slot(&p.reg, &mut reg, x, SAMPLE_HP | SAMPLE_HP_REST);
        }
        prefilter_grouped(&p.reg, &self.groups, &mut reg, own);
        self.reg = reg;
        if hp_flags & (SAMPLE_HP | SAMPLE_HP_REST) != 0 {
            // SVE's samples before the restart: its high-passes' state, as in the other path.
            let mut hp = self.hp;
            for x in head.iter() {
                high_pass(p.highpass, &mut hp, x);
            }
            self.hp = hp;
        }
        let reads = own.iter().skip(GROUP - 1).step_by(GROUP);
        let mut n = 0u32;
        if target.two() {
            let mut s = BlockStats::<T, 2>::default();
            for x in reads {
                if x.flags & SAMPLE_EST != 0 {
                    s.add(ip, ai, x.z, &[x.u, x.r]);
                    n += 1;
                }
            }
            // A copy for the update (see `run`).
            let s = core::hint::black_box(s);
            self.restarts(b);
            let bi = (n != 0).then(|| self.update2(target, &s));
            self.finish(b, bi)
        } else {
            let mut s = BlockStats::<T, 3>::default();
            for x in reads {
                if x.flags & SAMPLE_EST != 0 {
                    s.add(ip, ai, x.z, &[x.u, x.r, T::ONE]);
                    n += 1;
                }
            }
            let s = core::hint::black_box(s);
            self.restarts(b);
            let bi = (n != 0).then(|| self.update3(target, &s));
            self.finish(b, bi)
        }
    }

    /// One block whose sums are formed already ([`BlockSums`], the host's in-line task):
    /// restarts first, then the block update and the divergence watch.
    #[inline(always)]
    pub fn run_sums(&mut self, b: &Block<T>, sums: &BlockSums<T>) -> BlockResult<T> {
        let target = b.target;
        self.restarts(b);
        let bi = if b.samples == 0 || sums.n == 0 {
            None
        } else if target.two() {
            Some(self.update2(target, &sums.s2))
        } else {
            Some(self.update3(target, &sums.s3))
        };
        self.finish(b, bi)
    }

    #[inline(always)]
    fn update2(&mut self, target: Target, s: &BlockStats<T, 2>) -> BlockInfo<T> {
        let p = if target == Target::Sve2 {
            &self.p.sve2
        } else {
            &self.p.dive2
        };
        self.est2.update_block(p, s)
    }

    #[inline(always)]
    fn update3(&mut self, target: Target, s: &BlockStats<T, 3>) -> BlockInfo<T> {
        let p = if target == Target::Sve3 {
            &self.p.sve3
        } else {
            &self.p.dive3
        };
        self.est3.update_block(p, s)
    }

    /// The block's restarts (before its update).
    #[inline(always)]
    fn restarts(&mut self, b: &Block<T>) {
        if let Some(th) = b.restart {
            self.restart(b.target, th);
        }
        if b.restart_watch {
            self.watch.restart();
        }
    }

    /// After the block update `bi` (`None`: a block without samples, which only restarts:
    /// θ̂ stays, no flags), the divergence watch and the result.
    #[inline(always)]
    fn finish(&mut self, b: &Block<T>, bi: Option<BlockInfo<T>>) -> BlockResult<T> {
        let target = b.target;
        let mut flags = 0;
        let updated = bi.is_some();
        if let Some(bi) = bi {
            flags = est_flags(bi.info);
            flags |= self.watch(target, bi.info, bi.e_ms, bi.w_ms, true);
        }
        BlockResult {
            target,
            theta: self.theta(target),
            flags,
            epoch: b.epoch,
            updated,
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

impl<T: SineTable> EstimatorTask<T> {
    /// The chunks of tones the block's header asks for ([`ToneAhead`]: those starting N to
    /// 2N − 1 samples after the close; none, one or two), in order: `f` gets each one's key
    /// and the tones' constants, to fill a chunk with [`fill_chunk`] (or [`Self::fill`]).
    #[inline(always)]
    pub fn tones_ahead(
        &self,
        a: &ToneAhead,
        mut f: impl FnMut(&ChunkKey<T>, &ExcitationParams<T>),
    ) {
        let p = match a.which {
            TONES_DIVE => &self.p.exc_dive,
            TONES_SVE => &self.p.exc_sve,
            _ => return,
        };
        // Chunk m + 1 after the current one starts left + m·RESYNC samples after the close.
        let (n, left) = (a.n.min(64), a.at.left.min(RESYNC));
        let mut m = n.saturating_sub(left).div_ceil(RESYNC);
        while left + m * RESYNC < 2 * n {
            f(&a.at.key(m, p), p);
            m += 1;
        }
    }

    /// [`fill_chunk`] (for the task's callers that do not hold the constants).
    #[inline(always)]
    pub fn fill(p: &ExcitationParams<T>, key: &ChunkKey<T>, out: &mut [T; RESYNC as usize]) {
        fill_chunk(p, key, out)
    }
}
