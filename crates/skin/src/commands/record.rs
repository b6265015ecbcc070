//! `skin record OUT.mcap`: every frame of a running skin into an MCAP file;
//! `skin record --recover FILE`: a finished copy of a file whose recorder was
//! killed.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use skinware_record::{Compression, RecordOptions, RecordSummary, Recorder, ServiceChoice, Split};

/// Arguments of `skin record`.
#[derive(clap::Args)]
pub struct Args {
    /// The file to write (never overwritten). With --recover, where the
    /// finished copy goes (default: FILE with `.recovered.mcap`).
    out: Option<PathBuf>,
    /// The skin.
    #[arg(long, default_value = "default")]
    skin: String,
    /// Only these layers (comma-separated); all by default.
    #[arg(long, value_delimiter = ',')]
    layers: Option<Vec<String>>,
    /// Record services too: all of them, or those named (comma-separated).
    #[arg(long, num_args = 0..=1, default_missing_value = "*", value_delimiter = ',')]
    services: Option<Vec<String>>,
    /// Stop after this many seconds (else at Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Map images per second (0: none).
    #[arg(long, default_value_t = 4.0)]
    map_hz: f64,
    /// Width of the map image, pixels.
    #[arg(long, default_value_t = 480)]
    map_width: usize,
    /// Point clouds and contact markers per second for ROS tools (Foxglove,
    /// rviz2): copies of the newest frames, beside every frame as
    /// skinware's own message. 0: none, and no /diagnostics or /tf_static.
    #[arg(long, default_value_t = 10.0)]
    ros2_hz: f64,
    /// The frame every link hangs from in /tf_static (the robot's root).
    #[arg(long, default_value = "base_link")]
    root_frame: String,
    /// Chunk compression.
    #[arg(long, value_enum, default_value = "zstd")]
    compression: CompressionArg,
    /// SCHED_FIFO priority of the threads that read the frames (0: the
    /// normal scheduler). Above applications and below drivers, they cannot
    /// be kept waiting by the compression, which stays in the normal scheduler.
    /// Needs root or an rtprio limit; refused, they read in the normal scheduler.
    #[arg(long, default_value_t = skinware_record::recorder::DEFAULT_READER_PRIORITY)]
    fifo_priority: u8,
    /// Go on in a new file every this many seconds (at least 1): OUT.mcap
    /// is written as OUT_000.mcap, OUT_001.mcap, ..., each a whole MCAP
    /// file. A long recording needs it to keep the recorder's memory flat.
    #[arg(long, value_name = "SECONDS")]
    split_seconds: Option<f64>,
    /// Go on in a new file once one holds this many MB (at least 1), as
    /// --split-seconds does.
    #[arg(long, value_name = "MB")]
    split_mb: Option<f64>,
    /// Wait up to this many seconds for the skin to come up before recording.
    #[arg(long)]
    wait: Option<f64>,
    /// Stop when every recorded channel's writer is gone (the skin stopped).
    #[arg(long)]
    until_gone: bool,
    /// Print the summary as JSON.
    #[arg(long)]
    json: bool,
    /// Read FILE up to its last complete chunk and write a finished copy.
    #[arg(long, value_name = "FILE")]
    recover: Option<PathBuf>,
}

/// `--compression` (also `skin bench kilohertz --record-compression`).
#[derive(Clone, Copy, clap::ValueEnum)]
pub(crate) enum CompressionArg {
    Zstd,
    Lz4,
    None,
}

impl CompressionArg {
    /// The library's compression.
    pub(crate) fn library(self) -> Compression {
        match self {
            CompressionArg::Zstd => Compression::Zstd,
            CompressionArg::Lz4 => Compression::Lz4,
            CompressionArg::None => Compression::None,
        }
    }
}

/// Runs `skin record`.
pub fn run(args: &Args) -> Result<()> {
    if let Some(input) = &args.recover {
        return recover(input, args);
    }
    let Some(out) = &args.out else {
        bail!(
            "name the file to write: `skin record OUT.mcap` (or `skin record --recover FILE` to finish a broken one)"
        );
    };
    let options = record_options(args)?;
    let shutdown = super::run::shutdown_on_signals()?;
    if let Some(wait) = args.wait {
        if !(wait.is_finite() && wait >= 0.0) {
            bail!("--wait {wait} must be a number of seconds");
        }
        wait_for_skin(&args.skin, Duration::from_secs_f64(wait.min(86_400.0)), &shutdown)?;
    }
    let recorder = match Recorder::start(out, options) {
        Ok(recorder) => recorder,
        // Which skins there are, for a skin name that is not one of them.
        Err(_) if skinware::list_skin_channels(&skinware::shm::segment_dir(), &args.skin)?.is_empty() => {
            return Err(crate::skins::missing_skin(&args.skin)).with_context(|| {
                format!("cannot record skin {} (`skin record --wait 60` waits for it to start)", args.skin)
            });
        }
        Err(e) => return Err(e).with_context(|| format!("cannot record skin {}", args.skin)),
    };
    let channels = recorder.channels();
    let first = recorder.parts().first().map_or_else(|| out.display().to_string(), |p| p.display().to_string());
    let then = if args.split_seconds.is_some() || args.split_mb.is_some() { " and the parts after it" } else { "" };
    eprintln!(
        "recording {} channel(s) of skin {} into {first}{then}: {}",
        channels.len(),
        args.skin,
        channels.join(", ")
    );
    record_until_done(&recorder, args, &shutdown);
    let summary = recorder.finish().with_context(|| format!("recording {} stopped", out.display()))?;
    print_summary(&summary, args.json)
}

/// The recorder's options from the command line, checked.
fn record_options(args: &Args) -> Result<RecordOptions> {
    if let Some(seconds) = args.seconds
        && !(seconds.is_finite() && seconds > 0.0 && seconds < 1e9)
    {
        bail!("--seconds {seconds} must be a positive number");
    }
    if !(args.map_hz.is_finite() && args.map_hz >= 0.0) {
        bail!("--map-hz {} must be 0 (no map) or more", args.map_hz);
    }
    if !(args.ros2_hz.is_finite() && (args.ros2_hz == 0.0 || (0.1..=60.0).contains(&args.ros2_hz))) {
        bail!("--ros2-hz {} must be 0 (no messages for ROS tools) or from 0.1 to 60", args.ros2_hz);
    }
    if args.root_frame.is_empty() || args.root_frame.chars().any(char::is_whitespace) {
        bail!("--root-frame {:?} must be one word, the name of a TF frame (such as base_link)", args.root_frame);
    }
    if args.fifo_priority > 99 {
        bail!("--fifo-priority {} must be 0 (the normal scheduler) or 1 to 99", args.fifo_priority);
    }
    let split = split(args.split_seconds, args.split_mb)?;
    let services = match &args.services {
        None => ServiceChoice::None,
        Some(names) if names.iter().any(|n| n == "*") => ServiceChoice::All,
        Some(names) => ServiceChoice::Named(names.clone()),
    };
    Ok(RecordOptions {
        skin: args.skin.clone(),
        layers: args.layers.clone(),
        services,
        map_hz: args.map_hz,
        map_width: args.map_width,
        ros2_hz: args.ros2_hz,
        root_frame: args.root_frame.clone(),
        compression: args.compression.library(),
        reader_priority: args.fifo_priority,
        command: std::env::args().collect::<Vec<_>>().join(" "),
        split,
        ..RecordOptions::default()
    })
}

/// The split asked for by `--split-seconds` and `--split-mb`, checked.
fn split(seconds: Option<f64>, mb: Option<f64>) -> Result<Option<Split>> {
    if let Some(seconds) = seconds
        && !(seconds.is_finite() && (1.0..1e9).contains(&seconds))
    {
        bail!(
            "--split-seconds {seconds} must be a number of seconds, 1 or more (a part is closed at a flush, once a second)"
        );
    }
    if let Some(mb) = mb
        && !(mb.is_finite() && (1.0..1e12).contains(&mb))
    {
        bail!("--split-mb {mb} must be a number of megabytes, 1 or more");
    }
    if seconds.is_none() && mb.is_none() {
        return Ok(None);
    }
    Ok(Some(Split { max_bytes: mb.map(|mb| (mb * 1e6) as u64), max_duration: seconds.map(Duration::from_secs_f64) }))
}

/// Records until Ctrl-C, `--seconds`, `--until-gone` or a failure, showing
/// progress (one line rewritten on a terminal, a line every 10 s in a log).
fn record_until_done(recorder: &Recorder, args: &Args, shutdown: &std::sync::atomic::AtomicBool) {
    let started = Instant::now();
    let live = std::io::stderr().is_terminal();
    let mut next_line = Instant::now() + Duration::from_secs(10);
    loop {
        std::thread::sleep(Duration::from_millis(200));
        if shutdown.load(Ordering::Relaxed) || recorder.has_failed() {
            break;
        }
        if args.seconds.is_some_and(|s| started.elapsed().as_secs_f64() >= s) {
            break;
        }
        if args.until_gone && recorder.all_gone() {
            eprintln!("every recorded channel's writer is gone: stopping");
            break;
        }
        let p = recorder.progress();
        let line = format!(
            "{:7.1} s  {:>9} frames  {:8.1} MB ({:.1} MB on disk)  lost {}",
            p.seconds,
            p.frames,
            p.message_bytes as f64 / 1e6,
            p.file_bytes as f64 / 1e6,
            p.lost
        );
        if live {
            eprint!("\r{line}  ");
        } else if Instant::now() >= next_line {
            eprintln!("{line}");
            next_line += Duration::from_secs(10);
        }
    }
    if live {
        eprintln!();
    }
}

/// The recording's summary, as a table or JSON, on stdout.
fn print_summary(summary: &RecordSummary, json: bool) -> Result<()> {
    let mut stdout = std::io::stdout().lock();
    if json {
        serde_json::to_writer_pretty(&mut stdout, summary)?;
        writeln!(stdout)?;
        return Ok(());
    }
    writeln!(
        stdout,
        "{}: {:.1} s, {} frames ({:.0}/s), {:.1} MB of messages ({:.2} MB/s), {:.1} MB on disk ({}), {} map images, lost {}",
        summary.path.display(),
        summary.seconds,
        summary.frames,
        summary.frames_per_s,
        summary.message_bytes as f64 / 1e6,
        summary.mb_per_s,
        summary.file_bytes as f64 / 1e6,
        summary.compression,
        summary.images,
        summary.lost
    )?;
    if let [first, .., last] = summary.parts.as_slice() {
        writeln!(stdout, "  in {} files, {} to {}", summary.parts.len(), first.display(), last.display())?;
    }
    for (name, channel) in &summary.channels {
        let waits = match channel.file_waits {
            0 => String::new(),
            n => format!(", waited {n} times for the file (the disk or the compression was behind)"),
        };
        writeln!(
            stdout,
            "  {name} ({}): {} frames, lost {} in {} gaps, {} faulted{waits}",
            channel.kind, channel.frames, channel.lost, channel.gaps, channel.faulted
        )?;
    }
    if summary.reader_priority > 0 && !summary.readers_realtime {
        writeln!(
            stdout,
            "  the readers ran in the normal scheduler (SCHED_FIFO {} refused: run as root or raise the user's \
             rtprio limit)",
            summary.reader_priority
        )?;
    }
    Ok(())
}

/// Waits until the skin is up: every layer of its published geometry
/// running, and no new channel for a second (its services start after its
/// layers). A skin without a published geometry (bare writers) is up once a
/// channel runs and none has appeared for a second.
fn wait_for_skin(skin: &str, limit: Duration, shutdown: &std::sync::atomic::AtomicBool) -> Result<()> {
    let dir = skinware::shm::segment_dir();
    let started = Instant::now();
    let mut known: Vec<String> = Vec::new();
    let mut stable_since = Instant::now();
    loop {
        let running: Vec<String> = skinware::list_skin_channels(&dir, skin)
            .unwrap_or_default()
            .into_iter()
            .filter(|c| c.skin == skin && c.state != skinware::WriterState::Gone)
            .map(|c| c.channel)
            .collect();
        if running != known {
            known = running;
            stable_since = Instant::now();
        }
        let layers_up = match skinware_geometry::SkinGeometry::open_in(&dir, skin) {
            Ok(geometry) => geometry.layers.iter().all(|l| known.contains(&l.name)),
            Err(_) => !known.is_empty(),
        };
        if layers_up && stable_since.elapsed() >= Duration::from_secs(1) {
            return Ok(());
        }
        if started.elapsed() > limit || shutdown.load(Ordering::Relaxed) {
            bail!(
                "skin {skin} did not come up within {:.1} s (running channels in {}: {})",
                limit.as_secs_f64(),
                dir.display(),
                if known.is_empty() { "none".to_owned() } else { known.join(", ") }
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn recover(input: &Path, args: &Args) -> Result<()> {
    let out = args.out.clone().unwrap_or_else(|| {
        let stem = input.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        input.with_file_name(format!("{stem}.recovered.mcap"))
    });
    let recovered = skinware_record::file::recover(input, &out, args.compression.library().mcap())?;
    let mut stdout = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut stdout, &recovered)?;
        writeln!(stdout)?;
        return Ok(());
    }
    let ending = match recovered.input_ending {
        skinware_record::file::Ending::Finished => "it was finished: nothing was missing".to_owned(),
        skinware_record::file::Ending::Truncated => {
            "it was cut short (the recorder was killed, or the disk filled): every complete chunk was kept".to_owned()
        }
        skinware_record::file::Ending::Damaged => {
            format!("it is damaged: kept what came before ({})", recovered.stopped_by.as_deref().unwrap_or("?"))
        }
    };
    writeln!(stdout, "{} -> {}: {ending}", input.display(), out.display())?;
    writeln!(
        stdout,
        "  {} messages, {} attachments, {} metadata records; frames up to {}",
        recovered.messages,
        recovered.attachments,
        recovered.metadata,
        format_wall(recovered.last_log_time_ns)
    )?;
    for (channel, frames) in &recovered.frames {
        writeln!(stdout, "  {channel}: {frames} frames")?;
    }
    Ok(())
}

/// A wall-clock time in ns as UTC `YYYY-MM-DD HH:MM:SS.mmm`.
pub fn format_wall(ns: u64) -> String {
    let secs = ns / 1_000_000_000;
    let (days, rest) = (secs / 86_400, secs % 86_400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}.{:03} UTC",
        rest / 3600,
        rest % 3600 / 60,
        rest % 60,
        ns % 1_000_000_000 / 1_000_000
    )
}
