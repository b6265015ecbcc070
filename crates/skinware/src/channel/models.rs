//! The doorbell, and the ringer and lookout that ring it for a writer,
//! against every interleaving of one publish (or request) and
//! the sleepers. Futexes are modelled with loom's mutex and condition
//! variable: `wait` checks the word and goes to sleep under the mutex, and
//! `wake_all` notifies under it, which is the atomicity the kernel gives a
//! futex's check-and-queue against a wake. A lost wake-up leaves a thread
//! asleep forever, which loom reports as a deadlock.

use std::io;
use std::time::Duration;

use super::doorbell::*;
use crate::channel::lookout::{WakeBy, Watch};
use crate::channel::ring::{META_WORDS, Meta, Ring};
use crate::channel::ringer::Handoff;
use crate::sync::{AtomicU32, AtomicU64, Ordering};
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
    super::doorbell::ring(&channel.notify, seq, &channel.futex);
}

/// Publishes frame `seq` and hands the wake to a ringer, as a writer
/// with a ringer does; wakes the readers itself if the ringer is behind.
fn publish_deferred(channel: &Channel, handoff: &Handoff, seq: u64) {
    let ring = Ring::new(&channel.published, &channel.slots, 2);
    let payload = ring.begin(seq);
    payload[0].store(seq * 100, Ordering::Relaxed);
    ring.publish(&Meta { seq, acquired_ns: 0, published_ns: 0, status: 0 });
    let announced = super::doorbell::announce(&channel.notify, seq);
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
    let announced = super::doorbell::announce(&channel.notify, seq);
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
                let end = wait_for_frame(&channel.notify, || ring.published(), 1, u64::MAX, || false, &channel.futex)
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
