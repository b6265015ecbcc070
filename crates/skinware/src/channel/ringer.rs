//! The wake of sleeping readers, made by a second thread instead of the
//! writer's.
//!
//! Waking a reader asleep on another, idle CPU costs the *waking* thread an
//! inter-processor interrupt: 14 µs p50 and 25–60 µs p99 on this project's
//! 2-vCPU machines, more than the rest of a publish. Waking a thread on the
//! waker's own CPU, at a lower real-time priority, costs about 2 µs, because
//! it neither interrupts another CPU nor preempts the waker (`skin bench
//! wake` measures both). So a writer hands the wake to its *ringer*: a thread
//! that follows the writer onto its CPU, one real-time priority below it. The
//! ringer runs as soon as the writer sleeps until its next period and pays the
//! interrupt there, off the acquisition's time line. The frame is visible to
//! readers before either wake: a reader that polls, or is about to sleep,
//! never waits for the ringer.
//!
//! The handoff delays a sleeping reader by at most one publish: whenever the
//! ringer has not rung the previous handoff when the writer publishes again
//! (it was starved, or the writer never sleeps), the writer wakes the readers
//! itself, whether or not a reader announced itself since: a reader asleep
//! since the previous frame does not announce itself again. A ringer that
//! stops (a failed system call, a panic) says so, and its writer wakes its
//! readers itself from then on.
//!
//! This module is the protocol between the two threads, model-checked with
//! loom below; the thread itself lives in `crate::writer`.

use std::io;
use std::time::Duration;

use super::doorbell::Futex;
use crate::sync::{AtomicU32, Ordering};

/// What a writer and its ringer share (process-private memory).
#[derive(Debug, Default)]
pub(crate) struct Handoff {
    /// Handoffs the writer made. The ringer sleeps on it; only the writer
    /// changes it (and [`Handoff::stop`], once the writer is done).
    requested: AtomicU32,
    /// The last handoff the ringer has rung.
    rung: AtomicU32,
    /// The CPU the writer ran on at its last handoff, for the ringer to
    /// follow (`u32::MAX`: unknown).
    writer_cpu: AtomicU32,
    /// Set once, when the writer goes away.
    stopping: AtomicU32,
    /// Set once, when the ringer's thread ends for any reason.
    ringer_gone: AtomicU32,
}

impl Handoff {
    /// Writer, after a publish that found a reader asleep: asks the ringer to
    /// wake it. Returns `false`, asking nothing, if the ringer has not yet
    /// rung the previous handoff; the writer then wakes the readers itself.
    pub(crate) fn hand_off(&self, writer_cpu: u32, futex: &impl Futex) -> bool {
        let requested = self.requested.load(Ordering::Relaxed);
        // Acquire: pairs with the ringer's Release in `rung`; nothing is
        // read through it, it only orders the check before the new request.
        if self.rung.load(Ordering::Acquire) != requested {
            return false;
        }
        self.writer_cpu.store(writer_cpu, Ordering::Relaxed);
        // Release: the ringer that sees this request (its Acquire in `next`)
        // also sees the writer's swap of the doorbell word before it, so its
        // wake comes after the change the sleepers are waiting for.
        self.requested.store(requested.wrapping_add(1), Ordering::Release);
        futex.wake_all(&self.requested);
        true
    }

    /// Writer: whether the ringer has not yet rung the last handoff. The
    /// writer then wakes the readers itself at its next publish, even if none
    /// announced itself since (one asleep since the previous frame does not).
    pub(crate) fn behind(&self) -> bool {
        // Acquire: pairs with the ringer's Release in `rung`.
        self.rung.load(Ordering::Acquire) != self.requested.load(Ordering::Relaxed)
    }

    /// Writer: whether the ringer's thread has ended (see [`Handoff::ringer_ended`]).
    pub(crate) fn ringer_gone(&self) -> bool {
        self.ringer_gone.load(Ordering::Acquire) != 0
    }

    /// Ringer: its thread is ending and will ring nothing more.
    pub(crate) fn ringer_ended(&self) {
        self.ringer_gone.store(1, Ordering::Release);
    }

    /// Ringer: sleeps until there is a handoff to ring, and returns it with
    /// the writer's CPU; `None` once the writer is gone.
    pub(crate) fn next(&self, futex: &impl Futex, slice: Duration) -> io::Result<Option<(u32, u32)>> {
        loop {
            // The word first, then the stop flag: a stop after this load
            // changes the word, so the wait below returns at once.
            let requested = self.requested.load(Ordering::Acquire);
            if self.stopping.load(Ordering::Acquire) != 0 {
                return Ok(None);
            }
            if requested != self.rung.load(Ordering::Relaxed) {
                return Ok(Some((requested, self.writer_cpu.load(Ordering::Relaxed))));
            }
            futex.wait(&self.requested, requested, slice)?;
        }
    }

    /// Ringer: the readers of handoff `requested` are woken.
    pub(crate) fn rung(&self, requested: u32) {
        self.rung.store(requested, Ordering::Release);
    }

    /// The writer's side is done: the ringer returns from [`Handoff::next`].
    pub(crate) fn stop(&self, futex: &impl Futex) {
        self.stopping.store(1, Ordering::Release);
        // Changing the word reaches a ringer between its check and its sleep.
        self.requested.fetch_add(1, Ordering::Release);
        futex.wake_all(&self.requested);
    }
}
