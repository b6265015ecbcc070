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

#[cfg(all(test, loom))]
mod loom_tests {
    //! The doorbell against every interleaving of one publish (or request) and
    //! the sleepers. Futexes are modelled with loom's mutex and condition
    //! variable: `wait` checks the word and goes to sleep under the mutex, and
    //! `wake_all` notifies under it, which is the atomicity the kernel gives a
    //! futex's check-and-queue against a wake. A lost wake-up leaves a thread
    //! asleep forever, which loom reports as a deadlock.

    use super::*;
    use crate::channel::lookout::{WakeBy, Watch};
    use crate::channel::ring::{META_WORDS, Meta, Ring};
    use crate::channel::ringer::Handoff;
    use loom::sync::atomic::AtomicBool;
    use loom::sync::{Arc, Condvar, Mutex};

    struct ModelFutex {
        queue: Mutex<()>,
        woken: Condvar,
    }

    impl ModelFutex {
        fn new() -> ModelFutex {
            ModelFutex { queue: Mutex::new(()), woken: Condvar::new() }
        }
    }

    impl Futex for ModelFutex {
        fn now_ns(&self) -> u64 {
            0
        }
        fn wait(&self, word: &AtomicU32, expected: u32, _timeout: Duration) -> io::Result<Wake> {
            let queued = self.queue.lock().unwrap();
            if word.load(Ordering::Relaxed) != expected {
                return Ok(Wake::Recheck);
            }
            drop(self.woken.wait(queued).unwrap());
            Ok(Wake::Recheck)
        }
        fn wake_all(&self, _word: &AtomicU32) {
            let _queued = self.queue.lock().unwrap();
            self.woken.notify_all();
        }
    }

    struct Channel {
        published: crate::sync::AtomicU64,
        slots: Vec<crate::sync::AtomicU64>,
        notify: AtomicU32,
        requests: AtomicU32,
        futex: ModelFutex,
        /// The writer's and its ringer's own futex (a process-private one):
        /// apart, so that waking the ringer never wakes a reader by accident.
        handoff_futex: ModelFutex,
    }

    fn channel() -> Arc<Channel> {
        Arc::new(Channel {
            published: crate::sync::AtomicU64::new(0),
            slots: (0..2 * (META_WORDS + 1)).map(|_| crate::sync::AtomicU64::new(0)).collect(),
            notify: AtomicU32::new(0),
            requests: AtomicU32::new(0),
            futex: ModelFutex::new(),
            handoff_futex: ModelFutex::new(),
        })
    }

    fn publish(channel: &Channel, seq: u64) {
        let ring = Ring::new(&channel.published, &channel.slots, 2);
        let payload = ring.begin(seq);
        payload[0].store(seq * 100, Ordering::Relaxed);
        ring.publish(&Meta { seq, acquired_ns: 0, published_ns: 0, status: 0 });
        super::ring(&channel.notify, seq, &channel.futex);
    }

    /// Publishes frame `seq` and hands the wake to a ringer, as a writer
    /// with a ringer does; wakes the readers itself if the ringer is behind.
    fn publish_deferred(channel: &Channel, handoff: &Handoff, seq: u64) {
        let ring = Ring::new(&channel.published, &channel.slots, 2);
        let payload = ring.begin(seq);
        payload[0].store(seq * 100, Ordering::Relaxed);
        ring.publish(&Meta { seq, acquired_ns: 0, published_ns: 0, status: 0 });
        let announced = super::announce(&channel.notify, seq);
        let behind = handoff.behind();
        if (announced || behind) && (behind || !handoff.hand_off(0, &channel.handoff_futex)) {
            channel.futex.wake_all(&channel.notify);
        }
    }

    /// Publishes frame `seq` as a writer with a lookout does: leaves the
    /// wake to the lookout if it is watching, else wakes the readers itself.
    fn publish_watched(channel: &Channel, watch: &Watch, seq: u64) {
        let ring = Ring::new(&channel.published, &channel.slots, 2);
        let payload = ring.begin(seq);
        payload[0].store(seq * 100, Ordering::Relaxed);
        ring.publish(&Meta { seq, acquired_ns: 0, published_ns: 0, status: 0 });
        let announced = super::announce(&channel.notify, seq);
        if watch.published(announced, seq, 0) == WakeBy::Writer {
            channel.futex.wake_all(&channel.notify);
        }
    }

    /// A lookout that watches for `looks` looks, then gives up, as the
    /// thread in `crate::writer` does at the end of its spin.
    fn spawn_lookout(channel: &Arc<Channel>, watch: &Arc<Watch>, looks: u32) -> loom::thread::JoinHandle<()> {
        let (channel, watch) = (channel.clone(), watch.clone());
        loom::thread::spawn(move || {
            let mut left = looks;
            watch.watch(&channel.notify, &channel.futex, || {
                left -= 1;
                left > 0
            });
        })
    }

    /// A reader waiting for a frame above `after`; its thread returns how
    /// the wait ended.
    fn spawn_waiter(channel: &Arc<Channel>, after: u64) -> loom::thread::JoinHandle<io::Result<WaitEnd>> {
        let channel = channel.clone();
        loom::thread::spawn(move || {
            let ring = Ring::new(&channel.published, &channel.slots, 2);
            wait_for_frame(&channel.notify, || ring.published(), after, u64::MAX, || false, &channel.futex)
        })
    }

    /// The ringer thread's loop, as `crate::writer` runs it.
    fn spawn_ringer(channel: &Arc<Channel>, handoff: &Arc<Handoff>) -> loom::thread::JoinHandle<()> {
        let (channel, handoff) = (channel.clone(), handoff.clone());
        loom::thread::spawn(move || {
            while let Some((requested, _cpu)) = handoff.next(&channel.handoff_futex, Duration::MAX).unwrap() {
                channel.futex.wake_all(&channel.notify);
                handoff.rung(requested);
            }
        })
    }

    fn model(check: impl Fn() + Sync + Send + 'static) {
        let mut model = loom::model::Builder::new();
        if model.preemption_bound.is_none() {
            model.preemption_bound = Some(3);
        }
        model.check(check);
    }

    /// Two readers wait for the first frame while the writer publishes it:
    /// both wake, whichever way their announcements interleave with it.
    #[test]
    fn loom_doorbell_never_loses_a_reader() {
        model(|| {
            let channel = channel();
            let readers: Vec<_> = (0..2)
                .map(|_| {
                    let channel = channel.clone();
                    loom::thread::spawn(move || {
                        let ring = Ring::new(&channel.published, &channel.slots, 2);
                        let end =
                            wait_for_frame(&channel.notify, || ring.published(), 0, u64::MAX, || false, &channel.futex)
                                .unwrap();
                        assert_eq!(end, WaitEnd::Ready);
                        let mut out = [0u64; 1];
                        let (meta, _) = ring.read_latest(&mut out, 4).unwrap();
                        assert_eq!(out[0], meta.seq * 100);
                    })
                })
                .collect();
            publish(&channel, 1);
            for reader in readers {
                reader.join().unwrap();
            }
        });
    }

    /// A reader that already has frame 1 waits for frame 2 while the writer
    /// publishes frames 2 and 3: the second publish finds the announcement of
    /// a reader that slept through nothing, and the reader wakes.
    #[test]
    fn loom_doorbell_wakes_a_reader_waiting_for_a_later_frame() {
        model(|| {
            let channel = channel();
            publish(&channel, 1);
            let reader = {
                let channel = channel.clone();
                loom::thread::spawn(move || {
                    let ring = Ring::new(&channel.published, &channel.slots, 2);
                    let end =
                        wait_for_frame(&channel.notify, || ring.published(), 1, u64::MAX, || false, &channel.futex)
                            .unwrap();
                    assert_eq!(end, WaitEnd::Ready);
                    assert!(ring.published() >= 2);
                })
            };
            publish(&channel, 2);
            publish(&channel, 3);
            reader.join().unwrap();
        });
    }

    /// A sporadic writer waiting for a request is always woken by one.
    #[test]
    fn loom_doorbell_never_loses_a_request() {
        model(|| {
            let channel = channel();
            let mut served = requests_served(&channel.requests);
            let asker = {
                let channel = channel.clone();
                loom::thread::spawn(move || request(&channel.requests, &channel.futex))
            };
            let end = wait_for_request(&channel.requests, &mut served, u64::MAX, || false, &channel.futex).unwrap();
            assert_eq!(end, WaitEnd::Ready);
            assert_eq!(served, 1);
            asker.join().unwrap();
        });
    }

    /// A stop raised while a reader waits (flag, then nudge) always ends the wait.
    #[test]
    fn loom_doorbell_stop_always_reaches_a_sleeper() {
        model(|| {
            let channel = channel();
            let stopped = Arc::new(AtomicBool::new(false));
            let reader = {
                let (channel, stopped) = (channel.clone(), stopped.clone());
                loom::thread::spawn(move || {
                    let ring = Ring::new(&channel.published, &channel.slots, 2);
                    let end = wait_for_frame(
                        &channel.notify,
                        || ring.published(),
                        0,
                        u64::MAX,
                        || stopped.load(Ordering::Acquire),
                        &channel.futex,
                    )
                    .unwrap();
                    assert_eq!(end, WaitEnd::Stopped);
                })
            };
            stopped.store(true, Ordering::Release);
            nudge(&channel.notify, &channel.futex);
            reader.join().unwrap();
        });
    }
    /// A reader waits for frame 1 while the writer publishes it and hands the
    /// wake to its ringer: the reader wakes, whichever way the three threads
    /// interleave (and the ringer stops when the writer goes).
    #[test]
    fn loom_a_ringer_wakes_a_reader_the_writer_handed_it() {
        model(|| {
            let channel = channel();
            let handoff = Arc::new(Handoff::default());
            let ringer = spawn_ringer(&channel, &handoff);
            let reader = spawn_waiter(&channel, 0);
            publish_deferred(&channel, &handoff, 1);
            assert_eq!(reader.join().unwrap().unwrap(), WaitEnd::Ready);
            handoff.stop(&channel.handoff_futex);
            ringer.join().unwrap();
        });
    }

    /// A ringer that never runs (starved for good, or dead) loses no wake: a
    /// reader asleep since the handoff of frame 1, which announces itself no
    /// more, is woken by the writer at frame 2.
    #[test]
    fn loom_a_ringer_that_never_runs_loses_no_wake() {
        model(|| {
            let channel = channel();
            let handoff = Arc::new(Handoff::default());
            let reader = spawn_waiter(&channel, 0);
            publish_deferred(&channel, &handoff, 1);
            publish_deferred(&channel, &handoff, 2);
            assert_eq!(reader.join().unwrap().unwrap(), WaitEnd::Ready);
        });
    }

    /// Two publishes while a reader waits for the second: whether the ringer
    /// rang the first in time or the writer woke the readers itself, the
    /// reader wakes for frame 2.
    #[test]
    fn loom_a_ringer_that_falls_behind_loses_no_wake() {
        model(|| {
            let channel = channel();
            let handoff = Arc::new(Handoff::default());
            let ringer = spawn_ringer(&channel, &handoff);
            let reader = spawn_waiter(&channel, 1);
            publish_deferred(&channel, &handoff, 1);
            publish_deferred(&channel, &handoff, 2);
            assert_eq!(reader.join().unwrap().unwrap(), WaitEnd::Ready);
            handoff.stop(&channel.handoff_futex);
            ringer.join().unwrap();
        });
    }
    /// A reader waits for frame 1 while a lookout watches for it and gives
    /// up after two looks: whether the writer's publish comes before, during
    /// or after the watch, the reader wakes (woken by the lookout or by the
    /// writer, never by neither).
    #[test]
    fn loom_a_lookout_or_the_writer_wakes_a_reader() {
        model(|| {
            let channel = channel();
            let watch = Arc::new(Watch::default());
            let lookout = spawn_lookout(&channel, &watch, 2);
            let reader = spawn_waiter(&channel, 0);
            publish_watched(&channel, &watch, 1);
            assert_eq!(reader.join().unwrap().unwrap(), WaitEnd::Ready);
            lookout.join().unwrap();
        });
    }

    /// A lookout that took frame 1's wake and never rings it (it stalled
    /// for good): the writer, finding it still behind at frame 2, wakes the
    /// reader asleep since frame 1, which announces itself no more.
    #[test]
    fn loom_a_lookout_that_never_rings_loses_no_wake() {
        model(|| {
            let channel = channel();
            let watch = Arc::new(Watch::default());
            watch.begin_watching_and_stall();
            let reader = spawn_waiter(&channel, 0);
            publish_watched(&channel, &watch, 1);
            publish_watched(&channel, &watch, 2);
            assert_eq!(reader.join().unwrap().unwrap(), WaitEnd::Ready);
        });
    }

    /// Two publishes while a reader waits for the second and a lookout
    /// watches once: a lookout that took frame 1's wake and has not rung it
    /// when frame 2 comes leaves frame 2's wake to the writer, and the reader
    /// wakes either way.
    #[test]
    fn loom_a_lookout_that_falls_behind_loses_no_wake() {
        model(|| {
            let channel = channel();
            let watch = Arc::new(Watch::default());
            let lookout = spawn_lookout(&channel, &watch, 1);
            let reader = spawn_waiter(&channel, 1);
            publish_watched(&channel, &watch, 1);
            publish_watched(&channel, &watch, 2);
            assert_eq!(reader.join().unwrap().unwrap(), WaitEnd::Ready);
            lookout.join().unwrap();
        });
    }
}
