//! What the soak watches between and during faults: the memory and open
//! descriptors of every long-lived process, the files in the segment
//! directory, and verifying readers that stop getting frames while their
//! layer publishes (stuck readers). And the consumers it stops at the end:
//! the browser-like client, the recorder and the viewer.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::io::Read;
use std::path::Path;
use std::process::Child;
use std::time::Duration;

use super::reader::LayerTally;
use super::report::{LongestWait, ProcessSeries, Sample, SoakReport, StuckEpisode};
use super::{STUCK_AFTER_S, Soak, reader::ReaderReport};
use crate::procs::{self, Guarded};

/// How often the processes are sampled.
const SAMPLE_NS: u64 = 2_000_000_000;
/// How often the readers' reports are looked at.
const STUCK_CHECK_NS: u64 = 250_000_000;
/// A reader's report older than this says nothing about its frames now (it
/// writes one every 250 ms, to a file on tmpfs).
const REPORT_FRESH_NS: u64 = 1_000_000_000;

/// The monitor's state.
#[derive(Default)]
pub(super) struct Monitor {
    /// `skin run`'s process id.
    pub(super) skin_pid: u32,
    pub(super) viewer: Option<Guarded>,
    pub(super) browser: Option<Child>,
    pub(super) recorder: Option<Child>,
    /// Samples by (name, pid): `(s since start, RSS KiB, fds)`.
    samples: BTreeMap<(String, u32), Vec<Sample>>,
    next_sample_ns: u64,
    next_stuck_check_ns: u64,
    /// (reader pid, layer) found stuck and not yet moving again.
    stuck_now: HashSet<(u32, String)>,
    /// Reader processes whose reports stopped coming, not yet writing again.
    silent_now: HashSet<u32>,
    /// Episodes counted: (reader pid, layer, the reader's last new frame
    /// before it, ns), so that one found live is not found again in the record.
    counted: HashSet<(u32, String, u64)>,
    /// How many of each (reader pid, layer)'s long pauses were looked at.
    gaps_seen: HashMap<(u32, String), usize>,
    pub(super) segment_files_max: usize,
    /// Seconds of the fault phase.
    pub(super) faults_seconds: f64,
}

impl Monitor {
    /// The processes' series, finished.
    pub(super) fn series(&self) -> Vec<ProcessSeries> {
        self.samples
            .iter()
            .map(|((name, pid), samples)| {
                let mut series = ProcessSeries {
                    name: name.clone(),
                    pid: *pid,
                    samples: samples.clone(),
                    ..ProcessSeries::default()
                };
                series.finish();
                series
            })
            .collect()
    }

    /// Stops the browser (its report kept), the recorder (its summary kept;
    /// its file removed) and the viewer.
    pub(super) fn stop_consumers(&mut self, work: &Path, report: &mut SoakReport) {
        if let Some(mut browser) = self.browser.take() {
            drop(browser.stdin.take());
            wait_or_kill(&mut browser, Duration::from_secs(5));
            report.browser =
                std::fs::read(work.join("browser.json")).ok().and_then(|b| serde_json::from_slice(&b).ok());
        }
        if let Some(mut recorder) = self.recorder.take() {
            procs::signal(recorder.id(), rustix::process::Signal::INT);
            let mut text = String::new();
            if let Some(mut stdout) = recorder.stdout.take() {
                // It prints its summary as it exits, which closes the pipe.
                let reader = std::thread::spawn(move || {
                    let _ = stdout.read_to_string(&mut text);
                    text
                });
                wait_or_kill(&mut recorder, Duration::from_secs(20));
                text = reader.join().unwrap_or_default();
            }
            report.recorder = serde_json::from_str(text.trim())
                .ok()
                .or_else(|| (!text.trim().is_empty()).then(|| serde_json::Value::String(text.trim().to_owned())));
            let _ = std::fs::remove_file(work.join("soak.mcap"));
        }
        if let Some(viewer) = self.viewer.take() {
            procs::signal(viewer.0.id(), rustix::process::Signal::INT);
            let mut viewer = viewer;
            wait_or_kill(&mut viewer.0, Duration::from_secs(5));
        }
    }
}

/// Waits up to `patience` for `child` to exit, then kills it.
pub(super) fn wait_or_kill(child: &mut Child, patience: Duration) {
    let deadline = std::time::Instant::now() + patience;
    while child.try_wait().ok().flatten().is_none() {
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    let _ = child.wait();
}

impl Soak<'_> {
    /// One look: samples the processes and the segment directory when due,
    /// and checks the readers for stuck ones when due.
    pub(super) fn watch(&mut self) {
        let now = skinware::os::monotonic_ns();
        if now >= self.monitor.next_sample_ns {
            self.monitor.next_sample_ns = now + SAMPLE_NS;
            self.sample();
        }
        if now >= self.monitor.next_stuck_check_ns {
            self.monitor.next_stuck_check_ns = now + STUCK_CHECK_NS;
            self.check_stuck(now);
        }
    }

    fn sample(&mut self) {
        let at = self.elapsed_s();
        let mut pids: Vec<(String, u32)> = vec![("soak (this process)".into(), std::process::id())];
        if self.monitor.skin_pid != 0 {
            pids.push(("skin run".into(), self.monitor.skin_pid));
            pids.extend(procs::supervised_pids(self.monitor.skin_pid));
        }
        let m = &self.monitor;
        pids.extend(m.viewer.as_ref().map(|v| ("viewer".into(), v.0.id())));
        pids.extend(m.browser.as_ref().map(|b| ("browser client".into(), b.id())));
        pids.extend(m.recorder.as_ref().map(|r| ("recorder".into(), r.id())));
        pids.extend(self.readers.iter().map(|r| (format!("reader {}", r.mode.name()), r.child.id())));
        for (name, pid) in pids {
            if let Some(found) = procs::resources_of(pid) {
                self.monitor.samples.entry((name, pid)).or_default().push((at, found.rss_kib, found.fds));
            }
        }
        let files = std::fs::read_dir(&self.options.dir).map(|e| e.count()).unwrap_or(0);
        self.monitor.segment_files_max = self.monitor.segment_files_max.max(files);
    }

    /// A reader is stuck when it is alive and running (not stopped, and
    /// started or resumed [`STUCK_AFTER_S`] ago), its layer has been
    /// publishing without a pause for [`STUCK_AFTER_S`] since the reader's
    /// last new frame, and it got none of those frames.
    ///
    /// Two ways find one. Live, from a fresh report: its last new frame is
    /// that old now. After the fact, from the reader's own record of its
    /// long pauses ([`LayerTally::long_gaps`]): the layer published that long
    /// within one of them. A report that is not fresh says nothing about the
    /// reader's frames, only that its process has not written for a while;
    /// for longer than [`STUCK_AFTER_S`] while running, that is an episode
    /// too (its process did not run).
    fn check_stuck(&mut self, now: u64) {
        let stuck_after = (STUCK_AFTER_S * 1e9) as u64;
        let mut found = Vec::new();
        for index in 0..self.readers.len() {
            let reader = &self.readers[index];
            let (pid, since_ns) = (reader.child.id(), reader.since_ns);
            if reader.stopped || now < since_ns + stuck_after {
                continue;
            }
            let Some(report) = ReaderReport::read(&reader.report) else { continue };
            let written_ago = now.saturating_sub(report.written_ns.max(since_ns));
            if written_ago > REPORT_FRESH_NS {
                if written_ago > stuck_after && self.monitor.silent_now.insert(pid) {
                    found.push(self.episode(index, "", report.written_ns.max(since_ns), now, Cause::NoReport));
                }
                continue;
            }
            self.monitor.silent_now.remove(&pid);
            for layer in &self.options.layers {
                let tally = report.layers.get(&layer.name).cloned().unwrap_or_default();
                found.extend(self.stuck_in_record(index, &layer.name, &tally));
                let last = tally.last_new_ns.max(since_ns);
                let key = (pid, layer.name.clone());
                // Frames it could have had: the layer's current run of
                // frames after the reader's last one (a writer that died
                // just after that frame and a successor 2 s later do not
                // make 2 s of frames to have).
                let available = self.observer.publishing_since(&layer.name, last);
                let stuck = available.is_some_and(|since| now.saturating_sub(since) > stuck_after);
                if !stuck {
                    self.monitor.stuck_now.remove(&key);
                    continue;
                }
                if self.monitor.stuck_now.insert(key)
                    && self.monitor.counted.insert((pid, layer.name.clone(), tally.last_new_ns))
                {
                    let cause = if tally.attached { Cause::Live } else { Cause::Unattached };
                    found.push(self.episode(index, &layer.name, last, now, cause));
                }
            }
        }
        for episode in found {
            println!(
                "soak: {:.1} s: reader {} (pid {}) {}",
                episode.at_s,
                episode.mode,
                episode.pid,
                if episode.layer.is_empty() {
                    format!(
                        "has not written its report for {:.1} s while running: STUCK (its process did not run)",
                        episode.silent_s
                    )
                } else {
                    format!(
                        "had no new frame of {} for {:.1} s while it published {} ({})",
                        episode.layer, episode.silent_s, episode.published_meanwhile, episode.found_by
                    )
                }
            );
            if episode.attached {
                self.report.stuck_readers.push(episode);
            } else {
                self.report.unattached_readers.push(episode);
            }
        }
    }

    /// The stuck episodes in the long pauses `tally` recorded since the last
    /// look, and the longest run of frames any of them held, kept.
    fn stuck_in_record(&mut self, index: usize, layer: &str, tally: &LayerTally) -> Vec<StuckEpisode> {
        let reader = &self.readers[index];
        let pid = reader.child.id();
        let seen = self.monitor.gaps_seen.entry((pid, layer.to_owned())).or_default();
        let new_gaps = tally.long_gaps.get(*seen..).unwrap_or_default().to_vec();
        *seen = tally.long_gaps.len();
        let since_ns = reader.since_ns;
        let mut found = Vec::new();
        for gap in new_gaps {
            // A reader stopped and resumed within its pause: counted from the resumption.
            let from = if since_ns > gap.from_ns && since_ns < gap.to_ns { since_ns } else { gap.from_ns };
            let run = self.observer.longest_run_within(layer, from, gap.to_ns);
            let longest = &mut self.report.longest_reader_wait_while_publishing;
            if run as f64 / 1e6 > longest.ms {
                *longest = LongestWait {
                    ms: run as f64 / 1e6,
                    mode: reader.mode.name().to_owned(),
                    pid,
                    layer: layer.to_owned(),
                    at_s: gap.to_ns.saturating_sub(self.started_ns) as f64 / 1e9,
                    followed: gap.followed,
                };
            }
            if run as f64 > STUCK_AFTER_S * 1e9 && self.monitor.counted.insert((pid, layer.to_owned(), gap.from_ns)) {
                found.push(self.episode(index, layer, from, gap.to_ns, Cause::Record));
            }
        }
        found
    }

    fn episode(&self, index: usize, layer: &str, from_ns: u64, to_ns: u64, cause: Cause) -> StuckEpisode {
        let reader = &self.readers[index];
        StuckEpisode {
            mode: reader.mode.name().to_owned(),
            pid: reader.child.id(),
            layer: layer.to_owned(),
            at_s: to_ns.saturating_sub(self.started_ns) as f64 / 1e9,
            silent_s: to_ns.saturating_sub(from_ns) as f64 / 1e9,
            published_meanwhile: if layer.is_empty() {
                0
            } else {
                self.observer.published_between(layer, from_ns, to_ns)
            },
            attached: cause != Cause::Unattached,
            found_by: cause.describe().to_owned(),
        }
    }
}

/// How a stuck episode was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Cause {
    /// A fresh report's last new frame was old.
    Live,
    /// The same, for a reader that never attached.
    Unattached,
    /// The reader's own record of a long pause.
    Record,
    /// The reader's process wrote no report while it should have run.
    NoReport,
}

impl Cause {
    fn describe(self) -> &'static str {
        match self {
            Cause::Live => "STUCK, seen live",
            Cause::Unattached => "it cannot attach",
            Cause::Record => "STUCK, in the reader's own record",
            Cause::NoReport => "STUCK, its process did not run",
        }
    }
}
