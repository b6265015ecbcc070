//! The wake of sleeping readers, made by a thread that is already awake on
//! another CPU when the frame is published: the writer's *lookout*.
//!
//! Both of the other ways cost an interrupt to a halted CPU somewhere. The
//! writer's own wake pays it on the acquisition thread (14–60 µs on this
//! project's 2-vCPU machines); the ringer ([`super::ringer`]) pays it off the
//! acquisition's time line but only once the writer sleeps, so readers wake
//! later. A periodic writer publishes on a grid, so a thread can be running
//! on another CPU just before each frame: it sleeps until shortly before the
//! earliest publication it expects ([`crate::anticipate`]), then spins on one
//! word of process-private memory. The writer, after publishing, leaves on
//! that word whether readers are asleep (one compare-and-swap, no system
//! call); the lookout, on a CPU that is awake, wakes them at once. The cost is
//! the lookout's spinning, which is CPU time on the other CPU: it watches
//! only for frames some reader has announced it sleeps for.
//!
//! When the lookout is not watching (it was late, the frame was, or no reader
//! had announced itself when it looked), the writer hands the wake to its
//! ringer, as with [`crate::ReaderWake::Ringer`] (or, without one, wakes the
//! readers itself). A lookout that has not rung the last frame when the next
//! is published leaves that wake to them too.
//!
//! This module is the protocol on that word, model-checked with loom in
//! [`super::doorbell`]'s models; the thread lives in `crate::writer`.

use crate::sync::{AtomicU32, AtomicU64, Ordering};

use super::doorbell::Futex;

/// The lookout is not watching: the writer hands the wake to its ringer (or,
/// without one, wakes the readers itself).
const IDLE: u32 = 0;
/// The lookout is spinning on the word, ready to wake readers.
const WATCHING: u32 = 1;
/// The writer published and readers are asleep: the lookout wakes them.
const RING: u32 = 2;
/// The writer published and nobody was asleep.
const PUBLISHED: u32 = 3;

/// Who wakes the readers of a frame just published.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum WakeBy {
    /// Nobody sleeps: no wake.
    Nobody,
    /// The lookout, which was watching.
    Lookout,
    /// The writer's side (its ringer, or the writer itself), now.
    Writer,
}

/// What a writer and its lookout share (process-private memory).
#[derive(Debug)]
pub(crate) struct Watch {
    /// `IDLE`, `WATCHING`, `RING` or `PUBLISHED`. Only the lookout sets
    /// `WATCHING` (from `IDLE`) and `IDLE`; only the writer moves it from
    /// `WATCHING` to `RING` or `PUBLISHED`.
    state: AtomicU32,
    /// When the writer last published, for the lookout to learn its grid.
    last_published_ns: AtomicU64,
    /// The CPU the writer last published from (`u32::MAX`: unknown), which
    /// the lookout keeps off.
    writer_cpu: AtomicU32,
    /// Set once, when the writer goes away; the lookout's sleeps wait on it.
    stopping: AtomicU32,
    /// Set once, when the lookout's thread ends for any reason.
    lookout_gone: AtomicU32,
}

impl Default for Watch {
    fn default() -> Self {
        Watch {
            state: AtomicU32::new(IDLE),
            last_published_ns: AtomicU64::new(0),
            writer_cpu: AtomicU32::new(u32::MAX),
            stopping: AtomicU32::new(0),
            lookout_gone: AtomicU32::new(0),
        }
    }
}

impl Watch {
    /// Writer, after every publish (`announced`: a reader sleeps for it):
    /// leaves the wake to a watching lookout, and says who wakes the readers.
    pub(crate) fn published(&self, announced: bool, published_ns: u64, writer_cpu: u32) -> WakeBy {
        let outcome = if announced { RING } else { PUBLISHED };
        // Release: the lookout that reads `RING` (Acquire) also sees the
        // writer's swap of the doorbell word before it, so its wake comes
        // after the change the sleepers wait for.
        let answered = self.state.compare_exchange(WATCHING, outcome, Ordering::AcqRel, Ordering::Acquire);
        // After the exchange, as a hint only: a lookout that sees the new
        // time gives up its watch, and its own exchange from `WATCHING`
        // decides whether the writer's answer is still its to take.
        self.last_published_ns.store(published_ns, Ordering::Relaxed);
        self.writer_cpu.store(writer_cpu, Ordering::Relaxed);
        match answered {
            Ok(_) if announced => WakeBy::Lookout,
            Ok(_) => WakeBy::Nobody,
            // The lookout has not yet rung the previous frame's sleepers, who
            // announce themselves no more: they are woken now.
            Err(RING) => WakeBy::Writer,
            Err(_) if announced => WakeBy::Writer,
            Err(_) => WakeBy::Nobody,
        }
    }

    /// Loom models: a lookout that began watching and never looks again
    /// (starved for good, or dead).
    #[cfg(all(test, loom))]
    pub(crate) fn begin_watching_and_stall(&self) {
        self.state.store(WATCHING, Ordering::Relaxed);
    }

    /// Lookout: watches for the next publish while `keep_watching` says so,
    /// spinning, and wakes the readers if the writer asks. Returns whether
    /// it woke them.
    pub(crate) fn watch(
        &self,
        notify: &AtomicU32,
        futex: &impl Futex,
        mut keep_watching: impl FnMut() -> bool,
    ) -> bool {
        let before = self.state.swap(WATCHING, Ordering::Relaxed);
        debug_assert_eq!(before, IDLE, "only the lookout leaves the idle state, and it came back to it");
        loop {
            let seen = self.state.load(Ordering::Acquire);
            if seen != WATCHING {
                return self.answer(seen, notify, futex);
            }
            if !keep_watching() {
                // A publish between the last look and this gives up nothing:
                // the exchange fails and the writer's answer is taken.
                return match self.state.compare_exchange(WATCHING, IDLE, Ordering::AcqRel, Ordering::Acquire) {
                    Ok(_) => false,
                    Err(seen) => self.answer(seen, notify, futex),
                };
            }
            spin();
        }
    }

    fn answer(&self, seen: u32, notify: &AtomicU32, futex: &impl Futex) -> bool {
        let ring = seen == RING;
        if ring {
            futex.wake_all(notify);
        }
        // After the wake: a writer that finds `RING` still here at its next
        // publish wakes the readers itself.
        self.state.store(IDLE, Ordering::Release);
        ring
    }

    /// Lookout: when the writer last published (0: not yet); a hint, which
    /// orders nothing.
    pub(crate) fn last_published_ns(&self) -> u64 {
        self.last_published_ns.load(Ordering::Relaxed)
    }

    /// Lookout: the CPU the writer last published from, if known.
    pub(crate) fn writer_cpu(&self) -> Option<u32> {
        Some(self.writer_cpu.load(Ordering::Relaxed)).filter(|&cpu| cpu != u32::MAX)
    }

    /// Lookout: the word its sleeps wait on, which [`Watch::stop`] changes.
    pub(crate) fn stopping_word(&self) -> &AtomicU32 {
        &self.stopping
    }

    /// Lookout: whether the writer is gone.
    pub(crate) fn is_stopping(&self) -> bool {
        self.stopping.load(Ordering::Acquire) != 0
    }

    /// The writer's side is done: the lookout's sleep returns and it ends.
    pub(crate) fn stop(&self, futex: &impl Futex) {
        self.stopping.store(1, Ordering::Release);
        futex.wake_all(&self.stopping);
    }

    /// Lookout: its thread is ending and will watch no more.
    pub(crate) fn lookout_ended(&self) {
        self.lookout_gone.store(1, Ordering::Release);
    }

    /// Writer: whether the lookout's thread has ended.
    pub(crate) fn lookout_gone(&self) -> bool {
        self.lookout_gone.load(Ordering::Acquire) != 0
    }
}

#[cfg(not(loom))]
fn spin() {
    std::hint::spin_loop();
}

#[cfg(loom)]
fn spin() {
    loom::thread::yield_now();
}
