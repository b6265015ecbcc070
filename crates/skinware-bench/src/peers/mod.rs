//! `skin bench peers`: the same 30,848-sensor frames delivered to 1, 4 and 15
//! waiting reader processes through skinware, the lock-based baseline and
//! (with the `iceoryx2` feature) iceoryx2, with the machine's own floors
//! measured in the same run: a plain `memcpy` of one frame (hot, just written
//! by another CPU, and by a reader woken for it), a bare cross-CPU futex wake,
//! and `cyclictest`'s timer wake-up latency.

mod configuration;
mod cyclictest;
mod futex_wake;
#[cfg(feature = "iceoryx2")]
mod iceoryx2_reader;
mod memcpy;
mod reader;
mod report;
mod rwlock_reader;
mod setup;
mod skinware_reader;

use anyhow::{Context, Result, bail};

pub(crate) use self::configuration::{collect_readers, spawn_readers};
use self::configuration::{run_mode, run_one};
use self::cyclictest::run_cyclictest;
use self::futex_wake::measure_futex_wake;
use self::memcpy::{measure_memcpy, measure_memcpy_cross_core, measure_memcpy_woken};
use self::setup::{FRAME_BYTES, woken_rounds};
use crate::run_options::RunOptions;

pub use self::cyclictest::Cyclictest;
pub use self::futex_wake::WakeLatency;
pub use self::reader::run_reader;
pub use self::report::{BusyRecord, PeerRecord, PeersReport, Summary};
pub use self::setup::{ANTICIPATE, PeerReaderArgs, PeerReaderSamples, RATE_HZ, SENSORS, SYSTEMS};

/// Runs the comparison, prints it and writes `peers.json`.
pub fn run(options: &RunOptions) -> Result<PeersReport> {
    let seconds = options.seconds_or(1.0, 10.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let memcpy_ns = measure_memcpy();
    let memcpy_cross_core_ns = measure_memcpy_cross_core();
    let memcpy_woken_ns = measure_memcpy_woken(woken_rounds(options.quick));
    let futex_wake_us = measure_futex_wake(woken_rounds(options.quick));
    let cyclictest_us = run_cyclictest(if options.quick { 2_000 } else { 20_000 });
    let mut records = Vec::new();
    for system in SYSTEMS {
        for readers in [1, 4, 15] {
            let (publish, latency, copy, frames) = run_one(options, system, readers, seconds)?;
            records.push(PeerRecord {
                system: system.to_string(),
                readers,
                publish_vs_memcpy: publish.p50 as f64 / memcpy_ns.max(1) as f64,
                latency_vs_memcpy: latency.p50 as f64 / memcpy_ns.max(1) as f64,
                copy_vs_memcpy: copy.p50 as f64 / memcpy_ns.max(1) as f64,
                copy_vs_woken_memcpy: copy.p50 as f64 / memcpy_woken_ns.max(1) as f64,
                publish_ns: publish.into(),
                latency_ns: latency.into(),
                copy_ns: copy.into(),
                frames_received: frames,
            });
        }
    }
    let mut busy_readers = Vec::new();
    for system in ["skinware", "rwlock"] {
        for readers in [0, 1, 4, 15] {
            let (publish, _, _, reads) = run_mode(options, system, readers, seconds, "busy")?;
            busy_readers.push(BusyRecord {
                system: system.into(),
                readers,
                frames_published: publish.samples,
                publish_ns: publish.into(),
                reads,
            });
        }
    }
    // The readers' sample files are gone by now; leave no empty directory behind.
    let _ = std::fs::remove_dir(options.out.join("peers-work"));
    let report = PeersReport {
        memcpy_ns,
        memcpy_cross_core_ns,
        memcpy_woken_ns,
        futex_wake_us,
        cyclictest_us,
        frame_bytes: FRAME_BYTES,
        rate_hz: RATE_HZ,
        records,
        busy_readers,
    };
    report::print_and_write(&report, seconds, &options.out)?;
    Ok(report)
}
