//! `skin driver CONFIG --name NAME` (hidden): one driver, in the process that
//! `skin run` started for it.

use std::path::Path;

use anyhow::{Context, Result};
use skin::config::drivers::{BuiltDriver, StatusSource};
use skinware::{DriverHandler, HandlerOptions};

/// Runs one driver until SIGINT or SIGTERM (or the supervisor's death).
pub fn run(config_path: &Path, name: &str) -> Result<()> {
    super::run::watch_supervisor()?;
    let config = skin::config::Config::load(config_path)?;
    let driver_config = config.driver(name)?;
    let built = driver_config.build(&config.skin)?;
    let status = built.status_source(&config.skin, name);
    let driver = match built {
        BuiltDriver::Replay(replay) => return run_replay(&config, name, *replay, status),
        driver => driver.into_driver().context("this driver runs under a driver handler")?,
    };
    let options = HandlerOptions { slots: driver_config.slots, access: config.access(), ..HandlerOptions::default() };
    let handler = DriverHandler::start(&config.skin, driver, &options)
        .with_context(|| format!("driver {name} could not start"))?;
    tracing::info!(driver = name, layers = ?handler.layers(), pid = std::process::id(), "driver acquiring");
    let stop = handler.stop_signal().clone();
    let publisher = publish_status(status, stop.clone());
    let stop_on_signal = stop.clone();
    stop_on_signals(move || stop_on_signal.stop())?;
    handler.run_until_stopped();
    stop.stop();
    let _ = publisher.join();
    tracing::info!(driver = name, "driver stopped");
    Ok(())
}

/// Rewrites the driver's status file until `stop`, then removes it.
fn publish_status(status: StatusSource, stop: skinware::Stop) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let dir = skinware::shm::segment_dir();
        let mut warned = false;
        let mut path = None;
        while !stop.is_stopped() {
            match status().publish(&dir) {
                Ok(written) => path = Some(written),
                Err(e) if !warned => {
                    tracing::warn!(dir = %dir.display(), error = %e, "cannot write the driver's status for `skin ls`");
                    warned = true;
                }
                Err(_) => {}
            }
            stop.sleep_until(skinware::os::monotonic_ns() + skin::driver_status::PUBLISH_EVERY.as_nanos() as u64);
        }
        if let Some(path) = path {
            let _ = std::fs::remove_file(path);
        }
    })
}

/// A `kind = "replay"` driver: the recording's layers (and, if asked, its
/// services) under this config's skin name; the supervisor publishes the
/// geometry, built from the recording's calibration and this config's regions.
fn run_replay(
    config: &skin::config::Config,
    name: &str,
    replay: skin::config::drivers::ReplayDriver,
    status: StatusSource,
) -> Result<()> {
    let options = skinware_record::ReplayOptions {
        skin: Some(config.skin.clone()),
        publish_geometry: false,
        access: config.access(),
        ..replay.options
    };
    let mut player = skinware_record::Replay::open(&replay.file, options)
        .with_context(|| format!("driver {name} could not replay {}", replay.file.display()))?;
    tracing::info!(driver = name, channels = ?player.channels(), file = %replay.file.display(), "replaying");
    let stop = player.stop_signal().clone();
    let publisher = publish_status(status, stop.clone());
    let stop_on_signal = stop.clone();
    stop_on_signals(move || stop_on_signal.stop())?;
    let report = player.run();
    stop.stop();
    let _ = publisher.join();
    let report = report.with_context(|| format!("driver {name}: replaying {} stopped", replay.file.display()))?;
    tracing::info!(driver = name, frames = report.frames, passes = report.passes, "replay stopped");
    Ok(())
}

fn stop_on_signals(stop: impl FnOnce() + Send + 'static) -> Result<()> {
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])
        .context("cannot install signal handlers")?;
    std::thread::spawn(move || {
        if signals.forever().next().is_some() {
            stop();
        }
    });
    Ok(())
}
