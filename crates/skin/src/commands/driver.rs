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
    let options = HandlerOptions {
        slots: driver_config.slots.unwrap_or(0),
        access: config.access(),
        ..HandlerOptions::default()
    };
    let stop = skinware::Stop::new();
    let stop_on_signal = stop.clone();
    stop_on_signals(move || stop_on_signal.stop())?;
    let mut waiting = WaitingForDevice::new(name);
    let (handler, status) = loop {
        let built = driver_config.build(&config.skin)?;
        let status = built.status_source(&config.skin, name);
        let driver = match built {
            BuiltDriver::Replay(replay) => return run_replay(&config, name, *replay, status, stop),
            driver => driver.into_driver().context("this driver runs under a driver handler")?,
        };
        match DriverHandler::start(&config.skin, driver, &options) {
            Ok(handler) => break (handler, status),
            Err(e) if device_missing(&e) => {
                if !waiting.wait(&e, &stop) {
                    return Ok(());
                }
            }
            Err(e) => return Err(e.into()),
        }
    };
    waiting.appeared();
    tracing::info!(driver = name, layers = ?handler.layers(), pid = std::process::id(), "driver acquiring");
    let handler_stop = handler.stop_signal().clone();
    let forward = stop.clone();
    std::thread::spawn(move || {
        while forward.sleep_until(u64::MAX) {}
        handler_stop.stop();
    });
    let stop = handler.stop_signal().clone();
    let publisher = publish_status(status, stop.clone());
    handler.run_until_stopped();
    stop.stop();
    let _ = publisher.join();
    tracing::info!(driver = name, "driver stopped");
    Ok(())
}

/// Whether a driver failed to start because its device is not there (yet):
/// an adapter not plugged in, a link an emulator has not made.
fn device_missing(error: &skinware::driver::HandlerError) -> bool {
    let skinware::driver::HandlerError::Start { .. } = error else { return false };
    let mut cause = std::error::Error::source(error);
    while let Some(next) = cause {
        if next.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::NotFound) {
            return true;
        }
        cause = next.source();
    }
    false
}

/// A driver process waiting for its device: it says so once, tries again
/// with a growing pause (0.2 s doubling to 5 s), and says when it appeared.
/// The supervisor sees a live process, so it neither restarts it nor logs
/// anything meanwhile, and the layers do not exist until the device does.
struct WaitingForDevice<'a> {
    driver: &'a str,
    since: Option<std::time::Instant>,
    pause: std::time::Duration,
}

impl<'a> WaitingForDevice<'a> {
    const FIRST_PAUSE: std::time::Duration = std::time::Duration::from_millis(200);
    const LONGEST_PAUSE: std::time::Duration = std::time::Duration::from_secs(5);

    fn new(driver: &'a str) -> Self {
        WaitingForDevice { driver, since: None, pause: Self::FIRST_PAUSE }
    }

    /// Pauses before the next try; `false` if stopped meanwhile.
    fn wait(&mut self, error: &skinware::driver::HandlerError, stop: &skinware::Stop) -> bool {
        if self.since.is_none() {
            self.since = Some(std::time::Instant::now());
            tracing::warn!(
                driver = self.driver,
                "waiting for device: {}; trying again every {} s at most (Ctrl-C to stop)",
                skin::report::causes_once(error),
                Self::LONGEST_PAUSE.as_secs()
            );
        }
        let awake = stop.sleep_until(skinware::os::monotonic_ns() + self.pause.as_nanos() as u64);
        self.pause = (self.pause * 2).min(Self::LONGEST_PAUSE);
        awake
    }

    /// The device is there: says after how long, if it was waited for.
    fn appeared(&self) {
        if let Some(since) = self.since {
            tracing::info!(driver = self.driver, waited_s = since.elapsed().as_secs_f64(), "the device appeared");
        }
    }
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
    stopped: skinware::Stop,
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
    std::thread::spawn({
        let stop = stop.clone();
        move || {
            while stopped.sleep_until(u64::MAX) {}
            stop.stop();
        }
    });
    let publisher = publish_status(status, stop.clone());
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
