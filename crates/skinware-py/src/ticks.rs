//! Time for the bindings: the clock frames are stamped with, and waits that
//! release the GIL and stay interruptible by Ctrl-C.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use pyo3::prelude::*;
use skinware::Stop;

/// Longest a wait runs without the GIL before it checks for a pending signal
/// (Ctrl-C): short enough that an interrupt feels immediate.
pub const SIGNAL_CHECK: Duration = Duration::from_millis(100);

/// CLOCK_MONOTONIC now, in ns: the clock of `Frame.acquired_ns` and
/// `Frame.published_ns`.
#[pyfunction]
pub fn monotonic_ns() -> u64 {
    skinware::os::monotonic_ns()
}

/// A timeout from Python: seconds (`None` for no limit), checked.
pub fn timeout(py: Python<'_>, seconds: Option<f64>) -> PyResult<Option<Duration>> {
    match seconds {
        None => Ok(None),
        Some(s) if s.is_finite() && s >= 0.0 => Ok(Some(Duration::from_secs_f64(s.min(1e9)))),
        Some(s) => Err(crate::errors::invalid(py, format!("timeout {s} s: give a number of seconds >= 0, or None"))),
    }
}

/// A rate from Python, in Hz, checked: the period it stands for.
pub fn period(py: Python<'_>, hz: f64, what: &str) -> PyResult<Duration> {
    match Duration::try_from_secs_f64(1.0 / hz) {
        Ok(period) if hz.is_finite() && hz <= 1e6 && period <= Duration::from_secs(86_400) => Ok(period),
        _ => Err(crate::errors::invalid(
            py,
            format!("{what} {hz} Hz: give a rate of at least one frame a day and at most 1 MHz"),
        )),
    }
}

/// An absolute-time schedule (deadlines at `start + k * period`, so lateness
/// never accumulates) whose waits release the GIL and check for signals.
/// Its state is one atomic, so that threads sharing an iterator never hold a
/// lock while they sleep without the GIL (a thread blocked on that lock while
/// holding the GIL would stop the sleeper from ever taking it back).
pub struct Schedule {
    period_ns: u64,
    next_ns: AtomicU64,
}

/// One deadline reached.
#[derive(Clone, Copy, Debug)]
pub struct Reached {
    /// The deadline, CLOCK_MONOTONIC ns.
    pub deadline_ns: u64,
    /// Whole periods skipped because the caller was late.
    pub missed: u64,
}

impl Schedule {
    /// A schedule whose first deadline is now.
    pub fn new(period: Duration) -> Schedule {
        let period_ns = (period.as_nanos().min(u128::from(u64::MAX)) as u64).max(1);
        Schedule { period_ns, next_ns: AtomicU64::new(monotonic_ns()) }
    }

    /// Sleeps until the next deadline (at once if it passed: the deadlines
    /// missed are skipped, not made up for). `Ok(None)` if `stop` was
    /// signalled; a Python exception if a signal handler raised one.
    pub fn wait(&self, py: Python<'_>, stop: &Stop) -> PyResult<Option<Reached>> {
        let deadline = self.next_ns.load(Ordering::Relaxed);
        loop {
            let now = monotonic_ns();
            if stop.is_stopped() {
                return Ok(None);
            }
            if now >= deadline {
                let missed = (now - deadline) / self.period_ns;
                let reached = deadline + missed * self.period_ns;
                self.next_ns.fetch_max(reached + self.period_ns, Ordering::Relaxed);
                return Ok(Some(Reached { deadline_ns: reached, missed }));
            }
            let slice_end = deadline.min(now.saturating_add(SIGNAL_CHECK.as_nanos() as u64));
            if !py.detach(|| stop.sleep_until(slice_end)) {
                return Ok(None);
            }
            py.check_signals()?;
        }
    }
}
