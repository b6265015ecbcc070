//! What the soak reports: the readers' verdicts, each fault with its times,
//! the recovery times per kind of fault, the processes' memory and
//! descriptors over time, what was left behind, and the verdict.

use std::collections::BTreeMap;

use serde::Serialize;

use super::reader::LayerTally;

/// The verifying readers of one mode, over all their incarnations.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ModeTotals {
    /// Their counts, over every layer.
    pub counts: LayerTally,
    /// Reader processes of this mode started (the first and each restart).
    pub incarnations: u64,
    /// Of them, killed before their first report (their counts are lost).
    pub killed_before_reporting: u64,
}

/// One fault, as injected.
#[derive(Clone, Debug, Default, Serialize)]
pub struct FaultRecord {
    /// Its number in the run, from 1.
    pub index: usize,
    /// Its kind (see [`super::injection::FaultKind`]).
    pub kind: String,
    /// What it hit (a process, a layer, a path).
    pub target: String,
    /// Seconds from the start of the soak to the injection (CLOCK_MONOTONIC).
    pub injected_s: f64,
    /// The injection on CLOCK_MONOTONIC, ns (the clock of the frames'
    /// times and of the skin's logs' monotonic stamps).
    pub injected_monotonic_ns: u64,
    /// The injection's wall-clock time, seconds since the Unix epoch.
    pub injected_unix_s: f64,
    /// Seconds from the start of the soak to the fault's end: the kill for a
    /// SIGKILL (also the driver's, beside stopped foreign writers or a
    /// FIFO squat), the SIGCONT for a stop, the restore for a cable pull,
    /// the removal for a squat, the unlink of a live name, the end of the
    /// CPU hog.
    pub ended_s: f64,
    /// The end on CLOCK_MONOTONIC, ns.
    pub ended_monotonic_ns: u64,
    /// The end's wall-clock time, seconds since the Unix epoch.
    pub ended_unix_s: f64,
    /// How long the fault was held (0 for a kill or an unlink).
    pub held_s: f64,
    /// From the fault's end until every layer had published a frame again
    /// (the publication time of the last layer's first frame after the
    /// end); `None` if not within the soak's wait.
    pub back_after_end_ms: Option<f64>,
    /// The same from the injection.
    pub back_after_injection_ms: Option<f64>,
    /// From the end until every layer and every service had published again.
    pub services_back_after_end_ms: Option<f64>,
    /// For an unlinked name: from the unlink until the writer's socket and
    /// name lock were back at their paths.
    pub name_back_ms: Option<f64>,
    /// The viewer's browser's longest wait for an update (over 300 ms) that
    /// overlapped the fault, from its injection until a second after every
    /// layer and service was back; `None` if it had no such wait.
    pub viewer_longest_wait_ms: Option<f64>,
    /// What else happened (e.g. the supervisor killed a stopped driver).
    pub note: String,
    /// The soak was interrupted (Ctrl-C) before every layer was back: the
    /// fault is logged but counts in no recovery figure.
    pub interrupted: bool,
}

/// Percentiles of a set of durations, ms.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct MsStats {
    /// Median.
    pub p50: f64,
    /// 99th percentile (nearest rank).
    pub p99: f64,
    /// Worst.
    pub max: f64,
    /// How many.
    pub samples: usize,
}

impl MsStats {
    /// The statistics of `values` (any order).
    pub fn of(values: &[f64]) -> MsStats {
        let mut sorted = values.to_vec();
        sorted.sort_by(f64::total_cmp);
        let at = |q: f64| sorted[((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len()) - 1];
        if sorted.is_empty() {
            return MsStats::default();
        }
        MsStats { p50: at(0.5), p99: at(0.99), max: sorted[sorted.len() - 1], samples: sorted.len() }
    }
}

/// The recovery of one kind of fault over the run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Recovery {
    /// Faults of this kind injected.
    pub count: usize,
    /// Of them, after which some layer did not publish again within the wait.
    pub not_back: usize,
    /// From the fault's end until every layer published again, ms.
    pub after_end_ms: MsStats,
    /// From the injection until every layer published again, ms.
    pub after_injection_ms: MsStats,
    /// From the fault's end until every layer and service published again, ms.
    pub services_after_end_ms: MsStats,
    /// The viewer's browser's longest wait for an update during a fault of
    /// this kind, ms (0: none over 300 ms).
    pub viewer_longest_wait_ms: f64,
}

/// A verifying reader that stopped getting frames while its layer published.
#[derive(Clone, Debug, Serialize)]
pub struct StuckEpisode {
    /// The reader's mode.
    pub mode: String,
    /// Its process id.
    pub pid: u32,
    /// The layer.
    pub layer: String,
    /// Seconds from the start of the soak to when it was found stuck.
    pub at_s: f64,
    /// Seconds without a new frame at that moment.
    pub silent_s: f64,
    /// Frames the layer published meanwhile.
    pub published_meanwhile: usize,
    /// Whether the reader was attached (else it could not open the layer).
    pub attached: bool,
    /// How it was found: live from the reader's report, in the reader's own
    /// record of its pauses, or from its reports not coming (its process did
    /// not run; `layer` is empty then).
    pub found_by: String,
}

/// The longest a verifying reader went without a new frame while its
/// layer published without pausing: the soak's measure of "no reader gets
/// stuck", from the readers' own records of their pauses over a second.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LongestWait {
    /// The layer's run of frames within the reader's pause, ms (0: no pause
    /// over a second held more than one frame).
    pub ms: f64,
    /// The reader's mode.
    pub mode: String,
    /// Its process id.
    pub pid: u32,
    /// The layer.
    pub layer: String,
    /// Seconds from the start of the soak to the end of the pause.
    pub at_s: f64,
    /// Whether the pause ended with a successor writer's frame.
    pub followed: bool,
}

/// One sample of a process: `(seconds since the start of the soak, RSS KiB, fds)`.
pub type Sample = (f64, u64, u64);

/// One process's resident memory and descriptors over the run.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ProcessSeries {
    /// What it is ("skin run", "driver virtual", "reader periodic", ...).
    pub name: String,
    /// Its process id.
    pub pid: u32,
    /// Seconds it was sampled over.
    pub seconds: f64,
    /// Resident memory, KiB: first, last and largest sample.
    pub rss_kib_first: u64,
    /// See `rss_kib_first`.
    pub rss_kib_last: u64,
    /// See `rss_kib_first`.
    pub rss_kib_max: u64,
    /// Open descriptors: first, last and most.
    pub fds_first: u64,
    /// See `fds_first`.
    pub fds_last: u64,
    /// See `fds_first`.
    pub fds_max: u64,
    /// Whether its memory grew over the run: the median of the last quarter
    /// of the samples above 1.2 times that of the first quarter plus 2 MiB
    /// (only for a process sampled 60 s or more).
    pub rss_grew: bool,
    /// Whether its descriptors grew: the last sample above the first quarter's most plus 2.
    pub fds_grew: bool,
    /// `[seconds since the start of the soak, RSS KiB, fds]`, one per sample.
    pub samples: Vec<Sample>,
}

impl ProcessSeries {
    /// Fills the first/last/max figures and the growth flags from `samples`.
    pub fn finish(&mut self) {
        let Some(first) = self.samples.first().copied() else { return };
        let last = *self.samples.last().unwrap_or(&first);
        self.seconds = last.0 - first.0;
        (self.rss_kib_first, self.rss_kib_last) = (first.1, last.1);
        (self.fds_first, self.fds_last) = (first.2, last.2);
        self.rss_kib_max = self.samples.iter().map(|s| s.1).max().unwrap_or(0);
        self.fds_max = self.samples.iter().map(|s| s.2).max().unwrap_or(0);
        let quarter = (self.samples.len() / 4).max(1);
        let median = |part: &[Sample]| {
            let mut rss: Vec<u64> = part.iter().map(|s| s.1).collect();
            rss.sort_unstable();
            rss[rss.len() / 2]
        };
        if self.seconds >= 60.0 && self.samples.len() >= 8 {
            let early = median(&self.samples[..quarter]);
            let late = median(&self.samples[self.samples.len() - quarter..]);
            self.rss_grew = late as f64 > early as f64 * 1.2 + 2048.0;
            let early_fds = self.samples[..quarter].iter().map(|s| s.2).max().unwrap_or(0);
            self.fds_grew = last.2 > early_fds + 2;
        }
    }
}

/// Everything the soak measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SoakReport {
    /// The config the soak was given, and the one it ran (with the pattern).
    pub config: String,
    /// The skin's name.
    pub skin: String,
    /// The seed of the faults: the same seed gives the same faults in the same order.
    pub seed: u64,
    /// Minutes asked for.
    pub minutes: f64,
    /// Seconds the faults ran for.
    pub seconds: f64,
    /// The layers and their taxels.
    pub layers: BTreeMap<String, usize>,
    /// The services' channels.
    pub services: Vec<String>,
    /// The verifying readers, by mode.
    pub readers: BTreeMap<String, ModeTotals>,
    /// All modes together.
    pub totals: LayerTally,
    /// Readers found stuck (attached, not stopped, their layer publishing,
    /// no new frame for [`super::STUCK_AFTER_S`] s).
    pub stuck_readers: Vec<StuckEpisode>,
    /// Readers that could not attach to a publishing layer for as long.
    pub unattached_readers: Vec<StuckEpisode>,
    /// The longest any reader went without a new frame while its layer
    /// published.
    pub longest_reader_wait_while_publishing: LongestWait,
    /// Every fault, in order.
    pub faults: Vec<FaultRecord>,
    /// Per kind of fault.
    pub recovery: BTreeMap<String, Recovery>,
    /// Whether every layer was back within 1 s of the end of every fault.
    pub every_layer_back_within_1s: bool,
    /// Memory and descriptors per process over time.
    pub processes: Vec<ProcessSeries>,
    /// Files in the segment directory during the run: the most at once.
    pub segment_files_max: usize,
    /// Files left in the soak's segment directory after everything stopped.
    pub leaked_files: Vec<String>,
    /// Of them, channels (sockets and name locks).
    pub leaked_channels: usize,
    /// The browser-like client of the viewer: what it received.
    pub browser: Option<serde_json::Value>,
    /// The browser's longest wait for an update, and the fault it fell in.
    pub browser_longest_gap_during: Option<String>,
    /// What the recorder said at the end.
    pub recorder: Option<serde_json::Value>,
    /// The supervisor's restarts of each driver and service, from its log.
    pub supervisor_restarts: usize,
    /// Real-time settings refused to the soak's observer.
    pub observer_rt_refused: Vec<String>,
    /// The correctness failures found (the soak exits non-zero if any).
    pub failures: Vec<String>,
    /// Whether it found none.
    pub passed: bool,
}

impl SoakReport {
    /// Prints the tables.
    pub fn print(&self) {
        let taxels: usize = self.layers.values().sum();
        println!(
            "soak of {} ({} layers, {taxels} taxels; services: {}): {:.0} s of faults, seed {}",
            self.config,
            self.layers.len(),
            if self.services.is_empty() { "none".to_owned() } else { self.services.join(", ") },
            self.seconds,
            self.seed
        );
        self.print_readers();
        self.print_recovery();
        self.print_processes();
        self.print_verdict();
    }

    fn print_readers(&self) {
        println!();
        println!(
            "| readers | processes | frames verified | torn | backwards | lost, counted | lost silently | over-counted | lost at a writer change | repeats | follows |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|");
        for (mode, totals) in &self.readers {
            let c = &totals.counts;
            println!(
                "| {mode} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
                totals.incarnations,
                c.verified,
                c.torn,
                c.backwards,
                c.lost_counted,
                c.lost_silently,
                c.over_counted,
                c.lost_at_follow,
                c.repeats,
                c.follows
            );
        }
        let t = &self.totals;
        println!(
            "| all | | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            t.verified,
            t.torn,
            t.backwards,
            t.lost_counted,
            t.lost_silently,
            t.over_counted,
            t.lost_at_follow,
            t.repeats,
            t.follows
        );
    }

    fn print_recovery(&self) {
        println!();
        println!(
            "| fault | count | every layer back after the fault's end, ms p50 / p99 / max | after the injection, ms p50 / p99 / max | layers and services after the end, max ms | not back | viewer's longest wait for an update, ms |"
        );
        println!("|---|---|---|---|---|---|---|");
        // Printed under the table too, since the two columns are easy to misread.
        for (kind, r) in &self.recovery {
            let ms = |s: &MsStats| {
                if s.samples == 0 { "–".to_owned() } else { format!("{:.0} / {:.0} / {:.0}", s.p50, s.p99, s.max) }
            };
            println!(
                "| {kind} | {} | {} | {} | {} | {} | {} |",
                r.count,
                ms(&r.after_end_ms),
                ms(&r.after_injection_ms),
                if r.services_after_end_ms.samples == 0 {
                    "–".into()
                } else {
                    format!("{:.0}", r.services_after_end_ms.max)
                },
                r.not_back,
                if r.viewer_longest_wait_ms > 0.0 {
                    format!("{:.0}", r.viewer_longest_wait_ms)
                } else {
                    "< 300".into()
                }
            );
        }
        println!(
            "back = the publication of the last layer's first frame after the moment (it includes waiting for each layer's next period, up to 33 ms on the paper's skin); the end is the kill, the SIGCONT, the restore, the removal or the hog's exit (docs/bench/soak.md)"
        );
    }

    fn print_processes(&self) {
        println!();
        println!(
            "| process | processes | longest-lived: pid, s sampled | its RSS MiB first / last / max | its fds first / last / max | RSS / fds most of any | grew |"
        );
        println!("|---|---|---|---|---|---|---|");
        let mut names: Vec<&str> = self.processes.iter().map(|p| p.name.as_str()).collect();
        names.dedup();
        for name in names {
            let all: Vec<&ProcessSeries> = self.processes.iter().filter(|p| p.name == name).collect();
            let Some(p) = all.iter().copied().max_by(|a, b| a.seconds.total_cmp(&b.seconds)) else { continue };
            let mib = |kib: u64| kib as f64 / 1024.0;
            let grew: Vec<String> = all
                .iter()
                .filter(|p| p.rss_grew || p.fds_grew)
                .map(|p| {
                    format!(
                        "{} ({}{})",
                        p.pid,
                        if p.rss_grew { "RSS " } else { "" },
                        if p.fds_grew { "fds" } else { "" }
                    )
                })
                .collect();
            println!(
                "| {} | {} | {}, {:.0} | {:.1} / {:.1} / {:.1} | {} / {} / {} | {:.1} / {} | {} |",
                name,
                all.len(),
                p.pid,
                p.seconds,
                mib(p.rss_kib_first),
                mib(p.rss_kib_last),
                mib(p.rss_kib_max),
                p.fds_first,
                p.fds_last,
                p.fds_max,
                mib(all.iter().map(|p| p.rss_kib_max).max().unwrap_or(0)),
                all.iter().map(|p| p.fds_max).max().unwrap_or(0),
                grew.join(", ")
            );
        }
    }

    fn print_verdict(&self) {
        println!();
        println!(
            "stuck readers: {}; readers unable to attach for {} s: {}; leaked files: {} ({} channel files); most files in the segment directory at once: {}",
            self.stuck_readers.len(),
            super::STUCK_AFTER_S,
            self.unattached_readers.len(),
            self.leaked_files.len(),
            self.leaked_channels,
            self.segment_files_max
        );
        let wait = &self.longest_reader_wait_while_publishing;
        if wait.ms > 0.0 {
            println!(
                "longest a reader went without a frame while its layer published: {:.0} ms ({} reader pid {}, {}, ending at {:.1} s{})",
                wait.ms,
                wait.mode,
                wait.pid,
                wait.layer,
                wait.at_s,
                if wait.followed { ", ended by following a successor" } else { "" }
            );
        } else {
            println!(
                "longest a reader went without a frame while its layer published: no pause over 1 s held two frames"
            );
        }
        for file in &self.leaked_files {
            println!("  left behind: {file}");
        }
        if let Some(browser) = &self.browser {
            let mut shown = browser.clone();
            if let Some(stalls) = shown.as_object_mut().and_then(|o| o.remove("stalls")) {
                let count = stalls.as_array().map_or(0, Vec::len);
                println!("viewer's browser: {shown}; {count} wait(s) over 300 ms for an update");
            } else {
                println!("viewer's browser: {shown}");
            }
        }
        if let Some(gap) = &self.browser_longest_gap_during {
            println!("  its longest wait for an update: {gap}");
        }
        if let Some(recorder) = &self.recorder {
            println!("recorder: {recorder}");
        }
        println!("supervisor restarts (from its log): {}", self.supervisor_restarts);
        println!(
            "every layer back within 1 s of every fault's end: {}",
            if self.every_layer_back_within_1s { "yes" } else { "NO (a goal, not asserted)" }
        );
        if self.passed {
            println!("soak: PASSED (no torn, backwards or silently lost frame, no stuck reader, no leaked channel)");
        } else {
            println!("soak: FAILED");
            for failure in &self.failures {
                println!("  {failure}");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ms_stats_are_nearest_rank() {
        let values: Vec<f64> = (1..=200).rev().map(f64::from).collect();
        let stats = MsStats::of(&values);
        assert_eq!((stats.p50, stats.p99, stats.max, stats.samples), (100.0, 198.0, 200.0, 200));
        assert_eq!(MsStats::of(&[]).samples, 0);
    }

    #[test]
    fn growth_is_flagged_only_for_a_long_steady_rise() {
        let series = |rss: &dyn Fn(u64) -> u64, fds: &dyn Fn(u64) -> u64| {
            let mut p = ProcessSeries {
                samples: (0..40).map(|i| (i as f64 * 2.0, rss(i), fds(i))).collect(),
                ..ProcessSeries::default()
            };
            p.finish();
            p
        };
        let flat = series(&|i| 10_000 + i % 3, &|_| 12);
        assert!(!flat.rss_grew && !flat.fds_grew);
        assert_eq!((flat.rss_kib_first, flat.fds_max), (10_000, 12));
        let leaking = series(&|i| 10_000 + 500 * i, &|i| 12 + i / 4);
        assert!(leaking.rss_grew && leaking.fds_grew);
        assert_eq!(leaking.rss_kib_max, 10_000 + 500 * 39);
    }
}
