//! `skin bench record`: the recorder and the replay on the paper's skin.
//!
//! `skin run` starts the paper's virtual skin (5 layers, 30,848 taxels, the
//! contact and motion services) in its own processes. This process records it
//! for a while with each compression (throughput, CPU of the recording
//! process, file size per minute, frames lost), then stops the skin, replays
//! the zstd recording and records the replay: the second recording's frames
//! must be the first's, bit for bit, and their publication times, taken
//! from the first frame of each, give the replay's timing error.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware_record::file::{RecordStream, read_header};
use skinware_record::{AtEnd, Compression, RecordOptions, Recorder, Replay, ReplayOptions, ServiceChoice};
use skinware_ros2::SkinFrame;

use crate::measure::{Percentiles, RunningSkin};
use crate::run_options::RunOptions;

const PAPER_SKIN: &str = include_str!("../../../examples/paper-virtual-skin.toml");

/// One recording.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingRun {
    /// zstd, lz4 or none.
    pub compression: String,
    /// Seconds recorded.
    pub seconds: f64,
    /// Frames written per second.
    pub frames_per_s: f64,
    /// Message MB per second (before compression).
    pub message_mb_per_s: f64,
    /// File MB per minute.
    pub file_mb_per_min: f64,
    /// CPU of the recording process, percent of one core.
    pub cpu_percent: f64,
    /// Frames lost.
    pub lost: u64,
    /// Map images per second.
    pub images_per_s: f64,
}

/// What `skin bench record` measured.
#[derive(Clone, Debug, Serialize)]
pub struct RecordReport {
    /// Taxels of the skin.
    pub taxels: usize,
    /// Each compression.
    pub runs: Vec<RecordingRun>,
    /// The zstd recording replayed at SCHED_FIFO with idle CPUs kept polling
    /// (a CPU wake latency of 0 µs), and recorded again.
    pub replay: ReplayRound,
    /// The same, before that request (idle vCPUs halt).
    pub replay_without_wake_latency: ReplayRound,
}

/// One replay of the recording, recorded again.
#[derive(Clone, Debug, Serialize)]
pub struct ReplayRound {
    /// The CPU wake latency requested, µs.
    pub requested_cpu_wake_latency_us: Option<u32>,
    /// The CPU wake latency this process held during the replay, µs.
    pub cpu_wake_latency_us: Option<u32>,
    /// Frames replayed.
    pub replayed_frames: u64,
    /// Frames of the replay's recording identical (payload and status) to the original's.
    pub identical_frames: u64,
    /// Frames the replay's recorder lost.
    pub recording_lost: u64,
    /// How far each frame's replayed minus recorded publication time strays
    /// from the first replayed frame's, µs.
    pub timing_error_us: Percentiles,
    /// How late the replay published after its schedule, µs (its own measure).
    pub late_us: Percentiles,
}

fn cpu_seconds() -> f64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
    t.tv_sec as f64 + t.tv_nsec as f64 / 1e9
}

/// Runs the measurement, prints it and writes `record.json`.
pub fn run(options: &RunOptions) -> Result<RecordReport> {
    let seconds = options.seconds_or(3.0, 20.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let dir = skinware::shm::segment_dir().join(format!("skinware-bench-record-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let result = measure(options, seconds, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    print(&report, seconds);
    let path = options.out.join("record.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("  written: {}", path.display());
    Ok(report)
}

fn measure(options: &RunOptions, seconds: f64, dir: &Path) -> Result<RecordReport> {
    let config = dir.join("paper.toml");
    std::fs::write(&config, PAPER_SKIN)?;
    let files = dir.join("files");
    std::fs::create_dir_all(&files)?;
    let skin = RunningSkin::start(&options.exe, &config, dir)?;
    let taxels = wait_for_skin(dir)?;
    let record_options = |compression| RecordOptions {
        skin: "default".into(),
        services: ServiceChoice::All,
        compression,
        dir: Some(dir.to_owned()),
        ..RecordOptions::default()
    };
    let mut runs = Vec::new();
    for (name, compression) in [("zstd", Compression::Zstd), ("lz4", Compression::Lz4), ("none", Compression::None)] {
        let path = files.join(format!("{name}.mcap"));
        let cpu_before = cpu_seconds();
        let recorder = Recorder::start(&path, record_options(compression))?;
        std::thread::sleep(Duration::from_secs_f64(seconds));
        let summary = recorder.finish()?;
        let cpu = cpu_seconds() - cpu_before;
        runs.push(RecordingRun {
            compression: name.into(),
            seconds: summary.seconds,
            frames_per_s: summary.frames_per_s,
            message_mb_per_s: summary.mb_per_s,
            file_mb_per_min: summary.file_bytes as f64 / 1e6 / summary.seconds * 60.0,
            cpu_percent: 100.0 * cpu / summary.seconds,
            lost: summary.lost,
            images_per_s: summary.images as f64 / summary.seconds,
        });
    }
    drop(skin);
    // The skin's writers are gone; their names are free for the replay.
    let original = files.join("zstd.mcap");
    // Without, then with, the CPU wake latency request: the kernel holds it
    // for the rest of this process's life.
    let plain = replay_round(&original, &files.join("replayed-plain.mcap"), dir, None)?;
    let polling = replay_round(&original, &files.join("replayed.mcap"), dir, Some(0))?;
    Ok(RecordReport { taxels, runs, replay: polling, replay_without_wake_latency: plain })
}

/// Replays `original` at SCHED_FIFO into the same skin and records it again into `replayed`.
fn replay_round(original: &Path, replayed: &Path, dir: &Path, cpu_wake_latency_us: Option<u32>) -> Result<ReplayRound> {
    let replay_options = ReplayOptions {
        start_delay: Duration::from_millis(500),
        at_end: AtEnd::Exit,
        dir: Some(dir.to_owned()),
        rt: skinware::RtOptions { fifo_priority: Some(70), cpu_wake_latency_us, ..Default::default() },
        ..ReplayOptions::default()
    };
    let mut replay = Replay::open(original, replay_options)?;
    let record_options = RecordOptions {
        skin: "default".into(),
        services: ServiceChoice::All,
        compression: Compression::Zstd,
        map_hz: 0.0,
        dir: Some(dir.to_owned()),
        ..RecordOptions::default()
    };
    let recorder = Recorder::start(replayed, record_options)?;
    let replay_report = replay.run()?;
    drop(replay);
    std::thread::sleep(Duration::from_millis(200));
    let second = recorder.finish()?;
    let (a, b) = (frames(original)?, frames(replayed)?);
    // Each replayed frame's publication time minus its recorded one: ideally
    // one constant (when the replay started); the error is how far each
    // strays from the first replayed frame's.
    let (mut identical, mut deltas) = (0u64, Vec::new());
    for (channel, frames_a) in &a {
        let Some(frames_b) = b.get(channel) else { bail!("the replay's recording has no channel {channel}") };
        // The replay's sequence numbers start at 1: its frame k is the recording's k-th.
        for fb in frames_b {
            let at = fb.seq.saturating_sub(1) as usize;
            let Some(fa) = frames_a.get(at) else { bail!("{channel}: the replay's recording has more frames") };
            if fa.bytes != fb.bytes || fa.status != fb.status {
                bail!("{channel}: frame {at} of the replay differs from the recording");
            }
            identical += 1;
            deltas.push((fb.published, fb.published as i64 - fa.published as i64));
        }
    }
    let reference = deltas.iter().min().map_or(0, |d| d.1);
    let mut errors: Vec<u64> = deltas.iter().map(|d| (d.1 - reference).unsigned_abs() / 1000).collect();
    let late_us = Percentiles {
        p50: replay_report.late_p50_ns / 1000,
        p99: replay_report.late_p99_ns / 1000,
        p999: replay_report.late_p999_ns / 1000,
        max: replay_report.late_max_ns / 1000,
        avg: replay_report.late_mean_ns / 1000.0,
        std: replay_report.late_std_ns / 1000.0,
        samples: replay_report.frames as usize,
    };
    Ok(ReplayRound {
        requested_cpu_wake_latency_us: cpu_wake_latency_us,
        // What the kernel granted: a refused request (no root) is only warned about.
        cpu_wake_latency_us: skinware::rt::held_cpu_wake_latency_us(),
        replayed_frames: replay_report.frames,
        identical_frames: identical,
        recording_lost: second.lost,
        timing_error_us: Percentiles::of(&mut errors),
        late_us,
    })
}

/// Waits until every layer of the published geometry and both services run; returns the taxels.
fn wait_for_skin(dir: &Path) -> Result<usize> {
    let started = Instant::now();
    loop {
        if let Ok(geometry) = skinware_geometry_sensors(dir) {
            let channels = skinware::list_channels(dir).unwrap_or_default();
            let running = |name: &str| {
                channels
                    .iter()
                    .any(|c| c.channel == name && c.state == skinware::WriterState::Running && c.stats.frames > 5)
            };
            if geometry.1.iter().all(|l| running(l)) && running("contact") && running("motion") {
                return Ok(geometry.0);
            }
        }
        if started.elapsed() > Duration::from_secs(120) {
            bail!("the paper's skin did not come up within 120 s");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Taxels and layer names of the skin's published geometry, read from the
/// layers' channels (the bench does not link the geometry crate).
fn skinware_geometry_sensors(dir: &Path) -> Result<(usize, Vec<String>)> {
    let layers: Vec<_> = skinware::list_channels(dir)?
        .into_iter()
        .filter(|c| c.kind == Some(skinware::ChannelKind::Layer) && c.state == skinware::WriterState::Running)
        .collect();
    if layers.len() < 5 {
        bail!("not all layers yet");
    }
    let taxels = layers.iter().map(|c| c.payload_bytes as usize / 2).sum();
    Ok((taxels, layers.into_iter().map(|c| c.channel).collect()))
}

struct Recorded {
    bytes: Vec<u8>,
    status: u64,
    seq: u64,
    published: u64,
}

fn frames(path: &Path) -> Result<BTreeMap<String, Vec<Recorded>>> {
    let mut stream = RecordStream::open(path)?;
    let (header, first) = read_header(&mut stream)?;
    let mut out: BTreeMap<String, Vec<Recorded>> = BTreeMap::new();
    let mut add = |message: skinware_record::mcap::records::MessageHeader, data: &[u8]| -> Result<()> {
        if let Some(channel) = header.channels.get(&message.channel_id) {
            let frame: SkinFrame = skinware_ros2::decode(data, skinware_ros2::SKIN_FRAME)?;
            out.entry(channel.channel.clone()).or_default().push(Recorded {
                bytes: frame.channel_bytes(),
                status: frame.status,
                seq: frame.seq,
                published: message.publish_time,
            });
        }
        Ok(())
    };
    if let Some((message, data)) = first {
        add(message, &data)?;
    }
    while let Some(record) = stream.next_record()? {
        if let skinware_record::mcap::records::Record::Message { header: message, data } = record {
            add(message, &data)?;
        }
    }
    Ok(out)
}

fn print(report: &RecordReport, seconds: f64) {
    println!(
        "skin bench record: the paper's skin ({} taxels, 5 layers, contact and motion services), {seconds} s per recording",
        report.taxels
    );
    println!("  compression  frames/s  message MB/s  file MB/min  recorder CPU  map images/s  lost");
    for r in &report.runs {
        println!(
            "  {:<11}  {:>8.0}  {:>12.2}  {:>11.1}  {:>11.1}%  {:>12.1}  {:>4}",
            r.compression, r.frames_per_s, r.message_mb_per_s, r.file_mb_per_min, r.cpu_percent, r.images_per_s, r.lost
        );
    }
    println!("  the zstd recording replayed at SCHED_FIFO 70 and recorded again (µs; timing error = each frame's");
    println!("  replayed minus recorded publication time, against the first frame's; lateness = the replay's own):");
    println!(
        "  idle CPUs         identical  lost  error p50  p99  p99.9    max  late p50  p99  p99.9    max  p99 <= 1 ms"
    );
    for round in [&report.replay_without_wake_latency, &report.replay] {
        let (t, l) = (&round.timing_error_us, &round.late_us);
        println!(
            "  {:<16}  {:>4}/{:<4}  {:>4}  {:>9}  {:>3}  {:>5}  {:>5}  {:>8}  {:>3}  {:>5}  {:>5}  {}",
            match (round.requested_cpu_wake_latency_us, round.cpu_wake_latency_us) {
                (_, Some(_)) => "polling (0 µs)",
                (Some(_), None) => "halt (refused)",
                (None, None) => "halt (default)",
            },
            round.identical_frames,
            round.replayed_frames,
            round.recording_lost,
            t.p50,
            t.p99,
            t.p999,
            t.max,
            l.p50,
            l.p99,
            l.p999,
            l.max,
            if t.p99 <= 1000 { "met" } else { "NOT met" }
        );
    }
}
