//! The futex-wake floor of `skin bench peers`: a bare wake from one CPU to
//! a real-time thread sleeping on the other.

use std::time::Duration;

use serde::Serialize;
use skinware::{Stop, Ticker};

use super::setup::RATE_HZ;
use crate::measure::Percentiles;

/// A wake-up latency, µs.
#[derive(Debug, Default, Serialize)]
pub struct WakeLatency {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Worst case.
    pub max: f64,
}

/// Wake-up latency of a bare futex: a real-time thread on one CPU stamps the
/// time and wakes a real-time thread sleeping on the other, every 5 ms. This is
/// the floor under any reader woken by a writer (skinware's doorbell, the
/// rwlock's condition variable, iceoryx2's event), where `cyclictest` measures
/// a timer waking its own CPU.
pub(super) fn measure_futex_wake(rounds: u32) -> WakeLatency {
    use rustix::thread::futex;
    use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
    let word = AtomicU32::new(0);
    let stamp = AtomicU64::new(0);
    let stop = Stop::new();
    let mut samples = std::thread::scope(|scope| {
        let reader = scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[1]);
            let _ = skinware::os::set_fifo_priority(70);
            let mut samples = Vec::with_capacity(rounds as usize);
            let mut last = 0;
            let timeout = rustix::time::Timespec { tv_sec: 1, tv_nsec: 0 };
            while last < rounds {
                let now = word.load(Ordering::Acquire);
                if now == last {
                    if let Err(rustix::io::Errno::TIMEDOUT) =
                        futex::wait(&word, futex::Flags::PRIVATE, last, Some(&timeout))
                    {
                        break;
                    }
                    continue;
                }
                samples.push(skinware::os::monotonic_ns().saturating_sub(stamp.load(Ordering::Acquire)));
                last = now;
            }
            samples
        });
        scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[0]);
            let _ = skinware::os::set_fifo_priority(80);
            let mut ticker = Ticker::new(Duration::from_secs_f64(1.0 / RATE_HZ));
            for round in 1..=rounds {
                if ticker.wait(&stop).is_none() {
                    break;
                }
                stamp.store(skinware::os::monotonic_ns(), Ordering::Release);
                word.store(round, Ordering::Release);
                let _ = futex::wake(&word, futex::Flags::PRIVATE, 1);
            }
        });
        let samples = reader.join().unwrap_or_default();
        stop.stop();
        samples
    });
    if samples.is_empty() {
        return WakeLatency::default();
    }
    let p = Percentiles::of(&mut samples);
    WakeLatency { p50: p.p50 as f64 / 1e3, p99: p.p99 as f64 / 1e3, max: p.max as f64 / 1e3 }
}
