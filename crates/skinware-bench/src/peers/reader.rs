//! The reader processes of `skin bench peers` (the `bench-peer-reader` role).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use skinware::RtOptions;

#[cfg(feature = "iceoryx2")]
use super::iceoryx2_reader;
use super::setup::{PeerReaderArgs, PeerReaderSamples, SYSTEMS};
use super::{rwlock_reader, skinware_reader};

/// A waiting reader process: for every frame, the time from its publication
/// to holding a private copy of it.
pub fn run_reader(args: &PeerReaderArgs) -> Result<()> {
    enter_scheduler(&args.mode)?;
    // A safety deadline; the parent normally stops us by closing our stdin.
    let deadline = skinware::os::monotonic_ns() + (args.seconds * 1e9) as u64;
    let stopped = stop_when_stdin_closes();
    let running = || !stopped.load(Ordering::Relaxed) && skinware::os::monotonic_ns() < deadline;
    let mut samples = PeerReaderSamples::default();
    let busy = args.mode == "busy";
    match args.system.as_str() {
        "skinware" if busy => skinware_reader::read_busy(&args.name, running, &mut samples)?,
        "rwlock" if busy => rwlock_reader::read_busy(&args.name, running, &mut samples)?,
        "skinware" | "skinware-spin" => skinware_reader::read_waiting(&args.system, &args.name, running, &mut samples)?,
        "rwlock" => rwlock_reader::read_waiting(&args.name, deadline, running, &mut samples)?,
        #[cfg(feature = "iceoryx2")]
        "iceoryx2" => iceoryx2_reader::read_waiting(&args.name, busy, running, &mut samples)?,
        other => bail!("unknown system {other:?}; use one of {SYSTEMS:?}"),
    }
    print_debug(args, &samples);
    std::fs::write(&args.out, serde_json::to_vec(&samples)?)?;
    Ok(())
}

/// Puts this process in the scheduler of its `mode`.
fn enter_scheduler(mode: &str) -> Result<()> {
    // Waiting readers are real-time, as a control loop would be. Busy readers
    // never sleep, so they stay in the normal scheduler: under SCHED_FIFO
    // they would run one after another instead of side by side.
    if mode == "busy" {
        skinware::os::set_normal_scheduling().context("cannot leave the real-time scheduler")?;
    } else {
        let _ = RtOptions { fifo_priority: Some(70), ..RtOptions::default() }.apply();
    }
    Ok(())
}

/// A flag set once stdin closes: how the parent stops its readers.
fn stop_when_stdin_closes() -> Arc<AtomicBool> {
    let stopped = Arc::new(AtomicBool::new(false));
    let flag = stopped.clone();
    std::thread::spawn(move || {
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
        flag.store(true, Ordering::Relaxed);
    });
    stopped
}

/// With `SKINWARE_BENCH_DEBUG` set, prints what this reader did and its CPU time.
fn print_debug(args: &PeerReaderArgs, samples: &PeerReaderSamples) {
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
}
