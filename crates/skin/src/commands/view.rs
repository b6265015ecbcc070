//! `skin view`: a live web view of a running skin.

use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
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
    /// Seconds to wait for the skin's geometry if it is not published yet
    /// (`skin run`, `skin replay` and `skin demo` publish it a moment after
    /// they start).
    #[arg(long, default_value_t = 10.0, value_name = "SECONDS")]
    wait: f64,
    #[command(flatten)]
    remote: super::bridge::RemoteArgs,
}

/// Runs `skin view` until SIGINT or SIGTERM.
pub fn run(args: &Args) -> Result<()> {
    skinware::shm::validate_name("skin", &args.skin)?;
    if !(args.wait.is_finite() && args.wait >= 0.0) {
        bail!("--wait {} must be a number of seconds", args.wait);
    }
    if args.remote.remote.is_some() {
        return super::bridge::view(&args.remote, &args.skin, &args.listen);
    }
    // The port first: a port in use is said at once, not after the wait.
    let listener = view::bind(&args.listen)?;
    let shutdown = super::run::shutdown_on_signals()?;
    let site = Site::new(&args.skin, None, shutdown.clone());
    // Each browser reloads the geometry when it connects (the first gets
    // this one, already encoded); this waits for there to be a skin to show.
    let wait = Duration::from_secs_f64(args.wait.min(86_400.0));
    let found = site.geometry.get_waiting(&skinware::shm::segment_dir(), &args.skin, wait, &shutdown, || {
        eprintln!(
            "skin view: skin {} has no geometry yet; waiting up to {} s for `skin run`, `skin replay` or \
             `skin demo` to publish it",
            args.skin, args.wait
        );
    });
    if shutdown.load(Ordering::Relaxed) {
        return Ok(());
    }
    found
        .map_err(|e| crate::skins::missing_geometry(&args.skin, e))
        .with_context(|| format!("cannot show skin {}", args.skin))?;
    println!("skin view: skin {} on http://{}/ ; Ctrl-C to stop", args.skin, listener.local_addr()?);
    view::serve(listener, &site)
}
