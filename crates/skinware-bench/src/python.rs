//! `skin bench python`: the Python bindings beside the Rust reader, in one run.
//!
//! This process writes a layer of the paper's whole-skin size (30,848
//! sensors) at a fixed rate, times the Rust reader's `latest()` and its
//! as-soon-as-available latency, then runs the same reads from Python
//! (`$SKINWARE_PYTHON`, with the `skinware` package installed) on the same
//! writer: `latest()` (a new read-only numpy array per frame), `read_into()`
//! (the caller's array) and `wait_newer()`'s latency from publication to the
//! frame in Python.

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use skinware::{Reader, Stop, Ticker, TopologyBuilder, Writer, WriterOptions};

use crate::measure::Percentiles;

const SCRIPT: &str = include_str!("python_bench.py");
/// The paper's whole skin, as one layer.
const SENSORS: u32 = 30_848;

/// Options of `skin bench python`.
#[derive(Clone, Debug)]
pub struct PythonBenchOptions {
    /// CI-sized: fewer reads and frames.
    pub quick: bool,
    /// Where `python.json` goes.
    pub out: PathBuf,
    /// Seconds of as-soon-as-available frames (each side).
    pub seconds: Option<f64>,
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
    /// Rust `wait_newer()`: publication to return.
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
    let rate_hz = 500.0;
    let reads = if options.quick { 3_000 } else { 20_000 };
    let seconds = options.seconds.unwrap_or(if options.quick { 2.0 } else { 10.0 });
    let frames = (seconds * rate_hz) as usize;
    let skin = format!("pybench{}", std::process::id());
    let layer = "skin";

    let mut builder = TopologyBuilder::new(layer, "pressure", rate_hz);
    builder.patch(0);
    for module in 0..SENSORS / 16 {
        builder.module(module, module * 16..(module + 1) * 16);
    }
    let topology = builder.build()?;
    let writer_options = WriterOptions { period: Some(Duration::from_secs_f64(1.0 / rate_hz)), ..Default::default() };
    let mut writer = Writer::create(&skin, layer, topology.frame_bytes(), &topology.encode(), &writer_options)?;
    let stop = Stop::new();
    writer.set_stop(&stop);
    let writing = std::thread::spawn(move || {
        let mut values = vec![0u16; SENSORS as usize];
        let mut k = 0u16;
        writer.run_periodic(Ticker::from_hz(rate_hz), |frame| {
            k = k.wrapping_add(1);
            values.fill(k);
            frame.write_responses(0, &values)
        })
    });
    let result = measure(&skin, layer, reads, frames, rate_hz, options);
    stop.stop();
    writing.join().map_err(|_| anyhow::anyhow!("the writer thread panicked"))??;
    let report = result?;
    print(&report);
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let path = options.out.join("python.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("  written: {}", path.display());
    Ok(report)
}

fn measure(
    skin: &str,
    layer: &str,
    reads: usize,
    frames: usize,
    rate_hz: f64,
    options: &PythonBenchOptions,
) -> Result<PythonReport> {
    let mut reader = Reader::open(skin, layer)?;
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
    let mut newer = Vec::with_capacity(frames);
    reader.wait_newer(Duration::from_secs(5))?;
    for _ in 0..frames {
        let published = reader.wait_newer(Duration::from_secs(5))?.published_ns();
        newer.push(skinware::os::monotonic_ns().saturating_sub(published));
    }

    let output = Command::new(&options.python)
        .args(["-c", SCRIPT, skin, layer, &reads.to_string(), &frames.to_string()])
        .output()
        .with_context(|| format!("cannot run {}", options.python))?;
    if !output.status.success() {
        bail!("the Python side failed: {}", String::from_utf8_lossy(&output.stderr));
    }
    let mut python: PythonSide = serde_json::from_slice(&output.stdout).context("the Python side's JSON")?;
    Ok(PythonReport {
        sensors: SENSORS,
        rate_hz,
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
