//! The doorbell: how a reader sleeps until a frame is published, and how a
//! sporadic writer sleeps until a reader asks for one. The whole futex
//! protocol is here; the words live in the segment's doorbell page
//! ([`super::layout::Doorbell`]) and the system calls in [`crate::os`].
//!
//! **Frames (`notify`).** The word holds `(seq << 1) | waiters`.
//!
//! * A reader that wants a frame newer than `after` loads the word, checks
//!   `published`, then *announces* itself by setting the waiters bit with a
//!   read-modify-write and checks again. Only if neither the word's sequence
//!   part nor `published` moved in between does it sleep, on the value it
//!   announced, so a publish anywhere in that window makes the sleep return at
//!   once.
//! * The writer, after publishing frame `seq`, swaps `seq << 1` into the word
//!   (clearing the bit) and makes the wake system call only if the bit was
//!   set: with nobody waiting, a publish costs one atomic swap and no system
//!   call. A reader that died asleep leaves the bit set and costs one spare
//!   wake at most.
//!
//! **Requests (`requests`).** A counter that readers increment (and wake) to
//! ask a sporadic writer for a frame; the writer remembers the last value it
//! served and sleeps while the counter still holds it.
//!
//! **Nudges.** Stopping, or a writer leaving, changes a word and wakes
//! everyone on it: sleepers re-check their condition and see why. The writer's
//! next publish overwrites `notify` anyway, so a nudge costs nobody anything.
//!
//! Nothing on this page is on the data path, and the writer never waits on
//! it for a frame: whatever a reader writes here can delay no publish and
//! corrupt no frame.
//!
//! The loom model at the bottom checks the announcement against every
//! interleaving with a publish: a reader that announced itself before a
//! publish is always woken (no lost wake-up), and so are a sporadic writer
//! asked for a frame and a reader whose stop signal is raised.

#![forbid(unsafe_code)]

use std::io;
use std::time::Duration;

use crate::sync::{AtomicU32, Ordering};

/// How a futex wait ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Wake {
    /// Woken, interrupted, or the word no longer held the expected value: re-check.
    Recheck,
    /// The timeout passed.
    TimedOut,
}

/// The futex operations the doorbell needs, on process-shared words. The OS
/// provides them with real futexes ([`crate::os::SHARED_FUTEX`]); the loom
/// model with a mutex and a condition variable.
pub(crate) trait Futex {
    /// Now, in CLOCK_MONOTONIC nanoseconds.
    fn now_ns(&self) -> u64;
    /// Sleeps while `word` holds `expected`, at most `timeout`. Returns at
    /// once if it holds something else.
    fn wait(&self, word: &AtomicU32, expected: u32, timeout: Duration) -> io::Result<Wake>;
    /// Wakes every sleeper on `word`.
    fn wake_all(&self, word: &AtomicU32);
}

/// How a wait on the doorbell ended (a failed system call is the `Err` beside it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum WaitEnd {
    /// What was waited for happened.
    Ready,
    /// The deadline passed first.
    TimedOut,
    /// The stop signal was raised first.
    Stopped,
}

/// Writer, after publishing frame `seq`: wakes sleeping readers, and makes the
/// system call only if one announced itself.
#[cfg(loom)]
pub(crate) fn ring(notify: &AtomicU32, seq: u64, futex: &impl Futex) {
    if announce(notify, seq) {
        futex.wake_all(notify);
    }
}

/// Writer, after publishing frame `seq`: changes the word readers sleep on,
/// and says whether one announced it sleeps. Then someone must `wake_all` the
/// word: the writer itself or its ringer ([`super::ringer`]).
pub(crate) fn announce(notify: &AtomicU32, seq: u64) -> bool {
    // Release: a reader that sees this value (its Acquire load in
    // `wait_for_frame`) also sees the publish before it. The swap also clears
    // the announcement, so a reader that died asleep costs one wake at most.
    let announced = notify.swap((seq as u32) << 1, Ordering::Release);
    announced & 1 != 0
}

/// Whether a reader has announced that it sleeps (or is about to) until the
/// next publish. A hint for a writer's lookout ([`super::lookout`]): a reader
/// that announces itself after the look misses nothing, since the writer's
/// ringer (or the writer) then wakes it.
pub(crate) fn someone_waits(notify: &AtomicU32) -> bool {
    notify.load(Ordering::Relaxed) & 1 != 0
}

/// Changes `word` and wakes everyone on it, so that a sleeper, or a thread
/// about to sleep on the old value, re-checks its condition at once.
pub(crate) fn nudge(word: &AtomicU32, futex: &impl Futex) {
    // Changing the word before the wake is what reaches a thread that is
    // between its check and its sleep. Adding 2 leaves `notify`'s waiters bit
    // alone; for `requests` any change is a request, which a sporadic writer
    // answers with one spare frame at worst.
    word.fetch_add(2, Ordering::Release);
    futex.wake_all(word);
}

/// Reader: sleeps until `published()` exceeds `after`, the deadline passes, or
/// `stopped()` turns true. Never spins; each pass is one futex sleep.
pub(crate) fn wait_for_frame(
    notify: &AtomicU32,
    published: impl Fn() -> u64,
    after: u64,
    deadline_ns: u64,
    stopped: impl Fn() -> bool,
    futex: &impl Futex,
) -> io::Result<WaitEnd> {
    loop {
        // The word first, then the stop flag and the frame: a stop or publish
        // after this load changes the word, so the announcement below notices
        // it. (Checking the flag first loses a stop raised between the two:
        // the loom model found that.) Acquire: pairs with the Release in
        // `ring` and `nudge`.
        let seen = notify.load(Ordering::Acquire);
        if stopped() {
            return Ok(WaitEnd::Stopped);
        }
        if published() > after {
            return Ok(WaitEnd::Ready);
        }
        // Announce ourselves, then re-check: a publish between our check and
        // the announcement changed the word, so we go round instead of
        // sleeping past it. AcqRel: the read half orders the re-check of
        // `published` after it.
        let announced = notify.fetch_or(1, Ordering::AcqRel);
        if announced >> 1 != seen >> 1 || published() > after {
            continue;
        }
        let now = futex.now_ns();
        if now >= deadline_ns {
            return Ok(WaitEnd::TimedOut);
        }
        // Sleeps only while the word still holds what we announced: a publish
        // after the announcement changes it, and the kernel checks the value
        // and queues us atomically with respect to the writer's wake.
        futex.wait(notify, announced | 1, Duration::from_nanos(deadline_ns - now))?;
    }
}

/// Reader: asks a sporadic writer for a frame.
pub(crate) fn request(requests: &AtomicU32, futex: &impl Futex) {
    // Release: pairs with the Acquire load in `wait_for_request`.
    requests.fetch_add(1, Ordering::Release);
    futex.wake_all(requests);
}

/// Sporadic writer: sleeps until the request counter differs from `served`,
/// then records the new value in `served`.
pub(crate) fn wait_for_request(
    requests: &AtomicU32,
    served: &mut u32,
    deadline_ns: u64,
    stopped: impl Fn() -> bool,
    futex: &impl Futex,
) -> io::Result<WaitEnd> {
    loop {
        if stopped() {
            return Ok(WaitEnd::Stopped);
        }
        let seen = requests.load(Ordering::Acquire);
        if seen != *served {
            *served = seen;
            return Ok(WaitEnd::Ready);
        }
        let now = futex.now_ns();
        if now >= deadline_ns {
            return Ok(WaitEnd::TimedOut);
        }
        futex.wait(requests, seen, Duration::from_nanos(deadline_ns - now))?;
    }
}

/// The request count a new writer starts from: requests made before it
/// existed are not answered.
pub(crate) fn requests_served(requests: &AtomicU32) -> u32 {
    requests.load(Ordering::Acquire)
}
