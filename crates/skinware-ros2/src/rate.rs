//! Per-topic rate limits: whether a message sent `hz` times a second is due.
//! The recorder's ROS view and the DDS bridge share it.

use std::time::{Duration, Instant};

/// Whether something done `hz` times a second is due, on a ticker at least as fast.
pub struct Every {
    period: Option<Duration>,
    next: Instant,
}

impl Every {
    /// Due at once, then every `1/hz` s; never for `hz` 0.
    pub fn new(hz: f64) -> Every {
        Every::phased(hz, 0.0)
    }

    /// As [`new`](Self::new), first due `phase` (0..1) of a period from
    /// now: several large messages at one rate, phased apart, are sent
    /// spread over the period rather than in one burst that a receiver's
    /// socket buffer cannot hold.
    pub fn phased(hz: f64, phase: f64) -> Every {
        // Also a NaN, an infinite rate or one whose period no Duration
        // holds (1e-30 Hz): never due, rather than a panic.
        let period = (hz > 0.0).then(|| Duration::try_from_secs_f64(1.0 / hz).ok()).flatten().filter(|p| !p.is_zero());
        let offset = period.map_or(Duration::ZERO, |p| p.mul_f64(phase.clamp(0.0, 1.0)));
        Every { period, next: Instant::now() + offset }
    }

    /// The same rate, first due `phase` (0..1) of a period from now.
    pub fn rephased(&self, phase: f64) -> Every {
        let offset = self.period.map_or(Duration::ZERO, |p| p.mul_f64(phase.clamp(0.0, 1.0)));
        Every { period: self.period, next: Instant::now() + offset }
    }

    /// Its period (`None`: never due).
    pub fn period(&self) -> Option<Duration> {
        self.period
    }

    /// Whether it is due now (and, if so, the next time is set).
    pub fn now(&mut self) -> bool {
        self.at(Instant::now())
    }

    /// Whether it is due at `now`.
    pub fn at(&mut self, now: Instant) -> bool {
        let Some(period) = self.period else { return false };
        // The ticker's wake-ups jitter: a due time a little ahead counts
        // (a few ms: more would make a slow rate on a fast ticker early).
        if now + (period / 4).min(Duration::from_millis(5)) < self.next {
            return false;
        }
        // After a late wake-up, no burst to catch up, and no new phase
        // either: the periods it missed are skipped, so that topics phased
        // apart stay apart after a stall.
        let mut next = self.next + period;
        if next <= now {
            let missed = (now - next).as_nanos() / period.as_nanos() + 1;
            let skip = u32::try_from(missed).ok().and_then(|missed| period.checked_mul(missed));
            next = skip.map_or(now + period, |skip| next + skip);
        }
        self.next = next;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ticks at `tick_hz` for a second, with every tick `late` behind time:
    /// how often `Every::new(hz)` was due.
    fn due_in_a_second(hz: f64, tick_hz: f64, late: Duration) -> usize {
        let start = Instant::now();
        let mut every = Every { period: Some(Duration::from_secs_f64(1.0 / hz)), next: start };
        let ticks = tick_hz as u32;
        (0..ticks).filter(|&k| every.at(start + Duration::from_secs_f64(f64::from(k) / tick_hz) + late)).count()
    }

    #[test]
    fn due_as_often_as_asked_on_a_faster_or_equal_ticker() {
        assert_eq!(due_in_a_second(10.0, 10.0, Duration::ZERO), 10);
        assert_eq!(due_in_a_second(4.0, 10.0, Duration::ZERO), 4);
        assert_eq!(due_in_a_second(10.0, 10.0, Duration::from_millis(3)), 10);
        assert_eq!(due_in_a_second(1.0, 60.0, Duration::ZERO), 1);
    }

    #[test]
    fn a_stall_keeps_each_topic_on_its_phase() {
        let start = Instant::now();
        let period = Duration::from_millis(100);
        let mut first = Every { period: Some(period), next: start };
        let mut second = Every { period: Some(period), next: start + Duration::from_millis(50) };
        assert!(first.at(start));
        // Both overdue after a 230 ms stall: each fires once, then keeps its phase.
        let late = start + Duration::from_millis(230);
        assert!(first.at(late) && second.at(late));
        assert_eq!(first.next, start + Duration::from_millis(300));
        assert_eq!(second.next, start + Duration::from_millis(250));
        assert!(!Every::new(1e-30).now() && !Every::new(f64::NAN).now() && !Every::new(f64::INFINITY).now());
    }

    #[test]
    fn early_wake_ups_are_not_skipped_and_never_due_at_zero() {
        let start = Instant::now();
        let mut every = Every { period: Some(Duration::from_millis(100)), next: start };
        assert!(every.at(start));
        // The next tick 5 ms early (the ticker's jitter) still counts.
        assert!(every.at(start + Duration::from_millis(95)));
        assert!(!Every::new(0.0).now());
    }
}
