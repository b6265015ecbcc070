//! `skin bench kilohertz`: the paper's skin (5 layers, 30,848 taxels) at
//! 1 kHz, first alone (the control), then with everything that reads it:
//! 15 application processes, both services at 1 kHz, the viewer with 3
//! browsers and the recorder. Then the viewer alone with 1 and 10 browsers,
//! and with one slow browser among them; beside it, in the same rounds, the
//! [`floor`] server with 1 and 10 browsers: what a browser costs when
//! nothing but its messages is done for it.
//!
//! The figures come from where they are made: each writer's shared
//! statistics (frames, missed periods, overruns, and its publish and
//! lateness histograms, taken as the difference between the start and the
//! end of the measured window), `/proc` for the CPU of every process, and
//! the consumers themselves for the latency from acquisition. The browsers
//! are WebSocket clients that speak the page's protocol (`docs/viewer.md`)
//! and acknowledge what they received at a display's 59.94 Hz (a slow one at
//! 5 Hz), so that the viewer's cost is measured without a browser's
//! rendering competing for the same two cores.

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{Reader, ReaderOptions, WriterStats, histogram_quantile};
use skinware_bench::app::AppSamples;
use skinware_bench::measure::{Percentiles, RunningSkin};
use skinware_bench::procs::{Guarded, start_viewer, supervised_pids};

use super::bench::Common;

pub mod floor;

const PAPER_SKIN: &str = include_str!("../../../../../examples/paper-virtual-skin.toml");
const LAYERS: usize = 5;
/// Taxels of the paper's skin, over its layers.
const TAXELS: usize = 30_848;
const APPS: usize = 15;
/// Applications that wait for every frame; the others read periodically at
/// random 10–100 Hz, as in the paper's experiment.
const ASAP_APPS: usize = 5;
const BROWSERS: usize = 3;
/// The browsers' display: the 59.94 Hz that "60 Hz" displays often run at.
/// A display's clock is not the skin's: at exactly 60 Hz on the writers'
/// own clock, each acknowledgement would come at the same few points of the
/// writers' 1 kHz period for a whole run, and a run would measure the
/// browsers at one phase of the skin instead of all of them.
const DISPLAY_HZ: f64 = 60_000.0 / 1_001.0;
/// Rounds of 1 and then 10 browsers (one in a quick run).
const VIEWER_ROUNDS: usize = 3;
const SLOW_BROWSER_HZ: f64 = 5.0;

/// One writer's figures over the measured window.
#[derive(Debug, Serialize)]
struct WriterFigures {
    layer: String,
    frames: u64,
    rate_hz: f64,
    missed_periods: u64,
    overruns: u64,
    /// Upper edges of the power-of-two histogram buckets, ns.
    publish_p50_ns: u64,
    publish_p99_ns: u64,
    publish_max_ns: u64,
    lateness_p99_ns: u64,
}

/// One run of the skin: the control or the loaded one.
#[derive(Debug, Serialize)]
struct PhaseReport {
    phase: String,
    seconds: f64,
    writers: Vec<WriterFigures>,
    /// Percent of one CPU, per component.
    cpu_percent: BTreeMap<String, f64>,
    /// From acquisition to each consumer holding the data, per consumer.
    latency_us: BTreeMap<String, Percentiles>,
    /// What the recorder said at the end (frames, lost, ...), if it ran.
    recorder: Option<serde_json::Value>,
    /// What the browsers received.
    browsers: Vec<BrowserFigures>,
}

#[derive(Clone, Debug, Default, Serialize)]
struct BrowserFigures {
    ack_hz: f64,
    updates_per_s: f64,
    kb_per_update: f64,
    /// From the acquisition of layer 0's newest frame to the update holding it, µs.
    latency_us: Percentiles,
}

/// The viewer with N browsers at once.
#[derive(Debug, Serialize)]
struct ViewerRun {
    /// The round of 1 and 10 browsers this run belongs to (the slow browser's run: the last).
    round: usize,
    browsers: usize,
    /// Whether one of them is the slow browser.
    with_slow_browser: bool,
    /// The window measured, seconds.
    seconds: f64,
    /// The viewer's threads' run time (`/proc/PID/task/*/schedstat`, in ns)
    /// over the window, in % of one core.
    viewer_cpu_percent: f64,
    /// Threads of the viewer that ended during the window, whose run time in
    /// it `viewer_cpu_percent` misses (0 in a sound run).
    viewer_threads_ended: usize,
    /// The same from `/proc/PID/stat`'s utime + stime, in clock ticks (what
    /// this bench reported before 2026-11-25: a tick is 1 % of a core-second).
    viewer_cpu_percent_ticks: f64,
    /// Of `viewer_cpu_percent`, the browsers' own threads (one per
    /// connection; not the shared layer readers): what the browsers cost,
    /// without the readers' share, which moves by up to a point between runs.
    sessions_cpu_percent: f64,
    per_browser: Vec<BrowserFigures>,
}

/// The [`floor`] server with N browsers.
#[derive(Debug, Serialize)]
struct FloorRun {
    /// The round of the viewer's runs this one was measured in.
    round: usize,
    browsers: usize,
    /// The window measured, seconds.
    seconds: f64,
    /// The run time of the floor server's browser threads (one per
    /// browser; not its rewriter or layer readers) over the window
    /// (schedstat, ns), in % of one core.
    cpu_percent: f64,
    /// The same for all its threads (with the rewriter, or the layer
    /// readers with `--floor-reads-skin`).
    process_cpu_percent: f64,
    /// Threads of the floor server that ended during the window (0 in a sound run).
    threads_ended: usize,
    per_browser: Vec<BrowserFigures>,
}

/// What one more browser costs, in % of one core, the median over the
/// rounds: (CPU with 10 browsers − CPU with 1) / 9, and each browser's own
/// thread with 10 browsers (its CPU / 10), which the layer readers' share
/// does not move.
#[derive(Debug, Default, Serialize)]
struct BrowserCost {
    viewer: f64,
    /// The floor server: one message of `floor_bytes` per acknowledgement.
    floor: f64,
    /// A viewer session's thread, with 10 browsers.
    viewer_session: f64,
    /// A floor server's browser thread, with 10 browsers.
    floor_thread: f64,
}

#[derive(Debug, Serialize)]
struct KilohertzReport {
    rate_hz: f64,
    taxels: usize,
    /// `reader_wake` of the layers' writers (`default`: not set).
    reader_wake: String,
    /// The `skin` executable that ran the viewer (`--viewer-exe`, or this one).
    viewer_exe: String,
    phases: Vec<PhaseReport>,
    viewer: Vec<ViewerRun>,
    /// `viewer_cpu_percent` with 10 browsers over that with 1: the median
    /// of [`viewer_cpu_ratios`](Self::viewer_cpu_ratios).
    viewer_cpu_ratio_10_to_1: f64,
    /// The same ratio in each round (1 browser, then 10, alternating: the
    /// machine's mood moves the readers' share between runs).
    viewer_cpu_ratios: Vec<f64>,
    /// The floor server with 1 and 10 browsers, in the same rounds.
    floor: Vec<FloorRun>,
    /// Bytes of the floor server's message: by default the viewer's update,
    /// 61,832 (`--floor-bytes`); with `floor_reads_skin`, the skin's own
    /// update, which is that size on this skin.
    floor_bytes: usize,
    /// Whether the floor server read the skin's layers with the viewer's
    /// readers and sent their board (`--floor-reads-skin`), rather than a
    /// stand-in rewritten every millisecond.
    floor_reads_skin: bool,
    /// The floor server's whole CPU with 10 browsers over 1, the median of
    /// the rounds: with `floor_reads_skin`, the ratio of a viewer whose
    /// sessions cost only the message.
    floor_cpu_ratio_10_to_1: f64,
    /// What one more browser costs the viewer and the floor server.
    browser_cost_percent: BrowserCost,
    /// The 10/1 ratio the viewer would have if each browser cost it what
    /// one costs the floor server, the rest of its CPU as measured with one
    /// browser: (S + 10 f) / (S + f), S = the viewer's CPU with 1 browser −
    /// the viewer's cost of a browser, f = the floor's; the median over the rounds.
    viewer_cpu_ratio_at_floor: f64,
}

/// A part of the bench that runs alone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Part {
    /// The viewer alone with 1, 10 and 9 + 1 slow browsers (no control or loaded run).
    Viewer,
    /// The control and the loaded run (no viewer scaling).
    Runs,
}

/// `reader_wake` for the layers' writers, as in a config's `[driver.rt]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Wake {
    /// A lookout spinning on another CPU when each frame is due.
    Lookout,
    /// A ringer on the writer's CPU, once the writer sleeps.
    Ringer,
    /// The writer's own thread.
    Writer,
}

impl Wake {
    fn name(self) -> &'static str {
        match self {
            Wake::Lookout => "lookout",
            Wake::Ringer => "ringer",
            Wake::Writer => "writer",
        }
    }
}

/// Bytes of the viewer's update of the paper's skin at 1 kHz (every layer's
/// responses, no overlays): the floor server's message unless told otherwise.
const UPDATE_BYTES: usize = skinware_viewer::protocol::UPDATE_HEADER_BYTES
    + LAYERS * skinware_viewer::protocol::LAYER_RECORD_BYTES
    + 2 * TAXELS;

/// What `skin bench kilohertz` runs, besides the options every bench takes.
#[derive(Clone, Copy, Debug, Default)]
pub struct Options<'a> {
    /// Measure this `skin` build's viewer rather than this one's (a before/after).
    pub viewer_exe: Option<&'a Path>,
    /// Run one part only (into a JSON file of its own, whose `phases` are empty).
    pub only: Option<Part>,
    /// `reader_wake` of the layers' writers; the library's default if `None`.
    pub wake: Option<Wake>,
    /// Bytes of the floor server's message; [`UPDATE_BYTES`] if `None`.
    pub floor_bytes: Option<usize>,
    /// The floor server reads the skin's layers as the viewer does.
    pub floor_reads_skin: bool,
}

/// Runs `skin bench kilohertz`.
pub fn bench(common: &Common, options: &Options) -> Result<()> {
    let Options { viewer_exe, only, wake, floor_bytes, floor_reads_skin } = *options;
    if floor_bytes.is_some() && floor_reads_skin {
        bail!("--floor-reads-skin sends the skin's frames, whose size is the skin's: drop --floor-bytes");
    }
    if only == Some(Part::Runs) && (floor_bytes.is_some() || floor_reads_skin) {
        bail!(
            "--floor-bytes and --floor-reads-skin set the floor server of the viewer part, which --only runs \
             leaves out: drop one of them"
        );
    }
    let seconds = common.seconds.unwrap_or(if common.quick { 3.0 } else { 15.0 });
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&common.out).with_context(|| format!("cannot create {}", common.out.display()))?;
    let exe = std::env::current_exe().context("cannot find this executable")?;
    let viewer_exe = viewer_exe.map(Path::to_path_buf).unwrap_or_else(|| exe.clone());
    let dir = skinware::shm::segment_dir().join(format!("skk{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let rounds = if common.quick { 1 } else { VIEWER_ROUNDS };
    let floor_bytes = floor_bytes.unwrap_or(UPDATE_BYTES);
    let floor = Floor { bytes: floor_bytes, reads_skin: floor_reads_skin };
    let result = measure(&exe, (&viewer_exe, floor), &dir, (seconds, rounds), &common.out, only, wake);
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    print(&report);
    let path = common.out.join(match only {
        Some(Part::Viewer) => "kilohertz-viewer.json",
        Some(Part::Runs) => "kilohertz-runs.json",
        None => "kilohertz.json",
    });
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("written: {}", path.display());
    Ok(())
}

fn measure(
    exe: &Path,
    // The viewer part's two servers: whose viewer, and what the floor does.
    (viewer_exe, floor_options): (&Path, Floor),
    dir: &Path,
    (seconds, rounds): (f64, usize),
    out: &Path,
    only: Option<Part>,
    wake: Option<Wake>,
) -> Result<KilohertzReport> {
    let phases = match only {
        Some(Part::Viewer) => Vec::new(),
        _ => vec![
            run_phase(exe, viewer_exe, (dir, wake), seconds, false, out)?,
            run_phase(exe, viewer_exe, (dir, wake), seconds, true, out)?,
        ],
    };
    let (viewer, floor) = if only == Some(Part::Runs) {
        (Vec::new(), Vec::new())
    } else {
        viewer_scaling(exe, viewer_exe, dir, seconds, rounds, floor_options)?
    };
    let cpu = |round: usize, n: usize| {
        let run = viewer.iter().find(|run| run.round == round && run.browsers == n && !run.with_slow_browser);
        run.map(|run| run.viewer_cpu_percent)
    };
    let floor_cpu = |round: usize, n: usize| {
        floor.iter().find(|run| run.round == round && run.browsers == n).map(|run| run.cpu_percent)
    };
    let ratios: Vec<f64> = (0..rounds).filter_map(|round| Some(cpu(round, 10)? / cpu(round, 1)?.max(1e-9))).collect();
    let ratio = median(&ratios);
    let per_browser = |one: Option<f64>, ten: Option<f64>| Some((ten? - one?) / 9.0);
    let viewer_costs: Vec<f64> = (0..rounds).filter_map(|round| per_browser(cpu(round, 1), cpu(round, 10))).collect();
    let floor_costs: Vec<f64> =
        (0..rounds).filter_map(|round| per_browser(floor_cpu(round, 1), floor_cpu(round, 10))).collect();
    let of_ten = |runs: Vec<f64>| median(&runs.iter().map(|cpu| cpu / 10.0).collect::<Vec<_>>());
    let viewer_session = of_ten(
        viewer
            .iter()
            .filter(|run| run.browsers == 10 && !run.with_slow_browser)
            .map(|run| run.sessions_cpu_percent)
            .collect(),
    );
    let floor_thread = of_ten(floor.iter().filter(|run| run.browsers == 10).map(|run| run.cpu_percent).collect());
    let ratios_at_floor: Vec<f64> = (0..rounds)
        .filter_map(|round| {
            let own = cpu(round, 1)? - per_browser(cpu(round, 1), cpu(round, 10))?;
            let browser = per_browser(floor_cpu(round, 1), floor_cpu(round, 10))?;
            // A round whose browsers measured dearer than its whole 1-browser run says nothing.
            (own > 0.0 && browser >= 0.0).then(|| (own + 10.0 * browser) / (own + browser))
        })
        .collect();
    let floor_process = |round: usize, n: usize| {
        floor.iter().find(|run| run.round == round && run.browsers == n).map(|run| run.process_cpu_percent)
    };
    let floor_ratios: Vec<f64> =
        (0..rounds).filter_map(|round| Some(floor_process(round, 10)? / floor_process(round, 1)?.max(1e-9))).collect();
    let reader_wake = wake.map_or("default", Wake::name).to_owned();
    Ok(KilohertzReport {
        rate_hz: 1000.0,
        taxels: TAXELS,
        reader_wake,
        viewer_exe: viewer_exe.display().to_string(),
        phases,
        viewer,
        viewer_cpu_ratio_10_to_1: ratio,
        viewer_cpu_ratios: ratios,
        floor,
        floor_bytes: floor_options.bytes,
        floor_reads_skin: floor_options.reads_skin,
        floor_cpu_ratio_10_to_1: median(&floor_ratios),
        browser_cost_percent: BrowserCost {
            viewer: median(&viewer_costs),
            floor: median(&floor_costs),
            viewer_session,
            floor_thread,
        },
        viewer_cpu_ratio_at_floor: median(&ratios_at_floor),
    })
}

/// The paper's skin at 1 kHz; with its services (also at 1 kHz) or none.
fn config(with_services: bool, wake: Option<Wake>) -> Result<String> {
    let layers_at = "rate_hz = { random = [30, 50] }";
    let rt = "[driver.rt]\n";
    if !PAPER_SKIN.contains(layers_at) || PAPER_SKIN.matches(rt).count() != 1 {
        bail!(
            "examples/paper-virtual-skin.toml no longer sets {layers_at:?} and one {rt:?}; update the kilohertz bench"
        );
    }
    let mut text = PAPER_SKIN.replace(layers_at, "rate_hz = 1000");
    if let Some(wake) = wake {
        text = text.replace(rt, &format!("{rt}reader_wake = \"{}\"\n", wake.name()));
    }
    Ok(match text.split_once("[[service]]") {
        Some((skin, services)) if with_services => {
            format!("{skin}[[service]]{}", services.replace("rate_hz = 50", "rate_hz = 1000"))
        }
        Some((skin, _)) => skin.to_owned(),
        None => bail!("examples/paper-virtual-skin.toml has no services; update the kilohertz bench"),
    })
}

fn start_skin(
    exe: &Path,
    (dir, wake): (&Path, Option<Wake>),
    with_services: bool,
) -> Result<(RunningSkin, Vec<Reader>)> {
    let path = dir.join(if with_services { "loaded.toml" } else { "control.toml" });
    std::fs::write(&path, config(with_services, wake)?)?;
    let skin = RunningSkin::start(exe, &path, dir)?;
    let options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut readers = Vec::new();
    for layer in 0..LAYERS {
        let name = format!("virtual-{layer}");
        let reader = loop {
            match Reader::open_with("default", &name, &options) {
                Ok(reader) => break reader,
                Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(100)),
                Err(e) => return Err(e).context(format!("the skin's layer {name} did not appear within 30 s")),
            }
        };
        readers.push(reader);
    }
    if with_services {
        for service in ["contact", "motion"] {
            while Reader::open_with("default", service, &options).is_err() {
                if Instant::now() > deadline {
                    bail!("the {service} service did not appear within 30 s");
                }
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
    Ok((skin, readers))
}

fn run_phase(
    exe: &Path,
    viewer_exe: &Path,
    (dir, wake): (&Path, Option<Wake>),
    seconds: f64,
    loaded: bool,
    out: &Path,
) -> Result<PhaseReport> {
    let phase = if loaded { "loaded" } else { "control" };
    eprintln!("kilohertz: {phase} run, {seconds} s");
    let (skin, readers) = start_skin(exe, (dir, wake), loaded)?;
    let skin_pid = skin.pid();
    let stop = Arc::new(AtomicBool::new(false));
    let marks = Arc::new(WindowMarks::default());
    let clock = SeqClock::start(dir, stop.clone());
    let mut apps = Vec::new();
    let mut viewer = None;
    let mut recorder = None;
    let mut browser_threads = Vec::new();
    let mut service_probe = None;
    let work = out.join("kilohertz-work");
    std::fs::create_dir_all(&work)?;
    if loaded {
        for app in 0..APPS {
            let mode = if app < ASAP_APPS { "asap" } else { "periodic" };
            let samples = work.join(format!("app-{app}.json"));
            let layers: Vec<String> = (0..LAYERS).map(|l| format!("virtual-{l}")).collect();
            let child = Command::new(exe)
                .arg("bench-app")
                .args(["--skin", "default", "--layers", &layers.join(","), "--mode", mode])
                .args(["--seconds", &(seconds + 2.0).to_string(), "--seed", &(app as u64 + 1).to_string()])
                .arg("--out")
                .arg(&samples)
                .env("SKINWARE_SHM_DIR", dir)
                .spawn()
                .context("cannot start an application process")?;
            apps.push((Guarded(child), samples));
        }
        let (child, address) = start_viewer(viewer_exe, dir, &[], None)?;
        viewer = Some(child);
        for _ in 0..BROWSERS {
            let (stop, marks, clock, address) = (stop.clone(), marks.clone(), clock.clone(), address.clone());
            browser_threads.push(std::thread::spawn(move || browse(&address, DISPLAY_HZ, (&stop, &marks), &clock)));
        }
        let file = work.join("kilohertz.mcap");
        let _ = std::fs::remove_file(&file);
        let child = Command::new(exe)
            .arg("record")
            .arg(&file)
            .args(["--services", "--json", "--seconds", &(seconds + 2.0).to_string()])
            .env("SKINWARE_SHM_DIR", dir)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .context("cannot start the recorder")?;
        recorder = Some(Guarded(child));
        service_probe = Some(ServiceProbe::start(dir, stop.clone()));
    }
    // Every consumer attached and running before the window opens.
    std::thread::sleep(Duration::from_secs(1));
    let mut pids: Vec<(String, u32)> = vec![("skin run (supervisor)".into(), skin_pid)];
    pids.extend(supervised_pids(skin_pid));
    for (index, (app, _)) in apps.iter().enumerate() {
        let kind = if index < ASAP_APPS { "apps (5 asap)" } else { "apps (10 periodic)" };
        pids.push((kind.into(), app.0.id()));
    }
    if let Some(viewer) = &viewer {
        pids.push(("viewer (3 browsers)".into(), viewer.0.id()));
    }
    if let Some(recorder) = &recorder {
        pids.push(("recorder".into(), recorder.0.id()));
    }
    let before_stats: Vec<WriterStats> = readers.iter().map(Reader::writer_stats).collect();
    let before_cpu = cpu_ticks(&pids);
    let started = Instant::now();
    let _ = marks.start.set(started);
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let _ = marks.end.set(Instant::now());
    let elapsed = started.elapsed().as_secs_f64();
    let after_cpu = cpu_ticks(&pids);
    let after_stats: Vec<WriterStats> = readers.iter().map(Reader::writer_stats).collect();
    stop.store(true, Ordering::Relaxed);
    let writers = before_stats
        .iter()
        .zip(&after_stats)
        .enumerate()
        .map(|(layer, (before, after))| writer_figures(format!("virtual-{layer}"), before, after, elapsed))
        .collect();
    let mut cpu_percent = BTreeMap::new();
    for ((name, _), (before, after)) in pids.iter().zip(before_cpu.iter().zip(&after_cpu)) {
        let ticks = after.saturating_sub(*before) as f64;
        *cpu_percent.entry(name.clone()).or_insert(0.0) += 100.0 * ticks / clock_ticks_per_s() / elapsed;
    }
    let mut latency_us = BTreeMap::new();
    let mut browsers = Vec::new();
    for thread in browser_threads {
        let figures = thread.join().map_err(|_| anyhow::anyhow!("a browser thread panicked"))??;
        browsers.push(figures);
    }
    for (index, browser) in browsers.iter().enumerate() {
        latency_us.insert(format!("viewer → browser {}", index + 1), browser.latency_us);
    }
    if let Some(probe) = service_probe {
        for (name, mut samples) in probe.finish()? {
            latency_us.insert(format!("{name} service (output visible)"), Percentiles::of(&mut samples));
        }
    }
    let mut asap = Vec::new();
    let mut periodic = Vec::new();
    for (index, (app, samples)) in apps.into_iter().enumerate() {
        let mut child = app;
        let status = child.0.wait()?;
        if !status.success() {
            bail!("application process {index} failed ({status})");
        }
        let samples: AppSamples = serde_json::from_slice(&std::fs::read(&samples)?)?;
        let into = if index < ASAP_APPS { &mut asap } else { &mut periodic };
        into.extend(samples.latency_ns.into_iter().flatten().map(|ns| ns / 1_000));
    }
    if !asap.is_empty() {
        latency_us.insert("apps, asap (wait_newer)".into(), Percentiles::of(&mut asap));
        latency_us.insert("apps, periodic 10–100 Hz (frame age)".into(), Percentiles::of(&mut periodic));
    }
    let recorder = match recorder {
        Some(mut child) => {
            let mut stdout = child.0.stdout.take().context("the recorder's output")?;
            child.0.wait()?;
            let mut text = String::new();
            std::io::Read::read_to_string(&mut stdout, &mut text)?;
            serde_json::from_str(&text).ok()
        }
        None => None,
    };
    drop(viewer);
    drop(clock);
    drop(skin);
    let _ = std::fs::remove_dir_all(&work);
    Ok(PhaseReport { phase: phase.into(), seconds: elapsed, writers, cpu_percent, latency_us, recorder, browsers })
}

fn writer_figures(layer: String, before: &WriterStats, after: &WriterStats, seconds: f64) -> WriterFigures {
    let delta = |a: &[u64; 32], b: &[u64; 32]| {
        let mut out = [0u64; 32];
        for (slot, (x, y)) in out.iter_mut().zip(a.iter().zip(b)) {
            *slot = y.saturating_sub(*x);
        }
        out
    };
    let write = delta(&before.write_histogram, &after.write_histogram);
    let lateness = delta(&before.lateness_histogram, &after.lateness_histogram);
    let frames = after.frames - before.frames;
    WriterFigures {
        layer,
        frames,
        rate_hz: frames as f64 / seconds,
        missed_periods: after.missed_periods - before.missed_periods,
        overruns: after.overruns - before.overruns,
        publish_p50_ns: histogram_quantile(&write, 0.5),
        publish_p99_ns: histogram_quantile(&write, 0.99),
        publish_max_ns: histogram_quantile(&write, 1.0),
        lateness_p99_ns: histogram_quantile(&lateness, 0.99),
    }
}

fn clock_ticks_per_s() -> f64 {
    rustix::param::clock_ticks_per_second() as f64
}

/// The median of `values` (0 for none).
fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    match sorted.len() {
        0 => 0.0,
        n if n % 2 == 1 => sorted[n / 2],
        n => (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0,
    }
}

/// The run time of each thread of process `pid` now (only those whose
/// names start with `named`, if given), in ns, by thread id (the first field of
/// `/proc/PID/task/TID/schedstat`): exact, where utime + stime count whole
/// clock ticks, each charged to whoever ran when it struck. Empty if the
/// process is gone.
fn thread_cpu_ns(pid: u32, named: Option<&str>) -> BTreeMap<u32, u64> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return BTreeMap::new() };
    tasks
        .flatten()
        .filter_map(|task| {
            let tid = task.file_name().to_str()?.parse::<u32>().ok()?;
            if let Some(named) = named {
                let comm = std::fs::read_to_string(task.path().join("comm")).ok()?;
                if !comm.starts_with(named) {
                    return None;
                }
            }
            let stat = std::fs::read_to_string(task.path().join("schedstat")).ok()?;
            Some((tid, stat.split_whitespace().next()?.parse::<u64>().ok()?))
        })
        .collect()
}

/// The run time between two [`thread_cpu_ns`] readings, in ns, and how many
/// threads ended in between (whose time since `before` is lost: schedstat
/// dies with its thread, where utime + stime keep it). A thread that both
/// started and ended in between is neither counted nor reported.
fn cpu_ns_between(before: &BTreeMap<u32, u64>, after: &BTreeMap<u32, u64>) -> (u64, usize) {
    let ran = after.iter().map(|(tid, ns)| ns.saturating_sub(before.get(tid).copied().unwrap_or(0))).sum();
    (ran, before.keys().filter(|tid| !after.contains_key(tid)).count())
}

/// utime + stime of each process, in clock ticks (0 for one that is gone).
fn cpu_ticks(pids: &[(String, u32)]) -> Vec<u64> {
    pids.iter()
        .map(|(_, pid)| {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            // Fields after the command name, which may hold spaces, in parentheses.
            let fields: Vec<&str> = stat.rsplit_once(')').map_or(vec![], |(_, rest)| rest.split_whitespace().collect());
            let field = |n: usize| fields.get(n).and_then(|f| f.parse::<u64>().ok()).unwrap_or(0);
            field(11) + field(12)
        })
        .collect()
}

/// Acquisition times of layer 0's frames by sequence number, for the
/// browsers to date what they receive. Its reader stops with `stop`, or
/// when the last clone is dropped.
#[derive(Clone)]
struct SeqClock {
    table: Arc<Mutex<BTreeMap<u64, u64>>>,
    _stop: Arc<StopOnDrop>,
}

/// Sets its flag when dropped.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

impl SeqClock {
    fn start(dir: &Path, stop: Arc<AtomicBool>) -> SeqClock {
        let table = Arc::new(Mutex::new(BTreeMap::new()));
        let clock = SeqClock { table: table.clone(), _stop: Arc::new(StopOnDrop(stop.clone())) };
        let options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
        std::thread::spawn(move || {
            let Ok(mut reader) = Reader::open_with("default", "virtual-0", &options) else { return };
            while !stop.load(Ordering::Relaxed) {
                if let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) {
                    let (seq, acquired) = (frame.seq(), frame.acquired_ns());
                    let mut table = table.lock().unwrap_or_else(|p| p.into_inner());
                    table.insert(seq, acquired);
                    while table.len() > 20_000 {
                        table.pop_first();
                    }
                }
            }
        });
        clock
    }

    fn acquired(&self, seq: u64) -> Option<u64> {
        self.table.lock().unwrap_or_else(|p| p.into_inner()).get(&seq).copied()
    }
}

/// Reads the services' channels as soon as they publish: from their inputs'
/// acquisition to their output being visible.
struct ServiceProbe(Vec<(String, std::thread::JoinHandle<Vec<u64>>)>);

impl ServiceProbe {
    fn start(dir: &Path, stop: Arc<AtomicBool>) -> ServiceProbe {
        let threads = ["contact", "motion"]
            .into_iter()
            .map(|service| {
                let options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
                let stop = stop.clone();
                let thread = std::thread::spawn(move || {
                    let mut samples = Vec::new();
                    let Ok(mut reader) = Reader::open_with("default", service, &options) else { return samples };
                    while !stop.load(Ordering::Relaxed) {
                        if let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) {
                            samples.push(frame.published_ns().saturating_sub(frame.acquired_ns()) / 1_000);
                        }
                    }
                    samples
                });
                (service.to_owned(), thread)
            })
            .collect();
        ServiceProbe(threads)
    }

    fn finish(self) -> Result<Vec<(String, Vec<u64>)>> {
        self.0
            .into_iter()
            .map(|(name, thread)| Ok((name, thread.join().map_err(|_| anyhow::anyhow!("a probe thread panicked"))?)))
            .collect()
    }
}

/// What the [`floor`] server does.
#[derive(Clone, Copy, Debug)]
struct Floor {
    /// Bytes of its message.
    bytes: usize,
    /// It reads the skin's layers as the viewer does (`--read-skin`).
    reads_skin: bool,
}

/// Starts the [`floor`] server (`skin bench-floor`) on the skin in segment
/// directory `dir`; returns it and where it listens.
fn start_floor(exe: &Path, floor: Floor, dir: &Path) -> Result<(Guarded, String)> {
    use std::io::BufRead;
    let mut command = Command::new(exe);
    command.args(["bench-floor", "--bytes", &floor.bytes.to_string()]).env("SKINWARE_SHM_DIR", dir);
    if floor.reads_skin {
        command.args(["--read-skin", "default"]);
    }
    let mut child = command
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .context("cannot start the floor server (`skin bench-floor`)")?;
    let stdout = child.stdout.take().context("the floor server's stdout")?;
    let child = Guarded(child);
    let mut address = String::new();
    std::io::BufReader::new(stdout).read_line(&mut address).context("cannot read the floor server's address")?;
    let address = address.trim().to_owned();
    if address.is_empty() {
        bail!("the floor server (`skin bench-floor`) exited before it said where it listens");
    }
    Ok((child, address))
}

/// Updates per second count only what a browser received inside the
/// measured window, which its caller marks here.
#[derive(Debug, Default)]
struct WindowMarks {
    start: OnceLock<Instant>,
    end: OnceLock<Instant>,
}

impl WindowMarks {
    fn contains(&self, at: Instant) -> bool {
        self.start.get().is_some_and(|start| at >= *start) && self.end.get().is_none_or(|end| at < *end)
    }

    fn seconds(&self) -> Option<f64> {
        Some(self.end.get()?.duration_since(*self.start.get()?).as_secs_f64())
    }
}

/// One browser: takes the geometry, then acknowledges the updates it
/// received `ack_hz` times a second, as a page does after each animation
/// frame that drew something.
fn browse(
    address: &str,
    ack_hz: f64,
    (stop, marks): (&AtomicBool, &WindowMarks),
    clock: &SeqClock,
) -> Result<BrowserFigures> {
    use skinware_viewer::session::{BrowserStream, Reads};
    use tungstenite::Message;
    let stream = BrowserStream::new(TcpStream::connect(address)?);
    let (mut socket, _) = tungstenite::client(format!("ws://{address}/ws"), stream)
        .map_err(|e| anyhow::anyhow!("WebSocket handshake with the viewer failed: {e}"))?;
    // Reads that find nothing return at once (writes still block); the
    // waiting is done by `poll`, whose timeout is a high-resolution timer. A
    // socket's read timeout counts in the kernel's ticks, which are in step
    // with the writers' periods: every acknowledgement of a run then came at
    // the same point of the skin's millisecond.
    socket.get_mut().reads = Reads::DontWait;
    let period = Duration::from_secs_f64(1.0 / ack_hz);
    let mut geometry = false;
    let (mut updates, mut bytes, mut unacked, mut in_window) = (0u64, 0u64, 0u32, 0u64);
    let mut latency = Vec::new();
    let mut last_seq = 0;
    let started = Instant::now();
    let mut next_ack = started + period;
    while !stop.load(Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Binary(data)) if data.first() == Some(&1) && !geometry => {
                geometry = true;
                socket.send(Message::text(r#"{"ack":2}"#))?;
            }
            Ok(Message::Binary(data)) if data.first() == Some(&2) => {
                updates += 1;
                if marks.contains(Instant::now()) {
                    in_window += 1;
                }
                bytes += data.len() as u64;
                unacked += 1;
                if let Some(seq) = data.get(32..40).map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
                    && seq != last_seq
                {
                    last_seq = seq;
                    if let Some(acquired) = clock.acquired(seq) {
                        latency.push(skinware::os::monotonic_ns().saturating_sub(acquired) / 1_000);
                    }
                }
            }
            Ok(Message::Text(text)) => bail!("the viewer refused the browser: {text}"),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {
                // Asleep until an update comes or the next acknowledgement
                // is due, as a page is between its animation frames (a client
                // that polled every 2 ms, before, loaded the machine with
                // wake-ups that grew with the browsers).
                let until_ack = next_ack.saturating_duration_since(Instant::now());
                let timeout = rustix::time::Timespec::try_from(until_ack)?;
                let mut readable = [rustix::event::PollFd::new(&socket.get_ref().stream, rustix::event::PollFlags::IN)];
                match rustix::event::poll(&mut readable, Some(&timeout)) {
                    Ok(_) | Err(rustix::io::Errno::INTR) => {}
                    Err(e) => return Err(std::io::Error::from(e).into()),
                }
            }
            Err(e) => return Err(e.into()),
        }
        let now = Instant::now();
        if now >= next_ack {
            if unacked > 0 {
                socket.send(Message::text(format!(r#"{{"ack":{unacked}}}"#)))?;
                unacked = 0;
            }
            while next_ack <= now {
                next_ack += period;
            }
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    let _ = socket.close(None);
    Ok(BrowserFigures {
        ack_hz,
        updates_per_s: marks.seconds().map_or(updates as f64 / seconds, |window| in_window as f64 / window),
        kb_per_update: bytes as f64 / 1e3 / updates.max(1) as f64,
        latency_us: Percentiles::of(&mut latency),
    })
}

/// The run time of some threads now, in ns, by thread id ([`thread_cpu_ns`]).
type RunTimes<'a> = dyn Fn() -> BTreeMap<u32, u64> + 'a;

/// What a window with browsers measured.
struct Window {
    seconds: f64,
    /// Run time of the measured threads in the window, ns.
    ran_ns: u64,
    /// Measured threads that ended in the window.
    threads_ended: usize,
    /// Clock ticks of the measured process in the window (the viewer's only).
    ticks: u64,
    /// Run time of the threads `part` measured in the window, ns.
    part_ns: u64,
    per_browser: Vec<BrowserFigures>,
}

/// Browsers acknowledging at `plan`'s rates on `address`: 1 s to settle,
/// then `seconds` measured by `threads` (run time by thread id) and `ticks`;
/// `check` runs at the end of the window, right after the browsers are told
/// to stop and before they are joined.
fn with_browsers(
    address: &str,
    plan: &[f64],
    (dir, seconds): (&Path, f64),
    (threads, part): (&RunTimes<'_>, &RunTimes<'_>),
    ticks: &dyn Fn() -> u64,
    check: &mut dyn FnMut(&BTreeMap<u32, u64>) -> Result<()>,
) -> Result<Window> {
    let stop = Arc::new(AtomicBool::new(false));
    let marks = Arc::new(WindowMarks::default());
    let clock = SeqClock::start(dir, stop.clone());
    let browsers: Vec<_> = plan
        .iter()
        .map(|&hz| {
            let (stop, marks, clock, address) = (stop.clone(), marks.clone(), clock.clone(), address.to_owned());
            std::thread::spawn(move || browse(&address, hz, (&stop, &marks), &clock))
        })
        .collect();
    std::thread::sleep(Duration::from_secs(1));
    let (ticks_before, before_ns, part_before) = (ticks(), threads(), part());
    let started = Instant::now();
    let _ = marks.start.set(started);
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let _ = marks.end.set(Instant::now());
    let (ticks_after, after_ns, part_after) = (ticks(), threads(), part());
    let elapsed = started.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    let checked = check(&after_ns);
    let mut per_browser = Vec::new();
    for browser in browsers {
        per_browser.push(browser.join().map_err(|_| anyhow::anyhow!("a browser thread panicked")));
    }
    checked?;
    let per_browser = per_browser.into_iter().map(|figures| figures?).collect::<Result<Vec<_>>>()?;
    let (ran_ns, threads_ended) = cpu_ns_between(&before_ns, &after_ns);
    let (part_ns, _) = cpu_ns_between(&part_before, &part_after);
    let ticks = ticks_after.saturating_sub(ticks_before);
    Ok(Window { seconds: elapsed, ran_ns, threads_ended, ticks, part_ns, per_browser })
}

/// The viewer alone on the 1 kHz skin with 1, then 10 browsers, `rounds`
/// times, each round with the [`floor`] server's 1 and 10 between; then the
/// viewer with 9 at 59.94 Hz and one slow browser at 5 Hz.
fn viewer_scaling(
    exe: &Path,
    viewer_exe: &Path,
    dir: &Path,
    seconds: f64,
    rounds: usize,
    floor_options: Floor,
) -> Result<(Vec<ViewerRun>, Vec<FloorRun>)> {
    let (skin, _readers) = start_skin(exe, (dir, None), false)?;
    let (mut viewer, address) = start_viewer(viewer_exe, dir, &[], None)?;
    let (mut floor_server, floor_address) = start_floor(exe, floor_options, dir)?;
    let floor_pid = floor_server.0.id();
    let (mut runs, mut floor_runs) = (Vec::new(), Vec::new());
    let one = vec![DISPLAY_HZ];
    let ten = vec![DISPLAY_HZ; 10];
    let mut plans: Vec<(usize, bool, Vec<f64>)> = (0..rounds)
        .flat_map(|round| {
            [
                (round, true, one.clone()),
                (round, false, one.clone()),
                (round, true, ten.clone()),
                (round, false, ten.clone()),
            ]
        })
        .collect();
    plans.push((rounds - 1, true, std::iter::repeat_n(DISPLAY_HZ, 9).chain([SLOW_BROWSER_HZ]).collect()));
    let viewer_pid = viewer.0.id();
    for (round, on_viewer, plan) in plans {
        let server = if on_viewer { "viewer" } else { "floor server" };
        eprintln!("kilohertz: {server} with {} browsers, {seconds} s", plan.len());
        let window = if on_viewer {
            let pids = [("viewer".to_string(), viewer_pid)];
            let mut check = |after_ns: &BTreeMap<u32, u64>| {
                if let Ok(Some(status)) = viewer.0.try_wait() {
                    bail!("the viewer exited during the run with {} browsers ({status})", plan.len());
                }
                if after_ns.is_empty() {
                    bail!(
                        "cannot read the viewer's threads' run time in /proc/{viewer_pid}/task/*/schedstat \
                         (a kernel without CONFIG_SCHED_INFO?)"
                    );
                }
                Ok(())
            };
            with_browsers(
                &address,
                &plan,
                (dir, seconds),
                (&|| thread_cpu_ns(viewer_pid, None), &|| {
                    thread_cpu_ns(viewer_pid, Some(skinware_viewer::server::BROWSER_THREAD_PREFIX))
                }),
                &|| cpu_ticks(&pids)[0],
                &mut check,
            )?
        } else {
            let mut check = |after_ns: &BTreeMap<u32, u64>| {
                if let Ok(Some(status)) = floor_server.0.try_wait() {
                    bail!("the floor server exited during the run with {} browsers ({status})", plan.len());
                }
                if after_ns.is_empty() {
                    bail!("cannot read the floor server's threads' run time in /proc/{floor_pid}/task/*/schedstat");
                }
                Ok(())
            };
            with_browsers(
                &floor_address,
                &plan,
                (dir, seconds),
                (&|| thread_cpu_ns(floor_pid, None), &|| thread_cpu_ns(floor_pid, Some(floor::BROWSER_THREAD))),
                &|| 0,
                &mut check,
            )?
        };
        let percent = |ns: u64| 100.0 * ns as f64 / 1e9 / window.seconds;
        if on_viewer {
            runs.push(ViewerRun {
                round,
                browsers: plan.len(),
                with_slow_browser: plan.contains(&SLOW_BROWSER_HZ),
                seconds: window.seconds,
                viewer_cpu_percent: percent(window.ran_ns),
                viewer_threads_ended: window.threads_ended,
                viewer_cpu_percent_ticks: 100.0 * window.ticks as f64 / clock_ticks_per_s() / window.seconds,
                sessions_cpu_percent: percent(window.part_ns),
                per_browser: window.per_browser,
            });
        } else {
            floor_runs.push(FloorRun {
                round,
                browsers: plan.len(),
                seconds: window.seconds,
                cpu_percent: percent(window.part_ns),
                process_cpu_percent: percent(window.ran_ns),
                threads_ended: window.threads_ended,
                per_browser: window.per_browser,
            });
        }
        // The servers notice the closed sockets (the viewer stops the shared readers).
        std::thread::sleep(Duration::from_millis(500));
    }
    drop(floor_server);
    drop(viewer);
    drop(skin);
    Ok((runs, floor_runs))
}

fn print(report: &KilohertzReport) {
    println!("The paper's skin ({} taxels, 5 layers) at {} Hz.", report.taxels, report.rate_hz);
    println!(
        "| run | layer | frames/s | missed periods | overruns | publish p50 / p99 / max (µs, bucket edge) | lateness p99 (µs) |"
    );
    println!("|---|---|---|---|---|---|---|");
    for phase in &report.phases {
        for writer in &phase.writers {
            println!(
                "| {} | {} | {:.1} | {} | {} | {} / {} / {} | {} |",
                phase.phase,
                writer.layer,
                writer.rate_hz,
                writer.missed_periods,
                writer.overruns,
                writer.publish_p50_ns / 1_000,
                writer.publish_p99_ns / 1_000,
                writer.publish_max_ns / 1_000,
                writer.lateness_p99_ns / 1_000
            );
        }
    }
    for phase in &report.phases {
        println!("{} run, CPU (% of one core):", phase.phase);
        for (name, percent) in &phase.cpu_percent {
            println!("  {name}: {percent:.1} %");
        }
        for (name, latency) in &phase.latency_us {
            println!(
                "  latency from acquisition, {name}: p50 {} µs, p99 {} µs, max {} µs ({} samples)",
                latency.p50, latency.p99, latency.max, latency.samples
            );
        }
        for browser in &phase.browsers {
            println!(
                "  browser at {} Hz: {:.1} updates/s, {:.1} kB per update, latency p50 {} µs p99 {} µs",
                browser.ack_hz,
                browser.updates_per_s,
                browser.kb_per_update,
                browser.latency_us.p50,
                browser.latency_us.p99
            );
        }
        if let Some(recorder) = &phase.recorder {
            println!(
                "  recorder: {} frames, {} lost",
                recorder.get("frames").unwrap_or(&serde_json::Value::Null),
                recorder.get("lost").unwrap_or(&serde_json::Value::Null)
            );
        }
    }
    println!(
        "| round | browsers | viewer CPU (% of one core; by ticks) | updates/s per browser (min–max) | latency p50 (µs, median browser) |"
    );
    println!("|---|---|---|---|---|");
    for run in &report.viewer {
        let rates: Vec<f64> = run.per_browser.iter().map(|b| b.updates_per_s).collect();
        let min = rates.iter().copied().fold(f64::INFINITY, f64::min);
        let max = rates.iter().copied().fold(0.0, f64::max);
        let mut p50s: Vec<u64> = run.per_browser.iter().map(|b| b.latency_us.p50).collect();
        p50s.sort_unstable();
        let slow = run.per_browser.iter().find(|b| b.ack_hz < DISPLAY_HZ);
        println!(
            "| {} | {}{} | {:.2} ({:.1}) | {:.1}–{:.1} | {} |",
            run.round + 1,
            run.browsers,
            if slow.is_some() { " (one at 5 Hz)" } else { "" },
            run.viewer_cpu_percent,
            run.viewer_cpu_percent_ticks,
            min,
            max,
            p50s.get(p50s.len() / 2).copied().unwrap_or(0)
        );
        if run.viewer_threads_ended > 0 {
            println!(
                "  {} of the viewer's threads ended during this window: its CPU above misses their time",
                run.viewer_threads_ended
            );
        }
        if let Some(slow) = slow {
            println!(
                "  the slow browser: {:.1} updates/s, latency p50 {} µs p99 {} µs",
                slow.updates_per_s, slow.latency_us.p50, slow.latency_us.p99
            );
        }
    }
    let ratios: Vec<String> = report.viewer_cpu_ratios.iter().map(|r| format!("{r:.2}x")).collect();
    println!(
        "viewer CPU, 10 browsers over 1: {:.2}x (median of the rounds: {})",
        report.viewer_cpu_ratio_10_to_1,
        ratios.join(", ")
    );
    if report.floor.is_empty() {
        return;
    }
    if report.floor_reads_skin {
        println!(
            "The floor server (the viewer's layer readers; their board sent once per acknowledgement, nothing else) \
             in the same rounds:"
        );
    } else {
        println!(
            "The floor server (one message of {} bytes per acknowledgement, nothing else) in the same rounds:",
            report.floor_bytes
        );
    }
    println!(
        "| round | browsers | its browser threads' CPU | its whole CPU (% of one core) | updates/s per browser (min–max) |"
    );
    println!("|---|---|---|---|---|");
    for run in &report.floor {
        let rates: Vec<f64> = run.per_browser.iter().map(|b| b.updates_per_s).collect();
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.1}–{:.1} |",
            run.round + 1,
            run.browsers,
            run.cpu_percent,
            run.process_cpu_percent,
            rates.iter().copied().fold(f64::INFINITY, f64::min),
            rates.iter().copied().fold(0.0, f64::max)
        );
        if run.threads_ended > 0 {
            println!("  {} of the floor server's threads ended during this window", run.threads_ended);
        }
    }
    println!(
        "a browser costs (10 − 1) / 9: the viewer {:.3} %, the floor server {:.3} % of one core (medians)",
        report.browser_cost_percent.viewer, report.browser_cost_percent.floor
    );
    println!(
        "each browser's own thread among 10: a viewer session {:.3} %, a floor server thread {:.3} % of one core (medians)",
        report.browser_cost_percent.viewer_session, report.browser_cost_percent.floor_thread
    );
    println!(
        "the viewer's 10/1 if each browser cost it the floor's: {:.2}x (median)",
        report.viewer_cpu_ratio_at_floor
    );
    println!(
        "the floor server's whole CPU, 10 browsers over 1{}: {:.2}x (median)",
        if report.floor_reads_skin { ", reading the skin as the viewer does" } else { "" },
        report.floor_cpu_ratio_10_to_1
    );
}
