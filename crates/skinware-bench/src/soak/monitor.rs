//! What the soak watches between and during faults: the memory and open
//! descriptors of every long-lived process, the files in the segment
//! directory, and verifying readers that stop getting frames while their
//! layer publishes (stuck readers). And the consumers it stops at the end:
//! the browser-like client, the recorder and the viewer.

use std::collections::{BTreeMap, HashSet};
use std::io::Read;
use std::path::Path;
use std::process::Child;
use std::time::Duration;

use super::report::{ProcessSeries, Sample, SoakReport, StuckEpisode};
use super::{STUCK_AFTER_S, Soak, reader::ReaderReport};
use crate::procs::{self, Guarded};

/// How often the processes are sampled.
const SAMPLE_NS: u64 = 2_000_000_000;
/// How often the readers' reports are looked at.
const STUCK_CHECK_NS: u64 = 250_000_000;

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
    fn check_stuck(&mut self, now: u64) {
        let stuck_after = (STUCK_AFTER_S * 1e9) as u64;
        let at_s = self.elapsed_s();
        let mut found = Vec::new();
        for reader in &self.readers {
            if reader.stopped || now < reader.since_ns + stuck_after {
                continue;
            }
            let pid = reader.child.id();
            let report = ReaderReport::read(&reader.report).unwrap_or_default();
            for layer in &self.options.layers {
                let tally = report.layers.get(&layer.name).cloned().unwrap_or_default();
                // A report that stopped coming counts from its writing: the
                // process itself may have hung.
                let last = tally.last_new_ns.max(reader.since_ns);
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
                if self.monitor.stuck_now.insert(key) {
                    found.push(StuckEpisode {
                        mode: reader.mode.name().to_owned(),
                        pid,
                        layer: layer.name.clone(),
                        at_s,
                        silent_s: now.saturating_sub(last) as f64 / 1e9,
                        published_meanwhile: self.observer.published_since(&layer.name, last),
                        attached: tally.attached,
                    });
                }
            }
        }
        for episode in found {
            println!(
                "soak: {:.1} s: reader {} (pid {}) has had no new frame of {} for {:.1} s while it published {} ({})",
                episode.at_s,
                episode.mode,
                episode.pid,
                episode.layer,
                episode.silent_s,
                episode.published_meanwhile,
                if episode.attached { "STUCK" } else { "it cannot attach" }
            );
            if episode.attached {
                self.report.stuck_readers.push(episode);
            } else {
                self.report.unattached_readers.push(episode);
            }
        }
    }
}
