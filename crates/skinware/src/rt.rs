//! Real-time helpers: absolute-time periodic scheduling, a stop signal that
//! interrupts every blocking call, and real-time thread set-up.

#![forbid(unsafe_code)]

use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use crate::channel::doorbell::{self, Futex as _, Wake};
use crate::channel::segment::Shared;
use crate::os::{self, PRIVATE_FUTEX, SHARED_FUTEX};
use crate::sync::{AtomicU32, Ordering};

/// A cloneable signal that stops blocking calls: [`Ticker::wait`],
/// [`Reader::wait_newer`](crate::Reader::wait_newer), [`Reader::request`](crate::Reader::request),
/// [`Writer::wait_request`](crate::Writer::wait_request) and the periodic loops.
///
/// Stopping wakes sleepers at once (it does not wait for their timeouts).
#[derive(Clone, Default)]
pub struct Stop {
    inner: Arc<StopInner>,
}

#[derive(Default)]
struct StopInner {
    /// 0 while running, 1 once stopped; also the futex word tickers sleep on.
    word: AtomicU32,
    /// Channels whose futex words must be woken too.
    channels: Mutex<Vec<Weak<Shared>>>,
}

impl std::fmt::Debug for Stop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Stop").field("stopped", &self.is_stopped()).finish()
    }
}

impl Stop {
    /// A new signal, not yet stopped.
    pub fn new() -> Stop {
        Stop::default()
    }

    /// Stops every blocking call that watches this signal, now and later.
    pub fn stop(&self) {
        self.inner.word.store(1, Ordering::Release);
        PRIVATE_FUTEX.wake_all(&self.inner.word);
        let channels = crate::lock(&self.inner.channels);
        for shared in channels.iter().filter_map(Weak::upgrade) {
            let doorbell = shared.doorbell();
            doorbell::nudge(&doorbell.notify, &SHARED_FUTEX);
            doorbell::nudge(&doorbell.requests, &SHARED_FUTEX);
        }
    }

    /// Whether [`stop`](Self::stop) was called.
    pub fn is_stopped(&self) -> bool {
        self.inner.word.load(Ordering::Acquire) != 0
    }

    /// Makes `stop` also wake sleepers on this channel's futex words.
    pub(crate) fn watch(&self, shared: &Arc<Shared>) {
        let mut channels = crate::lock(&self.inner.channels);
        channels.retain(|weak| weak.strong_count() > 0);
        channels.push(Arc::downgrade(shared));
    }

    /// Sleeps until the absolute CLOCK_MONOTONIC `deadline_ns`; `false` if stopped first.
    pub fn sleep_until(&self, deadline_ns: u64) -> bool {
        loop {
            if self.is_stopped() {
                return false;
            }
            if os::monotonic_ns() >= deadline_ns {
                return true;
            }
            match PRIVATE_FUTEX.wait_until(&self.inner.word, 0, deadline_ns) {
                Ok(Wake::TimedOut) => return !self.is_stopped(),
                Ok(Wake::Recheck) => {}
                // Only EFAULT/EINVAL are possible, neither with a valid word and
                // deadline; fall back to the plain sleep rather than spin.
                Err(_) => std::thread::sleep(Duration::from_nanos(deadline_ns.saturating_sub(os::monotonic_ns()))),
            }
        }
    }
}

/// One periodic wake-up.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Tick {
    /// The deadline this tick stands for (CLOCK_MONOTONIC ns).
    pub deadline_ns: u64,
    /// How late after its deadline the tick started, ns.
    pub lateness_ns: u64,
    /// Whether the previous period's work ran past this deadline (an overrun).
    pub overrun: bool,
    /// Whole periods skipped because of that overrun.
    pub missed: u64,
}

/// An absolute-time periodic schedule: deadlines lie on a fixed grid
/// `start + k * period`, so lateness never accumulates into drift.
#[derive(Clone, Debug)]
pub struct Ticker {
    period_ns: u64,
    next_ns: u64,
}

impl Ticker {
    /// A schedule whose first deadline is now.
    pub fn new(period: Duration) -> Ticker {
        Ticker::starting_at(period, os::monotonic_ns())
    }

    /// A schedule whose first deadline is `start_ns` (CLOCK_MONOTONIC).
    pub fn starting_at(period: Duration, start_ns: u64) -> Ticker {
        let period_ns = (period.as_nanos().min(u64::MAX as u128) as u64).max(1);
        Ticker { period_ns, next_ns: start_ns }
    }

    /// A schedule on the grid `origin_ns + k * period` (CLOCK_MONOTONIC)
    /// whose first deadline is the first point of the grid not yet passed.
    /// Threads given origins a fraction of a period apart keep their
    /// deadlines that far apart, however late each one starts.
    pub fn on_grid(period: Duration, origin_ns: u64) -> Ticker {
        let mut ticker = Ticker::starting_at(period, origin_ns);
        let now = os::monotonic_ns();
        if ticker.next_ns < now {
            let behind = now - ticker.next_ns;
            ticker.next_ns =
                ticker.next_ns.saturating_add(behind.div_ceil(ticker.period_ns).saturating_mul(ticker.period_ns));
        }
        ticker
    }

    /// A schedule at `hz` frames per second (at least one per ~584 years).
    pub fn from_hz(hz: f64) -> Ticker {
        Ticker::new(Duration::from_secs_f64(1.0 / hz.max(1e-9)))
    }

    /// The period.
    pub fn period(&self) -> Duration {
        Duration::from_nanos(self.period_ns)
    }

    /// Waits for the next deadline, or returns at once if it already passed
    /// (an overrun: the deadlines that passed are skipped, not made up for).
    /// `None` if `stop` was signalled.
    pub fn wait(&mut self, stop: &Stop) -> Option<Tick> {
        let deadline = self.next_ns;
        let called = os::monotonic_ns();
        let tick = if called <= deadline {
            if !stop.sleep_until(deadline) {
                return None;
            }
            Tick { deadline_ns: deadline, lateness_ns: os::monotonic_ns() - deadline, overrun: false, missed: 0 }
        } else {
            if stop.is_stopped() {
                return None;
            }
            let missed = (called - deadline) / self.period_ns;
            let grid = deadline + missed * self.period_ns;
            Tick { deadline_ns: grid, lateness_ns: called - grid, overrun: true, missed }
        };
        self.next_ns = tick.deadline_ns.saturating_add(self.period_ns);
        Some(tick)
    }
}

/// Which thread makes the system call that wakes as-soon-as-available readers
/// asleep on a channel. Whichever it is, the frame is visible to readers before the
/// wake, and the writer makes no system call when no reader sleeps.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ReaderWake {
    /// A thread of the writer's process, its *ringer*, which follows the
    /// writer onto its CPU one real-time priority below it and so runs as
    /// soon as the writer sleeps. The writer pays a wake on its own CPU
    /// (about 2 µs on a 2-vCPU VM) instead of an interrupt to another CPU
    /// (14–60 µs there), and readers wake later (about 14 µs at p50 there).
    /// If the ringer has not rung the previous publish when the writer
    /// publishes again, the writer wakes the readers itself, so a reader is
    /// never more than one frame late. Started at the writer's first frame,
    /// from its thread, and only if that thread is real-time (SCHED_FIFO or
    /// SCHED_RR): a writer in the normal scheduler wakes its readers itself.
    #[default]
    Ringer,
    /// The writer's own thread, right after the publish: readers wake
    /// sooner than with the ringer, and the acquisition thread pays the
    /// interrupt.
    Writer,
    /// A thread of the writer's process, its *lookout*, which keeps off the
    /// writer's CPU, learns the writer's grid, and is spinning on another
    /// CPU when each frame is due (from a timer set as early as its own
    /// wake-ups are late, p97), for frames some reader sleeps for. The
    /// writer makes no system call (one compare-and-swap) and readers are
    /// woken by a CPU that is already awake, so they wake sooner than with
    /// either of the others. The cost is the lookout's spinning, CPU time on
    /// another CPU every period a reader sleeps. When the lookout is not
    /// watching (it or the frame was late), the writer hands the wake to its
    /// ringer, which it also has. Needs what the ringer needs, a periodic writer
    /// ([`WriterOptions::period`](crate::WriterOptions::period)) and a second CPU it may run on; otherwise
    /// the writer uses the ringer, or wakes its readers itself.
    ///
    /// Not the default: on the 2-vCPU development VM it spent about 70 µs
    /// of the other CPU per frame, and the paper's skin at 1 kHz (5 writers)
    /// took 31–46 % of a core more with it, for no gain to readers in the
    /// normal scheduler (`docs/bench/kilohertz.md`). Real-time readers of a
    /// writer with CPU to spare gain the most.
    Lookout,
}

/// Real-time settings for a writer or reader thread.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RtOptions {
    /// SCHED_FIFO priority (1..=99), or `None` to stay in the normal scheduler.
    pub fifo_priority: Option<u8>,
    /// Lock the whole process in RAM (mlockall), so that page faults cannot stall it.
    pub lock_memory: bool,
    /// CPUs to pin the thread to; empty for no pinning.
    pub cpus: Vec<usize>,
    /// Ask the kernel to keep every idle CPU able to start running within
    /// this many µs (a PM QoS request through `/dev/cpu_dma_latency`, held
    /// for the rest of the process's life; 0 keeps idle CPUs polling).
    ///
    /// A sleeping real-time thread is only as punctual as its CPU's way out
    /// of idle. In a virtual machine an idle vCPU halts, and the host may
    /// take milliseconds to run it again when its timer fires. On the 2-vCPU
    /// development VM, a replay thread at SCHED_FIFO published its frames
    /// with a p99 lateness of 2.4 ms without this, and 172 µs with it at 0,
    /// side by side in one run (`docs/bench/record/record.json`). The cost:
    /// idle CPUs spin instead of sleeping, which uses power (or the host's
    /// CPU time). The request is for every CPU, and it lasts as long as
    /// the process.
    pub cpu_wake_latency_us: Option<u32>,
    /// For a writer's thread: which thread wakes the readers asleep for its
    /// frames ([`crate::ReaderWake`]; a reader's thread ignores it). Like
    /// the others, it takes effect where a writer is created with these
    /// settings (a driver's layers, a service), not by [`RtOptions::apply`].
    pub reader_wake: ReaderWake,
}

impl RtOptions {
    /// Applies the settings. The priority and the CPUs apply to the calling
    /// thread. `mlockall` applies to the whole process, and the CPU wake
    /// latency to every CPU of the machine while the process lives. Settings
    /// the system refuses (no privilege, no such CPU) are skipped. Each
    /// refusal comes back as a message, so the caller can warn once and
    /// carry on.
    pub fn apply(&self) -> Vec<String> {
        let mut refused = Vec::new();
        if let Some(priority) = self.fifo_priority
            && let Err(e) = os::set_fifo_priority(priority)
        {
            refused.push(format!(
                    "SCHED_FIFO priority {priority} refused ({e}); running in the normal scheduler (run as root or grant CAP_SYS_NICE / an rtprio limit)"
                ));
        }
        if self.lock_memory
            && let Err(e) = os::lock_memory()
        {
            refused.push(format!("mlockall refused ({e}); memory may be paged (raise RLIMIT_MEMLOCK or run as root)"));
        }
        if let Some(latency_us) = self.cpu_wake_latency_us
            && let Err(e) = hold_cpu_wake_latency(latency_us)
        {
            refused.push(format!(
                "a CPU wake latency of {latency_us} µs refused: {CPU_LATENCY_FILE}: {e}; idle CPUs may be slow to \
                 wake (run as root, on a kernel with PM QoS)"
            ));
        }
        if !self.cpus.is_empty()
            && let Err(e) = os::pin_to_cpus(&self.cpus)
        {
            refused.push(format!("pinning to CPUs {:?} refused ({e}); the thread may run on any CPU", self.cpus));
        }
        refused
    }
}

/// The kernel's PM QoS interface for CPU wake-up latency.
const CPU_LATENCY_FILE: &str = "/dev/cpu_dma_latency";

/// The process's CPU wake latency request: the value and the open file that
/// holds it (the kernel drops a request when its file is closed).
static CPU_LATENCY_REQUEST: Mutex<Option<(u32, std::fs::File)>> = Mutex::new(None);

/// Holds a request that idle CPUs wake within `latency_us` µs, for the rest
/// of the process's life. A request looser than one already held changes nothing.
fn hold_cpu_wake_latency(latency_us: u32) -> std::io::Result<()> {
    use std::io::Write;
    let mut held = crate::lock(&CPU_LATENCY_REQUEST);
    if held.as_ref().is_some_and(|(value, _)| *value <= latency_us) {
        return Ok(());
    }
    let mut file = std::fs::OpenOptions::new().write(true).open(CPU_LATENCY_FILE)?;
    // The kernel takes a binary s32 (or a hex string).
    let value = i32::try_from(latency_us).unwrap_or(i32::MAX);
    file.write_all(&value.to_ne_bytes())?;
    // The request just written is in force; replacing the older one closes it.
    *held = Some((latency_us, file));
    Ok(())
}

/// The CPU wake latency this process holds a request for, µs, if any.
pub fn held_cpu_wake_latency_us() -> Option<u32> {
    crate::lock(&CPU_LATENCY_REQUEST).as_ref().map(|(value, _)| *value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticker_counts_an_overrun_and_stays_on_its_grid() {
        let start = os::monotonic_ns();
        let period = Duration::from_millis(2);
        let mut ticker = Ticker::starting_at(period, start);
        let stop = Stop::new();
        let first = ticker.wait(&stop).unwrap();
        assert_eq!(first.deadline_ns, start);
        // Overrun: work that takes more than two periods.
        std::thread::sleep(Duration::from_millis(5));
        let late = ticker.wait(&stop).unwrap();
        assert!(late.overrun);
        assert!(late.missed >= 1, "{late:?}");
        assert_eq!((late.deadline_ns - start) % 2_000_000, 0, "left the grid: {late:?}");
        let next = ticker.wait(&stop).unwrap();
        assert_eq!(next.deadline_ns, late.deadline_ns + 2_000_000);
    }

    #[test]
    fn a_ticker_on_a_grid_starts_at_its_next_point_not_in_the_past() {
        let period = Duration::from_millis(10);
        let before = os::monotonic_ns();
        // An origin 3.5 periods ago: the first deadline is the grid's next point.
        let past = Ticker::on_grid(period, before - 35_000_000);
        let after = os::monotonic_ns();
        assert!(past.next_ns >= before, "a deadline in the past would count as missed periods");
        assert_eq!((past.next_ns - (before - 35_000_000)) % 10_000_000, 0, "left the grid");
        assert!(past.next_ns <= after + 10_000_000, "the first point not passed, not a later one");
        // An origin ahead is kept as it is.
        let ahead = Ticker::on_grid(period, after + 5_000_000_000);
        assert_eq!(ahead.next_ns, after + 5_000_000_000);
        // An origin at the clock's start with a period near the clock's range does not overflow.
        let far = Ticker::on_grid(Duration::from_secs(u64::MAX / 2_000_000_000), 0);
        assert!(far.next_ns > 0);
    }

    #[test]
    #[cfg_attr(miri, ignore = "Miri's isolation opens no files; the request is a write to a device file")]
    fn a_cpu_wake_latency_request_is_held_and_only_tightened() {
        let current = || -> Option<i32> {
            let bytes = std::fs::read(CPU_LATENCY_FILE).ok()?;
            Some(i32::from_ne_bytes(bytes.get(..4)?.try_into().ok()?))
        };
        if std::fs::OpenOptions::new().write(true).open(CPU_LATENCY_FILE).is_err() {
            println!("SKIPPED: {CPU_LATENCY_FILE} is not writable here (needs root and PM QoS)");
            assert!(!RtOptions { cpu_wake_latency_us: Some(7), ..RtOptions::default() }.apply().is_empty());
            return;
        }
        let refused = RtOptions { cpu_wake_latency_us: Some(7), ..RtOptions::default() }.apply();
        assert!(refused.is_empty(), "{refused:?}");
        assert_eq!(held_cpu_wake_latency_us(), Some(7));
        assert!(current().is_some_and(|us| us <= 7), "the kernel's latency limit: {:?}", current());
        // A looser request keeps the tighter one; a tighter one replaces it.
        assert!(RtOptions { cpu_wake_latency_us: Some(500), ..RtOptions::default() }.apply().is_empty());
        assert_eq!(held_cpu_wake_latency_us(), Some(7));
        assert!(RtOptions { cpu_wake_latency_us: Some(3), ..RtOptions::default() }.apply().is_empty());
        assert_eq!(held_cpu_wake_latency_us(), Some(3));
        assert!(current().is_some_and(|us| us <= 3), "the kernel's latency limit: {:?}", current());
    }

    #[test]
    fn stop_interrupts_a_long_sleep() {
        let stop = Stop::new();
        let mut ticker = Ticker::starting_at(Duration::from_secs(3600), os::monotonic_ns() + 3_600_000_000_000);
        let stopper = stop.clone();
        let started = std::time::Instant::now();
        let sleeper = std::thread::spawn(move || ticker.wait(&stop));
        std::thread::sleep(Duration::from_millis(20));
        stopper.stop();
        assert_eq!(sleeper.join().unwrap(), None);
        assert!(started.elapsed() < Duration::from_secs(60));
    }
}
