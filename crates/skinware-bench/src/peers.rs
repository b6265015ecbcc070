//! `skin bench peers`: the same 30,848-sensor frames delivered to 1, 4 and 15
//! waiting reader processes through skinware, the lock-based baseline and
//! (with the `iceoryx2` feature) iceoryx2, with the machine's own floors
//! measured in the same run: a plain `memcpy` of one frame (hot, just written
//! by another CPU, and by a reader woken for it), a bare cross-CPU futex wake,
//! and `cyclictest`'s timer wake-up latency.

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use skinware::{Reader, RtOptions, Stop, Ticker, Writer, WriterOptions};

use crate::measure::Percentiles;
use crate::rwlock_peer::RwLockChannel;

/// Sensors of the whole skin.
pub const SENSORS: usize = 30_848;
const FRAME_BYTES: usize = SENSORS * 2;
/// The systems compared (iceoryx2 with the cargo feature `iceoryx2`).
/// `skinware-spin` is skinware with readers that anticipate each frame
/// ([`skinware::ReaderOptions::anticipate`]).
#[cfg(feature = "iceoryx2")]
pub const SYSTEMS: &[&str] = &["skinware", "skinware-spin", "rwlock", "iceoryx2"];
/// The systems compared (iceoryx2 with the cargo feature `iceoryx2`).
#[cfg(not(feature = "iceoryx2"))]
pub const SYSTEMS: &[&str] = &["skinware", "skinware-spin", "rwlock"];
/// How long before each frame is due an anticipating reader starts spinning.
pub const ANTICIPATE: Duration = Duration::from_micros(250);
/// Frames per second delivered.
pub const RATE_HZ: f64 = 200.0;

/// Options of `skin bench peers`.
#[derive(Clone, Debug)]
pub struct PeersOptions {
    /// CI-sized: 1 s per configuration.
    pub quick: bool,
    /// Where `peers.json` goes.
    pub out: PathBuf,
    /// Seconds per configuration.
    pub seconds: Option<f64>,
    /// This executable, re-run for the reader processes.
    pub exe: PathBuf,
}

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
    /// One of [`SYSTEMS`].
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

/// `cyclictest`'s wake-up latency, µs.
#[derive(Debug, Default, Serialize)]
pub struct Cyclictest {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Worst case.
    pub max: f64,
    /// Why it is missing, if it is.
    pub skipped: Option<String>,
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

/// Runs the comparison, prints it and writes `peers.json`.
pub fn run(options: &PeersOptions) -> Result<PeersReport> {
    let seconds = options.seconds.unwrap_or(if options.quick { 1.0 } else { 10.0 });
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
    print(&report, seconds);
    let json = options.out.join("peers.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&report)?)?;
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
    Ok(report)
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

/// Median time of copying one frame between two buffers.
fn measure_memcpy() -> u64 {
    let source = vec![0x5au8; FRAME_BYTES];
    let mut target = vec![0u8; FRAME_BYTES];
    let mut samples: Vec<u64> = (0..2000)
        .map(|_| {
            let started = skinware::os::monotonic_ns();
            target.copy_from_slice(std::hint::black_box(&source));
            std::hint::black_box(&mut target);
            skinware::os::monotonic_ns() - started
        })
        .collect();
    Percentiles::of(&mut samples).p50
}

/// Median time of a `memcpy` of one frame that a thread on another CPU has
/// just written (both threads pinned, taking turns; the lock is not timed).
fn measure_memcpy_cross_core() -> u64 {
    let source = std::sync::Mutex::new(vec![0u8; FRAME_BYTES]);
    let turn = std::sync::Barrier::new(2);
    let rounds = 500u32;
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[0]);
            for round in 0..rounds {
                source.lock().unwrap_or_else(|p| p.into_inner()).fill(round as u8);
                turn.wait();
                turn.wait();
            }
        });
        let reader = scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[1]);
            let mut target = vec![0u8; FRAME_BYTES];
            let mut samples = Vec::with_capacity(rounds as usize);
            for _ in 0..rounds {
                turn.wait();
                let frame = source.lock().unwrap_or_else(|p| p.into_inner());
                let started = skinware::os::monotonic_ns();
                target.copy_from_slice(std::hint::black_box(&frame));
                std::hint::black_box(&mut target);
                samples.push(skinware::os::monotonic_ns() - started);
                drop(frame);
                turn.wait();
            }
            Percentiles::of(&mut samples).p50
        });
        reader.join().unwrap_or(0)
    })
}

/// Frames of the same-run baselines that mimic a waiting reader: one every
/// 5 ms, as in the comparison itself, so the reader's CPU idles in between.
fn woken_rounds(quick: bool) -> u32 {
    if quick { 100 } else { 1_000 }
}

/// Median time of a plain `memcpy` of a frame that another CPU has just
/// written, by a real-time thread that slept until it was published: exactly
/// the state of a waiting reader (its CPU idle for 5 ms, the frame in the
/// writer's cache, its own buffer possibly evicted), with the library taken
/// out. The wake and the lock are not timed.
fn measure_memcpy_woken(rounds: u32) -> u64 {
    let shared = std::sync::Mutex::new((0u32, vec![0u8; FRAME_BYTES]));
    let published = std::sync::Condvar::new();
    let stop = Stop::new();
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[0]);
            let _ = skinware::os::set_fifo_priority(80);
            let mut ticker = Ticker::new(Duration::from_secs_f64(1.0 / RATE_HZ));
            for round in 1..=rounds {
                if ticker.wait(&stop).is_none() {
                    break;
                }
                let mut frame = shared.lock().unwrap_or_else(|p| p.into_inner());
                frame.1.fill(round as u8);
                frame.0 = round;
                drop(frame);
                published.notify_one();
            }
        });
        let reader = scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[1]);
            let _ = skinware::os::set_fifo_priority(70);
            let mut target = vec![0u8; FRAME_BYTES];
            let mut samples = Vec::with_capacity(rounds as usize);
            let mut last = 0;
            while last < rounds {
                let guard = shared.lock().unwrap_or_else(|p| p.into_inner());
                let (frame, timed_out) = published
                    .wait_timeout_while(guard, Duration::from_secs(1), |frame| frame.0 == last)
                    .unwrap_or_else(|p| p.into_inner());
                if timed_out.timed_out() {
                    break;
                }
                let started = skinware::os::monotonic_ns();
                target.copy_from_slice(std::hint::black_box(&frame.1));
                std::hint::black_box(&mut target);
                samples.push(skinware::os::monotonic_ns() - started);
                last = frame.0;
            }
            samples
        });
        let mut samples = reader.join().unwrap_or_default();
        stop.stop();
        if samples.is_empty() { 0 } else { Percentiles::of(&mut samples).p50 }
    })
}

/// Wake-up latency of a bare futex: a real-time thread on one CPU stamps the
/// time and wakes a real-time thread sleeping on the other, every 5 ms. This is
/// the floor under any reader woken by a writer (skinware's doorbell, the
/// rwlock's condition variable, iceoryx2's event), where `cyclictest` measures
/// a timer waking its own CPU.
fn measure_futex_wake(rounds: u32) -> WakeLatency {
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

/// Runs `cyclictest` (from rt-tests) for `loops` wake-ups at 1 kHz, SCHED_FIFO 80.
fn run_cyclictest(loops: u32) -> Cyclictest {
    let output = Command::new("cyclictest")
        .args(["-q", "-m", "-p", "80", "-i", "1000", "-t", "1", "-h", "2000"])
        .args(["-l", &loops.to_string()])
        .output();
    let output = match output {
        Ok(output) if output.status.success() => output,
        Ok(output) => {
            return Cyclictest {
                skipped: Some(format!("cyclictest failed: {}", String::from_utf8_lossy(&output.stderr).trim())),
                ..Cyclictest::default()
            };
        }
        Err(e) => {
            return Cyclictest {
                skipped: Some(format!("cyclictest not found ({e}); install rt-tests")),
                ..Cyclictest::default()
            };
        }
    };
    // The histogram: one "latency_us count" line per microsecond.
    let mut histogram: Vec<(u64, u64)> = Vec::new();
    for line in String::from_utf8_lossy(&output.stdout).lines() {
        if line.starts_with('#') {
            continue;
        }
        let mut fields = line.split_whitespace();
        if let (Some(Ok(us)), Some(Ok(count))) = (fields.next().map(str::parse), fields.next().map(str::parse)) {
            if count > 0 {
                histogram.push((us, count));
            }
        }
    }
    let total: u64 = histogram.iter().map(|&(_, c)| c).sum();
    if total == 0 {
        return Cyclictest { skipped: Some("cyclictest printed no histogram".into()), ..Cyclictest::default() };
    }
    let quantile = |q: f64| {
        let rank = (q * total as f64).ceil() as u64;
        let mut seen = 0;
        for &(us, count) in &histogram {
            seen += count;
            if seen >= rank {
                return us as f64;
            }
        }
        histogram.last().map_or(0.0, |&(us, _)| us as f64)
    };
    Cyclictest {
        p50: quantile(0.5),
        p99: quantile(0.99),
        max: histogram.last().map_or(0.0, |&(us, _)| us as f64),
        skipped: None,
    }
}

/// What a peer reader process measured.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct PeerReaderSamples {
    /// Publish-to-holding latencies, ns.
    pub latency_ns: Vec<u64>,
    /// Time to copy the frame out once woken, ns.
    pub copy_ns: Vec<u64>,
    /// Frames copied in the busy mode.
    pub reads: usize,
}

fn run_one(
    options: &PeersOptions,
    system: &str,
    readers: usize,
    seconds: f64,
) -> Result<(Percentiles, Percentiles, Percentiles, usize)> {
    run_mode(options, system, readers, seconds, "wait")
}

/// Runs one configuration; readers `wait` for each frame or read `busy`
/// back to back. Returns (publish, latency, copy, frames or reads received).
fn run_mode(
    options: &PeersOptions,
    system: &str,
    readers: usize,
    seconds: f64,
    mode: &str,
) -> Result<(Percentiles, Percentiles, Percentiles, usize)> {
    let name = format!("peers{}{system}{readers}{mode}", std::process::id());
    let dir = skinware::shm::segment_dir();
    let stop = Stop::new();
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    let frame: Vec<u16> = (0..SENSORS).map(|i| (i % 4096) as u16).collect();
    let work = options.out.join("peers-work");
    std::fs::create_dir_all(&work)?;

    // The writer thread creates the channel (iceoryx2's ports cannot move
    // between threads), says it is ready, waits for the readers to attach,
    // then publishes in real time until stopped. Running it in its own thread
    // also keeps SCHED_FIFO away from this thread, whose children inherit it.
    enum Side {
        Skinware(Box<Writer>),
        RwLock(RwLockChannel),
        #[cfg(feature = "iceoryx2")]
        Iceoryx2(Box<crate::iceoryx2_peer::IceoryxWriter>),
    }
    let bytes: Vec<u8> = frame.iter().flat_map(|value| value.to_ne_bytes()).collect();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<()>>();
    let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
    let mut children = Vec::new();
    let publish = std::thread::scope(|scope| -> Result<Vec<u64>> {
        let (ready_tx, go_rx) = (ready_tx, go_rx);
        let (stop, frame, bytes, name) = (&stop, &frame, &bytes, &name);
        let writer = scope.spawn(move || -> Result<Vec<u64>> {
            let created = (|| -> Result<Side> {
                Ok(match system {
                    "skinware" | "skinware-spin" => {
                        let options = WriterOptions { period: Some(period), ..WriterOptions::default() };
                        Side::Skinware(Box::new(Writer::create(name, "frame", FRAME_BYTES, b"peers", &options)?))
                    }
                    #[cfg(feature = "iceoryx2")]
                    "iceoryx2" => Side::Iceoryx2(Box::new(crate::iceoryx2_peer::IceoryxWriter::create(name, SENSORS)?)),
                    _ => Side::RwLock(RwLockChannel::create(
                        &dir.join(format!("skinware-bench-rwlock.{name}")),
                        FRAME_BYTES,
                    )?),
                })
            })();
            let mut side = match created {
                Ok(side) => {
                    let _ = ready_tx.send(Ok(()));
                    side
                }
                Err(error) => {
                    let _ = ready_tx.send(Err(error));
                    return Ok(Vec::new());
                }
            };
            if go_rx.recv().is_err() {
                return Ok(Vec::new());
            }
            let _ = RtOptions { fifo_priority: Some(80), ..RtOptions::default() }.apply();
            let mut publish = Vec::with_capacity((RATE_HZ * seconds) as usize + 16);
            let mut ticker = Ticker::new(period);
            while ticker.wait(stop).is_some() {
                let started = skinware::os::monotonic_ns();
                match &mut side {
                    Side::Skinware(writer) => {
                        let mut guard = writer.begin();
                        guard.write_responses(0, frame)?;
                        guard.publish();
                    }
                    Side::RwLock(channel) => {
                        channel.publish(bytes)?;
                    }
                    #[cfg(feature = "iceoryx2")]
                    Side::Iceoryx2(writer) => writer.publish(frame)?,
                }
                publish.push(skinware::os::monotonic_ns() - started);
            }
            Ok(publish)
        });
        ready_rx.recv().map_err(|_| anyhow::anyhow!("the writer thread ended early"))??;
        for reader in 0..readers {
            let out = work.join(format!("{name}-{reader}.json"));
            let child = Command::new(&options.exe)
                .args(["bench-peer-reader", "--system", system, "--name", name, "--mode", mode])
                .args(["--seconds", &(seconds + 30.0).to_string()])
                .arg("--out")
                .arg(&out)
                .stdin(std::process::Stdio::piped())
                .spawn()
                .context("cannot start a peer reader process")?;
            children.push((child, out));
        }
        // Give every reader time to attach and start waiting.
        std::thread::sleep(Duration::from_millis(300));
        let _ = go_tx.send(());
        std::thread::sleep(Duration::from_secs_f64(seconds));
        stop.stop();
        writer.join().map_err(|_| anyhow::anyhow!("the writer thread panicked"))?
    })?;
    let mut publish = publish;
    let mut latency = Vec::new();
    let mut copy = Vec::new();
    let mut busy_reads = 0;
    // Readers stop when their stdin closes: all of them overlap the whole
    // publishing window, however the scheduler ran them.
    for (child, _) in children.iter_mut() {
        drop(child.stdin.take());
    }
    for (mut child, out) in children {
        let status = child.wait()?;
        if !status.success() {
            bail!("a {system} reader process failed ({status})");
        }
        let samples: PeerReaderSamples = serde_json::from_slice(&std::fs::read(&out)?)?;
        latency.extend(samples.latency_ns);
        copy.extend(samples.copy_ns);
        busy_reads += samples.reads;
        let _ = std::fs::remove_file(&out);
    }
    let frames = if mode == "busy" { busy_reads } else { latency.len() };
    Ok((Percentiles::of(&mut publish), Percentiles::of(&mut latency), Percentiles::of(&mut copy), frames))
}

/// Arguments of the peer reader role.
#[derive(Clone, Debug)]
pub struct PeerReaderArgs {
    /// `skinware` or `rwlock`.
    pub system: String,
    /// Channel name.
    pub name: String,
    /// How long to read.
    pub seconds: f64,
    /// `wait` (for every frame) or `busy` (back to back, on request).
    pub mode: String,
    /// Where to write the samples.
    pub out: PathBuf,
}

/// A waiting reader process: for every frame, the time from its publication
/// to holding a private copy of it.
pub fn run_reader(args: &PeerReaderArgs) -> Result<()> {
    // Waiting readers are real-time, as a control loop would be. Busy readers
    // never sleep, so they stay in the normal scheduler: under SCHED_FIFO
    // they would run one after another instead of side by side.
    if args.mode == "busy" {
        skinware::os::set_normal_scheduling().context("cannot leave the real-time scheduler")?;
    } else {
        let _ = RtOptions { fifo_priority: Some(70), ..RtOptions::default() }.apply();
    }
    // A safety deadline; the parent normally stops us by closing our stdin.
    let deadline = skinware::os::monotonic_ns() + (args.seconds * 1e9) as u64;
    let stopped = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stopped.clone();
    std::thread::spawn(move || {
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
        flag.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let running = || !stopped.load(std::sync::atomic::Ordering::Relaxed) && skinware::os::monotonic_ns() < deadline;
    let mut samples = PeerReaderSamples::default();
    let busy = args.mode == "busy";
    match args.system.as_str() {
        "skinware" if busy => {
            let mut reader = Reader::open(&args.name, "frame")?;
            while running() {
                if reader.latest().is_ok() {
                    samples.reads += 1;
                }
            }
        }
        "rwlock" if busy => {
            let path = skinware::shm::segment_dir().join(format!("skinware-bench-rwlock.{}", args.name));
            let channel = RwLockChannel::open(&path, FRAME_BYTES)?;
            let mut copy = vec![0u8; FRAME_BYTES];
            while running() {
                channel.read_latest(&mut copy)?;
                // Keep the copy observable, or the compiler may drop it.
                std::hint::black_box(&mut copy);
                samples.reads += 1;
            }
        }
        "skinware" | "skinware-spin" => {
            let anticipate = (args.system == "skinware-spin").then_some(ANTICIPATE);
            let options = skinware::ReaderOptions { anticipate, ..skinware::ReaderOptions::default() };
            let mut reader = Reader::open_with(&args.name, "frame", &options)?;
            while running() {
                if let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) {
                    let holding = skinware::os::monotonic_ns();
                    samples.latency_ns.push(holding.saturating_sub(frame.published_ns()));
                    samples.copy_ns.push(reader.stats().read_ns_last);
                }
            }
        }
        "rwlock" => {
            let path = skinware::shm::segment_dir().join(format!("skinware-bench-rwlock.{}", args.name));
            let channel = RwLockChannel::open(&path, FRAME_BYTES)?;
            let mut copy = vec![0u8; FRAME_BYTES];
            let mut last = 0;
            while running() {
                let until = (skinware::os::monotonic_ns() + 100_000_000).min(deadline);
                if let Some((seq, published_ns, copy_ns)) = channel.wait_newer(last, &mut copy, until)? {
                    std::hint::black_box(&mut copy);
                    let holding = skinware::os::monotonic_ns();
                    last = seq;
                    samples.latency_ns.push(holding.saturating_sub(published_ns));
                    samples.copy_ns.push(copy_ns);
                }
            }
        }
        #[cfg(feature = "iceoryx2")]
        "iceoryx2" => {
            let reader = crate::iceoryx2_peer::IceoryxReader::open(&args.name)?;
            let mut copy = vec![0u16; SENSORS];
            while running() {
                if let Some((published_ns, copy_ns)) = reader.wait_newer(&mut copy, Duration::from_millis(100))? {
                    std::hint::black_box(&mut copy);
                    let holding = skinware::os::monotonic_ns();
                    samples.latency_ns.push(holding.saturating_sub(published_ns));
                    samples.copy_ns.push(copy_ns);
                    samples.reads += usize::from(busy);
                }
            }
        }
        other => bail!("unknown system {other:?}; use one of {SYSTEMS:?}"),
    }
    if std::env::var_os("SKINWARE_BENCH_DEBUG").is_some() {
        let cpu = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
        eprintln!(
            "peer reader {} {}: {} reads, {} waits, {:.3} s of CPU",
            args.system,
            args.mode,
            samples.reads,
            samples.latency_ns.len(),
            cpu.tv_sec as f64 + cpu.tv_nsec as f64 / 1e9
        );
    }
    std::fs::write(&args.out, serde_json::to_vec(&samples)?)?;
    Ok(())
}
