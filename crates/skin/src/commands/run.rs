//! `skin run CONFIG`: the supervisor. Each driver runs in its own process, so
//! that a crash stays contained; a driver that exits is restarted with
//! exponential backoff, and its layers are revived by the new process.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use skinware_geometry::SkinGeometry;

use crate::config::{Config, RestartConfig};

/// A supervised child process: a driver or a service.
struct Supervised {
    /// "driver" or "service": also the hidden subcommand that runs it.
    role: &'static str,
    name: String,
    restart: RestartConfig,
    child: Option<Child>,
    started: Instant,
    restart_at: Option<Instant>,
    backoff_s: f64,
    restarts: u32,
}

fn spawn_child(config_path: &Path, role: &str, name: &str) -> Result<Child> {
    Command::new(std::env::current_exe().context("cannot find the skin executable")?)
        .arg(role)
        .arg(config_path)
        .arg("--name")
        .arg(name)
        .spawn()
        .with_context(|| format!("cannot start {role} {name}"))
}

/// Runs the supervisor until SIGINT or SIGTERM.
pub fn run(config_path: &Path) -> Result<()> {
    let shutdown = shutdown_on_signals()?;
    supervise(config_path, &shutdown)
}

/// A flag that SIGINT and SIGTERM set, instead of ending the process, so that
/// everything started can be stopped and its channels removed.
pub fn shutdown_on_signals() -> Result<Arc<AtomicBool>> {
    let shutdown = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, shutdown.clone()).context("cannot install signal handlers")?;
    }
    Ok(shutdown)
}

/// Publishes the geometry of the config at `config_path`, starts its drivers
/// and services and restarts any that exits, until `shutdown` is set; then
/// stops them and removes the skin's channels and geometry.
pub fn supervise(config_path: &Path, shutdown: &AtomicBool) -> Result<()> {
    let config = Config::load(config_path)?;
    let config_path = std::fs::canonicalize(config_path)?;
    let (geometry, published) = publish_geometry(&config)?;
    let mut children = start_children(&config, &config_path)?;
    println!(
        "skin {}: {} driver(s) and {} service(s) running; Ctrl-C to stop",
        config.skin,
        config.drivers.len(),
        config.services.len()
    );
    let mut layer_states: HashMap<String, &'static str> = HashMap::new();
    let mut next_state_poll = Instant::now();
    while !shutdown.load(Ordering::Relaxed) {
        let now = Instant::now();
        for supervised in &mut children {
            supervised.check(&config_path, now)?;
        }
        if now >= next_state_poll {
            next_state_poll = now + Duration::from_millis(100);
            log_layer_changes(&config.skin, &mut layer_states);
            republish_if_removed(&geometry, &published);
        }
        std::thread::sleep(Duration::from_millis(20));
    }

    tracing::info!("shutting down");
    stop_children(&mut children)?;
    remove_skin_channels(&config)?;
    let _ = std::fs::remove_file(&published);
    println!("skin {}: stopped, channels removed", config.skin);
    Ok(())
}

/// Builds (or loads from the cache) the geometry of `config` and publishes
/// it; returns it with the path it was published at.
fn publish_geometry(config: &Config) -> Result<(SkinGeometry, PathBuf)> {
    let (geometry, cached) = crate::geometry::load_or_build(config)?;
    let published = geometry.publish(&skinware::shm::segment_dir())?;
    tracing::info!(
        sensors = geometry.sensor_count(),
        regions = geometry.regions.names.len(),
        build_ms = format!("{:.0}", geometry.build_times.total_ms),
        from_cache = cached,
        path = %published.display(),
        "geometry published"
    );
    Ok((geometry, published))
}

/// Starts every driver, then every service, of `config`, each in its own process.
fn start_children(config: &Config, config_path: &Path) -> Result<Vec<Supervised>> {
    let roles = config
        .drivers
        .iter()
        .map(|d| ("driver", &d.name, &d.restart))
        .chain(config.services.iter().map(|s| ("service", &s.name, &s.restart)));
    let mut children = Vec::new();
    for (role, name, restart) in roles {
        let child = spawn_child(config_path, role, name)?;
        tracing::info!(role, name = %name, pid = child.id(), "started");
        children.push(Supervised {
            role,
            name: name.clone(),
            restart: restart.clone(),
            child: Some(child),
            started: Instant::now(),
            restart_at: None,
            backoff_s: restart.min_backoff_s,
            restarts: 0,
        });
    }
    Ok(children)
}

impl Supervised {
    /// One look at this child at `now`: notices that it exited (and schedules
    /// its restart after the backoff), or restarts it when that time has come.
    fn check(&mut self, config_path: &Path, now: Instant) -> Result<()> {
        let (name, role) = (&self.name, self.role);
        if let Some(child) = &mut self.child {
            if let Some(status) = child.try_wait()? {
                tracing::warn!(role, name = %name, %status, backoff_s = self.backoff_s, "exited; restarting");
                self.child = None;
                self.restart_at = Some(now + Duration::from_secs_f64(self.backoff_s));
                self.backoff_s = (self.backoff_s * 2.0).min(self.restart.max_backoff_s);
            } else if now.duration_since(self.started) > Duration::from_secs(30) {
                // Up for a while: the next crash starts from the shortest backoff again.
                self.backoff_s = self.restart.min_backoff_s;
            }
        } else if self.restart_at.is_some_and(|at| at <= now) {
            match spawn_child(config_path, role, name) {
                Ok(child) => {
                    self.restarts += 1;
                    tracing::info!(role, name = %name, pid = child.id(), restarts = self.restarts, "restarted");
                    self.child = Some(child);
                    self.started = now;
                    self.restart_at = None;
                }
                Err(e) => {
                    tracing::error!(role, name = %name, "{e:#}");
                    self.restart_at = Some(now + Duration::from_secs_f64(self.backoff_s));
                }
            }
        }
        Ok(())
    }
}

/// `skin clean` removes the geometry of a skin without a live writer, e.g.
/// while every driver waits to restart: put it back.
fn republish_if_removed(geometry: &SkinGeometry, published: &Path) {
    if !published.exists() {
        match geometry.publish(&skinware::shm::segment_dir()) {
            Ok(_) => {
                tracing::warn!(path = %published.display(), "the geometry had been removed; published again")
            }
            Err(e) => tracing::error!("cannot publish the geometry again: {e}"),
        }
    }
}

/// SIGTERMs every running child, then waits up to 5 s in all for them to
/// exit, SIGKILLing those that do not.
fn stop_children(children: &mut [Supervised]) -> Result<()> {
    for supervised in children.iter() {
        if let Some(child) = &supervised.child {
            if let Some(pid) = rustix::process::Pid::from_raw(child.id() as i32) {
                let _ = rustix::process::kill_process(pid, rustix::process::Signal::TERM);
            }
        }
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    for supervised in children.iter_mut() {
        if let Some(child) = &mut supervised.child {
            while child.try_wait()?.is_none() {
                if Instant::now() > deadline {
                    tracing::warn!(role = supervised.role, name = %supervised.name, "did not stop in 5 s; killing it");
                    let _ = child.kill();
                    let _ = child.wait();
                    break;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
        }
    }
    Ok(())
}

fn log_layer_changes(skin: &str, states: &mut HashMap<String, &'static str>) {
    let Ok(channels) = skinware::list_channels(&skinware::shm::segment_dir()) else {
        return;
    };
    for channel in channels.into_iter().filter(|c| c.skin == skin) {
        let state = channel.state.as_str();
        let previous = states.insert(channel.channel.clone(), state);
        if previous != Some(state) {
            tracing::info!(layer = %channel.channel, from = previous.unwrap_or("absent"), to = state, "layer state");
        }
    }
}

/// Removes the channels of this skin (their writers are stopped) and its
/// cable-pull control files.
fn remove_skin_channels(config: &Config) -> Result<()> {
    let dir = skinware::shm::segment_dir();
    for channel in skinware::list_channels(&dir)?.into_iter().filter(|c| c.skin == config.skin) {
        if !skinware::remove_channel_if_stale(&channel.path)? {
            tracing::warn!(channel = %channel.path.display(), "still has a live writer; left in place");
        }
    }
    for driver in &config.drivers {
        if let Ok(built) = driver.build(&config.skin) {
            for spec in skinware::Driver::layers(&built) {
                let _ = std::fs::remove_file(crate::config::pull_file(&config.skin, &spec.topology.name));
            }
        }
    }
    Ok(())
}
