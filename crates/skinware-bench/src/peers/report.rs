//! The report of `skin bench peers`: `peers.json` and the printed table.

use std::path::Path;

use anyhow::Result;
use serde::{Deserialize, Serialize};

use super::cyclictest::Cyclictest;
use super::futex_wake::WakeLatency;
use super::setup::SENSORS;
use crate::measure::Percentiles;

/// p50, p99 and max, ns.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct Summary {
    /// Median.
    pub p50: u64,
    /// 99th percentile.
    pub p99: u64,
    /// Worst case.
    pub max: u64,
}

impl From<Percentiles> for Summary {
    fn from(p: Percentiles) -> Summary {
        Summary { p50: p.p50, p99: p.p99, max: p.max }
    }
}

/// One (system, readers) result.
#[derive(Debug, Serialize)]
pub struct PeerRecord {
    /// One of [`SYSTEMS`](crate::peers::SYSTEMS).
    pub system: String,
    /// Reader processes.
    pub readers: usize,
    /// The writer's cost to publish one frame (copy included), ns.
    pub publish_ns: Summary,
    /// From publish to a waiting reader holding its copy, ns.
    pub latency_ns: Summary,
    /// `publish_ns.p50 / memcpy_ns`.
    pub publish_vs_memcpy: f64,
    /// `latency_ns.p50 / memcpy_ns`.
    pub latency_vs_memcpy: f64,
    /// A woken reader's time to copy the frame out (for skinware: the
    /// lock-free read; for rwlock: read-lock, copy, unlock), ns.
    pub copy_ns: Summary,
    /// `copy_ns.p50 / memcpy_ns`.
    pub copy_vs_memcpy: f64,
    /// `copy_ns.p50 / memcpy_woken_ns`: against a plain `memcpy` in the same
    /// state as a waiting reader.
    pub copy_vs_woken_memcpy: f64,
    /// Frames the readers received, all together.
    pub frames_received: usize,
}

/// The whole `peers.json`.
#[derive(Debug, Serialize)]
pub struct PeersReport {
    /// Median time of a plain `memcpy` of one frame, ns (source hot in this
    /// core's cache: the lower bound of any copy).
    pub memcpy_ns: u64,
    /// Median time of a `memcpy` of one frame that another core has just
    /// written, ns: the cache state a reader of a fresh frame faces.
    pub memcpy_cross_core_ns: u64,
    /// Median time of a `memcpy` of one frame that another CPU has just
    /// written, by a real-time thread woken for it after idling 5 ms, ns: the
    /// state of a waiting reader, without the library.
    pub memcpy_woken_ns: u64,
    /// A bare futex wake from one CPU to a thread sleeping on the other, µs:
    /// the floor under every waiting reader's latency.
    pub futex_wake_us: WakeLatency,
    /// `cyclictest` on this machine in the same run.
    pub cyclictest_us: Cyclictest,
    /// Frame size, bytes.
    pub frame_bytes: usize,
    /// Frames per second.
    pub rate_hz: f64,
    /// One record per (system, readers).
    pub records: Vec<PeerRecord>,
    /// The writer's publish cost while readers copy frames back to back (on
    /// request, without waiting): what readers cost each writer.
    pub busy_readers: Vec<BusyRecord>,
}

/// One (system, readers) result with readers reading back to back.
#[derive(Debug, Serialize)]
pub struct BusyRecord {
    /// `skinware` or `rwlock`.
    pub system: String,
    /// Reader processes.
    pub readers: usize,
    /// The writer's cost to publish one frame, ns.
    pub publish_ns: Summary,
    /// Frames the writer published (of the nominal rate x duration).
    pub frames_published: usize,
    /// Frames the readers copied, all together.
    pub reads: usize,
}

fn print(report: &PeersReport, seconds: f64) {
    println!(
        "skin bench peers: {} B frames ({} sensors) at {} Hz to waiting reader processes, {seconds} s each",
        report.frame_bytes, SENSORS, report.rate_hz
    );
    println!(
        "memcpy of one frame (median): {} ns hot, {} ns just written by another core, {} ns by a reader woken for it",
        report.memcpy_ns, report.memcpy_cross_core_ns, report.memcpy_woken_ns
    );
    println!(
        "futex wake across CPUs: p50 {:.0} us, p99 {:.0} us, max {:.0} us",
        report.futex_wake_us.p50, report.futex_wake_us.p99, report.futex_wake_us.max
    );
    match &report.cyclictest_us.skipped {
        Some(why) => println!("cyclictest: skipped ({why})"),
        None => println!(
            "cyclictest wake-up latency: p50 {:.0} us, p99 {:.0} us, max {:.0} us",
            report.cyclictest_us.p50, report.cyclictest_us.p99, report.cyclictest_us.max
        ),
    }
    println!(
        "\nx cpy: against the hot memcpy; x woken: against the memcpy by a woken reader\n{:<13} {:>7} | {:>9} {:>9} {:>9} {:>6} | {:>9} {:>9} {:>9} {:>6} | {:>9} {:>6} {:>7}",
        "system",
        "readers",
        "pub p50",
        "pub p99",
        "pub max",
        "x cpy",
        "lat p50",
        "lat p99",
        "lat max",
        "x cpy",
        "copy p50",
        "x cpy",
        "x woken"
    );
    let us = |ns: u64| ns as f64 / 1e3;
    for r in &report.records {
        println!(
            "{:<13} {:>7} | {:>7.1}us {:>7.1}us {:>7.1}us {:>6.1} | {:>7.1}us {:>7.1}us {:>7.1}us {:>6.1} | {:>7.1}us {:>6.1} {:>7.2}",
            r.system,
            r.readers,
            us(r.publish_ns.p50),
            us(r.publish_ns.p99),
            us(r.publish_ns.max),
            r.publish_vs_memcpy,
            us(r.latency_ns.p50),
            us(r.latency_ns.p99),
            us(r.latency_ns.max),
            r.latency_vs_memcpy,
            us(r.copy_ns.p50),
            r.copy_vs_memcpy,
            r.copy_vs_woken_memcpy
        );
    }
}

/// Prints the report, writes it to `peers.json` in `out`, then prints the
/// busy readers' table.
pub(super) fn print_and_write(report: &PeersReport, seconds: f64, out: &Path) -> Result<()> {
    print(report, seconds);
    let json = out.join("peers.json");
    std::fs::write(&json, serde_json::to_vec_pretty(report)?)?;
    println!("\nwith readers copying back to back (on request, never waiting):");
    println!(
        "{:<9} {:>7} | {:>9} {:>9} {:>9} | {:>9} {:>10}",
        "system", "readers", "pub p50", "pub p99", "pub max", "published", "reads"
    );
    for r in &report.busy_readers {
        println!(
            "{:<9} {:>7} | {:>7.1}us {:>7.1}us {:>7.1}us | {:>9} {:>10}",
            r.system,
            r.readers,
            r.publish_ns.p50 as f64 / 1e3,
            r.publish_ns.p99 as f64 / 1e3,
            r.publish_ns.max as f64 / 1e3,
            r.frames_published,
            r.reads
        );
    }
    println!("\nwrote {}", json.display());
    Ok(())
}
