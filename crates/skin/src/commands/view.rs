//! `skin view`: a live web view of a running skin.

use anyhow::{Context, Result};
use skinware_geometry::SkinGeometry;
use skinware_viewer::{self as view, Site};

/// Arguments of `skin view`.
#[derive(clap::Args)]
pub struct Args {
    /// Address to serve on; loopback unless you mean to share the view.
    #[arg(long, default_value = "127.0.0.1:8080")]
    listen: String,
    /// The skin to show.
    #[arg(long, default_value = "default")]
    skin: String,
    #[command(flatten)]
    remote: super::bridge::RemoteArgs,
}

/// Runs `skin view` until SIGINT or SIGTERM.
pub fn run(args: &Args) -> Result<()> {
    skinware::shm::validate_name("skin", &args.skin)?;
    if args.remote.remote.is_some() {
        return super::bridge::view(&args.remote, &args.skin, &args.listen);
    }
    // Each browser reloads the geometry when it connects; this only checks
    // now that there is a skin to show.
    SkinGeometry::open(&args.skin).with_context(|| format!("cannot show skin {}", args.skin))?;
    let listener = view::bind(&args.listen)?;
    let shutdown = super::run::shutdown_on_signals()?;
    println!("skin view: skin {} on http://{}/ ; Ctrl-C to stop", args.skin, listener.local_addr()?);
    view::serve(listener, &Site::new(&args.skin, None, shutdown))
}
