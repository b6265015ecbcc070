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
//! rendering competing for the same two cores. With `--chromium`, one of
//! the loaded run's three is the viewer's real page in headless Chromium
//! (module `page`), whose draws per second the run reports beside Chromium's
//! own CPU, which then competes with the skin for the same cores.

mod browser;
pub(crate) mod cpu;
pub mod floor;
mod page;
mod phase;
mod report;
mod viewer;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use crate::chromium::Programs;
use crate::run_options::RunOptions;
use phase::{LoadOptions, SkinChoice, run_phase};
use report::{BrowserCost, FloorRun, KilohertzReport, PhaseReport, ViewerRun};
use viewer::{Floor, viewer_scaling};

const LAYERS: usize = crate::skin_config::PAPER_LAYERS;
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
    /// Its name in a config and in the report.
    pub fn name(self) -> &'static str {
        match self {
            Wake::Lookout => "lookout",
            Wake::Ringer => "ringer",
            Wake::Writer => "writer",
        }
    }
}

/// Bytes of the viewer's update of the paper's skin at 1 kHz with raw
/// responses (every layer's, no overlays): the floor server's message
/// unless told otherwise. 61,872 in the viewer's protocol 2 (61,832 before:
/// its layer records grew from 24 to 32 bytes). Protocol 3's compact
/// responses make the viewer's own update about 27.5 KB at rest; the floor
/// still sends the raw size (and `--floor-reads-skin` the raw board), so it
/// is now a floor for a viewer that does not encode.
const UPDATE_BYTES: usize = skinware_viewer::protocol::UPDATE_HEADER_BYTES
    + LAYERS * skinware_viewer::protocol::LAYER_RECORD_BYTES
    + 2 * TAXELS;

/// What `skin bench kilohertz` runs.
#[derive(Clone, Debug)]
pub struct KilohertzOptions {
    /// Quick: 3 s per run and one round of the viewer's (else 15 s and
    /// three); `kilohertz.json` goes to `out`; `exe` runs the skin, the
    /// applications, the recorder, the floor server and (unless
    /// `viewer_exe`) the viewer.
    pub run: RunOptions,
    /// Measure this `skin` build's viewer rather than `exe`'s (a before/after).
    pub viewer_exe: Option<PathBuf>,
    /// Run one part only (into a JSON file of its own, whose `phases` are empty).
    pub only: Option<Part>,
    /// `reader_wake` of the layers' writers; the library's default if `None`.
    pub wake: Option<Wake>,
    /// Bytes of the floor server's message; the viewer's update for the
    /// paper's skin (`UPDATE_BYTES`, 61,872) if `None`.
    pub floor_bytes: Option<usize>,
    /// The floor server reads the skin's layers as the viewer does.
    pub floor_reads_skin: bool,
    /// Taxels of the skin over its 5 layers (the control and loaded runs
    /// only); the paper's 30,848 if `None`.
    pub taxels: Option<usize>,
    /// The recorder's `--compression` in the loaded run: `zstd` (`skin
    /// record`'s default) if `None`.
    pub record_compression: Option<skinware_record::Compression>,
    /// In the loaded run, the viewer's page in headless Chromium (through
    /// chromedriver) in place of one of the 3 emulated browsers.
    pub chromium: bool,
}

/// Runs `skin bench kilohertz`: prints its tables and writes its JSON.
pub fn bench(options: &KilohertzOptions) -> Result<()> {
    let KilohertzOptions {
        run,
        viewer_exe,
        only,
        wake,
        floor_bytes,
        floor_reads_skin,
        taxels,
        record_compression,
        chromium,
    } = options;
    let (only, wake, floor_reads_skin) = (*only, *wake, *floor_reads_skin);
    if floor_bytes.is_some() && floor_reads_skin {
        bail!("--floor-reads-skin sends the skin's frames, whose size is the skin's: drop --floor-bytes");
    }
    if only == Some(Part::Runs) && (floor_bytes.is_some() || floor_reads_skin) {
        bail!(
            "--floor-bytes and --floor-reads-skin set the floor server of the viewer part, which --only runs \
             leaves out: drop one of them"
        );
    }
    if taxels.is_some() && only != Some(Part::Runs) {
        bail!(
            "--taxels sets the skin of the control and loaded runs; the viewer part measures the paper's skin: \
             add --only runs"
        );
    }
    crate::skin_config::check_taxels(*taxels)?;
    if *chromium && only == Some(Part::Viewer) {
        bail!(
            "--chromium opens the viewer's page during the loaded run, which --only viewer leaves out: drop one of them"
        );
    }
    // Before any run, so that a missing browser is said at once.
    let chromium = if *chromium { Some(Programs::find().context("--chromium")?) } else { None };
    let seconds = run.seconds_or(3.0, 15.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&run.out).with_context(|| format!("cannot create {}", run.out.display()))?;
    let dir = skinware::shm::segment_dir().join(format!("skk{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let plan = Plan {
        exe: &run.exe,
        viewer_exe: viewer_exe.as_deref().unwrap_or(&run.exe),
        floor: Floor { bytes: floor_bytes.unwrap_or(UPDATE_BYTES), reads_skin: floor_reads_skin },
        dir: &dir,
        seconds,
        rounds: if run.quick { 1 } else { VIEWER_ROUNDS },
        out: &run.out,
        only,
        wake,
        taxels: *taxels,
        record_compression: record_compression.unwrap_or_default(),
        chromium: chromium.as_ref(),
    };
    let result = measure(&plan);
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    report::print(&report);
    let path = run.out.join(match only {
        Some(Part::Viewer) => "kilohertz-viewer.json",
        Some(Part::Runs) => "kilohertz-runs.json",
        None => "kilohertz.json",
    });
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("written: {}", path.display());
    Ok(())
}

/// What one run of the bench does, and where.
struct Plan<'a> {
    /// The `skin` executable.
    exe: &'a Path,
    /// The `skin` executable whose viewer is measured.
    viewer_exe: &'a Path,
    /// What the floor server does.
    floor: Floor,
    /// The bench's own segment directory.
    dir: &'a Path,
    /// Seconds per run.
    seconds: f64,
    /// Rounds of the viewer's runs.
    rounds: usize,
    /// Where the work files go.
    out: &'a Path,
    /// The part to run alone, if one.
    only: Option<Part>,
    /// `reader_wake` of the layers' writers.
    wake: Option<Wake>,
    /// Taxels of the skin; the paper's if `None`.
    taxels: Option<usize>,
    /// The recorder's compression in the loaded run.
    record_compression: skinware_record::Compression,
    /// chromedriver and Chromium, for the page in the loaded run (`--chromium`).
    chromium: Option<&'a Programs>,
}

/// Runs the parts of the bench `plan` asks for, and sums them up.
fn measure(plan: &Plan) -> Result<KilohertzReport> {
    let Plan { exe, viewer_exe, dir, seconds, out, wake, .. } = *plan;
    let load = LoadOptions { record_compression: plan.record_compression, chromium: plan.chromium };
    let phases = match plan.only {
        Some(Part::Viewer) => Vec::new(),
        _ => vec![
            run_phase(exe, viewer_exe, SkinChoice { dir, wake, taxels: plan.taxels }, seconds, None, out)?,
            run_phase(exe, viewer_exe, SkinChoice { dir, wake, taxels: plan.taxels }, seconds, Some(&load), out)?,
        ],
    };
    let (viewer, floor) = if plan.only == Some(Part::Runs) {
        (Vec::new(), Vec::new())
    } else {
        viewer_scaling(exe, viewer_exe, dir, seconds, plan.rounds, plan.floor)?
    };
    Ok(summarize(plan, phases, viewer, floor))
}

/// The report of the runs, with the figures drawn from the viewer's and
/// the floor server's runs: ratios of 10 browsers over 1 and a browser's
/// cost, the medians over the rounds.
fn summarize(plan: &Plan, phases: Vec<PhaseReport>, viewer: Vec<ViewerRun>, floor: Vec<FloorRun>) -> KilohertzReport {
    let Plan { viewer_exe, rounds, wake, floor: floor_options, .. } = *plan;
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
    KilohertzReport {
        rate_hz: 1000.0,
        taxels: plan.taxels.unwrap_or(TAXELS),
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
    }
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Options that would run `only`, with `--chromium`; nothing runs if
    /// they are refused, which is all these tests reach.
    fn chromium_with(only: Option<Part>) -> KilohertzOptions {
        KilohertzOptions {
            run: RunOptions {
                quick: true,
                out: std::env::temp_dir().join("kilohertz-chromium-test"),
                seconds: None,
                exe: PathBuf::from("/nonexistent/skin"),
            },
            viewer_exe: None,
            only,
            wake: None,
            floor_bytes: None,
            floor_reads_skin: false,
            taxels: None,
            record_compression: None,
            chromium: true,
        }
    }

    #[test]
    fn chromium_without_the_loaded_run_is_refused_naming_the_fix() {
        let error = bench(&chromium_with(Some(Part::Viewer))).unwrap_err().to_string();
        assert!(error.contains("--chromium") && error.contains("--only viewer"), "{error}");
    }
}
