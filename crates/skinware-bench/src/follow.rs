//! `skin bench follow`: how soon readers in every mode get a restarted
//! writer's first frame (issue #36, goal 2), with the process's successor
//! watcher and without it (the 100 ms re-check readers had before), side by
//! side in one run.
//!
//! A writer process (this executable's `bench-follow-writer` role) publishes
//! the paper's whole-skin frame (61,696 bytes) at 1 kHz; the bench SIGKILLs
//! it after a random 200-500 ms and starts its successor at once, as `skin
//! run` would after its backoff. The successor prints when it published its
//! first frame. Readers in this process, one per mode and per way of
//! following, note when they first hold a frame of each new writer; the
//! latency is that moment minus the successor's first publication. A
//! periodic reader (1 kHz) may first hold the successor's second or third
//! frame: that is what it gets, and it counts from the first.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{Reader, ReaderOptions, Stop, Ticker, Writer, WriterOptions};

use crate::run_options::RunOptions;

const SKIN: &str = "follow";
const CHANNEL: &str = "layer";
/// The paper's skin in one frame: 30,848 responses.
const FRAME_BYTES: usize = 30_848 * 2;
const PERIOD: Duration = Duration::from_millis(1);
/// How long a reader without the watcher waits before it re-checks its
/// writer: the blocking reads' slice before the watcher.
const RECHECK: Duration = Duration::from_millis(100);

/// Options of `skin bench follow`.
#[derive(Clone, Debug)]
pub struct FollowOptions {
    /// Quick: 15 writer restarts instead of 100 (`seconds` is not used);
    /// `follow.json` goes to `out`; `exe` starts the writer processes.
    pub run: RunOptions,
    /// Writer restarts to measure (default 100, or 15 with `quick`).
    pub rounds: Option<usize>,
}

/// Arguments of the hidden `bench-follow-writer` role.
#[derive(Clone, Debug, clap::Args)]
pub struct FollowWriterArgs {
    /// The segment directory.
    #[arg(long)]
    pub dir: PathBuf,
}

/// The writer process: publishes at 1 kHz until killed, and prints the
/// CLOCK_MONOTONIC time of its first publication.
pub fn run_writer(args: &FollowWriterArgs) -> Result<()> {
    let options = WriterOptions {
        dir: Some(args.dir.clone()),
        period: Some(PERIOD),
        unlink_on_drop: false,
        ..WriterOptions::default()
    };
    let mut writer = Writer::create(SKIN, CHANNEL, FRAME_BYTES, b"", &options).context("the follow bench's writer")?;
    let mut ticker = Ticker::new(PERIOD);
    let stop = Stop::new();
    let responses = vec![0u16; FRAME_BYTES / 2];
    // Two minutes at most: the bench kills it long before.
    let deadline = Instant::now() + Duration::from_secs(120);
    while Instant::now() < deadline && ticker.wait(&stop).is_some() {
        let mut frame = writer.begin();
        frame.write_responses(0, &responses)?;
        frame.publish();
        if writer.last_seq() == 1 {
            let mut stdout = std::io::stdout();
            writeln!(stdout, "first {}", writer.last_published_ns())?;
            stdout.flush()?;
        }
    }
    Ok(())
}

/// How a reader obtains frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
enum Mode {
    Periodic,
    Asap,
    Request,
    Anticipate,
}

impl Mode {
    const ALL: [Mode; 4] = [Mode::Periodic, Mode::Asap, Mode::Request, Mode::Anticipate];

    fn name(self) -> &'static str {
        match self {
            Mode::Periodic => "periodic 1 kHz",
            Mode::Asap => "as soon as available",
            Mode::Request => "on request",
            Mode::Anticipate => "anticipating",
        }
    }
}

/// When one reader first held a frame of each writer generation.
type Firsts = Arc<Mutex<Vec<(u64, u64)>>>;

/// One row of the result.
#[derive(Debug, Serialize)]
pub struct FollowRow {
    /// Reader mode.
    pub mode: &'static str,
    /// "watcher" (this release) or "re-check" (100 ms, as before).
    pub following: &'static str,
    /// Successors the reader got a frame of.
    pub followed: usize,
    /// Successors it got no frame of before the next restart.
    pub missed: usize,
    /// Successor's first publication to the reader holding a frame of it, ms.
    pub p50_ms: f64,
    /// 99th percentile, ms.
    pub p99_ms: f64,
    /// Maximum, ms.
    pub max_ms: f64,
}

/// What `skin bench follow` measured.
#[derive(Debug, Serialize)]
pub struct FollowReport {
    /// Writer restarts.
    pub restarts: usize,
    /// Frame size, bytes.
    pub frame_bytes: usize,
    /// One row per reader mode and way of following.
    pub rows: Vec<FollowRow>,
}

/// Runs `skin bench follow`.
pub fn run(options: &FollowOptions) -> Result<FollowReport> {
    let rounds = options.rounds.unwrap_or(if options.run.quick { 15 } else { 100 });
    if rounds == 0 {
        bail!("--rounds must be at least 1");
    }
    let dir = std::env::temp_dir().join(format!("skinware-follow-{}", std::process::id()));
    let shm = if std::path::Path::new("/dev/shm").is_dir() {
        PathBuf::from(format!("/dev/shm/skinware-follow-{}", std::process::id()))
    } else {
        dir
    };
    std::fs::create_dir_all(&shm).with_context(|| format!("cannot create {}", shm.display()))?;
    let result = measure(options, &shm, rounds);
    let _ = std::fs::remove_dir_all(&shm);
    let report = result?;
    print_table(&report);
    std::fs::create_dir_all(&options.run.out)?;
    let path = options.run.out.join("follow.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("JSON: {}", path.display());
    Ok(report)
}

struct Killed(Option<Child>);

impl Drop for Killed {
    fn drop(&mut self) {
        if let Some(child) = &mut self.0 {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

fn start_writer(options: &FollowOptions, dir: &std::path::Path) -> Result<(Killed, u64)> {
    let mut child = Command::new(&options.run.exe)
        .arg("bench-follow-writer")
        .arg("--dir")
        .arg(dir)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .context("cannot start the follow bench's writer")?;
    let stdout = child.stdout.take().context("no stdout")?;
    let child = Killed(Some(child));
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line)?;
    let first = line
        .strip_prefix("first ")
        .and_then(|ns| ns.trim().parse().ok())
        .with_context(|| format!("the writer said {line:?}, not its first publication"))?;
    Ok((child, first))
}

fn measure(options: &FollowOptions, dir: &std::path::Path, rounds: usize) -> Result<FollowReport> {
    let (mut writer, first) = start_writer(options, dir)?;
    let mut first_published = vec![(1u64, first)];
    let stop = Stop::new();
    let mut readers = Vec::new();
    for mode in Mode::ALL {
        for watched in [true, false] {
            let firsts: Firsts = Arc::default();
            let reader = open_reader(dir, mode, watched, &stop)?;
            let (stop, record) = (stop.clone(), firsts.clone());
            let thread = std::thread::spawn(move || read_until_stopped(reader, mode, watched, &stop, &record));
            readers.push((mode, watched, firsts, thread));
        }
    }
    let mut seed = 0x5eed_f011_u64 ^ u64::from(std::process::id());
    for round in 0..rounds {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        std::thread::sleep(Duration::from_millis(200 + seed % 300));
        if let Some(mut child) = writer.0.take() {
            child.kill()?;
            child.wait()?;
        }
        let (successor, first) = start_writer(options, dir)?;
        writer = successor;
        first_published.push((round as u64 + 2, first));
        eprint!("\rfollow: {}/{rounds} restarts", round + 1);
    }
    eprintln!();
    std::thread::sleep(Duration::from_millis(300));
    stop.stop();
    drop(writer);
    let mut rows = Vec::new();
    for (mode, watched, firsts, thread) in readers {
        let _ = thread.join();
        let held = skinware::lock(&firsts).clone();
        let mut latencies: Vec<f64> = Vec::new();
        let mut missed = 0;
        for &(generation, published) in first_published.iter().skip(1) {
            match held.iter().find(|(g, _)| *g == generation) {
                Some(&(_, at)) => latencies.push(at.saturating_sub(published) as f64 / 1e6),
                None => missed += 1,
            }
        }
        latencies.sort_by(f64::total_cmp);
        let quantile = |q: f64| {
            if latencies.is_empty() {
                return f64::NAN;
            }
            latencies[((latencies.len() as f64 * q).ceil() as usize).clamp(1, latencies.len()) - 1]
        };
        rows.push(FollowRow {
            mode: mode.name(),
            following: if watched { "watcher" } else { "re-check" },
            followed: latencies.len(),
            missed,
            p50_ms: quantile(0.5),
            p99_ms: quantile(0.99),
            max_ms: latencies.last().copied().unwrap_or(f64::NAN),
        });
    }
    Ok(FollowReport { restarts: rounds, frame_bytes: FRAME_BYTES, rows })
}

fn open_reader(dir: &std::path::Path, mode: Mode, watched: bool, stop: &Stop) -> Result<Reader> {
    let options = ReaderOptions {
        dir: Some(dir.to_owned()),
        no_successor_watch: !watched,
        anticipate: (mode == Mode::Anticipate).then_some(Duration::from_micros(200)),
        ..ReaderOptions::default()
    };
    let mut reader = Reader::open_with(SKIN, CHANNEL, &options).context("the follow bench's reader")?;
    reader.set_stop(stop);
    Ok(reader)
}

/// Reads in `mode` until stopped, noting when it first holds a frame of
/// each writer generation.
fn read_until_stopped(mut reader: Reader, mode: Mode, watched: bool, stop: &Stop, firsts: &Firsts) {
    let mut ticker = Ticker::new(PERIOD);
    let mut seen_generation = 0;
    let mut last_fresh = Instant::now();
    while !stop.is_stopped() {
        let got = match mode {
            Mode::Periodic => reader.next_periodic(&mut ticker).map(|f| f.is_fresh()),
            Mode::Asap | Mode::Anticipate => reader.wait_newer(RECHECK * 2).map(|_| true),
            Mode::Request => reader.request(RECHECK * 2).map(|_| true),
        };
        let now = skinware::os::monotonic_ns();
        if got.unwrap_or(false) {
            last_fresh = Instant::now();
            let generation = reader.writer_generation();
            if generation != seen_generation {
                seen_generation = generation;
                skinware::lock(firsts).push((generation, now));
            }
        } else if mode == Mode::Periodic && !watched && last_fresh.elapsed() >= RECHECK {
            // What a periodic reader had to do before: re-check its writer
            // when it has seen nothing new for the blocking reads' slice.
            reader.follow_recreated();
            last_fresh = Instant::now();
        }
    }
}

fn print_table(report: &FollowReport) {
    println!(
        "\nskin bench follow: {} writer restarts (SIGKILL, successor at once), {}-byte frames at 1 kHz",
        report.restarts, report.frame_bytes
    );
    println!("successor's first publication -> the reader holds a frame of it, ms");
    println!(
        "{:<22} {:<9} {:>8} {:>7} {:>8} {:>8} {:>8}",
        "reader", "follows", "followed", "missed", "p50", "p99", "max"
    );
    for row in &report.rows {
        println!(
            "{:<22} {:<9} {:>8} {:>7} {:>8.2} {:>8.2} {:>8.2}",
            row.mode, row.following, row.followed, row.missed, row.p50_ms, row.p99_ms, row.max_ms
        );
    }
}
