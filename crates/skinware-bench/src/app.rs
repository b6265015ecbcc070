//! An application process of the experiments: reads every given layer, each
//! in its own thread, and writes the time each read took.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use skinware::{Reader, Ticker};

use crate::run_options::parse_helper_seconds;

/// Arguments of the `bench-app` role.
#[derive(Clone, Debug, clap::Args)]
pub struct AppArgs {
    /// Skin name.
    #[arg(long)]
    pub skin: String,
    /// Layers to read.
    #[arg(long, value_delimiter = ',')]
    pub layers: Vec<String>,
    /// `periodic` (random 10-100 Hz per layer, seeded) or `asap`.
    #[arg(long, default_value = "periodic")]
    pub mode: String,
    /// How long to read.
    #[arg(long, value_parser = parse_helper_seconds)]
    pub seconds: f64,
    /// Seed of the random rates.
    #[arg(long)]
    pub seed: u64,
    /// Where to write the samples (JSON).
    #[arg(long)]
    pub out: PathBuf,
}

/// What an application measured.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct AppSamples {
    /// Per layer: the time to obtain one frame, ns.
    pub read_ns: Vec<Vec<u64>>,
    /// Per layer: the reader's rate, Hz (0 for asap).
    pub rate_hz: Vec<f64>,
    /// Per layer: from the frame's acquisition to this process holding its
    /// copy, ns (for a periodic reader this includes the frame's age).
    #[serde(default)]
    pub latency_ns: Vec<Vec<u64>>,
    /// When this process had opened every layer and started reading, and
    /// its deadline to stop (CLOCK_MONOTONIC), ns.
    pub window_ns: [u64; 2],
    /// Per layer: frames a reader that waits for every frame found it had
    /// missed (0 for a periodic reader, which reads the newest by design).
    #[serde(default)]
    pub skipped: Vec<u64>,
    /// Per layer: the frames it obtained and when (CLOCK_MONOTONIC, ns),
    /// beside `latency_ns`, so that a bench can keep those of its window.
    #[serde(default)]
    pub read_at_ns: Vec<Vec<u64>>,
    /// The CPU time of this process, from its start to its end, ns.
    #[serde(default)]
    pub cpu_ns: u64,
}

/// What one reader thread of an application obtained.
struct Read {
    samples: Vec<u64>,
    latency: Vec<u64>,
    read_at: Vec<u64>,
    skipped: u64,
    rate_hz: f64,
}

/// Runs the application role.
pub fn run(args: &AppArgs) -> Result<()> {
    let mut readers = Vec::new();
    for layer in &args.layers {
        readers.push(Reader::open(&args.skin, layer).with_context(|| format!("application cannot open {layer}"))?);
    }
    let duration = Duration::from_secs_f64(args.seconds);
    let started_ns = skinware::os::monotonic_ns();
    let deadline = Instant::now() + duration;
    let mut threads = Vec::new();
    for (l, mut reader) in readers.into_iter().enumerate() {
        let mut seed = args.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (l as u64 + 1);
        seed ^= seed >> 29;
        let rate_hz = if args.mode == "asap" { 0.0 } else { 10.0 + (seed % 9001) as f64 / 100.0 };
        threads.push(std::thread::spawn(move || -> Read {
            let mut samples = Vec::with_capacity(8192);
            let mut latency = Vec::with_capacity(8192);
            let mut read_at = Vec::with_capacity(8192);
            let mut skipped = 0;
            let mut ticker = Ticker::from_hz(rate_hz.max(1.0));
            while Instant::now() < deadline {
                let (read_ns, acquired_ns) = if rate_hz == 0.0 {
                    match reader.wait_newer(Duration::from_millis(200)) {
                        Ok(frame) => {
                            let acquired_ns = frame.acquired_ns();
                            skipped += frame.skipped();
                            (reader.stats().read_ns_last, acquired_ns)
                        }
                        Err(_) => continue,
                    }
                } else {
                    if ticker.wait(reader.stop_signal()).is_none() {
                        break;
                    }
                    let started = skinware::os::monotonic_ns();
                    match reader.latest() {
                        Ok(frame) => (skinware::os::monotonic_ns() - started, frame.acquired_ns()),
                        Err(_) => continue,
                    }
                };
                samples.push(read_ns);
                let now = skinware::os::monotonic_ns();
                latency.push(now.saturating_sub(acquired_ns));
                read_at.push(now);
            }
            Read { samples, latency, read_at, skipped, rate_hz }
        }));
    }
    let window_ns = [started_ns, started_ns + duration.as_nanos() as u64];
    let mut result = AppSamples { window_ns, ..AppSamples::default() };
    for thread in threads {
        let read = thread.join().map_err(|_| anyhow::anyhow!("reader thread panicked"))?;
        result.read_ns.push(read.samples);
        result.latency_ns.push(read.latency);
        result.read_at_ns.push(read.read_at);
        result.skipped.push(read.skipped);
        result.rate_hz.push(read.rate_hz);
    }
    let cpu = rustix::time::clock_gettime(rustix::time::ClockId::ProcessCPUTime);
    result.cpu_ns = cpu.tv_sec as u64 * 1_000_000_000 + cpu.tv_nsec as u64;
    std::fs::write(&args.out, serde_json::to_vec(&result)?)
        .with_context(|| format!("writing {}", args.out.display()))?;
    Ok(())
}
