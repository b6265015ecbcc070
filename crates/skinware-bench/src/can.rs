//! `skin bench can`: a CAN skin on the real driver path, measured end to end.
//! Emulated MTB boards stream over an SLCAN pseudo-terminal into the CAN
//! driver (SLCAN codec, `icub-mtb` decoder) and an as-soon-as-available reader
//! copies every frame. Each period the boards send, their taxels carry the
//! period's number (modulo 200), so a reader's frame says which sending it
//! came from: the latency is from the boards' write of that period to the
//! reader's copy. It includes the wait for the driver's next acquisition,
//! which is periodic and not synchronised with the boards (0 to 1 period):
//! that is what a reader of a real CAN skin sees.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{DriverHandler, HandlerOptions, Reader, ReaderOptions};
use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
use skinware_drivers::can::icub_mtb::{Board, BoardSettings};
use skinware_drivers::virtual_skin::BASELINE;
use skinware_emulate::{MtbBoards, MtbFaults, SlcanDevice, run_mtb};

use crate::measure::Percentiles;
use crate::run_options::RunOptions;

/// What `skin bench can` measured.
#[derive(Debug, Serialize)]
pub struct CanReport {
    /// Boards × triangles × 12 taxels.
    pub taxels: usize,
    /// The boards' period, ms.
    pub period_ms: u8,
    /// CAN frames the boards sent per second.
    pub bus_frames_per_s: f64,
    /// Layer frames the driver published per second.
    pub layer_frames_per_s: f64,
    /// The boards' write of a period to the reader's copy, µs.
    pub latency_us: Percentiles,
    /// Layer frames the reader missed (it reads every one it can).
    pub reader_skipped: u64,
    /// Failed acquisitions (a module not complete in time) during the run.
    pub faults: u64,
}

/// The emulated bus's geometry: 4 MTB boards of 16 triangles, every 20 ms.
const BOARDS: u8 = 4;
const TRIANGLES: u8 = 16;
const PERIOD_MS: u8 = 20;
/// Send times remembered, by period number.
const REMEMBERED: usize = 256;

/// The emulated boards' thread and what it shares: each period's values
/// carry its number, and its send time is kept.
struct Boards {
    sent_ns: Arc<Vec<AtomicU64>>,
    periods: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: std::thread::JoinHandle<u64>,
}

impl Boards {
    /// Starts the boards on a new SLCAN pseudo-terminal; returns them and its URL.
    fn start() -> Result<(Boards, String)> {
        let sent_ns: Arc<Vec<AtomicU64>> = Arc::new((0..REMEMBERED).map(|_| AtomicU64::new(0)).collect());
        let periods = Arc::new(AtomicU64::new(0));
        let mut device = SlcanDevice::new().context("cannot open a pseudo-terminal for the emulated boards")?;
        let url = device.url();
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (sent_ns, periods, stop) = (sent_ns.clone(), periods.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut emulated = MtbBoards::new(
                    BOARDS,
                    TRIANGLES,
                    Duration::from_millis(u64::from(PERIOD_MS)),
                    MtbFaults::default(),
                );
                let touch = move |_t: f64, responses: &mut [u16]| {
                    let period = periods.fetch_add(1, Ordering::Relaxed);
                    sent_ns[period as usize % REMEMBERED].store(skinware::os::monotonic_ns(), Ordering::Relaxed);
                    let value = BASELINE + 100 * (period % 200) as u16;
                    responses.iter_mut().for_each(|r| *r = value);
                };
                run_mtb(&mut emulated, &mut device, &touch, None, &|| stop.load(Ordering::Relaxed)).unwrap_or(0)
            })
        };
        Ok((Boards { sent_ns, periods, stop, thread }, url))
    }

    /// When the values of `frame` were sent (the latest period with its
    /// number sent before `copied_ns`), if still remembered.
    fn sent_ns_of(&self, frame: &skinware::Frame<'_>, copied_ns: u64) -> Option<u64> {
        // The number of the period these values were sent in (mod 200) …
        let residue = u64::from(frame.responses()[0].saturating_sub(15)) % 200;
        // … and the latest period with it sent before this copy.
        let newest = self.periods.load(Ordering::Relaxed);
        let sent = |p: u64| self.sent_ns[p as usize % REMEMBERED].load(Ordering::Relaxed);
        (newest.saturating_sub(REMEMBERED as u64 - 1)..newest)
            .rev()
            .find(|&p| p % 200 == residue && sent(p) <= copied_ns)
            .map(sent)
    }

    fn stop(self) {
        self.stop.store(true, Ordering::Relaxed);
        let _ = self.thread.join();
    }
}

/// The CAN driver on `url`, as `skin run` would run it, publishing layer
/// `bench/skin` in `dir`.
fn start_driver(url: String, dir: &std::path::Path) -> Result<DriverHandler> {
    let driver = CanDriver::new(CanDriverConfig {
        name: "bench-can".into(),
        layer: "skin".into(),
        interface: url,
        protocol: Protocol::IcubMtb {
            boards: (1..=BOARDS).map(|address| Board { address, triangles: (0..TRIANGLES).collect() }).collect(),
            settings: BoardSettings { period_ms: PERIOD_MS, no_load: 240, ..BoardSettings::default() },
        },
        rate_hz: 1000.0 / f64::from(PERIOD_MS),
        rt: skinware::RtOptions { fifo_priority: Some(80), ..skinware::RtOptions::default() },
    })?;
    let options = HandlerOptions { dir: Some(dir.to_owned()), ..HandlerOptions::default() };
    Ok(DriverHandler::start("bench", Box::new(driver), &options)?)
}

/// Runs the measurement, prints it and writes `can.json`.
pub fn run(options: &RunOptions) -> Result<CanReport> {
    let seconds = options.seconds_or(2.0, 20.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let taxels = usize::from(BOARDS) * usize::from(TRIANGLES) * 12;
    let (boards, url) = Boards::start()?;
    let dir = std::env::temp_dir().join(format!("skinware-bench-can-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let handler = start_driver(url, &dir)?;
    let mut reader =
        Reader::open_with("bench", "skin", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() })?;
    // Settle: the boards are configured and streaming.
    let settle = Instant::now();
    while reader.wait_newer(Duration::from_millis(500)).is_err() {
        if settle.elapsed() > Duration::from_secs(5) {
            bail!("the CAN layer never published a frame");
        }
    }
    let before = reader.writer_stats();
    let bus_periods_before = boards.periods.load(Ordering::Relaxed);
    let started = Instant::now();
    let mut latencies = Vec::new();
    let mut skipped = 0;
    while started.elapsed().as_secs_f64() < seconds {
        let Ok(frame) = reader.wait_newer(Duration::from_millis(200)) else { continue };
        let copied = skinware::os::monotonic_ns();
        skipped += frame.skipped();
        if let Some(sent) = boards.sent_ns_of(&frame, copied) {
            latencies.push(copied.saturating_sub(sent) / 1000);
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    let after = reader.writer_stats();
    let bus_periods = boards.periods.load(Ordering::Relaxed) - bus_periods_before;
    handler.stop();
    boards.stop();
    let _ = std::fs::remove_dir_all(&dir);
    let report = CanReport {
        taxels,
        period_ms: PERIOD_MS,
        bus_frames_per_s: bus_periods as f64 * 2.0 * f64::from(BOARDS) * f64::from(TRIANGLES) / elapsed,
        layer_frames_per_s: (after.frames - before.frames) as f64 / elapsed,
        latency_us: Percentiles::of(&mut latencies),
        reader_skipped: skipped,
        faults: after.faults - before.faults,
    };
    print_can(&report, seconds);
    let json = options.out.join("can.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&report)?)?;
    println!("wrote {}", json.display());
    Ok(report)
}

fn print_can(report: &CanReport, seconds: f64) {
    println!(
        "skin bench can: {BOARDS} MTB boards x {TRIANGLES} triangles ({} taxels), {PERIOD_MS} ms period, SLCAN on a pseudo-terminal, {seconds} s",
        report.taxels
    );
    println!("  bus: {:.0} CAN frames/s; layer: {:.1} frames/s", report.bus_frames_per_s, report.layer_frames_per_s);
    let l = &report.latency_us;
    println!(
        "  boards' write -> reader's copy: p50 {} us, p99 {} us, max {} us ({} frames; a periodic acquisition adds 0..{PERIOD_MS} ms)",
        l.p50, l.p99, l.max, l.samples
    );
    println!("  reader skipped {} frames; {} failed acquisitions", report.reader_skipped, report.faults);
}
