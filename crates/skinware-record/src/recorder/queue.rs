//! The queue from the reader threads to the file's thread: bounded, many
//! senders, one receiver, and every wait a sleep.
//!
//! Why not `std::sync::mpsc::sync_channel` (or crossbeam's channel, which it
//! is taken from): its senders *spin* while the receiver is between taking a
//! slot and marking it free, yielding now and then. `sched_yield` yields only
//! to threads of the same or higher priority, so a reader in SCHED_FIFO that
//! finds the slot the file's thread was preempted in keeps its CPU until the
//! file's thread runs somewhere else. With two readers spinning on two CPUs,
//! the file's thread, of lower priority, never ran again: a recording of the
//! paper's skin at 1 kHz with the file's thread at SCHED_FIFO 10 stopped
//! after 10 s and held both CPUs for 17 minutes (`docs/bench/record.md`, "The
//! queue that spun"). In the normal scheduler the file's thread gets at
//! least what real-time throttling leaves (5 % of each second), so the same
//! wait is a stall, of up to a second by that reckoning, instead of a
//! livelock: readers spinning at 40 % of a CPU and more, and frames lost
//! with it, were measured there in three of four runs of the old queue.
//!
//! Here a sender or the receiver that must wait sleeps on a condition
//! variable, and the lock is held only to move one item in or out: a thread
//! of higher priority that wants the lock while a preempted thread holds it
//! sleeps on its futex rather than spinning over it. (std's mutex does not
//! lend its holder the waiter's priority: a reader may still wait for the
//! file's thread to get a CPU, for the few instructions it holds the lock.)

use std::collections::VecDeque;
use std::sync::mpsc::{RecvTimeoutError, TrySendError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// A bounded queue of `capacity` items (at least 1): its sending half,
/// which may be cloned, and its receiving half.
pub(super) fn bounded<T>(capacity: usize) -> (QueueSender<T>, QueueReceiver<T>) {
    let capacity = capacity.max(1);
    let queue = Arc::new(Queue {
        state: Mutex::new(State {
            items: VecDeque::with_capacity(capacity),
            senders: 1,
            receiver_alive: true,
            receiver_waiting: false,
            senders_waiting: 0,
        }),
        capacity,
        not_empty: Condvar::new(),
        not_full: Condvar::new(),
    });
    (QueueSender { queue: queue.clone() }, QueueReceiver { queue })
}

struct Queue<T> {
    state: Mutex<State<T>>,
    capacity: usize,
    /// The receiver waits on it for an item or for the last sender to go.
    not_empty: Condvar,
    /// Senders wait on it for room or for the receiver to go.
    not_full: Condvar,
}

struct State<T> {
    items: VecDeque<T>,
    /// Sending halves alive: at 0 the receiver, once the queue is empty, is done.
    senders: usize,
    receiver_alive: bool,
    /// Whether the receiver sleeps on `not_empty`: a sender wakes it only
    /// then, so that a queue kept busy costs no system call per item.
    receiver_waiting: bool,
    /// Senders sleeping on `not_full`.
    senders_waiting: usize,
}

impl<T> Queue<T> {
    fn lock(&self) -> MutexGuard<'_, State<T>> {
        // Nothing in the queue's own code panics while holding the lock; an
        // item whose drop panicked elsewhere leaves the state whole.
        self.state.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// The sending half; clones send into the same queue.
pub(super) struct QueueSender<T> {
    queue: Arc<Queue<T>>,
}

impl<T> QueueSender<T> {
    /// Queues `item` if there is room now.
    pub(super) fn try_send(&self, item: T) -> Result<(), TrySendError<T>> {
        let state = self.queue.lock();
        if !state.receiver_alive {
            return Err(TrySendError::Disconnected(item));
        }
        if state.items.len() >= self.queue.capacity {
            return Err(TrySendError::Full(item));
        }
        self.push(state, item);
        Ok(())
    }

    /// Queues `item`, sleeping while the queue is full; gives it back once
    /// the receiver is gone.
    pub(super) fn send(&self, item: T) -> Result<(), T> {
        let mut state = self.queue.lock();
        loop {
            if !state.receiver_alive {
                return Err(item);
            }
            if state.items.len() < self.queue.capacity {
                self.push(state, item);
                return Ok(());
            }
            state.senders_waiting += 1;
            state = self.queue.not_full.wait(state).unwrap_or_else(std::sync::PoisonError::into_inner);
            state.senders_waiting -= 1;
        }
    }

    fn push(&self, mut state: MutexGuard<'_, State<T>>, item: T) {
        state.items.push_back(item);
        let wake = state.receiver_waiting;
        drop(state);
        if wake {
            self.queue.not_empty.notify_one();
        }
    }
}

impl<T> Clone for QueueSender<T> {
    fn clone(&self) -> Self {
        self.queue.lock().senders += 1;
        QueueSender { queue: self.queue.clone() }
    }
}

impl<T> Drop for QueueSender<T> {
    fn drop(&mut self) {
        let mut state = self.queue.lock();
        state.senders -= 1;
        let last = state.senders == 0;
        drop(state);
        if last {
            self.queue.not_empty.notify_one();
        }
    }
}

/// The receiving half. Dropping it gives every waiting and later send its
/// item back.
pub(super) struct QueueReceiver<T> {
    queue: Arc<Queue<T>>,
}

impl<T> QueueReceiver<T> {
    /// The oldest item, waiting at most `timeout` for one; `Disconnected`
    /// once the queue is empty and every sender is gone.
    pub(super) fn recv_timeout(&self, timeout: Duration) -> Result<T, RecvTimeoutError> {
        let deadline = Instant::now().checked_add(timeout);
        let mut state = self.queue.lock();
        loop {
            if let Some(item) = state.items.pop_front() {
                let wake = state.senders_waiting > 0;
                drop(state);
                if wake {
                    self.queue.not_full.notify_one();
                }
                return Ok(item);
            }
            if state.senders == 0 {
                return Err(RecvTimeoutError::Disconnected);
            }
            let left = match deadline {
                Some(deadline) => deadline.saturating_duration_since(Instant::now()),
                None => Duration::MAX,
            };
            if left.is_zero() {
                return Err(RecvTimeoutError::Timeout);
            }
            state.receiver_waiting = true;
            let (woken, _) =
                self.queue.not_empty.wait_timeout(state, left).unwrap_or_else(std::sync::PoisonError::into_inner);
            state = woken;
            state.receiver_waiting = false;
        }
    }
}

impl<T> Drop for QueueReceiver<T> {
    fn drop(&mut self) {
        let mut state = self.queue.lock();
        state.receiver_alive = false;
        // The items left are dropped here, not when the last sender goes.
        let items = std::mem::take(&mut state.items);
        drop(state);
        self.queue.not_full.notify_all();
        drop(items);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn items_come_out_in_the_order_they_went_in_and_the_queue_holds_its_capacity() {
        let (sender, receiver) = bounded::<u32>(3);
        for i in 0..3 {
            sender.try_send(i).unwrap();
        }
        assert!(matches!(sender.try_send(3), Err(TrySendError::Full(3))));
        assert_eq!(receiver.recv_timeout(Duration::ZERO), Ok(0));
        sender.try_send(3).unwrap();
        let got: Vec<u32> = (0..3).map(|_| receiver.recv_timeout(Duration::ZERO).unwrap()).collect();
        assert_eq!(got, [1, 2, 3]);
        assert_eq!(receiver.recv_timeout(Duration::from_millis(20)), Err(RecvTimeoutError::Timeout));
    }

    #[test]
    fn the_receiver_is_done_only_once_every_sender_is_gone_and_the_queue_is_empty() {
        let (sender, receiver) = bounded::<u32>(4);
        let second = sender.clone();
        sender.send(1).unwrap();
        drop(sender);
        second.send(2).unwrap();
        drop(second);
        assert_eq!(receiver.recv_timeout(Duration::ZERO), Ok(1));
        assert_eq!(receiver.recv_timeout(Duration::ZERO), Ok(2));
        assert_eq!(receiver.recv_timeout(Duration::from_secs(10)), Err(RecvTimeoutError::Disconnected));
    }

    #[test]
    fn a_sender_waiting_for_room_gets_its_item_back_when_the_receiver_goes() {
        let (sender, receiver) = bounded::<u32>(1);
        sender.send(1).unwrap();
        let waiting = std::thread::spawn(move || sender.send(2));
        std::thread::sleep(Duration::from_millis(50));
        drop(receiver);
        assert_eq!(waiting.join().unwrap(), Err(2));
    }

    #[test]
    fn a_receiver_waiting_wakes_for_the_last_sender_going_and_for_an_item() {
        let (sender, receiver) = bounded::<u32>(1);
        let later = sender.clone();
        let sending = std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis(30));
            sender.send(7).unwrap();
            drop(sender);
            std::thread::sleep(Duration::from_millis(30));
            drop(later);
        });
        assert_eq!(receiver.recv_timeout(Duration::from_secs(10)), Ok(7));
        assert_eq!(receiver.recv_timeout(Duration::from_secs(10)), Err(RecvTimeoutError::Disconnected));
        sending.join().unwrap();
    }

    /// The recorder's threads on one CPU: three senders in SCHED_FIFO 20 woken
    /// by timers every 20 µs (as a reader woken by its writer preempts the
    /// file's thread wherever it is), and a receiver in SCHED_FIFO 10 that
    /// works 2 µs on each item, so that the queue of 4 is full most of the
    /// time and a sender often finds the receiver in the middle of taking
    /// one. A queue whose senders spin until the receiver finishes never
    /// lets it finish: std's `sync_channel` in its place ended the test
    /// binary by the real-time limit below in 6 tries of 6, 10–12 s in
    /// (`docs/bench/record.md`, "The queue that spun"). This one delivers
    /// every item it took, in about 3 s.
    #[test]
    fn real_time_senders_on_one_cpu_never_keep_a_lower_priority_receiver_from_its_items() {
        const ATTEMPTS: u64 = 60_000;
        if let Err(e) = skinware::os::set_fifo_priority(1).and_then(|()| skinware::os::set_normal_scheduling()) {
            eprintln!("skipped: SCHED_FIFO refused ({e}); run as root to test the queue under real-time senders");
            return;
        }
        let Some(cpu) = skinware::os::allowed_cpus().ok().and_then(|cpus| cpus.first().copied()) else {
            eprintln!("skipped: the CPUs this thread may run on are unknown");
            return;
        };
        // A queue that spins would keep its real-time threads on `cpu` until
        // the test binary exits: past 10 s without blocking (this queue's
        // threads block every 20 µs) the kernel ends the binary instead,
        // with SIGXCPU ("CPU time limit exceeded").
        skinware::os::limit_realtime_run(Duration::from_secs(10)).expect("RLIMIT_RTTIME");
        let pin = move |priority: u8| {
            skinware::os::pin_to_cpus(&[cpu]).expect("pin to an allowed CPU");
            skinware::os::set_fifo_priority(priority).expect("SCHED_FIFO");
        };
        let (sender, receiver) = bounded::<u64>(4);
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            pin(10);
            let mut received = 0u64;
            while receiver.recv_timeout(Duration::from_secs(60)).is_ok() {
                received += 1;
                let working = Instant::now();
                while working.elapsed() < Duration::from_micros(2) {
                    std::hint::spin_loop();
                }
            }
            let _ = done.send(received);
        });
        let senders: Vec<_> = (0..3)
            .map(|_| {
                let sender = sender.clone();
                std::thread::spawn(move || {
                    pin(20);
                    let mut sent = 0u64;
                    for i in 0..ATTEMPTS {
                        std::thread::sleep(Duration::from_micros(20));
                        sent += u64::from(sender.try_send(i).is_ok());
                    }
                    sent
                })
            })
            .collect();
        drop(sender);
        // About a second when it works; a livelock never ends, and leaves its
        // spinning threads on CPU 0 until the test binary exits.
        let received = match finished.recv_timeout(Duration::from_secs(60)) {
            Ok(received) => received,
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                panic!("the receiver got no CPU for a minute: the real-time senders spin over it")
            }
            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => panic!("the receiving thread panicked"),
        };
        let sent: u64 = senders.into_iter().map(|s| s.join().unwrap()).sum();
        assert_eq!(received, sent);
        assert!(sent > 0);
    }

    #[test]
    fn many_senders_through_a_small_queue_lose_nothing_and_keep_each_senders_order() {
        let (sender, receiver) = bounded::<(usize, u32)>(2);
        let threads: Vec<_> = (0..4)
            .map(|s| {
                let sender = sender.clone();
                std::thread::spawn(move || {
                    for i in 0..2_000 {
                        sender.send((s, i)).unwrap();
                    }
                })
            })
            .collect();
        drop(sender);
        let mut next = [0u32; 4];
        while let Ok((s, i)) = receiver.recv_timeout(Duration::from_secs(10)) {
            assert_eq!(i, next[s]);
            next[s] += 1;
        }
        assert_eq!(next, [2_000; 4]);
        threads.into_iter().for_each(|t| t.join().unwrap());
    }
}
