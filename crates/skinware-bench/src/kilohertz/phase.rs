//! The control and the loaded run: the paper's skin at 1 kHz alone, then
//! with 15 applications, both services at 1 kHz, the viewer with 3
//! browsers (with `--chromium`, one of them the page in headless Chromium)
//! and the recorder.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use skinware::{Reader, ReaderOptions, WriterStats, histogram_quantile};

use super::browser::{SeqClock, WindowMarks, browse};
use super::cpu::{MachineTicks, clock_ticks_per_s, cpu_ticks};
use super::page::{ChromiumFigures, ChromiumPage};
use super::report::{BrowserFigures, MachineFigures, PhaseReport, ServiceCost, WriterFigures};
use super::{APPS, ASAP_APPS, BROWSERS, DISPLAY_HZ, LAYERS, Wake};
use crate::app::AppSamples;
use crate::chromium::Programs;
use crate::measure::{Percentiles, RunningSkin};
use crate::procs::{Guarded, start_viewer, supervised_pids};
use crate::skin_config::PaperSkin;

/// The skin a run starts: the paper's at 1 kHz, at its size or another.
#[derive(Clone, Copy, Debug)]
pub(super) struct SkinChoice<'a> {
    /// The bench's segment directory.
    pub(super) dir: &'a Path,
    /// `reader_wake` of the layers' writers.
    pub(super) wake: Option<Wake>,
    /// Taxels over the 5 layers; the paper's if `None`.
    pub(super) taxels: Option<usize>,
}

/// The paper's skin at 1 kHz; with its services (also at 1 kHz) or none.
fn config(with_services: bool, choice: SkinChoice) -> Result<String> {
    PaperSkin {
        services: with_services,
        reader_wake: choice.wake.map(Wake::name),
        taxels: choice.taxels,
        ..PaperSkin::at(1000.0)
    }
    .config()
}

/// Starts the paper's skin at 1 kHz in segment directory `dir` (with its
/// services, or none), and waits for its layers' (and services') channels;
/// returns it and a reader of each layer.
pub(super) fn start_skin(exe: &Path, choice: SkinChoice, with_services: bool) -> Result<(RunningSkin, Vec<Reader>)> {
    let dir = choice.dir;
    let path = dir.join(if with_services { "loaded.toml" } else { "control.toml" });
    std::fs::write(&path, config(with_services, choice)?)?;
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

/// One run of the paper's skin at 1 kHz: the control (no `load_options`,
/// the skin alone) or the loaded run (with everything that reads it, as
/// `load_options` say: the recorder's compression, and with `chromium`, the
/// viewer's page in it in place of one emulated browser).
pub(super) fn run_phase(
    exe: &Path,
    viewer_exe: &Path,
    choice: SkinChoice,
    seconds: f64,
    load_options: Option<&LoadOptions>,
    out: &Path,
) -> Result<PhaseReport> {
    let loaded = load_options.is_some();
    let dir = choice.dir;
    let phase = if loaded { "loaded" } else { "control" };
    eprintln!("kilohertz: {phase} run, {seconds} s");
    let (skin, readers) = start_skin(exe, choice, loaded)?;
    let stop = Arc::new(AtomicBool::new(false));
    let marks = Arc::new(WindowMarks::default());
    let clock = SeqClock::start(dir, stop.clone());
    let work = out.join("kilohertz-work");
    std::fs::create_dir_all(&work)?;
    let mut load = if let Some(options) = load_options {
        Load::start((exe, viewer_exe), (dir, &work), (seconds, options), (&stop, &marks, &clock))?
    } else {
        Load::default()
    };
    // Every consumer attached and running before the window opens.
    std::thread::sleep(Duration::from_secs(1));
    let pids = load.pids(skin.pid());
    // The page's counters (a WebDriver round trip: tens of ms, over a
    // second when the page is starved) outside the writers' window, which
    // they would lengthen; the page's rates come from its own clock.
    let page_before = load.chromium.as_ref().map(ChromiumPage::counters).transpose()?;
    let before_stats: Vec<WriterStats> = readers.iter().map(Reader::writer_stats).collect();
    let reader_options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
    let contact = if loaded { Reader::open_with("default", "contact", &reader_options).ok() } else { None };
    let contact_before = contact.as_ref().map(Reader::writer_stats);
    let before_cpu = cpu_ticks(&pids);
    let machine_before = MachineTicks::now();
    let started = Instant::now();
    let _ = marks.start.set(started);
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let _ = marks.end.set(Instant::now());
    let elapsed = started.elapsed().as_secs_f64();
    let after_cpu = cpu_ticks(&pids);
    let machine =
        MachineTicks::now().zip(machine_before).map(|(after, before)| machine_figures(after.since(before), elapsed));
    let after_stats: Vec<WriterStats> = readers.iter().map(Reader::writer_stats).collect();
    let page_after = load.chromium.as_ref().map(ChromiumPage::counters).transpose()?;
    let taxels: usize = readers.iter().map(|r| r.payload_bytes() / 2).sum();
    let contact_service = contact
        .as_ref()
        .zip(contact_before)
        .map(|(reader, before)| service_cost(&before, &reader.writer_stats(), taxels));
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
    let chromium = page_before.zip(page_after).map(|(before, after)| {
        ChromiumFigures::new(&before, &after, cpu_percent.get(CHROMIUM).copied().unwrap_or(0.0))
    });
    let (latency_us, browsers) = load.latencies()?;
    let recorder = load.recorder_said()?;
    drop(load);
    drop(clock);
    drop(skin);
    let _ = std::fs::remove_dir_all(&work);
    Ok(PhaseReport {
        phase: phase.into(),
        seconds: elapsed,
        writers,
        cpu_percent,
        latency_us,
        recorder,
        browsers,
        chromium,
        contact_service,
        machine,
    })
}

/// The machine's CPU over a window of `seconds`, from its ticks.
fn machine_figures(ticks: MachineTicks, seconds: f64) -> MachineFigures {
    let percent = |ticks: u64| 100.0 * ticks as f64 / clock_ticks_per_s() / seconds.max(1e-9);
    let (idle_percent, steal_percent) = (percent(ticks.idle), percent(ticks.steal));
    MachineFigures {
        busy_percent: (100.0 * ticks.cpus as f64 - idle_percent - steal_percent).max(0.0),
        idle_percent,
        steal_ms: 1e3 * ticks.steal as f64 / clock_ticks_per_s(),
    }
}

/// Chromium's processes, by name in a phase's CPU.
const CHROMIUM: &str = "Chromium (headless, the viewer's page, with chromedriver)";

/// A service's mean write time between two readings of its statistics
/// (each a running mean over every frame so far).
fn service_cost(before: &WriterStats, after: &WriterStats, taxels: usize) -> ServiceCost {
    let (frames, mean_ns) = crate::measure::write_ns_between(before, after);
    ServiceCost { frames, mean_ns, mean_ns_per_taxel: mean_ns as f64 / taxels.max(1) as f64 }
}

/// How the loaded run loads the skin, beyond the paper's mix.
pub(super) struct LoadOptions<'a> {
    /// The recorder's compression.
    pub(super) record_compression: skinware_record::Compression,
    /// chromedriver and Chromium, for the viewer's page in place of one
    /// emulated browser (`--chromium`).
    pub(super) chromium: Option<&'a Programs>,
}

/// What reads the skin in the loaded run: started before the measured
/// window, collected after it (none in the control run).
#[derive(Default)]
struct Load {
    /// The application processes, and where each writes its samples.
    apps: Vec<(Guarded, PathBuf)>,
    /// The viewer (`skin view`).
    viewer: Option<Guarded>,
    /// The recorder (`skin record`).
    recorder: Option<Guarded>,
    /// The viewer's emulated browsers.
    browsers: Vec<JoinHandle<Result<BrowserFigures>>>,
    /// The viewer's page in headless Chromium (`--chromium`).
    chromium: Option<ChromiumPage>,
    /// The services' probe.
    services: Option<ServiceProbe>,
}

impl Load {
    /// Starts the viewer (of `viewer_exe`) and its browsers (one of them
    /// the page in Chromium, with `chromium`), the applications, the
    /// recorder and the services' probe on the skin in `dir`, for `seconds`
    /// (and a margin); their files go to `work`. The viewer and Chromium
    /// come first: the page may take seconds to load, which the
    /// applications' and the recorder's time must not include.
    fn start(
        (exe, viewer_exe): (&Path, &Path),
        (dir, work): (&Path, &Path),
        (seconds, options): (f64, &LoadOptions),
        (stop, marks, clock): (&Arc<AtomicBool>, &Arc<WindowMarks>, &SeqClock),
    ) -> Result<Load> {
        let chromium = options.chromium;
        let mut load = Load::default();
        let (child, address) = start_viewer(viewer_exe, dir, &[], None)?;
        load.viewer = Some(child);
        if let Some(programs) = chromium {
            load.chromium = Some(ChromiumPage::open(programs, &address)?);
        }
        // Chromium is one of the viewer's 3 browsers, so that the viewer
        // serves as many as without it and its figures stay comparable.
        let emulated = if chromium.is_some() { BROWSERS - 1 } else { BROWSERS };
        for _ in 0..emulated {
            let (stop, marks, clock, address) = (stop.clone(), marks.clone(), clock.clone(), address.clone());
            load.browsers.push(std::thread::spawn(move || browse(&address, DISPLAY_HZ, (&stop, &marks), &clock)));
        }
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
            load.apps.push((Guarded(child), samples));
        }
        let file = work.join("kilohertz.mcap");
        let _ = std::fs::remove_file(&file);
        let child = Command::new(exe)
            .arg("record")
            .arg(&file)
            .args(["--services", "--json", "--seconds", &(seconds + 2.0).to_string()])
            .args(["--compression", options.record_compression.name()])
            .env("SKINWARE_SHM_DIR", dir)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .context("cannot start the recorder")?;
        load.recorder = Some(Guarded(child));
        load.services = Some(ServiceProbe::start(dir, stop.clone()));
        Ok(load)
    }

    /// The processes whose CPU the run measures, by component: the skin
    /// (`skin run` at `skin_pid` and what it supervises) and this load.
    fn pids(&self, skin_pid: u32) -> Vec<(String, u32)> {
        let mut pids: Vec<(String, u32)> = vec![("skin run (supervisor)".into(), skin_pid)];
        pids.extend(supervised_pids(skin_pid));
        for (index, (app, _)) in self.apps.iter().enumerate() {
            let kind = if index < ASAP_APPS { "apps (5 asap)" } else { "apps (10 periodic)" };
            pids.push((kind.into(), app.0.id()));
        }
        if let Some(viewer) = &self.viewer {
            let name = if self.chromium.is_some() { "viewer (2 browsers + Chromium)" } else { "viewer (3 browsers)" };
            pids.push((name.into(), viewer.0.id()));
        }
        if let Some(page) = &self.chromium {
            pids.extend(page.process_ids().into_iter().map(|pid| (CHROMIUM.to_owned(), pid)));
        }
        if let Some(recorder) = &self.recorder {
            pids.push(("recorder".into(), recorder.0.id()));
        }
        pids
    }

    /// Once the window is over and the stop flag set: the browsers' figures
    /// and every consumer's latency from acquisition (the browsers', the
    /// services' and, once they exited, the applications').
    fn latencies(&mut self) -> Result<(BTreeMap<String, Percentiles>, Vec<BrowserFigures>)> {
        let mut latency_us = BTreeMap::new();
        let mut browsers = Vec::new();
        for thread in self.browsers.drain(..) {
            let figures = thread.join().map_err(|_| anyhow::anyhow!("a browser thread panicked"))??;
            browsers.push(figures);
        }
        for (index, browser) in browsers.iter().enumerate() {
            latency_us.insert(format!("viewer → browser {}", index + 1), browser.latency_us);
        }
        if let Some(probe) = self.services.take() {
            for (name, mut samples) in probe.finish()? {
                latency_us.insert(format!("{name} service (output visible)"), Percentiles::of(&mut samples));
            }
        }
        let mut asap = Vec::new();
        let mut periodic = Vec::new();
        for (index, (app, samples)) in self.apps.drain(..).enumerate() {
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
        Ok((latency_us, browsers))
    }

    /// What the recorder said at its end (frames, lost, ...), once it exited.
    fn recorder_said(&mut self) -> Result<Option<serde_json::Value>> {
        let Some(mut child) = self.recorder.take() else { return Ok(None) };
        let mut stdout = child.0.stdout.take().context("the recorder's output")?;
        child.0.wait()?;
        let mut text = String::new();
        std::io::Read::read_to_string(&mut stdout, &mut text)?;
        Ok(serde_json::from_str(&text).ok())
    }
}

/// A writer's figures over a window, from its statistics at its start and end.
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
