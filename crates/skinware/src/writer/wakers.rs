//! The threads that wake a writer's sleeping readers for it, so that its
//! publish does not pay for the wake: the ringer, which wakes them from the
//! writer's own CPU after a handoff, and the lookout, which watches for
//! each expected frame from another CPU ([`crate::channel::ringer`],
//! [`crate::channel::lookout`]); and the writer's side of choosing who
//! wakes them ([`Publishing`]).

#![forbid(unsafe_code)]

use std::sync::Arc;
use std::time::Duration;

use crate::anticipate::{Anticipation, RecentQuantile};
use crate::channel::doorbell::{self, Futex as _};
use crate::channel::lookout::{WakeBy, Watch};
use crate::channel::ringer::Handoff;
use crate::channel::segment::Shared;
use crate::os::{self, PRIVATE_FUTEX, SHARED_FUTEX};
use crate::rt::ReaderWake;
use crate::sync::AtomicU32;

/// The writer's side of publishing: the next sequence number and who wakes
/// sleeping readers.
pub(super) struct Publishing {
    pub(super) next_seq: u64,
    pub(super) last_published_ns: u64,
    pub(super) woken_by_writer: u64,
    pub(super) handed_to_ringer: u64,
    pub(super) woken_by_lookout: u64,
    pub(super) reader_wake: ReaderWake,
    /// Started at the first frame with [`ReaderWake::Ringer`], or with the
    /// lookout for the frames it misses.
    pub(super) ringer: Option<Ringer>,
    /// Started at the first frame with [`ReaderWake::Lookout`].
    pub(super) lookout: Option<Lookout>,
    /// [`WriterOptions::period`], if periodic.
    pub(super) period_ns: Option<u64>,
    /// The deadline of the period being filled, while
    /// [`Writer::run_periodic`] fills it.
    pub(super) period_deadline_ns: Option<u64>,
}

impl Publishing {
    /// After the publish of a frame that `announced` sleepers wait for (or
    /// not): wakes them, or leaves the wake to the lookout or the ringer.
    pub(super) fn wake_sleepers(&mut self, label: &str, notify: &AtomicU32, announced: bool, published_ns: u64) {
        let handoff = self.ringer.as_ref().map(|ringer| &*ringer.state);
        // A ringer still behind on the last handoff leaves readers asleep
        // since then, who announce themselves no more: they are woken now.
        let ringer_behind = handoff.is_some_and(Handoff::behind);
        let mut wake = announced || ringer_behind;
        // Asked only where it is used: a ringer's writer publishing to nobody
        // asleep makes no call at all.
        let writer_cpu = || os::current_cpu().unwrap_or(u32::MAX);
        if let Some(lookout) = &self.lookout {
            match lookout.state.published(wake, published_ns, writer_cpu()) {
                WakeBy::Lookout => {
                    self.woken_by_lookout += 1;
                    wake = false;
                }
                WakeBy::Nobody => {}
                // Not watching, or behind on the last frame: the ringer's
                // (or the writer's) to wake.
                WakeBy::Writer => wake = true,
            }
            if lookout.state.lookout_gone() {
                tracing::warn!(channel = %label, "the lookout thread ended; its ringer (or the writer) wakes the readers");
                // It may have ended with a frame taken and not rung: one
                // spare wake, not counted.
                if !wake {
                    SHARED_FUTEX.wake_all(notify);
                }
                self.lookout = None;
                self.reader_wake = if self.ringer.is_some() { ReaderWake::Ringer } else { ReaderWake::Writer };
            }
        }
        if wake {
            let handed =
                !ringer_behind && handoff.is_some_and(|handoff| handoff.hand_off(writer_cpu(), &PRIVATE_FUTEX));
            if handed {
                self.handed_to_ringer += 1;
            } else {
                self.woken_by_writer += 1;
                SHARED_FUTEX.wake_all(notify);
            }
        }
        if handoff.is_some_and(Handoff::ringer_gone) {
            tracing::warn!(channel = %label, "the ringer thread ended; the writer wakes its readers itself");
            self.ringer = None;
            if self.reader_wake == ReaderWake::Ringer {
                self.reader_wake = ReaderWake::Writer;
            }
        }
    }
}

/// What a writer shares with one of the threads that wake its sleeping
/// readers for it: its ringer ([`Handoff`]) or its lookout ([`Watch`]).
pub(super) trait WakerState: Default + Send + Sync + 'static {
    /// The writer is going: the thread's wait returns and it ends.
    fn stop_thread(&self);
    /// The thread is ending, for any reason, and will wake no one more.
    fn thread_ended(&self);
}

impl WakerState for Handoff {
    fn stop_thread(&self) {
        self.stop(&PRIVATE_FUTEX);
    }
    fn thread_ended(&self) {
        self.ringer_ended();
    }
}

impl WakerState for Watch {
    fn stop_thread(&self) {
        self.stop(&PRIVATE_FUTEX);
    }
    fn thread_ended(&self) {
        self.lookout_ended();
    }
}

/// A thread that wakes a writer's sleeping readers for it; stopped and
/// joined on drop.
pub(super) struct WakerThread<S: WakerState> {
    pub(super) state: Arc<S>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// The process that started the thread: a child made by `fork` has a
    /// copy of this struct but not the thread.
    pid: u32,
}

/// The ringer ([`crate::channel::ringer`]).
pub(super) type Ringer = WakerThread<Handoff>;
/// The lookout ([`crate::channel::lookout`]).
pub(super) type Lookout = WakerThread<Watch>;

impl<S: WakerState> WakerThread<S> {
    fn spawn(name: &str, run: impl FnOnce(&S) + Send + 'static) -> std::io::Result<WakerThread<S>> {
        let state = Arc::new(S::default());
        let thread_state = state.clone();
        let thread = std::thread::Builder::new().name(name.into()).spawn(move || {
            // Said however the thread ends, a panic included.
            let _ended = ThreadEnded(&*thread_state);
            run(&thread_state);
        })?;
        Ok(WakerThread { state, thread: Some(thread), pid: std::process::id() })
    }
}

impl Ringer {
    /// Called from the writer's thread, whose CPU the ringer starts on.
    pub(super) fn start(shared: &Arc<Shared>, writer_priority: u8) -> std::io::Result<Ringer> {
        let shared = shared.clone();
        let writer_cpu = os::current_cpu();
        WakerThread::spawn("skinware-ringer", move |handoff| ring_for(&shared, handoff, writer_priority, writer_cpu))
    }
}

impl Lookout {
    pub(super) fn start(shared: &Arc<Shared>, writer_priority: u8, period_ns: u64) -> std::io::Result<Lookout> {
        let shared = shared.clone();
        WakerThread::spawn("skinware-lookout", move |watch| look_out_for(&shared, watch, writer_priority, period_ns))
    }
}

/// Tells the writer, when dropped, that its waking thread has ended.
struct ThreadEnded<'a, S: WakerState>(&'a S);

impl<S: WakerState> Drop for ThreadEnded<'_, S> {
    fn drop(&mut self) {
        self.0.thread_ended();
    }
}

impl<S: WakerState> Drop for WakerThread<S> {
    fn drop(&mut self) {
        self.state.stop_thread();
        if let Some(thread) = self.thread.take()
            && self.pid == std::process::id()
        {
            let _ = thread.join();
        }
    }
}

/// The ringer's loop: wakes the channel's sleeping readers for every handoff,
/// then moves to the CPU the writer ran on, so that the next handoff is a
/// wake on the writer's own CPU.
fn ring_for(shared: &Shared, handoff: &Handoff, writer_priority: u8, writer_cpu: Option<u32>) {
    // One below the writer (at priority 1, the same): it runs as soon as the
    // writer sleeps and never preempts it.
    if let Err(error) = os::set_fifo_priority(writer_priority.saturating_sub(1).max(1)) {
        tracing::warn!(channel = %shared.label, %error, "the ringer cannot take a real-time priority; the writer wakes its readers itself");
        return;
    }
    // On the writer's CPU from the start, not only after a first ring: the
    // first handoff, and with a lookout the rare ones it leaves, would
    // otherwise wake this thread on another CPU, the interrupt the ringer is
    // there to spare the writer.
    let mut on_cpu = None;
    if let Some(cpu) = writer_cpu {
        match os::pin_to_cpus(&[cpu as usize]) {
            Ok(()) => on_cpu = Some(cpu),
            Err(error) => {
                tracing::debug!(channel = %shared.label, %error, "the ringer cannot start on the writer's CPU {cpu}")
            }
        }
    }
    loop {
        match handoff.next(&PRIVATE_FUTEX, Duration::from_secs(1)) {
            Ok(Some((requested, writer_cpu))) => {
                SHARED_FUTEX.wake_all(&shared.doorbell().notify);
                handoff.rung(requested);
                // After the wake: the move costs this thread, not the readers.
                if writer_cpu != u32::MAX && on_cpu != Some(writer_cpu) {
                    on_cpu = Some(writer_cpu);
                    if let Err(error) = os::pin_to_cpus(&[writer_cpu as usize]) {
                        tracing::debug!(channel = %shared.label, %error, "the ringer cannot follow the writer to CPU {writer_cpu}");
                    }
                }
            }
            Ok(None) => return,
            Err(error) => {
                tracing::warn!(channel = %shared.label, %error, "the ringer stopped; the writer wakes its readers itself");
                return;
            }
        }
    }
}

/// The lookout's first timer lead and spin past the earliest expected frame,
/// before it has measured either.
const LOOKOUT_INITIAL_NS: u64 = 100_000;
/// The quantile (per mille) of its own lateness and the frames' that the
/// lookout is ready for: the frames beyond it go to the ringer.
const LOOKOUT_QUANTILE: usize = 970;
/// Added to the measured quantiles.
const LOOKOUT_MARGIN_NS: u64 = 10_000;
/// Watches in a row without a frame after which the lookout backs off.
const FRUITLESS_BEFORE_BACKING_OFF: u64 = 4;

/// Sleeps until `deadline_ns` unless the writer goes first (`false`).
fn lookout_sleep_until(watch: &Watch, deadline_ns: u64) -> bool {
    loop {
        if watch.is_stopping() {
            return false;
        }
        if os::monotonic_ns() >= deadline_ns {
            return true;
        }
        if let Err(error) = PRIVATE_FUTEX.wait_until(watch.stopping_word(), 0, deadline_ns) {
            // Only EFAULT/EINVAL are possible, neither with a valid word and deadline.
            tracing::debug!(%error, "the lookout's timed sleep failed; sleeping without it");
            std::thread::sleep(Duration::from_nanos(deadline_ns.saturating_sub(os::monotonic_ns())));
        }
    }
}

/// The lookout's loop: for each frame of the writer's grid that a reader
/// sleeps for, sleeps until just before it is due, on a CPU other than the
/// writer's, then watches for it and wakes the readers.
fn look_out_for(shared: &Shared, watch: &Watch, writer_priority: u8, period_ns: u64) {
    // One below the writer, as the ringer: its timer must not wait behind
    // the readers it is to wake, and it never preempts the writer.
    if let Err(error) = os::set_fifo_priority(writer_priority.saturating_sub(1).max(1)) {
        tracing::warn!(channel = %shared.label, %error, "the lookout cannot take a real-time priority; its ringer wakes the readers");
        return;
    }
    let allowed = match os::allowed_cpus() {
        Ok(cpus) => cpus,
        Err(error) => {
            tracing::warn!(channel = %shared.label, %error, "the lookout cannot read its CPUs; its ringer wakes the readers");
            return;
        }
    };
    let mut lookout = LookoutLoop::new(shared, watch, period_ns, allowed);
    while lookout.look() {}
}

/// What the lookout has learnt of the writer's grid and of its own
/// lateness, and where it is in its watching.
struct LookoutLoop<'a> {
    shared: &'a Shared,
    watch: &'a Watch,
    period_ns: u64,
    /// The longest lead and spin: a quarter period.
    ceiling: u64,
    /// The CPUs it may run on.
    allowed: Vec<usize>,
    grid: Anticipation,
    /// How much earlier than the earliest expected frame the lookout must
    /// set its timer: its own lateness less the frame's, which are not
    /// independent (a busy host is slow to run both vCPUs).
    lead_needed: RecentQuantile,
    /// How long after the earliest expected frame frames come.
    frame_late: RecentQuantile,
    /// The publication time of the last frame it noted.
    observed: u64,
    /// The writer's CPU it keeps off.
    avoiding: Option<u32>,
    /// Looks in a row that found nobody asleep.
    idle_looks: u64,
    /// Watches in a row that saw no frame (a writer whose fills fail, or
    /// that stopped): after a few, the lookout looks ever more rarely.
    fruitless: u64,
    /// The frame watched for last, and how late the lookout woke for it.
    watched_for: Option<(u64, u64)>,
}

impl<'a> LookoutLoop<'a> {
    fn new(shared: &'a Shared, watch: &'a Watch, period_ns: u64, allowed: Vec<usize>) -> LookoutLoop<'a> {
        LookoutLoop {
            shared,
            watch,
            period_ns,
            ceiling: (period_ns / 4).max(1),
            allowed,
            grid: Anticipation::new(0),
            lead_needed: RecentQuantile::new(LOOKOUT_QUANTILE, LOOKOUT_INITIAL_NS, LOOKOUT_MARGIN_NS),
            frame_late: RecentQuantile::new(LOOKOUT_QUANTILE, LOOKOUT_INITIAL_NS, LOOKOUT_MARGIN_NS),
            observed: 0,
            avoiding: None,
            idle_looks: 0,
            fruitless: 0,
            watched_for: None,
        }
    }

    /// One turn: notes the newest frame, then sleeps until the next one is
    /// due and watches for it. `false` when the lookout ends.
    fn look(&mut self) -> bool {
        if self.watch.is_stopping() || !self.keep_off_writer_cpu() {
            return false;
        }
        let last = self.watch.last_published_ns();
        self.note_frame(last);
        match self.grid.next_expected(last).filter(|_| last != 0) {
            Some(expected) => self.watch_for(last, expected),
            // No frame yet: nothing to anticipate.
            None => lookout_sleep_until(self.watch, os::monotonic_ns().saturating_add(self.period_ns)),
        }
    }

    /// Moves off the CPU the writer ran on last, if it moved; `false` if
    /// there is no other.
    fn keep_off_writer_cpu(&mut self) -> bool {
        let Some(cpu) = self.watch.writer_cpu().filter(|&cpu| self.avoiding != Some(cpu)) else {
            return true;
        };
        self.avoiding = Some(cpu);
        let others: Vec<usize> = self.allowed.iter().copied().filter(|&other| other != cpu as usize).collect();
        if others.is_empty() {
            tracing::warn!(channel = %self.shared.label, "the writer runs on the lookout's only CPU; its ringer wakes the readers");
            return false;
        }
        if let Err(error) = os::pin_to_cpus(&others) {
            tracing::debug!(channel = %self.shared.label, %error, "the lookout cannot keep off the writer's CPU {cpu}");
        }
        true
    }

    /// Learns from a frame published since the last look.
    fn note_frame(&mut self, last: u64) {
        if last == self.observed {
            return;
        }
        // Not the first frame: a writer's first is often off its grid
        // (published at start-up, before its first tick), which would set
        // the lookout's timer early for two windows.
        if self.observed != 0 {
            self.grid.observe(last, self.period_ns);
        }
        self.observed = last;
        self.fruitless = 0;
        // Every frame watched for, including those that came after the spin
        // ended: sampling only the ones caught would shrink the spin to the
        // earliest frames.
        if let Some((expected, woke_late)) = self.watched_for.take() {
            let late = last.saturating_sub(expected);
            self.frame_late.observe(late);
            self.lead_needed.observe(woke_late.saturating_sub(late));
        }
    }

    /// Sleeps until just before the frame after `last` (expected at
    /// `expected`) and watches for it, if someone sleeps for it. `false`
    /// when the lookout ends.
    fn watch_for(&mut self, last: u64, mut expected: u64) -> bool {
        let (watch, period_ns) = (self.watch, self.period_ns);
        let lead = self.lead_needed.value_ns().clamp(1, self.ceiling);
        // The spin ends at the frame, so a long one costs only the rare
        // late frames.
        let spin_after = self.frame_late.value_ns().clamp(1, 2 * self.ceiling);
        let now = os::monotonic_ns();
        // A frame that is late past the spin (or a stalled writer) is the
        // ringer's to wake: watch for the next one on the grid.
        if let Some(behind) = now.checked_sub(expected.saturating_add(spin_after)) {
            expected = expected.saturating_add((behind / period_ns + 1).saturating_mul(period_ns));
        }
        let wake_at = expected.saturating_sub(lead);
        if wake_at > now && !lookout_sleep_until(watch, wake_at) {
            return false;
        }
        let woke_late = os::monotonic_ns().saturating_sub(wake_at);
        let arrived = watch.last_published_ns();
        if arrived != last {
            if arrived >= wake_at {
                // The frame it was to watch for came first: the lookout woke
                // too late, by how much it needed more lead.
                let late = arrived.saturating_sub(expected);
                self.frame_late.observe(late);
                self.lead_needed.observe(woke_late.saturating_sub(late));
                self.watched_for = None;
            }
            // Otherwise a late frame came while it slept, after its spin
            // ended: noted at the top, or its lateness is lost and the spins
            // shrink to the frames that come early.
            return true;
        }
        let until = expected.saturating_add(spin_after);
        let notify = &self.shared.doorbell().notify;
        if !doorbell::someone_waits(notify) {
            // Nobody sleeps for this frame (yet): one who comes later is the
            // ringer's to wake. The lookout looks again one period later,
            // then ever fewer times while nobody sleeps (down to once in 64
            // periods), so that a channel without sleepers costs it almost
            // nothing.
            self.idle_looks = (self.idle_looks + 1).min(64);
            let skip = period_ns.saturating_mul(self.idle_looks);
            return lookout_sleep_until(watch, wake_at.max(now).saturating_add(skip));
        }
        self.idle_looks = 0;
        if self.fruitless >= FRUITLESS_BEFORE_BACKING_OFF {
            let skip = period_ns.saturating_mul((self.fruitless - FRUITLESS_BEFORE_BACKING_OFF + 1).min(64));
            self.fruitless += 1;
            return lookout_sleep_until(watch, until.saturating_add(skip));
        }
        // A frame published before the watch began was the ringer's to wake.
        self.watched_for = Some((expected, woke_late));
        watch.watch(notify, &SHARED_FUTEX, || {
            watch.last_published_ns() == last && os::monotonic_ns() < until && !watch.is_stopping()
        });
        if watch.last_published_ns() == last {
            self.fruitless += 1;
        }
        true
    }
}
