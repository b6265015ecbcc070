//! `skin bench wake`: what readers asleep on the futex cost a 1 kHz writer of
//! the whole skin's frame, with the wake made by the writer's thread, handed
//! to its ringer, or left to its lookout ([`skinware::ReaderWake`]).
//!
//! One writer thread (SCHED_FIFO 80) publishes the 30,848-sensor frame at
//! 1 kHz. It runs with 0 or 15 reader processes (SCHED_FIFO 70) that wait
//! for every frame on the futex, in both wake modes, interleaved in rounds so
//! that every configuration sees the same machine. For each configuration it
//! measures what the acquisition's timing is made of: the time from the
//! period's start to the frame being visible to readers, the start-time
//! jitter of the period (the writer's wake-up after its deadline), missed
//! periods, and the whole publish call; and, for the readers, the latency
//! from the publish to holding a copy. It also measures where the CPU goes:
//! the writer thread's and the whole writer process's CPU time per frame (the
//! difference is the ringer's).

use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{ReaderWake, RtOptions, Stop, Ticker, Writer, WriterOptions};

use crate::measure::Percentiles;
use crate::peers::{SENSORS, Summary, collect_readers, spawn_readers};
use crate::run_options::RunOptions;

/// Frames per second.
pub const RATE_HZ: f64 = 1_000.0;
/// Reader processes in the loaded configurations.
pub const READERS: usize = 15;

/// One configuration's figures, pooled over its rounds.
#[derive(Debug, Serialize)]
pub struct WakeRecord {
    /// `writer`, `ringer` or `lookout`.
    pub wake: String,
    /// Reader processes asleep for every frame.
    pub readers: usize,
    /// Frames published.
    pub frames: usize,
    /// From the period's start (its deadline) to the frame visible to readers, ns.
    pub visible_ns: Summary,
    /// From the period's deadline to the writer running (start-time jitter), ns.
    pub start_late_ns: Summary,
    /// Periods missed altogether.
    pub missed_periods: u64,
    /// The whole `begin` + fill + `publish` call, wake included, ns.
    pub publish_ns: Summary,
    /// From the publish to a reader holding its copy, ns.
    pub reader_latency_ns: Summary,
    /// Frames the readers received, all together.
    pub frames_received: usize,
    /// CPU time of the writer's thread per frame, ns.
    pub writer_thread_cpu_ns: f64,
    /// CPU time of the writer's process per frame (writer, ringer or lookout, and this
    /// bench's idle main thread), ns.
    pub writer_process_cpu_ns: f64,
    /// Publishes whose sleepers the ringer woke.
    pub woken_by_ringer: u64,
    /// Publishes whose sleepers the lookout woke.
    pub woken_by_lookout: u64,
    /// Publishes whose sleepers the writer woke itself.
    pub woken_by_writer: u64,
}

/// The whole `wake.json`.
#[derive(Debug, Serialize)]
pub struct WakeReport {
    /// Frame size, bytes.
    pub frame_bytes: usize,
    /// Frames per second.
    pub rate_hz: f64,
    /// Rounds each configuration ran in.
    pub rounds: u32,
    /// Seconds per configuration and round.
    pub seconds: f64,
    /// One per (wake, readers).
    pub records: Vec<WakeRecord>,
}

#[derive(Default)]
struct Pool {
    visible: Vec<u64>,
    start_late: Vec<u64>,
    missed: u64,
    publish: Vec<u64>,
    reader_latency: Vec<u64>,
    frames_received: usize,
    thread_cpu_ns: u64,
    process_cpu_ns: u64,
    by_ringer: u64,
    by_lookout: u64,
    by_writer: u64,
}

const CONFIGURATIONS: [(ReaderWake, usize); 6] = [
    (ReaderWake::Writer, 0),
    (ReaderWake::Ringer, 0),
    (ReaderWake::Lookout, 0),
    (ReaderWake::Writer, READERS),
    (ReaderWake::Ringer, READERS),
    (ReaderWake::Lookout, READERS),
];

/// Runs the comparison, prints it and writes `wake.json`.
pub fn run(options: &RunOptions) -> Result<WakeReport> {
    let seconds = options.seconds_or(1.0, 1.5);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    // Many short rounds, interleaved: this VM's stalls of several
    // milliseconds come in bursts, which then fall on every configuration.
    let rounds = if options.quick { 1 } else { 10 };
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let mut pools: Vec<Pool> = CONFIGURATIONS.iter().map(|_| Pool::default()).collect();
    for _ in 0..rounds {
        for (pool, &(wake, readers)) in pools.iter_mut().zip(CONFIGURATIONS.iter()) {
            run_configuration(options, wake, readers, seconds, pool)?;
        }
    }
    let _ = std::fs::remove_dir(options.out.join("peers-work"));
    let records = pools
        .into_iter()
        .zip(CONFIGURATIONS.iter())
        .map(|(mut pool, &(wake, readers))| {
            let frames = pool.publish.len();
            let per_frame = |ns: u64| ns as f64 / frames.max(1) as f64;
            WakeRecord {
                wake: wake_name(wake).into(),
                readers,
                frames,
                visible_ns: Percentiles::of(&mut pool.visible).into(),
                start_late_ns: Percentiles::of(&mut pool.start_late).into(),
                missed_periods: pool.missed,
                publish_ns: Percentiles::of(&mut pool.publish).into(),
                reader_latency_ns: Percentiles::of(&mut pool.reader_latency).into(),
                frames_received: pool.frames_received,
                writer_thread_cpu_ns: per_frame(pool.thread_cpu_ns),
                writer_process_cpu_ns: per_frame(pool.process_cpu_ns),
                woken_by_ringer: pool.by_ringer,
                woken_by_lookout: pool.by_lookout,
                woken_by_writer: pool.by_writer,
            }
        })
        .collect();
    let report = WakeReport { frame_bytes: SENSORS * 2, rate_hz: RATE_HZ, rounds, seconds, records };
    print(&report);
    let path = options.out.join("wake.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(report)
}

fn wake_name(wake: ReaderWake) -> &'static str {
    match wake {
        ReaderWake::Writer => "writer",
        ReaderWake::Ringer => "ringer",
        ReaderWake::Lookout => "lookout",
    }
}

/// One configuration for `seconds`, its samples added to `pool`.
fn run_configuration(
    options: &RunOptions,
    wake: ReaderWake,
    readers: usize,
    seconds: f64,
    pool: &mut Pool,
) -> Result<()> {
    let name = format!("wake{}{}{readers}", std::process::id(), wake_name(wake));
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    let frame: Vec<u16> = (0..SENSORS).map(|i| (i % 4096) as u16).collect();
    let work = options.out.join("peers-work");
    std::fs::create_dir_all(&work)?;
    let writer_options = WriterOptions { period: Some(period), reader_wake: wake, ..WriterOptions::default() };
    let writer = Writer::create(&name, "frame", SENSORS * 2, b"wake", &writer_options)?;
    let children = spawn_readers(&options.exe, &work, "skinware", &name, "wait", readers, seconds)?;
    // Every reader attached and asleep before the first measured frame.
    std::thread::sleep(Duration::from_millis(300));
    let stop = Stop::new();
    let measured = std::thread::scope(|scope| {
        let (stop, frame) = (&stop, &frame);
        let publisher = scope.spawn(move || publish_frames(writer, period, stop, frame));
        std::thread::sleep(Duration::from_secs_f64(seconds));
        stop.stop();
        publisher.join().map_err(|_| anyhow::anyhow!("the writer thread panicked"))?
    })?;
    let (latency, _copy, received) = collect_readers(children, "skinware", "wait")?;
    pool.visible.extend(measured.visible);
    pool.start_late.extend(measured.start_late);
    pool.missed += measured.missed;
    pool.publish.extend(measured.publish);
    pool.reader_latency.extend(latency);
    pool.frames_received += received;
    pool.thread_cpu_ns += measured.thread_cpu_ns;
    pool.process_cpu_ns += measured.process_cpu_ns;
    pool.by_ringer += measured.by_ringer;
    pool.by_lookout += measured.by_lookout;
    pool.by_writer += measured.by_writer;
    Ok(())
}

struct Measured {
    visible: Vec<u64>,
    start_late: Vec<u64>,
    missed: u64,
    publish: Vec<u64>,
    thread_cpu_ns: u64,
    process_cpu_ns: u64,
    by_ringer: u64,
    by_lookout: u64,
    by_writer: u64,
}

fn cpu_ns(clock: rustix::time::ClockId) -> u64 {
    let now = rustix::time::clock_gettime(clock);
    now.tv_sec as u64 * 1_000_000_000 + now.tv_nsec as u64
}

/// The writer's thread: real-time, one frame per period until stopped. The
/// ringer starts at its first frame, from this thread, as in a driver.
fn publish_frames(mut writer: Writer, period: Duration, stop: &Stop, frame: &[u16]) -> Result<Measured> {
    use rustix::time::ClockId;
    let _ = RtOptions { fifo_priority: Some(80), ..RtOptions::default() }.apply();
    let capacity = (RATE_HZ * 120.0) as usize;
    let mut measured = Measured {
        visible: Vec::with_capacity(capacity),
        start_late: Vec::with_capacity(capacity),
        missed: 0,
        publish: Vec::with_capacity(capacity),
        thread_cpu_ns: 0,
        process_cpu_ns: 0,
        by_ringer: 0,
        by_lookout: 0,
        by_writer: 0,
    };
    // One unmeasured frame: the ringer's thread starts here.
    let mut first = writer.begin();
    first.write_responses(0, frame)?;
    first.publish();
    let (thread_cpu, process_cpu) = (cpu_ns(ClockId::ThreadCPUTime), cpu_ns(ClockId::ProcessCPUTime));
    let counts = writer.wake_counts();
    let mut ticker = Ticker::new(period);
    while let Some(tick) = ticker.wait(stop) {
        let started = skinware::os::monotonic_ns();
        let mut guard = writer.begin();
        guard.write_responses(0, frame)?;
        guard.publish();
        measured.publish.push(skinware::os::monotonic_ns() - started);
        measured.visible.push(writer.last_published_ns().saturating_sub(tick.deadline_ns));
        measured.start_late.push(tick.lateness_ns);
        measured.missed += tick.missed;
    }
    measured.thread_cpu_ns = cpu_ns(ClockId::ThreadCPUTime) - thread_cpu;
    measured.process_cpu_ns = cpu_ns(ClockId::ProcessCPUTime) - process_cpu;
    let after = writer.wake_counts();
    measured.by_ringer = after.by_ringer - counts.by_ringer;
    measured.by_lookout = after.by_lookout - counts.by_lookout;
    measured.by_writer = after.by_writer - counts.by_writer;
    Ok(measured)
}

fn us(ns: u64) -> String {
    format!("{:.1}", ns as f64 / 1e3)
}

fn print(report: &WakeReport) {
    println!(
        "One writer of {} B frames at {} Hz (SCHED_FIFO 80); readers asleep on the futex (SCHED_FIFO 70); {} round(s) of {} s per configuration. Times in µs: p50 / p99 / max.",
        report.frame_bytes, report.rate_hz, report.rounds, report.seconds
    );
    println!(
        "| wake | readers | period start → visible | start jitter | missed | publish call | reader latency | writer thread CPU/frame | process CPU/frame | woken by lookout / ringer / writer |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|");
    let triple = |s: &Summary| format!("{} / {} / {}", us(s.p50), us(s.p99), us(s.max));
    for record in &report.records {
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {:.1} | {:.1} | {} / {} / {} |",
            record.wake,
            record.readers,
            triple(&record.visible_ns),
            triple(&record.start_late_ns),
            record.missed_periods,
            triple(&record.publish_ns),
            if record.readers == 0 { "–".to_string() } else { triple(&record.reader_latency_ns) },
            record.writer_thread_cpu_ns / 1e3,
            record.writer_process_cpu_ns / 1e3,
            record.woken_by_lookout,
            record.woken_by_ringer,
            record.woken_by_writer,
        );
    }
    let find = |wake: &str, readers: usize| report.records.iter().find(|r| r.wake == wake && r.readers == readers);
    for wake in ["writer", "ringer", "lookout"] {
        if let (Some(idle), Some(loaded)) = (find(wake, 0), find(wake, READERS)) {
            let ratio = |a: u64, b: u64| a as f64 / b.max(1) as f64;
            println!(
                "{wake} wake, {READERS} readers against none (p99): visible {:.2}x, start jitter {:.2}x, publish call {:.2}x; missed {} against {}",
                ratio(loaded.visible_ns.p99, idle.visible_ns.p99),
                ratio(loaded.start_late_ns.p99, idle.start_late_ns.p99),
                ratio(loaded.publish_ns.p99, idle.publish_ns.p99),
                loaded.missed_periods,
                idle.missed_periods
            );
        }
    }
    if let Some(own) = find("writer", READERS) {
        for wake in ["ringer", "lookout"] {
            if let Some(other) = find(wake, READERS) {
                println!(
                    "{wake} wake against the writer's own, reader latency p50 {:+.1} µs, p99 {:+.1} µs; process CPU per frame {:+.1} µs",
                    (other.reader_latency_ns.p50 as f64 - own.reader_latency_ns.p50 as f64) / 1e3,
                    (other.reader_latency_ns.p99 as f64 - own.reader_latency_ns.p99 as f64) / 1e3,
                    (other.writer_process_cpu_ns - own.writer_process_cpu_ns) / 1e3,
                );
            }
        }
    }
}
