//! `skin echo LAYER`: print a layer's frames, in any reader mode.

use std::io::Write;
use std::time::Duration;

use anyhow::{Context, Result};
use skinware::{Error, Reader, ReaderOptions, Ticker};

/// How `echo` reads.
#[derive(Clone, Copy, clap::ValueEnum)]
enum Mode {
    /// At a fixed rate (--rate), absolute time.
    Periodic,
    /// Every frame, as soon as it is published.
    Asap,
    /// Ask for a frame (a sporadic writer acquires one) every period.
    Request,
}

/// Arguments of `skin echo`.
#[derive(clap::Args)]
pub struct Args {
    /// The layer (channel) name.
    layer: String,
    /// The skin.
    #[arg(long, default_value = "default")]
    skin: String,
    /// Reader mode.
    #[arg(long, value_enum, default_value = "asap")]
    mode: Mode,
    /// Rate of the periodic and request modes, Hz.
    #[arg(long, default_value_t = 10.0)]
    rate: f64,
    /// Stop after this many frames.
    #[arg(long)]
    count: Option<u64>,
    /// Print every response, not just a summary.
    #[arg(long)]
    full: bool,
    /// Seconds to wait for a frame before reporting the writer's state.
    #[arg(long, default_value_t = 2.0)]
    timeout: f64,
}

/// Runs `skin echo`.
pub fn run(args: &Args) -> Result<()> {
    let options = ReaderOptions { allow_gone: true, ..ReaderOptions::default() };
    let mut reader = Reader::open_with(&args.skin, &args.layer, &options)
        .with_context(|| format!("cannot attach to layer {}/{}", args.skin, args.layer))?;
    let timeout = Duration::from_secs_f64(args.timeout.clamp(0.001, 86_400.0));
    let mut ticker = Ticker::from_hz(args.rate.clamp(0.001, 100_000.0));
    let mut out = std::io::stdout().lock();
    let mut printed = 0;
    while args.count.is_none_or(|count| printed < count) {
        let result = match args.mode {
            Mode::Periodic => reader.next_periodic(&mut ticker),
            Mode::Asap => reader.wait_newer(timeout),
            Mode::Request => {
                let _ = ticker.wait(reader.stop_signal());
                reader.request(timeout)
            }
        };
        match result {
            Ok(frame) => {
                let responses = frame.responses();
                let (min, max) = responses.iter().fold((u16::MAX, 0), |(lo, hi), &r| (lo.min(r), hi.max(r)));
                let mean = responses.iter().map(|&r| f64::from(r)).sum::<f64>() / responses.len().max(1) as f64;
                write!(
                    out,
                    "seq {} acquired {} ns status {:#x} skipped {} sensors {} min {min} mean {mean:.1} max {max}",
                    frame.seq(),
                    frame.acquired_ns(),
                    frame.status().0,
                    frame.skipped(),
                    responses.len()
                )?;
                if args.full {
                    write!(out, " responses {responses:?}")?;
                }
                writeln!(out)?;
                printed += 1;
            }
            Err(Error::Timeout { .. }) | Err(Error::NoFrameYet { .. }) => {
                writeln!(out, "no new frame; writer is {}", reader.writer_state())?;
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}
