//! The reader processes of `skin bench peers` (the `bench-peer-reader` role).

use std::time::Duration;

use anyhow::{Context, Result, bail};
use skinware::{Reader, RtOptions};

#[cfg(feature = "iceoryx2")]
use super::setup::SENSORS;
use super::setup::{ANTICIPATE, FRAME_BYTES, PeerReaderArgs, PeerReaderSamples, SYSTEMS};
use crate::rwlock_peer::RwLockChannel;

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
