//! What `skin bench kilohertz` measured (`kilohertz.json`), and its tables.

use std::collections::BTreeMap;

use serde::Serialize;

use super::DISPLAY_HZ;
use super::page::{ChromiumFigures, MIN_FPS};
use crate::measure::Percentiles;

/// One writer's figures over the measured window.
#[derive(Debug, Serialize)]
pub(super) struct WriterFigures {
    pub(super) layer: String,
    pub(super) frames: u64,
    pub(super) rate_hz: f64,
    pub(super) missed_periods: u64,
    pub(super) overruns: u64,
    /// Upper edges of the power-of-two histogram buckets, ns.
    pub(super) publish_p50_ns: u64,
    pub(super) publish_p99_ns: u64,
    pub(super) publish_max_ns: u64,
    pub(super) lateness_p99_ns: u64,
}

/// One run of the skin: the control or the loaded one.
#[derive(Debug, Serialize)]
pub(super) struct PhaseReport {
    pub(super) phase: String,
    pub(super) seconds: f64,
    pub(super) writers: Vec<WriterFigures>,
    /// Percent of one CPU, per component.
    pub(super) cpu_percent: BTreeMap<String, f64>,
    /// From acquisition to each consumer holding the data, per consumer.
    pub(super) latency_us: BTreeMap<String, Percentiles>,
    /// What the recorder said at the end (frames, lost, ...), if it ran.
    pub(super) recorder: Option<serde_json::Value>,
    /// What the emulated browsers received.
    pub(super) browsers: Vec<BrowserFigures>,
    /// What the page in headless Chromium drew (`--chromium`, loaded run only).
    pub(super) chromium: Option<ChromiumFigures>,
    /// The contact service's cost over the window, as `skin services`
    /// reports it (its channel's write time), if it ran.
    pub(super) contact_service: Option<ServiceCost>,
    /// The whole machine's CPU over the window (`/proc/stat`), if readable.
    pub(super) machine: Option<MachineFigures>,
}

/// The whole machine's CPU over a run's window: everything on it, the
/// bench's processes and anything else.
#[derive(Clone, Copy, Debug, Serialize)]
pub(super) struct MachineFigures {
    /// Busy, % of one CPU (200 is both of 2 cores): neither idle nor stolen.
    pub(super) busy_percent: f64,
    /// Idle, % of one CPU.
    pub(super) idle_percent: f64,
    /// Time the hypervisor took from vCPUs that had work (steal), ms summed
    /// over the CPUs: no thread of the guest ran then, whatever its priority.
    pub(super) steal_ms: f64,
}

/// A service's write time per frame over the measured window.
#[derive(Clone, Copy, Debug, Serialize)]
pub(super) struct ServiceCost {
    pub(super) frames: u64,
    /// Mean, ns (from its statistics' running mean and frame count at both ends).
    pub(super) mean_ns: u64,
    /// Per taxel of the skin, ns.
    pub(super) mean_ns_per_taxel: f64,
}

#[derive(Clone, Debug, Default, Serialize)]
pub(super) struct BrowserFigures {
    pub(super) ack_hz: f64,
    pub(super) updates_per_s: f64,
    pub(super) kb_per_update: f64,
    /// From the acquisition of layer 0's newest frame to the update holding it, µs.
    pub(super) latency_us: Percentiles,
}

/// The viewer with N browsers at once.
#[derive(Debug, Serialize)]
pub(super) struct ViewerRun {
    /// The round of 1 and 10 browsers this run belongs to (the slow browser's run: the last).
    pub(super) round: usize,
    pub(super) browsers: usize,
    /// Whether one of them is the slow browser.
    pub(super) with_slow_browser: bool,
    /// The window measured, seconds.
    pub(super) seconds: f64,
    /// The viewer's threads' run time (`/proc/PID/task/*/schedstat`, in ns)
    /// over the window, in % of one core.
    pub(super) viewer_cpu_percent: f64,
    /// Threads of the viewer that ended during the window, whose run time in
    /// it `viewer_cpu_percent` misses (0 in a sound run).
    pub(super) viewer_threads_ended: usize,
    /// The same from `/proc/PID/stat`'s utime + stime, in clock ticks (what
    /// this bench reported before 2026-11-25: a tick is 1 % of a core-second).
    pub(super) viewer_cpu_percent_ticks: f64,
    /// Of `viewer_cpu_percent`, the browsers' own threads (one per
    /// connection; not the shared layer readers): what the browsers cost,
    /// without the readers' share, which moves by up to a point between runs.
    pub(super) sessions_cpu_percent: f64,
    pub(super) per_browser: Vec<BrowserFigures>,
}

/// The [`floor`] server with N browsers.
#[derive(Debug, Serialize)]
pub(super) struct FloorRun {
    /// The round of the viewer's runs this one was measured in.
    pub(super) round: usize,
    pub(super) browsers: usize,
    /// The window measured, seconds.
    pub(super) seconds: f64,
    /// The run time of the floor server's browser threads (one per
    /// browser; not its rewriter or layer readers) over the window
    /// (schedstat, ns), in % of one core.
    pub(super) cpu_percent: f64,
    /// The same for all its threads (with the rewriter, or the layer
    /// readers with `--floor-reads-skin`).
    pub(super) process_cpu_percent: f64,
    /// Threads of the floor server that ended during the window (0 in a sound run).
    pub(super) threads_ended: usize,
    pub(super) per_browser: Vec<BrowserFigures>,
}

/// What one more browser costs, in % of one core, the median over the
/// rounds: (CPU with 10 browsers − CPU with 1) / 9, and each browser's own
/// thread with 10 browsers (its CPU / 10), which the layer readers' share
/// does not move.
#[derive(Debug, Default, Serialize)]
pub(super) struct BrowserCost {
    pub(super) viewer: f64,
    /// The floor server: one message of `floor_bytes` per acknowledgement.
    pub(super) floor: f64,
    /// A viewer session's thread, with 10 browsers.
    pub(super) viewer_session: f64,
    /// A floor server's browser thread, with 10 browsers.
    pub(super) floor_thread: f64,
}

#[derive(Debug, Serialize)]
pub(super) struct KilohertzReport {
    pub(super) rate_hz: f64,
    pub(super) taxels: usize,
    /// `reader_wake` of the layers' writers (`default`: not set).
    pub(super) reader_wake: String,
    /// The `skin` executable that ran the viewer (`--viewer-exe`, or this one).
    pub(super) viewer_exe: String,
    pub(super) phases: Vec<PhaseReport>,
    pub(super) viewer: Vec<ViewerRun>,
    /// `viewer_cpu_percent` with 10 browsers over that with 1: the median
    /// of [`viewer_cpu_ratios`](Self::viewer_cpu_ratios).
    pub(super) viewer_cpu_ratio_10_to_1: f64,
    /// The same ratio in each round (1 browser, then 10, alternating: the
    /// machine's mood moves the readers' share between runs).
    pub(super) viewer_cpu_ratios: Vec<f64>,
    /// The floor server with 1 and 10 browsers, in the same rounds.
    pub(super) floor: Vec<FloorRun>,
    /// Bytes of the floor server's message: by default the viewer's update,
    /// 61,872 (`--floor-bytes`); with `floor_reads_skin`, the skin's own
    /// update, which is that size on this skin.
    pub(super) floor_bytes: usize,
    /// Whether the floor server read the skin's layers with the viewer's
    /// readers and sent their board (`--floor-reads-skin`), rather than a
    /// stand-in rewritten every millisecond.
    pub(super) floor_reads_skin: bool,
    /// The floor server's whole CPU with 10 browsers over 1, the median of
    /// the rounds: with `floor_reads_skin`, the ratio of a viewer whose
    /// sessions cost only the message.
    pub(super) floor_cpu_ratio_10_to_1: f64,
    /// What one more browser costs the viewer and the floor server.
    pub(super) browser_cost_percent: BrowserCost,
    /// The 10/1 ratio the viewer would have if each browser cost it what
    /// one costs the floor server, the rest of its CPU as measured with one
    /// browser: (S + 10 f) / (S + f), S = the viewer's CPU with 1 browser −
    /// the viewer's cost of a browser, f = the floor's; the median over the rounds.
    pub(super) viewer_cpu_ratio_at_floor: f64,
}

/// Prints the report's tables.
pub(super) fn print(report: &KilohertzReport) {
    print_phases(report);
    // `--only runs` has no viewer part to print.
    if !report.viewer.is_empty() {
        print_viewer(report);
    }
    if !report.floor.is_empty() {
        print_floor(report);
    }
}

/// The control and the loaded run: the writers' table, then each run's CPU and latencies.
fn print_phases(report: &KilohertzReport) {
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
        if let Some(machine) = &phase.machine {
            println!(
                "  the whole machine: busy {:.1} %, idle {:.1} % (of 200); the hypervisor took {:.0} ms from vCPUs with work (steal)",
                machine.busy_percent, machine.idle_percent, machine.steal_ms
            );
        }
        for (name, latency) in &phase.latency_us {
            println!(
                "  latency from acquisition, {name}: p50 {} µs, p99 {} µs, max {} µs ({} samples)",
                latency.p50, latency.p99, latency.max, latency.samples
            );
        }
        for browser in &phase.browsers {
            println!(
                "  browser at {:.2} Hz: {:.1} updates/s, {:.1} kB per update, latency p50 {} µs p99 {} µs",
                browser.ack_hz,
                browser.updates_per_s,
                browser.kb_per_update,
                browser.latency_us.p50,
                browser.latency_us.p99
            );
        }
        if let Some(page) = &phase.chromium {
            print_chromium(page);
        }
        if let Some(cost) = &phase.contact_service {
            println!(
                "  contact service (as `skin services` reports it): {:.1} µs mean per frame over {} frames, {:.2} ns per taxel",
                cost.mean_ns as f64 / 1e3,
                cost.frames,
                cost.mean_ns_per_taxel
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
}

/// What the page in Chromium drew, against issue #41's 30 fps.
fn print_chromium(page: &ChromiumFigures) {
    let rates = &page.page;
    println!(
        "  Chromium (the viewer's page, headless): {:.1} fps (draws of new updates; ≥ {MIN_FPS} asked: {}), \
         {:.1} updates/s, {:.1} kB per update ({:.1} kB with raw responses), render {:.2} ms/draw, decode {:.3} ms/update",
        rates.fps,
        if page.meets_30_fps { "met" } else { "NOT met" },
        rates.updates_per_s,
        rates.bytes_per_update / 1e3,
        rates.raw_bytes_per_update / 1e3,
        rates.render_ms,
        rates.decode_ms
    );
    println!(
        "  Chromium's own CPU (with chromedriver): {:.1} % of one core, on the same cores as the skin",
        page.cpu_percent
    );
}

/// The viewer's runs with 1 and 10 browsers, and the 10/1 ratio.
fn print_viewer(report: &KilohertzReport) {
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
}

/// The floor server's runs, and what a browser costs it and the viewer.
fn print_floor(report: &KilohertzReport) {
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
