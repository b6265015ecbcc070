//! `skin info FILE.mcap`: what a recording holds.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Result;
use skinware_record::file::Ending;

use super::record::format_wall;

/// Arguments of `skin info`.
#[derive(clap::Args)]
pub struct Args {
    /// The recording (for a split recording, the name it was recorded
    /// under: each of its parts is described in turn).
    file: PathBuf,
    /// Print JSON for scripts (a split recording's name: an array, a part each).
    #[arg(long)]
    json: bool,
}

/// Runs `skin info`.
pub fn run(args: &Args) -> Result<()> {
    let parts = skinware_record::recording_parts(&args.file);
    let split = parts != [args.file.clone()];
    let infos = parts.iter().map(|part| skinware_record::scan(part)).collect::<Result<Vec<_>, _>>()?;
    let mut out = std::io::stdout().lock();
    if args.json {
        if split {
            serde_json::to_writer_pretty(&mut out, &infos)?;
        } else {
            serde_json::to_writer_pretty(&mut out, &infos[0])?;
        }
        writeln!(out)?;
        return Ok(());
    }
    if split {
        let frames: u64 = infos.iter().map(|info| info.frames).sum();
        writeln!(
            out,
            "{}: recorded in {} parts, {} frames in all ({} to {}); `skin replay {}` plays them in turn",
            args.file.display(),
            infos.len(),
            frames,
            parts[0].display(),
            parts[parts.len() - 1].display(),
            args.file.display()
        )?;
    }
    for info in &infos {
        describe(&mut out, info)?;
    }
    Ok(())
}

/// One file's description, as `skin info` prints it.
fn describe(out: &mut impl Write, info: &skinware_record::RecordingInfo) -> Result<()> {
    let first = info.channels.values().filter(|c| c.frames > 0).map(|c| c.first_ns).min().unwrap_or(0);
    writeln!(out, "{}: skin {}, {:.1} MB", info.path.display(), info.skin, info.file_bytes as f64 / 1e6)?;
    writeln!(
        out,
        "  {:.1} s from {}, {} frames, lost {}{}",
        info.duration_s,
        format_wall(first),
        info.frames,
        info.lost,
        if info.has_geometry { ", geometry included" } else { ", no geometry" }
    )?;
    match info.ending {
        Ending::Finished => {}
        Ending::Truncated => writeln!(
            out,
            "  UNFINISHED: the recorder stopped without closing the file (killed, or the disk filled). \
             Everything above was read from its complete chunks; `skin record --recover {}` writes a finished copy.",
            info.path.display()
        )?,
        Ending::Damaged => writeln!(
            out,
            "  DAMAGED {}: everything above was read from before the damage; `skin record --recover {}` keeps it.",
            info.damage.as_deref().unwrap_or(""),
            info.path.display()
        )?,
    }
    for (name, c) in &info.channels {
        let rate = if c.last_ns > c.first_ns {
            (c.frames.saturating_sub(1)) as f64 * 1e9 / (c.last_ns - c.first_ns) as f64
        } else {
            0.0
        };
        writeln!(
            out,
            "  {:<8} {name}: {} frames ({rate:.1}/s, {} bytes each), lost {} in {} gaps, {} faulted",
            c.kind, c.frames, c.payload_bytes, c.lost, c.gaps, c.faulted
        )?;
    }
    writeln!(out, "  topics:")?;
    for (topic, count) in &info.topics {
        writeln!(out, "    {topic}: {count} messages")?;
    }
    Ok(())
}
