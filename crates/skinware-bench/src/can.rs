//! `skin bench can`: a CAN skin on the real driver path, measured end to end.
//! Emulated MTB boards stream over an SLCAN pseudo-terminal into the CAN
//! driver (SLCAN codec, `icub-mtb` decoder) and an as-soon-as-available reader
//! copies every frame. Each period the boards send, their taxels carry the
//! period's number (modulo 200), so a reader's frame says which sending it
//! came from: the latency is from the boards' write of that period to the
//! reader's copy. It includes the wait for the driver's next acquisition,
//! which is periodic and not synchronised with the boards (0 to 1 period):
//! that is what a reader of a real CAN skin sees.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{DriverHandler, HandlerOptions, Reader, ReaderOptions};
use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
use skinware_drivers::can::icub_mtb::{Board, BoardSettings};
use skinware_drivers::virtual_skin::BASELINE;
use skinware_emulate::{MtbBoards, MtbFaults, SlcanDevice, run_mtb};

use crate::measure::Percentiles;

/// Options of `skin bench can`.
#[derive(Clone, Debug)]
pub struct CanOptions {
    /// CI-sized: 2 s instead of 20 s.
    pub quick: bool,
    /// Where `can.json` goes.
    pub out: PathBuf,
    /// Seconds of measurement.
    pub seconds: Option<f64>,
}

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

/// Runs the measurement, prints it and writes `can.json`.
pub fn run(options: &CanOptions) -> Result<CanReport> {
    let seconds = options.seconds.unwrap_or(if options.quick { 2.0 } else { 20.0 });
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let (boards, triangles, period_ms) = (4u8, 16u8, 20u8);
    let taxels = usize::from(boards) * usize::from(triangles) * 12;

    // The boards: each period's values carry its number; its send time is kept.
    const REMEMBERED: usize = 256;
    let sent_ns: Arc<Vec<AtomicU64>> = Arc::new((0..REMEMBERED).map(|_| AtomicU64::new(0)).collect());
    let periods = Arc::new(AtomicU64::new(0));
    let mut device = SlcanDevice::new().context("cannot open a pseudo-terminal for the emulated boards")?;
    let url = device.url();
    let stop_boards = Arc::new(AtomicBool::new(false));
    let bus_frames = {
        let (sent_ns, periods, stop) = (sent_ns.clone(), periods.clone(), stop_boards.clone());
        std::thread::spawn(move || {
            let mut emulated =
                MtbBoards::new(boards, triangles, Duration::from_millis(u64::from(period_ms)), MtbFaults::default());
            let touch = move |_t: f64, responses: &mut [u16]| {
                let period = periods.fetch_add(1, Ordering::Relaxed);
                sent_ns[period as usize % REMEMBERED].store(skinware::os::monotonic_ns(), Ordering::Relaxed);
                let value = BASELINE + 100 * (period % 200) as u16;
                responses.iter_mut().for_each(|r| *r = value);
            };
            run_mtb(&mut emulated, &mut device, &touch, None, &|| stop.load(Ordering::Relaxed)).unwrap_or(0)
        })
    };

    // The driver, as `skin run` would run it.
    let dir = std::env::temp_dir().join(format!("skinware-bench-can-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let driver = CanDriver::new(CanDriverConfig {
        name: "bench-can".into(),
        layer: "skin".into(),
        interface: url,
        protocol: Protocol::IcubMtb {
            boards: (1..=boards).map(|address| Board { address, triangles: (0..triangles).collect() }).collect(),
            settings: BoardSettings { period_ms, no_load: 240, ..BoardSettings::default() },
        },
        rate_hz: 1000.0 / f64::from(period_ms),
        rt: skinware::RtOptions { fifo_priority: Some(80), ..skinware::RtOptions::default() },
    })
    .map_err(anyhow::Error::msg)?;
    let handler = DriverHandler::start(
        "bench",
        Box::new(driver),
        &HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() },
    )?;
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
    let bus_periods_before = periods.load(Ordering::Relaxed);
    let started = Instant::now();
    let latencies = Mutex::new(Vec::new());
    let mut skipped = 0;
    while started.elapsed().as_secs_f64() < seconds {
        let Ok(frame) = reader.wait_newer(Duration::from_millis(200)) else { continue };
        let copied = skinware::os::monotonic_ns();
        skipped += frame.skipped();
        // The number of the period these values were sent in (mod 200) …
        let residue = u64::from(frame.responses()[0].saturating_sub(15)) % 200;
        // … and the latest period with it sent before this copy.
        let newest = periods.load(Ordering::Relaxed);
        let sending = (newest.saturating_sub(REMEMBERED as u64 - 1)..newest)
            .rev()
            .find(|&p| p % 200 == residue && sent_ns[p as usize % REMEMBERED].load(Ordering::Relaxed) <= copied);
        if let Some(p) = sending {
            let sent = sent_ns[p as usize % REMEMBERED].load(Ordering::Relaxed);
            skinware::lock(&latencies).push(copied.saturating_sub(sent) / 1000);
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    let after = reader.writer_stats();
    let bus_periods = periods.load(Ordering::Relaxed) - bus_periods_before;
    handler.stop();
    stop_boards.store(true, Ordering::Relaxed);
    let _ = bus_frames.join();
    let _ = std::fs::remove_dir_all(&dir);
    let mut latencies = latencies.into_inner().unwrap_or_else(|e| e.into_inner());
    let report = CanReport {
        taxels,
        period_ms,
        bus_frames_per_s: bus_periods as f64 * 2.0 * f64::from(boards) * f64::from(triangles) / elapsed,
        layer_frames_per_s: (after.frames - before.frames) as f64 / elapsed,
        latency_us: Percentiles::of(&mut latencies),
        reader_skipped: skipped,
        faults: after.faults - before.faults,
    };
    println!(
        "skin bench can: {} MTB boards x {} triangles ({} taxels), {} ms period, SLCAN on a pseudo-terminal, {seconds} s",
        boards, triangles, taxels, period_ms
    );
    println!("  bus: {:.0} CAN frames/s; layer: {:.1} frames/s", report.bus_frames_per_s, report.layer_frames_per_s);
    let l = &report.latency_us;
    println!(
        "  boards' write -> reader's copy: p50 {} us, p99 {} us, max {} us ({} frames; a periodic acquisition adds 0..{} ms)",
        l.p50, l.p99, l.max, l.samples, period_ms
    );
    println!("  reader skipped {} frames; {} failed acquisitions", report.reader_skipped, report.faults);
    let json = options.out.join("can.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&report)?)?;
    println!("wrote {}", json.display());
    Ok(report)
}
