//! `skin top`: live per-layer statistics.

use std::io::Write;
use std::time::Duration;

use anyhow::Result;

/// Arguments of `skin top`.
#[derive(clap::Args)]
pub struct Args {
    /// Only this skin.
    #[arg(long)]
    skin: Option<String>,
    /// Print one sample and exit.
    #[arg(long)]
    once: bool,
    /// Print JSON for scripts (one document per sample).
    #[arg(long)]
    json: bool,
    /// Seconds between samples.
    #[arg(long, default_value_t = 1.0)]
    interval: f64,
}

/// Runs `skin top`.
pub fn run(args: &Args) -> Result<()> {
    let window = Duration::from_secs_f64(args.interval.clamp(0.05, 3600.0));
    let mut first = true;
    loop {
        let layers = crate::layers::gather(args.skin.as_deref(), window)?;
        // A skin that is not there (a typo) is an error, not an empty table;
        // one that goes away later leaves the table empty until it is back.
        if let Some(skin) = args.skin.as_deref()
            && first
            && layers.is_empty()
            && skinware::list_skin_channels(&skinware::shm::segment_dir(), skin)?.is_empty()
        {
            return Err(crate::skins::missing_skin(skin));
        }
        first = false;
        let mut out = std::io::stdout().lock();
        if args.json {
            serde_json::to_writer(&mut out, &serde_json::json!({ "layers": layers }))?;
            writeln!(out)?;
        } else {
            if !args.once {
                write!(out, "\x1b[2J\x1b[H")?;
            }
            writeln!(
                out,
                "{:<24} {:<8} {:>8} {:>9} {:>11} {:>10} {:>10} {:>9} {:>7} {:>8}",
                "LAYER",
                "STATE",
                "SENSORS",
                "RATE Hz",
                "LATENCY us",
                "WRITE us",
                "WORST us",
                "OVERRUNS",
                "FAULTS",
                "RESTARTS"
            )?;
            for l in &layers {
                writeln!(
                    out,
                    "{:<24} {:<8} {:>8} {:>9.1} {:>11.1} {:>10.1} {:>10.1} {:>9} {:>7} {:>8}",
                    format!("{}/{}", l.skin, l.name),
                    l.state,
                    l.sensors,
                    l.rate_hz,
                    l.latency_ns as f64 / 1e3,
                    l.write_ns_mean as f64 / 1e3,
                    l.write_ns_max as f64 / 1e3,
                    l.overruns,
                    l.faults,
                    l.restarts
                )?;
            }
            if layers.is_empty() {
                writeln!(
                    out,
                    "(no layer{}; channels are in {}; {})",
                    args.skin.as_deref().map(|s| format!(" of skin {s}")).unwrap_or_default(),
                    skinware::shm::segment_dir().display(),
                    crate::skins::HOW_TO_START
                )?;
            }
        }
        out.flush()?;
        if args.once {
            return Ok(());
        }
    }
}
