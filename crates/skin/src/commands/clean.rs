//! `skin clean`: remove dead skins' channels.

use anyhow::Result;

/// Arguments of `skin clean`.
#[derive(clap::Args)]
pub struct Args {
    /// Also remove unusable files named like channels (corrupt, foreign, other ABI versions).
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
    Ok(())
}
