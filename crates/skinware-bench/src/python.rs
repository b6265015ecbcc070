//! `skin bench python`: the Python bindings beside the Rust reader, in one run.
//!
//! `skin run` writes one virtual layer of the paper's whole-skin size (30,848
//! sensors) at 100 Hz in its own process. This process times the Rust
//! reader's `latest()` and its as-soon-as-available latency on it, then runs
//! the same reads from Python (`$SKINWARE_PYTHON`, with the `skinware`
//! package installed), in another process, on the same writer: `latest()` (a
//! new read-only numpy array per frame), `read_into()` (the caller's array)
//! and `wait_newer()`'s latency from publication to the frame in Python. So
//! both readers are a process apart from the writer, as an application is.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use skinware::{Reader, ReaderOptions, WriterState};

use crate::measure::{Percentiles, RunningSkin};
use crate::run_options::RunOptions;

const SCRIPT: &str = include_str!("python_bench.py");
/// The paper's whole skin, as one layer.
const SENSORS: u32 = 30_848;
const RATE_HZ: f64 = 100.0;
const LAYER: &str = "bench-0";
/// One virtual layer of 30,848 sensors.
const CONFIG: &str = r#"
skin = "pybench"

[[driver]]
name = "bench"
kind = "virtual"
sensors = 30848
layers = 1
rate_hz = 100
"#;

/// Options of `skin bench python`.
#[derive(Clone, Debug)]
pub struct PythonBenchOptions {
    /// Quick: fewer reads and frames; `seconds` of as-soon-as-available
    /// frames (each side); `python.json` goes to `out`; `exe` runs the writer.
    pub run: RunOptions,
    /// The Python with the `skinware` package.
    pub python: String,
}

/// What `skin bench python` measured, ns.
#[derive(Clone, Debug, Serialize)]
pub struct PythonReport {
    /// Sensors per frame.
    pub sensors: u32,
    /// The writer's rate, Hz.
    pub rate_hz: f64,
    /// Rust `Reader::latest()`: the lock-free copy into the reader's buffer.
    pub rust_latest: Percentiles,
    /// Rust `latest()` plus a copy into a new `Vec<u16>` (what the binding
    /// does before numpy takes the vector over).
    pub rust_latest_to_vec: Percentiles,
    /// Python `Reader.latest()`: a new read-only numpy array.
    pub python_latest: Percentiles,
    /// Python `Reader.read_into(out)`.
    pub python_read_into: Percentiles,
    /// Rust `wait_newer()`: publication to return, in blocks alternating
    /// with the Python reader's.
    pub rust_newer_latency: Percentiles,
    /// Python `wait_newer()`: publication to the frame in Python.
    pub python_newer_latency: Percentiles,
    /// Frames the Python as-soon-as-available reader skipped.
    pub python_newer_skipped: u64,
    /// Versions: Python, numpy, the package.
    pub versions: Versions,
}

/// The Python side's versions.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Versions {
    /// CPython.
    pub python: String,
    /// numpy.
    pub numpy: String,
    /// The `skinware` package.
    pub skinware: String,
}

#[derive(Deserialize)]
struct PythonSide {
    latest_ns: Vec<u64>,
    read_into_ns: Vec<u64>,
    newer_latency_ns: Vec<u64>,
    newer_skipped: u64,
    python: String,
    numpy: String,
    skinware: String,
}

/// Runs the benchmark, prints its table and writes `python.json`.
pub fn run(options: &PythonBenchOptions) -> Result<PythonReport> {
    let probe = Command::new(&options.python).args(["-c", "import skinware, numpy"]).output();
    match probe {
        Ok(output) if output.status.success() => {}
        Ok(output) => bail!(
            "{} cannot import skinware and numpy ({}); install the bindings with `pip install ./crates/skinware-py`, or set SKINWARE_PYTHON",
            options.python,
            String::from_utf8_lossy(&output.stderr).trim()
        ),
        Err(e) => {
            bail!("cannot run {}: {e}; set SKINWARE_PYTHON to a Python with the skinware package", options.python)
        }
    }
    let reads = if options.run.quick { 3_000 } else { 20_000 };
    let seconds = options.run.seconds_or(3.0, 20.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    let frames = (seconds * RATE_HZ) as usize;
    let dir = skinware::shm::segment_dir().join(format!("skinware-bench-python-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let result = start_skin(options, &dir).and_then(|_skin| measure(&dir, reads, frames, options));
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    print(&report);
    std::fs::create_dir_all(&options.run.out)
        .with_context(|| format!("cannot create {}", options.run.out.display()))?;
    let path = options.run.out.join("python.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("  written: {}", path.display());
    Ok(report)
}

fn start_skin(options: &PythonBenchOptions, dir: &Path) -> Result<RunningSkin> {
    RunningSkin::start_until(&options.run.exe, CONFIG, dir, "the one-layer skin", |channels| {
        channels.iter().any(|c| c.channel == LAYER && c.state == WriterState::Running && c.stats.frames > 5)
    })
}

fn measure(dir: &Path, reads: usize, frames: usize, options: &PythonBenchOptions) -> Result<PythonReport> {
    let (skin, layer) = ("pybench", LAYER);
    let mut reader =
        Reader::open_with(skin, layer, &ReaderOptions { dir: Some(dir.to_owned()), ..Default::default() })?;
    reader.wait_newer(Duration::from_secs(5))?;
    let mut latest = Vec::with_capacity(reads);
    let mut to_vec = Vec::with_capacity(reads);
    for _ in 0..reads {
        let started = skinware::os::monotonic_ns();
        let frame = reader.latest()?;
        latest.push(skinware::os::monotonic_ns() - started);
        std::hint::black_box(frame.seq());
    }
    for _ in 0..reads {
        let started = skinware::os::monotonic_ns();
        let copy: Vec<u16> = reader.latest()?.responses().to_vec();
        to_vec.push(skinware::os::monotonic_ns() - started);
        std::hint::black_box(copy);
    }
    // The Python process times its reads alone, then both readers take
    // frames as soon as available in alternating blocks: never at once (on 2
    // cores the second woken would wait for the first's CPU), both through
    // the same stretch of the machine's life.
    let mut child = Command::new(&options.python)
        .args(["-c", SCRIPT, skin, layer, &reads.to_string()])
        .env("SKINWARE_SHM_DIR", dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .with_context(|| format!("cannot run {}", options.python))?;
    let mut stdin = child.stdin.take().context("the Python side's input")?;
    let mut stdout = BufReader::new(child.stdout.take().context("the Python side's output")?);
    let mut line = String::new();
    stdout.read_line(&mut line)?;
    let mut newer = Vec::with_capacity(frames);
    if line.trim() == "ready" {
        let block = (frames / 10).max(1);
        for _ in 0..frames.div_ceil(block) {
            writeln!(stdin, "{block}")?;
            line.clear();
            stdout.read_line(&mut line)?;
            if line.trim() != "done" {
                break;
            }
            reader.wait_newer(Duration::from_secs(5))?;
            for _ in 0..block {
                let published = reader.wait_newer(Duration::from_secs(5))?.published_ns();
                newer.push(skinware::os::monotonic_ns().saturating_sub(published));
            }
        }
        writeln!(stdin)?;
    }
    drop(stdin);
    let mut json = String::new();
    stdout.read_to_string(&mut json)?;
    let output = child.wait_with_output()?;
    if !output.status.success() || newer.is_empty() {
        bail!("the Python side failed: {line}{}", String::from_utf8_lossy(&output.stderr));
    }
    let mut python: PythonSide = serde_json::from_str(&json).context("the Python side's JSON")?;
    Ok(PythonReport {
        sensors: SENSORS,
        rate_hz: RATE_HZ,
        rust_latest: Percentiles::of(&mut latest),
        rust_latest_to_vec: Percentiles::of(&mut to_vec),
        python_latest: Percentiles::of(&mut python.latest_ns),
        python_read_into: Percentiles::of(&mut python.read_into_ns),
        rust_newer_latency: Percentiles::of(&mut newer),
        python_newer_latency: Percentiles::of(&mut python.newer_latency_ns),
        python_newer_skipped: python.newer_skipped,
        versions: Versions { python: python.python, numpy: python.numpy, skinware: python.skinware },
    })
}

fn print(report: &PythonReport) {
    let us = |ns: u64| ns as f64 / 1000.0;
    println!(
        "\nPython bindings beside the Rust reader: one {}-sensor layer at {} Hz (Python {}, numpy {})",
        report.sensors, report.rate_hz, report.versions.python, report.versions.numpy
    );
    println!("  {:<44} {:>9} {:>9} {:>9} {:>9} {:>8}", "read", "p50 µs", "p99 µs", "max µs", "mean µs", "samples");
    let rows = [
        ("Rust latest() (copy into the reader's buffer)", &report.rust_latest),
        ("Rust latest() + copy into a new Vec<u16>", &report.rust_latest_to_vec),
        ("Python latest() (new read-only numpy array)", &report.python_latest),
        ("Python read_into(out)", &report.python_read_into),
        ("Rust wait_newer(): publication to return", &report.rust_newer_latency),
        ("Python wait_newer(): publication to frame", &report.python_newer_latency),
    ];
    for (name, p) in rows {
        println!(
            "  {:<44} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>8}",
            name,
            us(p.p50),
            us(p.p99),
            us(p.max),
            p.avg / 1000.0,
            p.samples
        );
    }
    println!("  frames the Python as-soon-as-available reader skipped: {}", report.python_newer_skipped);
}
