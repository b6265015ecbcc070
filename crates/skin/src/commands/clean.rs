//! `skin clean`: remove dead skins' channels.

use anyhow::Result;

/// Arguments of `skin clean`.
#[derive(clap::Args)]
pub struct Args {
    /// Also remove files named like channels that are not channel sockets (files of older skinware versions, foreign files).
    #[arg(long)]
    force: bool,
}

/// Runs `skin clean`.
pub fn run(args: &Args) -> Result<()> {
    let dir = skinware::shm::segment_dir();
    let removed = skinware::remove_stale_channels(&dir, args.force)?;
    for path in &removed {
        println!("removed {}", path.display());
    }
    println!("{} stale channel(s) removed from {}", removed.len(), dir.display());
    // A published geometry outlives nothing: it goes when its skin has no live writer.
    let live: std::collections::HashSet<String> = skinware::list_channels(&dir)?
        .into_iter()
        .filter(|c| c.state != skinware::WriterState::Gone)
        .map(|c| c.skin)
        .collect();
    for entry in std::fs::read_dir(&dir)?.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        if let Some(skin) = name.strip_prefix("skinware-geometry.")
            && !live.contains(skin)
            && std::fs::remove_file(entry.path()).is_ok()
        {
            println!("removed {} (the geometry of skin {skin}, which has no live writer)", entry.path().display());
        }
    }
    // A driver's status file goes with its driver.
    let now = skin::driver_status::now_ns();
    for found in skin::driver_status::find(&dir, None)? {
        // One that cannot be read is left alone unless forced, as foreign files are.
        let dead = found.status.as_ref().map_or(args.force, |status| !status.is_live(now));
        if dead && std::fs::remove_file(&found.path).is_ok() {
            println!("removed {} (the status of a driver that is gone)", found.path.display());
        }
    }
    Ok(())
}
