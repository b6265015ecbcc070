//! `skin pull`: the cable-pull fault injection, on command.

use anyhow::{Context, Result};

/// Arguments of `skin pull`.
#[derive(clap::Args)]
pub struct Args {
    /// The layer whose cable to pull.
    layer: String,
    /// The skin.
    #[arg(long, default_value = "default")]
    skin: String,
    /// Plug the cable back in instead.
    #[arg(long)]
    restore: bool,
}

/// Runs `skin pull`.
pub fn run(args: &Args) -> Result<()> {
    skinware::shm::validate_name("skin", &args.skin)?;
    skinware::shm::validate_name("layer", &args.layer)?;
    let file = skin::config::pull_file(&args.skin, &args.layer);
    if args.restore {
        match std::fs::remove_file(&file) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(e).with_context(|| format!("cannot remove {}", file.display())),
        }
        println!("{}/{}: cable plugged back in", args.skin, args.layer);
    } else {
        // Replaced whole, never written through a link or into a FIFO that
        // someone left at this name.
        skinware::shm::replace_file(&file, b"pulled\n", 0o644)
            .with_context(|| format!("cannot create {}", file.display()))?;
        println!("{}/{}: cable pulled (undo with --restore)", args.skin, args.layer);
    }
    Ok(())
}
