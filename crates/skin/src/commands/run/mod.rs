//! `skin run CONFIG`: the supervisor. Each driver runs in its own process, so
//! that a crash stays contained; a driver that exits is restarted with
//! exponential backoff; the new process takes over its layers' names and
//! their readers follow it. A
//! driver or service that lives but has hung (no frame and no failed
//! acquisition on any of its periodic channels for 20 periods, and at least
//! 1 s) is killed and restarted the same way.

mod state_log;

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use skinware_geometry::SkinGeometry;

use skinware::{ChannelInfo, WriterState};

use skin::config::{Config, RestartConfig};

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
    heartbeat: Heartbeat,
    /// Whether this child has been seen healthy: every periodic channel of
    /// it written by it, running and publishing, for as long as it takes to
    /// call a silent channel hung (20 periods, at least 1 s). A child that dies
    /// after that is restarted after the shortest backoff; the backoff
    /// doubles only for children that die before they ever were healthy
    /// (a crash loop), so that a driver killed now and then by a fault is
    /// always back within a fraction of a second.
    healthy: bool,
    /// Since when every periodic channel of it has been publishing.
    healthy_since: Option<Instant>,
}

/// The periodic channels of one child and when each last showed progress: a
/// frame published or a failed acquisition counted. A pulled cable keeps
/// counting failures; a hung or stopped process counts nothing.
#[derive(Default)]
struct Heartbeat {
    /// Channel names and their nominal periods.
    channels: Vec<(String, Duration)>,
    /// Per channel: frames + failures last seen, and since when.
    progress: HashMap<String, (u64, Instant)>,
    /// Per channel, a reader kept open: its writer's statistics are read from
    /// memory, with no hand-over to wait for (a stopped process answers none).
    readers: HashMap<String, skinware::Reader>,
    /// The skin the channels belong to.
    skin: String,
}

/// A child whose periodic channels have all been silent this long (in
/// periods, and at least [`MIN_HANG`]) has hung.
const HANG_PERIODS: u32 = 20;
/// The shortest silence taken for a hang.
const MIN_HANG: Duration = Duration::from_secs(1);

/// Set in every child to the supervisor's pid; see [`watch_supervisor`].
const SUPERVISOR_PID: &str = "SKIN_SUPERVISOR_PID";

fn spawn_child(config_path: &Path, role: &str, name: &str) -> Result<Child> {
    Command::new(std::env::current_exe().context("cannot find the skin executable")?)
        .env(SUPERVISOR_PID, std::process::id().to_string())
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
    keep_executable_in_memory();
    supervise(config_path, &shutdown)
}

/// Keeps this executable's pages (and its libraries') in RAM, locked by the
/// supervisor, which starts every driver and service from the same file. A
/// driver restarted after memory pressure evicted those pages waits for the
/// disk to load them again: a cold `skin --version` takes 1.15 s on this
/// VM's idle disk (after `drop_caches`), against 0.00 s warm. In the 1-hour
/// soak, while two builds ran beside it, five driver restarts took 0.5 to
/// 1.8 s longer than usual before the new driver created its channels,
/// and missed the goal of every layer back within 1 s; a cold executable
/// is the likely cause (not yet shown: `drop_caches` cannot evict pages a
/// process maps, which reclaim under pressure can). Locking only what is
/// mapped now costs the executable's size once (about 10 MB of code), not
/// the supervisor's future allocations. Without the privilege
/// (RLIMIT_MEMLOCK too small, not root), restarts only lose that protection.
fn keep_executable_in_memory() {
    if let Err(error) = skinware::os::lock_current_memory() {
        tracing::info!(%error, "cannot lock the skin executable in memory (mlockall); a driver restarted after its pages were evicted may wait for the disk (raise RLIMIT_MEMLOCK or run as root)");
    }
}

/// In a driver or service process: asks the kernel for SIGTERM when the
/// supervisor dies, however it dies. The request only covers a parent still
/// alive when it is made, so a supervisor that died between starting this
/// process and the request (this process is then someone else's child) is
/// caught by comparing the parent with the supervisor `skin run` named.
pub fn watch_supervisor() -> Result<()> {
    rustix::process::set_parent_process_death_signal(Some(rustix::process::Signal::TERM))
        .context("cannot ask to be told of the supervisor's death (prctl PR_SET_PDEATHSIG)")?;
    let Some(expected) = std::env::var_os(SUPERVISOR_PID) else {
        return Ok(()); // started by hand, not by `skin run`
    };
    let expected = expected.to_string_lossy().into_owned();
    let parent = rustix::process::getppid().map_or(0, |pid| pid.as_raw_nonzero().get());
    if parent.to_string() != expected {
        anyhow::bail!(
            "the supervisor (pid {expected}) is gone: this process's parent is now {parent}; exiting rather than running unsupervised"
        );
    }
    Ok(())
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
    let emulated = if config.emulators.is_empty() {
        String::new()
    } else {
        format!(" ({} emulated bus(es))", config.emulators.len())
    };
    println!(
        "skin {}: {} driver(s){emulated} and {} service(s) running; Ctrl-C to stop",
        config.skin,
        config.drivers.len(),
        config.services.len()
    );
    let mut layer_states = state_log::StateLog::default();
    // Every child process ever started: the writers whose channels it looks at.
    let mut spawned: HashSet<u32> = HashSet::new();
    // Only records its children wrote, as this user, are trusted.
    let own_uid = rustix::process::geteuid().as_raw();
    let mut next_state_poll = Instant::now();
    while !shutdown.load(Ordering::Relaxed) {
        let now = Instant::now();
        for supervised in &mut children {
            supervised.check(&config_path, now)?;
        }
        if now >= next_state_poll {
            next_state_poll = now + Duration::from_millis(100);
            spawned.extend(children.iter().filter_map(|c| c.child.as_ref().map(Child::id)));
            // Only this skin's channels, and only those its own children
            // write (by the name record, read without asking anyone): a
            // stopped process of anyone else's never costs this loop a wait.
            let channels: Vec<ChannelInfo> =
                skinware::list_channels_where(&skinware::shm::segment_dir(), Some(&config.skin), |writer| {
                    spawned.contains(&writer.pid) && writer.owner_uid == own_uid
                })
                .unwrap_or_default();
            for supervised in &mut children {
                supervised.kill_if_hung(now, &channels);
            }
            log_layer_changes(&channels, &mut layer_states, now);
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
        .emulators
        .iter()
        .map(|e| ("emulator", &e.name, &e.restart))
        .chain(config.drivers.iter().map(|d| ("driver", &d.name, &d.restart)))
        .chain(config.services.iter().map(|s| ("service", &s.name, &s.restart)));
    let mut children = Vec::new();
    let mut emulators_ready = config.emulators.is_empty();
    for (role, name, restart) in roles {
        if role != "emulator" && !emulators_ready {
            wait_for_emulator_links(config);
            emulators_ready = true;
        }
        let heartbeat = Heartbeat {
            channels: periodic_channels(config, role, name)?,
            progress: HashMap::new(),
            readers: HashMap::new(),
            skin: config.skin.clone(),
        };
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
            heartbeat,
            healthy: false,
            healthy_since: None,
        });
    }
    Ok(children)
}

/// Waits (at most 2 s) until every SLCAN emulator's link exists, so that the
/// drivers find their buses at their first try.
fn wait_for_emulator_links(config: &Config) {
    let deadline = Instant::now() + Duration::from_secs(2);
    let links: Vec<&Path> = config.emulators.iter().filter_map(|e| e.link.as_deref()).collect();
    while Instant::now() < deadline && !links.iter().all(|link| link.exists()) {
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// The channels the driver or service `name` publishes periodically, with
/// their periods (sporadic ones publish only when asked, so have no heartbeat).
fn periodic_channels(config: &Config, role: &str, name: &str) -> Result<Vec<(String, Duration)>> {
    let period = |hz: f64| Duration::from_secs_f64(1.0 / hz);
    if role == "emulator" {
        return Ok(Vec::new());
    }
    if role == "driver" {
        let driver = config.driver(name)?.build(&config.skin)?;
        return Ok(driver
            .layers()
            .into_iter()
            .filter(|spec| spec.topology.rate_hz > 0.0)
            .map(|spec| (spec.topology.name.clone(), period(spec.topology.rate_hz)))
            .collect());
    }
    let service = config.service(name)?;
    let Some(hz) = service.rate_hz else {
        return Ok(Vec::new());
    };
    let mut channels = vec![(service.name.clone(), period(hz))];
    if service.kind == skin::config::ServiceKind::Contact {
        channels.push((skinware_services::taxel_channel(&service.name), period(hz)));
    }
    Ok(channels)
}

impl Supervised {
    /// Kills the child if it lives but every one of its periodic channels
    /// (owned by it) has shown no progress for [`HANG_PERIODS`] periods; its
    /// exit is then handled like any other, with a restart after the backoff.
    ///
    /// `listed` is this skin's channels as just listed: a reader is opened
    /// (or opened again, for a restarted child) only on a channel listed as
    /// this child's, so that the supervisor asks no other process for one.
    fn kill_if_hung(&mut self, now: Instant, listed: &[ChannelInfo]) {
        let Some(child) = &mut self.child else { return };
        let pid = child.id();
        let (mut watched, mut hung, mut publishing) = (0, 0, 0);
        let mut silent_for = Duration::ZERO;
        let Heartbeat { channels, progress, readers, skin } = &mut self.heartbeat;
        for (name, period) in channels.iter() {
            let hang_after = (*period * HANG_PERIODS).max(MIN_HANG);
            if readers.get(name).is_none_or(|reader| reader.writer_pid() != pid) {
                readers.remove(name);
                match listed.iter().find(|c| &c.channel == name && c.writer_pid == pid) {
                    Some(c) if c.problem.is_none() && c.state != WriterState::Gone => {
                        match skinware::Reader::open(skin, name) {
                            Ok(reader) => readers.insert(name.clone(), reader),
                            Err(_) => continue,
                        };
                    }
                    Some(c) if c.problem.is_some() => {
                        // Recorded as this child's, but it hands nothing
                        // over (stopped or hung before a reader was opened
                        // on it): as silent as a writer can be.
                        let seen = progress.entry(name.clone()).or_insert((u64::MAX, now));
                        watched += 1;
                        let silence = now.duration_since(seen.1);
                        if silence > hang_after {
                            hung += 1;
                            silent_for = silent_for.max(silence);
                        }
                        continue;
                    }
                    _ => continue,
                }
            }
            let Some(reader) = readers.get_mut(name) else { continue };
            // A paused writer is silent on purpose (a replay holding its
            // last frames, or between the recorded frames of a long pause).
            if reader.writer_pid() != pid || matches!(reader.writer_state(), WriterState::Gone | WriterState::Paused) {
                continue;
            }
            let stats = reader.writer_stats();
            if stats.frames > 0 && reader.writer_state() == WriterState::Running {
                publishing += 1;
            }
            let beat = stats.frames.wrapping_add(stats.faults);
            let seen = progress.entry(name.clone()).or_insert((beat, now));
            if seen.0 != beat {
                *seen = (beat, now);
            }
            watched += 1;
            let silence = now.duration_since(seen.1);
            if silence > hang_after {
                hung += 1;
                silent_for = silent_for.max(silence);
            }
        }
        // Healthy: every periodic channel publishing, for as long as it
        // takes to call a silent one hung (a child that dies right after
        // its first frame is a crash loop, and keeps backing off).
        if !channels.is_empty() && publishing == channels.len() {
            let since = *self.healthy_since.get_or_insert(now);
            let longest = channels.iter().map(|(_, period)| *period).max().unwrap_or_default();
            if now.duration_since(since) >= (longest * HANG_PERIODS).max(MIN_HANG) {
                self.healthy = true;
            }
        } else {
            self.healthy_since = None;
        }
        if watched > 0 && hung == watched {
            tracing::warn!(
                role = self.role,
                name = %self.name,
                pid,
                silent_ms = silent_for.as_millis() as u64,
                "hung: no frame and no failed acquisition on any of its channels; killing it to restart it"
            );
            let _ = child.kill();
            self.heartbeat.progress.clear();
        }
    }

    /// One look at this child at `now`: notices that it exited (and schedules
    /// its restart after the backoff), or restarts it when that time has come.
    fn check(&mut self, config_path: &Path, now: Instant) -> Result<()> {
        let (name, role) = (&self.name, self.role);
        if let Some(child) = &mut self.child {
            if let Some(status) = child.try_wait()? {
                if self.healthy {
                    // It had been working: not a crash loop.
                    self.backoff_s = self.restart.min_backoff_s;
                }
                tracing::warn!(role, name = %name, %status, backoff_s = self.backoff_s, "exited; restarting");
                self.child = None;
                self.healthy = false;
                self.healthy_since = None;
                // The next child starts with no history: a beat of the dead
                // one's must not make the new one look silent.
                self.heartbeat.progress.clear();
                self.heartbeat.readers.clear();
                self.restart_at = Some(now + Duration::from_secs_f64(self.backoff_s));
                self.backoff_s = (self.backoff_s * 2.0).min(self.restart.max_backoff_s);
            } else if now.duration_since(self.started) > Duration::from_secs(30) {
                // Up for a while (a child with no periodic channel to be
                // seen healthy by): the next crash starts from the shortest
                // backoff again.
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
                    tracing::error!(role, name = %name, "{}", skin::report::causes_once(e.as_ref()));
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
        if let Some(child) = &supervised.child
            && let Some(pid) = rustix::process::Pid::from_raw(child.id() as i32)
        {
            let _ = rustix::process::kill_process(pid, rustix::process::Signal::TERM);
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

fn log_layer_changes(channels: &[ChannelInfo], states: &mut state_log::StateLog, now: Instant) {
    let seen = channels.iter().map(|channel| (channel.channel.as_str(), channel.state.as_str()));
    for line in states.observe(now, seen) {
        state_log::log(&line);
    }
}

/// Removes the channels of this skin (their writers are stopped), its
/// drivers' status files and its cable-pull control files.
fn remove_skin_channels(config: &Config) -> Result<()> {
    let dir = skinware::shm::segment_dir();
    for channel in skinware::list_skin_channels(&dir, &config.skin)? {
        if !skinware::remove_channel_if_stale(&channel.path)? {
            tracing::warn!(channel = %channel.path.display(), "still has a live writer; left in place");
        }
    }
    // The drivers are stopped: their status files go too (one killed at the
    // stop deadline could not remove its own).
    for found in skin::driver_status::find(&dir, Some(&config.skin))? {
        let _ = std::fs::remove_file(found.path);
    }
    for driver in &config.drivers {
        if let Ok(built) = driver.build(&config.skin) {
            for spec in built.layers() {
                let _ = std::fs::remove_file(skin::config::pull_file(&config.skin, &spec.topology.name));
            }
        }
    }
    Ok(())
}
