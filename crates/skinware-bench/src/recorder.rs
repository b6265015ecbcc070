//! `skin bench recorder`: whether `skin record --services` keeps up with the
//! paper's skin at 1 kHz (5 layers and 3 service channels: about 8,000
//! frames and 100 MB of messages a second).
//!
//! `skin run` starts the skin in its own processes; `skin record` records
//! it in another, once with each compression. Per recording: the frames
//! written and lost (and how often a reader found the file's queue full),
//! MB/s of messages and of file, the recording process's CPU (and its
//! file thread's, where the compression runs), and its resident memory
//! sampled every second. Then the control: the uncompressed recording's
//! bytes written again to a file beside it, by one thread, at the pace the
//! recorder wrote them (1 MiB at a time, synced every second, as the
//! recorder does), and once as fast as the disk takes them.

#![forbid(unsafe_code)]

use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;

use crate::kilohertz::cpu::{cpu_ns_between, thread_cpu_ns};
use crate::measure::RunningSkin;
use crate::procs::resources_of;
use crate::run_options::RunOptions;
use crate::skin_config::PaperSkin;

/// The rate of the skin's layers and services.
const RATE_HZ: f64 = 1000.0;
/// Bytes per write of the plain write, as the recorder's chunks.
const WRITE_BYTES: usize = 1 << 20;
/// Bytes of the uncompressed recording the plain write holds in memory and writes over and over.
const PLAIN_WRITE_BUFFER: usize = 64 << 20;

/// One recording by `skin record`.
#[derive(Clone, Debug, Serialize)]
pub struct RecorderRun {
    /// zstd, lz4 or none.
    pub compression: String,
    /// Seconds recorded (the recorder's own count).
    pub seconds: f64,
    /// Frames written.
    pub frames: u64,
    /// Frames lost.
    pub lost: u64,
    /// Times a reader found the queue to the file full.
    pub file_waits: u64,
    /// Whether every reader thread ran in SCHED_FIFO.
    pub readers_realtime: bool,
    /// Message MB per second, before compression.
    pub message_mb_per_s: f64,
    /// File MB per second.
    pub file_mb_per_s: f64,
    /// CPU of the recording process, % of one core, over the recording.
    pub cpu_percent: f64,
    /// CPU of its file thread (which compresses), % of one core.
    pub file_thread_cpu_percent: f64,
    /// Resident memory once a second, KiB.
    pub rss_kib: Vec<u64>,
}

/// The recorder's uncompressed bytes written again by one thread.
#[derive(Clone, Debug, Serialize)]
pub struct PlainWrite {
    /// Bytes written.
    pub bytes: u64,
    /// At the recorder's pace: MB/s.
    pub paced_mb_per_s: f64,
    /// At the recorder's pace: the writing thread's CPU, % of one core.
    pub paced_cpu_percent: f64,
    /// As fast as the disk takes them (synced at the end): MB/s.
    pub fastest_mb_per_s: f64,
}

/// What `skin bench recorder` measured.
#[derive(Clone, Debug, Serialize)]
pub struct RecorderReport {
    /// Taxels of the skin.
    pub taxels: usize,
    /// Rate of its layers and services.
    pub rate_hz: f64,
    /// Seconds per recording asked for.
    pub seconds: f64,
    /// Each compression.
    pub runs: Vec<RecorderRun>,
    /// The control.
    pub plain_write: PlainWrite,
}

/// Runs the measurement on the paper's skin, or on one of `taxels` over
/// the same 5 layers, prints it and writes `recorder.json` (or
/// `recorder-TAXELS.json`).
pub fn run(options: &RunOptions, taxels: Option<usize>) -> Result<RecorderReport> {
    crate::skin_config::check_taxels(taxels)?;
    let seconds = options.seconds_or(5.0, 60.0);
    if !(seconds.is_finite() && seconds >= 2.0) {
        bail!("--seconds must be at least 2 (the memory is sampled once a second)");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let dir = skinware::shm::segment_dir().join(format!("skrc{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    // The files go to the disk the user records to, not to the tmpfs of the channels.
    let files = options.out.join("recorder-work");
    let _ = std::fs::remove_dir_all(&files);
    std::fs::create_dir_all(&files).with_context(|| format!("cannot create {}", files.display()))?;
    let result = measure(options, (seconds, taxels), &dir, &files);
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&files);
    let report = result?;
    print(&report);
    let path = options.out.join(match taxels {
        Some(taxels) => format!("recorder-{taxels}.json"),
        None => "recorder.json".to_owned(),
    });
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("  written: {}", path.display());
    Ok(report)
}

fn measure(
    options: &RunOptions,
    (seconds, taxels): (f64, Option<usize>),
    dir: &Path,
    files: &Path,
) -> Result<RecorderReport> {
    let skin = RunningSkin::start_until(
        &options.exe,
        &PaperSkin { taxels, ..PaperSkin::at(RATE_HZ) }.config()?,
        dir,
        "the paper's skin at 1 kHz",
        |channels| {
            let running =
                |c: &&skinware::ChannelInfo| c.state == skinware::WriterState::Running && c.stats.frames > 100;
            channels.iter().filter(running).count() >= 8
        },
    )?;
    let taxels = skinware::list_channels(dir)?
        .iter()
        .filter(|c| c.kind == Some(skinware::ChannelKind::Layer))
        .map(|c| c.payload_bytes as usize / 2)
        .sum();
    let mut runs = Vec::new();
    for compression in ["zstd", "lz4", "none"] {
        let file = files.join(format!("{compression}.mcap"));
        runs.push(record(&options.exe, dir, &file, compression, seconds)?);
        if compression != "none" {
            let _ = std::fs::remove_file(&file);
        }
    }
    skin.stop(Duration::from_secs(20))?;
    let none = runs.iter().find(|r| r.compression == "none").context("the uncompressed recording")?;
    let plain_write = plain_write(&files.join("none.mcap"), &files.join("plain.bin"), none.file_mb_per_s)?;
    Ok(RecorderReport { taxels, rate_hz: RATE_HZ, seconds, runs, plain_write })
}

/// Records for `seconds` with `skin record` and samples it meanwhile.
fn record(exe: &Path, dir: &Path, file: &Path, compression: &str, seconds: f64) -> Result<RecorderRun> {
    let mut child = Command::new(exe)
        .arg("record")
        .arg(file)
        .args(["--services", "--json", "--compression", compression, "--seconds", &seconds.to_string()])
        .env("SKINWARE_SHM_DIR", dir)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .spawn()
        .context("cannot start `skin record`")?;
    let pid = child.id();
    let mut rss_kib = Vec::new();
    let started = Instant::now();
    let first = process_cpu_ns(pid);
    let file_thread_first = thread_cpu_ns(pid, Some("rec-file"));
    let (mut last, mut file_thread_last, mut last_at) = (first, file_thread_first.clone(), started);
    let mut next_sample = started + Duration::from_secs(1);
    while child.try_wait()?.is_none() {
        if Instant::now() >= next_sample {
            if let Some(resources) = resources_of(pid) {
                rss_kib.push(resources.rss_kib);
            }
            // The last readings before the recorder finishes its file and exits.
            if let Some(cpu) = process_cpu_ns(pid) {
                last = Some(cpu);
                file_thread_last = thread_cpu_ns(pid, Some("rec-file"));
                last_at = Instant::now();
            }
            next_sample += Duration::from_secs(1);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut said = String::new();
    child.stdout.take().context("the recorder's output")?.read_to_string(&mut said)?;
    let summary: serde_json::Value =
        serde_json::from_str(&said).with_context(|| format!("`skin record` said no summary: {said:?}"))?;
    let number = |key: &str| summary[key].as_f64().with_context(|| format!("`skin record` gave no {key}"));
    let recorded = number("seconds")?;
    let cpu_seconds = last.zip(first).map_or(0.0, |(last, first)| last.saturating_sub(first) as f64 / 1e9);
    let sampled = last_at.duration_since(started).as_secs_f64().max(1e-3);
    let (file_thread_ns, _) = cpu_ns_between(&file_thread_first, &file_thread_last);
    let channels = summary["channels"].as_object().context("`skin record` gave no channels")?;
    Ok(RecorderRun {
        compression: compression.into(),
        seconds: recorded,
        frames: number("frames")? as u64,
        lost: number("lost")? as u64,
        file_waits: channels.values().filter_map(|c| c["file_waits"].as_u64()).sum(),
        readers_realtime: summary["readers_realtime"].as_bool().unwrap_or(false),
        message_mb_per_s: number("mb_per_s")?,
        file_mb_per_s: number("file_bytes")? / 1e6 / recorded.max(1e-9),
        cpu_percent: 100.0 * cpu_seconds / sampled,
        file_thread_cpu_percent: 100.0 * file_thread_ns as f64 / 1e9 / sampled,
        rss_kib,
    })
}

/// The run time of every thread of process `pid` so far, ns; `None` once it is gone.
fn process_cpu_ns(pid: u32) -> Option<u64> {
    let threads = thread_cpu_ns(pid, None);
    (!threads.is_empty()).then(|| threads.values().sum())
}

/// Writes as many bytes as `source` holds to `target`, at `mb_per_s` and
/// then as fast as it can, one thread, as the recorder's file thread writes
/// them: `source`'s first [`PLAIN_WRITE_BUFFER`] bytes over and over, read
/// beforehand, so that reading them costs the writing thread nothing.
fn plain_write(source: &Path, target: &Path, mb_per_s: f64) -> Result<PlainWrite> {
    let total = std::fs::metadata(source).with_context(|| format!("cannot read {}", source.display()))?.len();
    let mut buffer = Vec::new();
    std::fs::File::open(source)?.take(PLAIN_WRITE_BUFFER as u64).read_to_end(&mut buffer)?;
    if buffer.is_empty() {
        bail!("{} is empty: the uncompressed recording wrote nothing", source.display());
    }
    // Whole writes: every chunk then starts at a multiple of a write and ends within the buffer.
    if buffer.len() >= WRITE_BYTES {
        buffer.truncate(buffer.len() / WRITE_BYTES * WRITE_BYTES);
    }
    let chunks = (0..total).step_by(WRITE_BYTES).map(|at| {
        let from = (at as usize) % buffer.len();
        let len = (total - at).min(WRITE_BYTES as u64) as usize;
        &buffer[from..(from + len).min(buffer.len())]
    });
    let chunks: Vec<&[u8]> = chunks.collect();
    let bytes_written: u64 = chunks.iter().map(|c| c.len() as u64).sum();
    let write = |pace: Option<f64>| -> Result<(f64, f64)> {
        let _ = std::fs::remove_file(target);
        let mut file = std::fs::File::create(target).with_context(|| format!("cannot create {}", target.display()))?;
        let cpu_before = thread_cpu_s();
        let started = Instant::now();
        let mut next_sync = started + Duration::from_secs(1);
        for (index, chunk) in chunks.iter().enumerate() {
            if let Some(mb_per_s) = pace {
                let due = started + Duration::from_secs_f64((index * WRITE_BYTES) as f64 / 1e6 / mb_per_s);
                std::thread::sleep(due.saturating_duration_since(Instant::now()));
            }
            file.write_all(chunk)?;
            if pace.is_some() && Instant::now() >= next_sync {
                file.sync_data()?;
                next_sync += Duration::from_secs(1);
            }
        }
        file.sync_data()?;
        let elapsed = started.elapsed().as_secs_f64();
        Ok((bytes_written as f64 / 1e6 / elapsed, 100.0 * (thread_cpu_s() - cpu_before) / elapsed))
    };
    let (paced_mb_per_s, paced_cpu_percent) = write(Some(mb_per_s.max(1e-3)))?;
    let (fastest_mb_per_s, _) = write(None)?;
    let _ = std::fs::remove_file(target);
    Ok(PlainWrite { bytes: bytes_written, paced_mb_per_s, paced_cpu_percent, fastest_mb_per_s })
}

/// This thread's CPU time, s.
fn thread_cpu_s() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 / 1e9
}

fn print(report: &RecorderReport) {
    println!(
        "skin bench recorder: `skin record --services` of the paper's skin ({} taxels, 5 layers and 3 service \
         channels at {} Hz), {} s per compression",
        report.taxels, report.rate_hz, report.seconds
    );
    println!(
        "  compression  frames written  lost  queue full  message MB/s  file MB/s  recorder CPU  file thread  RSS first / max / last (MiB)"
    );
    for r in &report.runs {
        let mib = |kib: Option<&u64>| kib.map_or(0.0, |&kib| kib as f64 / 1024.0);
        println!(
            "  {:<11}  {:>14}  {:>4}  {:>10}  {:>12.1}  {:>9.1}  {:>11.1}%  {:>10.1}%  {:.1} / {:.1} / {:.1}{}",
            r.compression,
            r.frames,
            r.lost,
            r.file_waits,
            r.message_mb_per_s,
            r.file_mb_per_s,
            r.cpu_percent,
            r.file_thread_cpu_percent,
            mib(r.rss_kib.first()),
            mib(r.rss_kib.iter().max()),
            mib(r.rss_kib.last()),
            if r.readers_realtime { "" } else { "  (readers not real-time: SCHED_FIFO refused)" }
        );
    }
    let plain = &report.plain_write;
    println!(
        "  plain write of the uncompressed file's {:.0} MB by one thread: at the recorder's {:.1} MB/s, {:.1}% of a \
         core; as fast as it goes, {:.0} MB/s",
        plain.bytes as f64 / 1e6,
        plain.paced_mb_per_s,
        plain.paced_cpu_percent,
        plain.fastest_mb_per_s
    );
}
