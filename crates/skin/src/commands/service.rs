//! `skin service CONFIG --name NAME` (hidden): one service, in the process
//! that `skin run` started for it.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use skinware::{Stop, WriterOptions};
use skinware_geometry::{GeometryError, SkinGeometry};

use skin::config::ServiceKind;

/// Runs one service until SIGINT or SIGTERM (or the supervisor's death).
pub fn run(config_path: &Path, name: &str) -> Result<()> {
    super::run::watch_supervisor()?;
    let config = skin::config::Config::load(config_path)?;
    let service = config.service(name)?;
    let stop = Stop::new();
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])
        .context("cannot install signal handlers")?;
    {
        let stop = stop.clone();
        std::thread::spawn(move || {
            if signals.forever().next().is_some() {
                stop.stop();
            }
        });
    }
    let rt = service.rt_options();
    let options = WriterOptions { access: config.access(), reader_wake: rt.reader_wake, ..WriterOptions::default() };
    // The service runs in this thread; its writers' ringers copy its priority.
    for refusal in rt.apply() {
        tracing::warn!(service = name, "{refusal}");
    }
    tracing::info!(service = name, kind = ?service.kind, pid = std::process::id(), "service starting");
    match service.kind {
        ServiceKind::Contact => {
            let geometry = wait_for_geometry(&config.skin, &stop)?;
            skinware_services::run_contact_service(&config.skin, &service.contact(), &geometry, &options, &stop)
        }
        ServiceKind::Motion => skinware_services::run_motion_service(&config.skin, &service.motion(), &options, &stop),
    }
    .with_context(|| format!("service {name}"))?;
    tracing::info!(service = name, "service stopped");
    Ok(())
}

/// The published geometry; `skin run` publishes it before starting anything,
/// so a short wait only covers a restart racing a re-publication.
fn wait_for_geometry(skin: &str, stop: &Stop) -> Result<SkinGeometry> {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match SkinGeometry::open(skin) {
            Ok(geometry) => return Ok(geometry),
            Err(GeometryError::Missing { .. }) if Instant::now() < deadline && !stop.is_stopped() => {
                std::thread::sleep(Duration::from_millis(50));
            }
            Err(e) => return Err(e.into()),
        }
    }
}
