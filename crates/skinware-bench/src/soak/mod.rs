//! `skin bench soak CONFIG --minutes N`: a skin under `skin run`, read by
//! verifying reader processes in every mode, both services, the viewer with
//! a browser-like client and a recorder, while faults are injected one at a
//! time at random (from a printed seed): driver and reader SIGKILL and
//! SIGSTOP, cable pulls, stopped foreign writers, name squats and unlinks,
//! and a CPU hog.
//!
//! It reports frames verified, torn, backwards, lost and counted against
//! lost silently; stuck readers; the memory and descriptors of every
//! process over time and what was left in the segment directory; and, per
//! kind of fault, the time until every layer runs again. It fails (the
//! command exits non-zero) on a torn, backwards or silently lost frame, a
//! stuck reader or a leaked channel; times are reported, not asserted.
//!
//! Everything runs in a segment directory of its own, so the soak never
//! touches a skin the user runs.

#![forbid(unsafe_code)]

pub mod browser;
pub mod config;
mod faults;
pub mod helpers;
mod injection;
mod monitor;
mod observer;
pub mod reader;
pub mod report;
mod squats;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use crate::measure::RunningSkin;
use crate::procs::{self, Guarded};
use crate::run_options::{DurationError, RunOptions, parse_up_to};
use config::ConfigParser;
pub use injection::FaultKind;
use observer::Observer;
use reader::Mode;
use report::SoakReport;

/// A verifying reader without a new frame this long, while its layer
/// publishes, is stuck.
pub const STUCK_AFTER_S: f64 = 2.0;

/// How long the soak waits for every layer to run again after a fault.
const RECOVERY_WAIT: Duration = Duration::from_secs(30);

/// One layer of the skin the soak runs.
#[derive(Clone, Debug)]
pub struct LayerPlan {
    /// Its channel name.
    pub name: String,
    /// Its taxels.
    pub taxels: usize,
    /// The file whose existence pulls its cable (`skin pull`).
    pub pull_file: PathBuf,
}

/// What `skin bench soak` is given.
#[derive(Clone, Debug)]
pub struct SoakBenchOptions {
    /// `out` takes `soak.json`, the soak's config and `soak-work/`; `quick`
    /// is two minutes of faults unless `minutes` says otherwise; `exe` runs
    /// the skin, its commands and the soak's helpers (`seconds` is not used).
    pub run: RunOptions,
    /// The skin to soak: a config of virtual drivers (its drivers publish
    /// their verification pattern during the soak; the contact and motion
    /// services are added if it has no service).
    pub config: PathBuf,
    /// Minutes of faults (default 60; 2 with `quick`).
    pub minutes: Option<f64>,
    /// The faults' seed, to run the same faults again (a new one if `None`).
    pub seed: Option<u64>,
}

/// The most minutes of faults: a day.
const MAX_MINUTES: f64 = 24.0 * 60.0;

/// `--minutes` of the soak: more than 0, at most a day.
pub fn parse_minutes(text: &str) -> Result<f64, DurationError> {
    parse_up_to(text, "minutes", MAX_MINUTES, "a day")
}

/// Runs `skin bench soak`: writes the soak's version of the config (read
/// with `parser`, `skin run`'s) and soaks it, in a segment directory of its
/// own, until done or interrupted (Ctrl-C, SIGTERM); fails if the soak
/// found a correctness failure, or was interrupted.
pub fn bench(options: &SoakBenchOptions, parser: &dyn ConfigParser) -> Result<()> {
    let interrupted = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, interrupted.clone()).context("cannot install signal handlers")?;
    }
    let out = &options.run.out;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let dir = skinware::shm::segment_dir().join(format!("skin-soak-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)
        .with_context(|| format!("cannot create the soak's segment directory {}", dir.display()))?;
    let prepared = match config::prepare(&options.config, &dir, out, parser) {
        Ok(prepared) => prepared,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&dir);
            return Err(e);
        }
    };
    let soak = SoakOptions {
        run: options.run.clone(),
        source_config: options.config.display().to_string(),
        config: prepared.path,
        skin: prepared.plan.skin,
        layers: prepared.plan.layers,
        services: prepared.plan.services,
        dir,
        minutes: options.minutes.unwrap_or(if options.run.quick { 2.0 } else { 60.0 }),
        seed: options.seed,
        interrupted: interrupted.clone(),
    };
    let report = run(&soak)?;
    if interrupted.load(Ordering::Relaxed) {
        bail!("interrupted: the report above covers the faults until then");
    }
    if !report.passed {
        bail!("the soak found {} correctness failure(s): {}", report.failures.len(), report.failures.join("; "));
    }
    Ok(())
}

/// What the soak runs, its config prepared.
pub struct SoakOptions {
    /// `exe`, the `skin` executable, starts the skin, its commands and the
    /// soak's hidden roles; `out` takes `soak.json` and the work files.
    pub run: RunOptions,
    /// The config the user gave, for the report.
    pub source_config: String,
    /// The config to run: the user's, with `verify_pattern` on its virtual
    /// drivers (written by the caller).
    pub config: PathBuf,
    /// The skin's name.
    pub skin: String,
    /// Its layers.
    pub layers: Vec<LayerPlan>,
    /// The channels of its periodic services.
    pub services: Vec<String>,
    /// The soak's own segment directory: empty, and removed at the end.
    pub dir: PathBuf,
    /// Minutes of faults.
    pub minutes: f64,
    /// The faults' seed (a new one if `None`).
    pub seed: Option<u64>,
    /// Set by Ctrl-C or SIGTERM: the soak stops, cleans up and reports.
    pub interrupted: Arc<AtomicBool>,
}

/// A verifying reader process.
struct ReaderProcess {
    mode: Mode,
    child: Child,
    report: PathBuf,
    /// When it was started or last resumed (CLOCK_MONOTONIC ns): it is not
    /// held stuck before [`STUCK_AFTER_S`] after that.
    since_ns: u64,
    stopped: bool,
}

/// The running soak: its processes and what it has seen.
struct Soak<'o> {
    options: &'o SoakOptions,
    work: PathBuf,
    /// Where the verifying readers write their reports: on tmpfs, so that
    /// a disk busy with someone else's writes cannot delay a report and
    /// make a reader look stuck.
    reports: PathBuf,
    started: Instant,
    /// The same moment on CLOCK_MONOTONIC, ns.
    started_ns: u64,
    chaos: faults::Chaos,
    skin: Option<RunningSkin>,
    readers: Vec<ReaderProcess>,
    /// Report files of readers that were killed or stopped, for the totals.
    finished_reports: Vec<(Mode, PathBuf)>,
    incarnations: u64,
    observer: Observer,
    monitor: monitor::Monitor,
    /// Paths the soak created in the segment directory (squats), removed at the end.
    squats: Vec<PathBuf>,
    /// Processes the soak stopped, resumed before anything else at the end.
    stopped: Vec<u32>,
    /// Helper processes (foreign writers), killed at the end.
    helpers: Vec<Guarded>,
    report: SoakReport,
}

/// A new directory of the soak's own on tmpfs (`/dev/shm`), private to
/// this user, for the readers' reports.
fn reports_dir() -> Result<PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    let path = PathBuf::from(format!(
        "/dev/shm/skinware-soak-reports-{}-{}",
        std::process::id(),
        skinware::os::monotonic_ns()
    ));
    // Not recursive: a path someone else made first is refused, not used.
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&path)
        .with_context(|| format!("cannot create {} for the readers' reports (is /dev/shm mounted?)", path.display()))?;
    Ok(path)
}

/// Moves the readers' reports from tmpfs into the work directory, for the
/// record.
fn keep_reports(reports: &Path, work: &Path) {
    for entry in std::fs::read_dir(reports).into_iter().flatten().flatten() {
        let _ = std::fs::copy(entry.path(), work.join(entry.file_name()));
    }
    let _ = std::fs::remove_dir_all(reports);
}

/// Runs the soak, prints its tables and writes `soak.json` into `out`.
pub fn run(options: &SoakOptions) -> Result<SoakReport> {
    if !(options.minutes.is_finite() && options.minutes > 0.0 && options.minutes <= MAX_MINUTES) {
        bail!("--minutes must be more than 0 and at most a day ({})", options.minutes);
    }
    let seed = options.seed.unwrap_or_else(|| skinware::os::monotonic_ns() | 1);
    let work = options.run.out.join("soak-work");
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).with_context(|| format!("cannot create {}", work.display()))?;
    let reports = reports_dir()?;
    println!(
        "soak: {} minute(s) of faults on {} (seed {seed}; the same seed gives the same faults), segment directory {}",
        options.minutes,
        options.source_config,
        options.dir.display()
    );
    let layer_names: Vec<String> = options.layers.iter().map(|l| l.name.clone()).collect();
    let observer = Observer::start(&options.skin, options.dir.clone(), &layer_names, &options.services);
    let mut soak = Soak {
        options,
        work: work.clone(),
        reports: reports.clone(),
        started: Instant::now(),
        started_ns: skinware::os::monotonic_ns(),
        chaos: faults::Chaos::new(seed),
        skin: None,
        readers: Vec::new(),
        finished_reports: Vec::new(),
        incarnations: 0,
        monitor: monitor::Monitor::default(),
        report: SoakReport {
            config: options.source_config.clone(),
            skin: options.skin.clone(),
            seed,
            minutes: options.minutes,
            layers: options.layers.iter().map(|l| (l.name.clone(), l.taxels)).collect(),
            services: options.services.clone(),
            observer_rt_refused: observer.rt_refused.clone(),
            ..SoakReport::default()
        },
        observer,
        squats: Vec::new(),
        stopped: Vec::new(),
        helpers: Vec::new(),
    };
    let ran = soak.start_and_run();
    let stopped = soak.stop_everything();
    let mut report = soak.summarize();
    if let Err(e) = &ran {
        report.failures.push(format!("the soak itself failed: {e:#}"));
        report.passed = false;
    }
    if let Err(e) = &stopped {
        report.failures.push(format!("stopping the skin failed: {e:#}"));
        report.passed = false;
    }
    let _ = std::fs::remove_dir_all(&options.dir);
    keep_reports(&reports, &work);
    report.print();
    let path = options.run.out.join("soak.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!("written: {} (faults, recovery, processes over time); logs in {}", path.display(), work.display());
    ran?;
    Ok(report)
}

impl Soak<'_> {
    /// Seconds since the soak started.
    fn elapsed_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }

    fn interrupted(&self) -> bool {
        self.options.interrupted.load(Ordering::Relaxed)
    }

    /// A command for one of the soak's processes: in the soak's segment
    /// directory, in a process group of its own (Ctrl-C reaches the soak
    /// only, which stops everything in order), its standard error in a log.
    fn command(&self, log: &str) -> Result<Command> {
        use std::os::unix::process::CommandExt;
        let mut command = Command::new(&self.options.run.exe);
        let log = self.work.join(log);
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log)
            .with_context(|| format!("cannot open {}", log.display()))?;
        command
            .env("SKINWARE_SHM_DIR", &self.options.dir)
            .env("RUST_LOG", "warn")
            .env("NO_COLOR", "1")
            .stderr(file)
            .process_group(0);
        Ok(command)
    }

    fn start_and_run(&mut self) -> Result<()> {
        self.start_skin()?;
        for mode in reader::MODES {
            self.spawn_reader(mode)?;
        }
        self.wait_for_readers()?;
        let (viewer, address) = procs::start_viewer(
            &self.options.run.exe,
            &self.options.dir,
            &["--skin", &self.options.skin],
            Some(&self.work.join("viewer.log")),
        )?;
        self.monitor.viewer = Some(viewer);
        let browser = self
            .command("browser.log")?
            .args(["bench-soak-browser", "--address", &address, "--report"])
            .arg(self.work.join("browser.json"))
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .context("cannot start the browser-like client")?;
        self.monitor.browser = Some(browser);
        let seconds = self.options.minutes * 60.0 + 600.0;
        let mut recorder = self.command("recorder.log")?;
        recorder
            .arg("record")
            .arg(self.work.join("soak.mcap"))
            .args(["--skin", &self.options.skin, "--layers", &self.options.layers[0].name])
            .args(["--services", "--json", "--map-hz", "0", "--wait", "30", "--seconds", &format!("{seconds:.0}")])
            .stdout(Stdio::piped());
        self.monitor.recorder = Some(recorder.spawn().context("cannot start the recorder")?);
        // Everything attached and running before the first fault.
        self.idle(Duration::from_secs(3));
        println!(
            "soak: {:.1} s: the skin, {} verifying readers, the viewer, its browser and the recorder run; faults begin",
            self.elapsed_s(),
            self.readers.len()
        );
        self.run_faults()
    }

    fn start_skin(&mut self) -> Result<()> {
        let log = self.work.join("skin-run.log");
        let skin = RunningSkin::start_logged(&self.options.run.exe, &self.options.config, &self.options.dir, &log)?;
        self.monitor.skin_pid = skin.pid();
        self.skin = Some(skin);
        // The geometry of a skin not yet cached takes a while to build.
        let deadline = Instant::now() + Duration::from_secs(180);
        let since = skinware::os::monotonic_ns();
        while !self.observer.all_published_since(since) {
            if Instant::now() > deadline || self.interrupted() {
                bail!(
                    "the skin's layers and services did not all publish within 180 s of `skin run` (see {})",
                    log.display()
                );
            }
            if let Some(skin) = &mut self.skin
                && let Some(status) = skin.try_wait()
            {
                bail!("`skin run` exited ({status}) before its layers ran (see {})", log.display());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        println!("soak: {:.1} s: every layer and service publishes", self.elapsed_s());
        Ok(())
    }

    /// Starts a verifying reader process of `mode` over every layer.
    fn spawn_reader(&mut self, mode: Mode) -> Result<()> {
        self.incarnations += 1;
        let report = self.reports.join(format!("reader-{}-{}.json", mode.name(), self.incarnations));
        let layers: Vec<&str> = self.options.layers.iter().map(|l| l.name.as_str()).collect();
        let child = self
            .command(&format!("reader-{}.log", mode.name()))?
            .args([
                "bench-soak-reader",
                "--skin",
                &self.options.skin,
                "--mode",
                mode.name(),
                "--layers",
                &layers.join(","),
            ])
            .arg("--report")
            .arg(&report)
            .stdin(Stdio::piped())
            .spawn()
            .context("cannot start a verifying reader")?;
        self.readers.push(ReaderProcess {
            mode,
            child,
            report,
            since_ns: skinware::os::monotonic_ns(),
            stopped: false,
        });
        Ok(())
    }

    fn wait_for_readers(&mut self) -> Result<()> {
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            let attached = self.readers.iter().all(|r| {
                reader::ReaderReport::read(&r.report).is_some_and(|report| {
                    report.layers.len() == self.options.layers.len()
                        && report.layers.values().all(|t| t.last_new_ns > 0)
                })
            });
            if attached {
                return Ok(());
            }
            if Instant::now() > deadline || self.interrupted() {
                bail!("the verifying readers did not all get frames within 30 s (see {})", self.work.display());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Waits `duration` while watching: samples the processes, looks for
    /// stuck readers. Returns early (false) if the soak was interrupted.
    fn idle(&mut self, duration: Duration) -> bool {
        let until = Instant::now() + duration;
        loop {
            self.watch();
            if self.interrupted() {
                return false;
            }
            let now = Instant::now();
            if now >= until {
                return true;
            }
            std::thread::sleep((until - now).min(Duration::from_millis(10)));
        }
    }

    /// Stops every process of the soak, the stopped ones first resumed, and
    /// the skin last (its supervisor then removes its channels); removes the
    /// squats; notes what was left in the segment directory.
    fn stop_everything(&mut self) -> Result<()> {
        for pid in self.stopped.drain(..) {
            procs::signal(pid, rustix::process::Signal::CONT);
        }
        for squat in self.squats.drain(..) {
            squats::remove_squat(&squat);
        }
        self.helpers.clear();
        let mut readers = std::mem::take(&mut self.readers);
        for reader in &mut readers {
            procs::signal(reader.child.id(), rustix::process::Signal::CONT);
            drop(reader.child.stdin.take());
        }
        for mut reader in readers {
            let deadline = Instant::now() + Duration::from_secs(5);
            while reader.child.try_wait().ok().flatten().is_none() && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = reader.child.kill();
            let _ = reader.child.wait();
            self.finished_reports.push((reader.mode, reader.report));
        }
        self.monitor.stop_consumers(&self.work, &mut self.report);
        let stopped = match self.skin.take() {
            Some(skin) => skin.stop(Duration::from_secs(15)),
            None => Ok(()),
        };
        // What `skin run` left, and what the soak's own helpers left.
        std::thread::sleep(Duration::from_millis(200));
        let mut leaked: Vec<String> = std::fs::read_dir(&self.options.dir)
            .map(|entries| entries.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
            .unwrap_or_default();
        leaked.sort();
        self.report.leaked_channels =
            leaked.iter().filter(|name| name.starts_with("skinware.") || name.starts_with(".skinware-lock.")).count();
        self.report.leaked_files = leaked;
        stopped
    }

    /// The fault during which the browser waited longest for an update, if
    /// that wait overlapped one (from the fault's injection until every
    /// layer and service was back, plus a second).
    fn browser_gap_cause(&self, report: &SoakReport) -> Option<String> {
        let browser = report.browser.as_ref()?;
        let gap_s = browser.get("longest_gap_ms")?.as_f64()? / 1e3;
        let ended_ns = browser.get("longest_gap_ended_ns")?.as_u64()?;
        let ended_s = ended_ns.checked_sub(self.started_ns)? as f64 / 1e9;
        let fault = report.faults.iter().find(|f| {
            let back_s = f.services_back_after_end_ms.or(f.back_after_end_ms).unwrap_or(0.0) / 1e3;
            ended_s - gap_s <= f.ended_s + back_s + 1.0 && ended_s >= f.injected_s
        });
        Some(match fault {
            Some(f) => {
                format!("{:.0} ms, ending at {ended_s:.1} s: during fault {} ({})", gap_s * 1e3, f.index, f.kind)
            }
            None => format!("{:.0} ms, ending at {ended_s:.1} s: during no fault", gap_s * 1e3),
        })
    }

    /// Adds up the readers' reports and the recovery times, and gives the verdict.
    fn summarize(&mut self) -> SoakReport {
        let mut report = std::mem::take(&mut self.report);
        report.seconds = self.monitor.faults_seconds;
        for (mode, path) in &self.finished_reports {
            let totals = report.readers.entry(mode.name().to_owned()).or_default();
            totals.incarnations += 1;
            match reader::ReaderReport::read(path) {
                Some(found) => {
                    for tally in found.layers.values() {
                        totals.counts.add(tally);
                        report.totals.add(tally);
                    }
                }
                None => totals.killed_before_reporting += 1,
            }
        }
        faults::summarize_recovery(&mut report);
        report.browser_longest_gap_during = self.browser_gap_cause(&report);
        report.processes = self.monitor.series();
        report.segment_files_max = self.monitor.segment_files_max;
        report.supervisor_restarts = std::fs::read_to_string(self.work.join("skin-run.log"))
            .map(|log| log.lines().filter(|line| line.contains("restarted")).count())
            .unwrap_or(0);
        let t = &report.totals;
        let mut failures = Vec::new();
        if t.torn > 0 {
            failures.push(format!("{} torn frame(s); the first: {}", t.torn, t.first_torn.clone().unwrap_or_default()));
        }
        if t.backwards > 0 {
            failures.push(format!("{} frame(s) whose sequence number went backwards", t.backwards));
        }
        if t.lost_silently > 0 {
            failures.push(format!("{} frame(s) lost without Frame::skipped counting them", t.lost_silently));
        }
        if t.over_counted > 0 {
            failures.push(format!("Frame::skipped counted {} frame(s) more than were lost", t.over_counted));
        }
        if !report.stuck_readers.is_empty() {
            failures.push(format!("{} stuck reader episode(s)", report.stuck_readers.len()));
        }
        if report.leaked_channels > 0 {
            failures.push(format!("{} channel file(s) left in the segment directory", report.leaked_channels));
        }
        if t.verified == 0 {
            failures.push("no frame was verified at all".into());
        }
        report.passed = failures.is_empty();
        report.failures = failures;
        report
    }
}
