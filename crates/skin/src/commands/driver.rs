//! `skin driver CONFIG --name NAME` (hidden): one driver, in the process that
//! `skin run` started for it.

use std::path::Path;

use anyhow::{Context, Result};
use skinware::{DriverHandler, HandlerOptions};

/// Runs one driver until SIGINT or SIGTERM (or the supervisor's death).
pub fn run(config_path: &Path, name: &str) -> Result<()> {
    super::run::watch_supervisor()?;
    let config = skin::config::Config::load(config_path)?;
    let driver_config = config.driver(name)?;
    let driver = driver_config.build(&config.skin)?;
    let options = HandlerOptions { slots: driver_config.slots, access: config.access(), ..HandlerOptions::default() };
    let handler = DriverHandler::start(&config.skin, driver.into_driver(), &options)
        .with_context(|| format!("driver {name} could not start"))?;
    tracing::info!(driver = name, layers = ?handler.layers(), pid = std::process::id(), "driver acquiring");
    let stop = handler.stop_signal().clone();
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])
        .context("cannot install signal handlers")?;
    std::thread::spawn(move || {
        if signals.forever().next().is_some() {
            stop.stop();
        }
    });
    handler.run_until_stopped();
    tracing::info!(driver = name, "driver stopped");
    Ok(())
}
