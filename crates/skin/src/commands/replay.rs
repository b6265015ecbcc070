//! `skin replay FILE.mcap`: a recording back into live channels (a split
//! recording's parts one after the other).

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use skinware_record::{AtEnd, Replay, ReplayOptions};

/// Arguments of `skin replay`.
#[derive(clap::Args)]
pub struct Args {
    /// The recording: one file, or the name it was recorded under with
    /// `--split-seconds`/`--split-mb` (`run.mcap` plays `run_000.mcap`,
    /// `run_001.mcap`, ... in turn), or its parts, in order.
    #[arg(required = true, num_args = 1..)]
    files: Vec<PathBuf>,
    /// Publish under this skin name (default: the recorded one).
    #[arg(long)]
    skin: Option<String>,
    /// Playback speed: 2 plays twice as fast.
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Start again at the end, until Ctrl-C.
    #[arg(long = "loop")]
    loop_: bool,
    /// At the end, keep the channels (paused, with their last frames) until Ctrl-C.
    #[arg(long, conflicts_with = "loop_")]
    hold: bool,
    /// Start this many seconds into the recording.
    #[arg(long)]
    from: Option<f64>,
    /// Stop this many seconds into the recording.
    #[arg(long)]
    to: Option<f64>,
    /// Replay only the layers (for live services to run on them).
    #[arg(long)]
    no_services: bool,
    /// Create the channels, then wait this many seconds before the first frame.
    #[arg(long, default_value_t = 0.0)]
    start_delay: f64,
    /// Who may read the channels: owner, group or everyone.
    #[arg(long, default_value = "owner")]
    access: String,
    /// SCHED_FIFO priority of the publishing thread (needs root or CAP_SYS_NICE).
    #[arg(long)]
    fifo_priority: Option<u8>,
    /// Keep idle CPUs able to wake within this many µs while replaying (0:
    /// polling; needs root). In a virtual machine a halted vCPU can wake
    /// milliseconds late; this keeps frames on time at the cost of idle CPUs spinning.
    #[arg(long)]
    cpu_wake_latency_us: Option<u32>,
    /// Print the report as JSON.
    #[arg(long)]
    json: bool,
}

/// The files to replay, in order (a split recording's parts found from the
/// name it was recorded under), and how to name them in messages.
fn recording_files(given: &[PathBuf]) -> Result<(Vec<PathBuf>, String)> {
    let parts = match given {
        [one] => skinware_record::recording_parts(one),
        several => several.to_vec(),
    };
    let named = match parts.as_slice() {
        [one] => one.display().to_string(),
        [first, .., last] => format!("{} to {} ({} parts)", first.display(), last.display(), parts.len()),
        [] => anyhow::bail!("give the recording to replay: skin replay FILE.mcap"),
    };
    Ok((parts, named))
}

/// Runs `skin replay`.
pub fn run(args: &Args) -> Result<()> {
    if !args.start_delay.is_finite() {
        anyhow::bail!("--start-delay {} must be a number of seconds", args.start_delay);
    }
    let access = match args.access.as_str() {
        "owner" => skinware::Access::Owner,
        "group" => skinware::Access::Group,
        "everyone" => skinware::Access::Everyone,
        other => anyhow::bail!("--access {other:?}: use owner, group or everyone"),
    };
    let options = ReplayOptions {
        skin: args.skin.clone(),
        speed: args.speed,
        at_end: if args.loop_ {
            AtEnd::Loop
        } else if args.hold {
            AtEnd::Hold
        } else {
            AtEnd::Exit
        },
        from_s: args.from,
        to_s: args.to,
        services: !args.no_services,
        start_delay: Duration::from_secs_f64(args.start_delay.clamp(0.0, 3600.0)),
        access,
        rt: skinware::RtOptions {
            fifo_priority: args.fifo_priority,
            cpu_wake_latency_us: args.cpu_wake_latency_us,
            ..Default::default()
        },
        ..ReplayOptions::default()
    };
    let (parts, file) = recording_files(&args.files)?;
    let mut replay = match Replay::open_parts(&parts, options) {
        Ok(replay) => replay,
        Err(e @ skinware_record::RecordError::Channel(skinware::Error::Busy { .. })) => {
            return Err(anyhow::Error::new(e).context(format!(
                "cannot replay {}: that skin is running here; stop it, or replay beside it under another name \
                 (--skin replayed)",
                file
            )));
        }
        Err(e) => return Err(anyhow::Error::new(e).context(format!("cannot replay {file}"))),
    };
    eprintln!(
        "replaying {file} as skin {} (recorded as {}): {}; Ctrl-C stops",
        replay.skin(),
        replay.recorded_skin(),
        replay.channels().join(", ")
    );
    let stop = replay.stop_signal().clone();
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])
        .context("cannot install signal handlers")?;
    std::thread::spawn(move || {
        if signals.forever().next().is_some() {
            stop.stop();
        }
    });
    let report = replay.run().with_context(|| format!("replaying {file} stopped"))?;
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &report)?;
        writeln!(out)?;
        return Ok(());
    }
    writeln!(
        out,
        "replayed {} frames in {:.1} s ({} pass(es)); published after their scheduled time by p50 {:.3} ms, p99 {:.3} ms, max {:.3} ms",
        report.frames,
        report.seconds,
        report.passes,
        report.late_p50_ns as f64 / 1e6,
        report.late_p99_ns as f64 / 1e6,
        report.late_max_ns as f64 / 1e6
    )?;
    for (channel, frames) in &report.channels {
        writeln!(out, "  {channel}: {frames} frames")?;
    }
    Ok(())
}
