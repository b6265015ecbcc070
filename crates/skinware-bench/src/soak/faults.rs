//! The faults: what each kind does, the seeded order they come in, their
//! log lines, and their recovery times summed up per kind.

use std::io::BufRead;
use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use rustix::process::Signal;

use super::helpers::FOREIGN_SKIN;
use super::injection::{FaultKind, Injected, KINDS};
use super::report::{FaultRecord, MsStats, Recovery, SoakReport};
use super::squats::{channel_paths, remove_squat};
use super::{RECOVERY_WAIT, Soak};
use crate::procs::{self, Guarded};

/// xorshift64*: the faults' order, targets and durations from a printed seed.
pub(super) struct Chaos {
    state: u64,
    round: Vec<FaultKind>,
}

impl Chaos {
    pub(super) fn new(seed: u64) -> Chaos {
        Chaos { state: seed | 1, round: Vec::new() }
    }

    /// A number in `0..below` (`below` > 0).
    pub(super) fn below(&mut self, below: u64) -> u64 {
        self.state ^= self.state >> 12;
        self.state ^= self.state << 25;
        self.state ^= self.state >> 27;
        self.state.wrapping_mul(0x2545_F491_4F6C_DD1D) % below.max(1)
    }

    /// A duration in `lo..hi` seconds.
    pub(super) fn seconds(&mut self, lo: f64, hi: f64) -> Duration {
        Duration::from_secs_f64(lo + (hi - lo) * self.below(1_000_000) as f64 / 1e6)
    }

    /// The next kind of fault: every kind once per round, in a shuffled order.
    pub(super) fn next_kind(&mut self) -> FaultKind {
        if self.round.is_empty() {
            self.round = KINDS.to_vec();
            for i in (1..self.round.len()).rev() {
                let j = self.below(i as u64 + 1) as usize;
                self.round.swap(i, j);
            }
        }
        self.round.pop().unwrap_or(FaultKind::DriverKill)
    }
}

/// `HH:MM:SS.mmm` UTC of a Unix time.
fn clock(unix_s: f64) -> String {
    let ms = (unix_s * 1000.0) as u64;
    let (s, ms) = (ms / 1000, ms % 1000);
    format!("{:02}:{:02}:{:02}.{ms:03}", s / 3600 % 24, s / 60 % 60, s % 60)
}

impl Soak<'_> {
    /// Injects faults one at a time, each after a pause of 2-5 s and once
    /// every layer runs again after the previous one, for the soak's minutes
    /// and at least one round of every kind.
    pub(super) fn run_faults(&mut self) -> Result<()> {
        let phase = Instant::now();
        let minutes = Duration::from_secs_f64(self.options.minutes * 60.0);
        let mut index = 0;
        let result = loop {
            let pause = self.chaos.seconds(2.0, 5.0);
            // At least one round, so that a short run (CI's) has every kind.
            if !self.idle(pause) || (phase.elapsed() >= minutes && index >= KINDS.len()) {
                break Ok(());
            }
            index += 1;
            let kind = self.chaos.next_kind();
            let injected = match self.inject(kind, index) {
                Ok(injected) => injected,
                Err(e) => break Err(e.context(format!("fault {index} ({})", kind.name()))),
            };
            self.await_recovery(injected);
            if let Err(e) = self.after_fault() {
                break Err(e);
            }
        };
        self.monitor.faults_seconds = phase.elapsed().as_secs_f64();
        result
    }

    /// Waits until every layer has published after the fault's end (or
    /// [`RECOVERY_WAIT`]), then logs and keeps the fault.
    fn await_recovery(&mut self, injected: Injected) {
        let Injected { mut record, injected_ns, ended_ns } = injected;
        self.observer.mark(ended_ns);
        let deadline = Instant::now() + RECOVERY_WAIT;
        let mut recovered = None;
        while Instant::now() < deadline {
            recovered = self.observer.recovered();
            if recovered.is_some() || !self.idle(Duration::from_millis(5)) {
                break;
            }
        }
        // The services may come a little after the layers.
        if recovered.is_some_and(|r| r.all_ns.is_none()) {
            let until = Instant::now() + Duration::from_secs(5);
            while Instant::now() < until && self.observer.recovered().is_some_and(|r| r.all_ns.is_none()) {
                self.idle(Duration::from_millis(5));
            }
            recovered = self.observer.recovered();
        }
        let ms = |ns: u64, from: u64| ns.saturating_sub(from) as f64 / 1e6;
        if let Some(r) = recovered {
            record.back_after_end_ms = Some(ms(r.layers_ns, ended_ns));
            record.back_after_injection_ms = Some(ms(r.layers_ns, injected_ns));
            record.services_back_after_end_ms = r.all_ns.map(|all| ms(all, ended_ns));
        }
        record.interrupted = recovered.is_none() && self.interrupted();
        let back = match record.back_after_end_ms {
            None if record.interrupted => "interrupted before every layer was back".to_owned(),
            Some(after_end) => format!(
                "every layer back {after_end:.0} ms after its end ({:.0} ms after the injection)",
                record.back_after_injection_ms.unwrap_or(0.0)
            ),
            None => format!("SOME LAYER NOT BACK within {} s", RECOVERY_WAIT.as_secs()),
        };
        println!(
            "soak: {:7.1} s ({} UTC) fault {:3} {:<24} {}; held {:.2} s; {back}{}",
            record.injected_s,
            clock(record.injected_unix_s),
            record.index,
            record.kind,
            record.target,
            record.held_s,
            match (&record.name_back_ms, record.note.is_empty()) {
                (Some(ms), _) => format!("; its name back after {ms:.0} ms"),
                (None, false) => format!(" [{}]", record.note),
                (None, true) => String::new(),
            }
        );
        self.report.faults.push(record);
    }

    /// Ends what a fault left for after the recovery (the foreign writers).
    fn after_fault(&mut self) -> Result<()> {
        for pid in self.stopped.drain(..) {
            procs::signal(pid, Signal::CONT);
        }
        for mut helper in self.helpers.drain(..) {
            drop(helper.0.stdin.take());
            super::monitor::wait_or_kill(&mut helper.0, Duration::from_secs(3));
        }
        // A foreign writer killed at the deadline leaves its channels.
        for entry in std::fs::read_dir(&self.options.dir)?.flatten() {
            if entry.file_name().to_string_lossy().starts_with(&format!("skinware.{FOREIGN_SKIN}.")) {
                let _ = skinware::remove_channel_if_stale(&entry.path());
            }
        }
        Ok(())
    }

    fn inject(&mut self, kind: FaultKind, index: usize) -> Result<Injected> {
        match kind {
            FaultKind::DriverKill => {
                let (name, pid) = self.driver()?;
                let injected = self.begin(kind, index, format!("{name} (pid {pid}) killed"));
                procs::signal(pid, Signal::KILL);
                Ok(injected)
            }
            FaultKind::DriverStop => self.driver_stop(index),
            FaultKind::ReaderKill => self.reader_kill(index),
            FaultKind::ReaderStop => self.reader_stop(index),
            FaultKind::CablePull => self.cable_pull(index),
            FaultKind::ForeignStoppedWriters => self.foreign_stopped_writers(index),
            FaultKind::FifoSquatDriverKill => self.fifo_squat_driver_kill(index),
            FaultKind::UnlinkLiveName => self.unlink_live_name(index),
            FaultKind::SquatFile | FaultKind::SquatFifo | FaultKind::SquatSymlink => self.squat(kind, index),
            FaultKind::CpuHog => self.cpu_hog(index),
        }
    }

    fn driver_stop(&mut self, index: usize) -> Result<Injected> {
        let (name, pid) = self.driver()?;
        let hold = self.chaos.seconds(0.2, 2.5);
        let mut injected = self.begin(FaultKind::DriverStop, index, format!("{name} (pid {pid}) stopped"));
        procs::signal(pid, Signal::STOP);
        self.stopped.push(pid);
        self.idle(hold);
        let killed =
            matches!(procs::state_of(pid), Some('Z') | None) || procs::parent_of(pid) != Some(self.monitor.skin_pid);
        procs::signal(pid, Signal::CONT);
        self.stopped.retain(|&p| p != pid);
        self.end(&mut injected);
        if killed {
            injected.record.note = "the supervisor killed it as hung while it was stopped".into();
        }
        Ok(injected)
    }

    fn reader_kill(&mut self, index: usize) -> Result<Injected> {
        let victim = self.chaos.below(self.readers.len() as u64) as usize;
        let mut reader = self.readers.swap_remove(victim);
        let injected = self.begin(
            FaultKind::ReaderKill,
            index,
            format!("reader {} (pid {}) killed", reader.mode.name(), reader.child.id()),
        );
        let _ = reader.child.kill();
        let _ = reader.child.wait();
        self.finished_reports.push((reader.mode, reader.report));
        self.spawn_reader(reader.mode)?;
        Ok(injected)
    }

    fn reader_stop(&mut self, index: usize) -> Result<Injected> {
        let victim = self.chaos.below(self.readers.len() as u64) as usize;
        let hold = self.chaos.seconds(0.3, 3.0);
        let pid = self.readers[victim].child.id();
        let what = format!("reader {} (pid {pid}) stopped", self.readers[victim].mode.name());
        let mut injected = self.begin(FaultKind::ReaderStop, index, what);
        self.readers[victim].stopped = true;
        procs::signal(pid, Signal::STOP);
        self.stopped.push(pid);
        self.idle(hold);
        // Before the signal: the reader may get a frame before `kill`
        // returns, and its pause must count from here.
        let resumed_ns = skinware::os::monotonic_ns();
        procs::signal(pid, Signal::CONT);
        self.stopped.retain(|&p| p != pid);
        if let Some(reader) = self.readers.iter_mut().find(|r| r.child.id() == pid) {
            reader.stopped = false;
            reader.since_ns = resumed_ns;
        }
        self.end(&mut injected);
        Ok(injected)
    }

    fn cable_pull(&mut self, index: usize) -> Result<Injected> {
        let layer = self.options.layers[self.chaos.below(self.options.layers.len() as u64) as usize].clone();
        let hold = self.chaos.seconds(0.5, 3.0);
        let mut injected = self.begin(FaultKind::CablePull, index, format!("{} cable pulled", layer.name));
        std::fs::write(&layer.pull_file, b"pulled by skin bench soak\n")
            .with_context(|| format!("cannot create {}", layer.pull_file.display()))?;
        self.squats.push(layer.pull_file.clone());
        self.idle(hold);
        remove_squat(&layer.pull_file);
        self.squats.retain(|p| p != &layer.pull_file);
        self.end(&mut injected);
        Ok(injected)
    }

    fn unlink_live_name(&mut self, index: usize) -> Result<Injected> {
        let layer = self.options.layers[self.chaos.below(self.options.layers.len() as u64) as usize].name.clone();
        let paths = channel_paths(&self.options.dir, &self.options.skin, &layer);
        let mut injected =
            self.begin(FaultKind::UnlinkLiveName, index, format!("{layer}: socket and name lock unlinked"));
        for path in &paths {
            let _ = std::fs::remove_file(path);
        }
        let unlinked = Instant::now();
        while unlinked.elapsed() < Duration::from_secs(5) && !paths.iter().all(|p| p.exists()) {
            self.idle(Duration::from_millis(5));
        }
        if paths.iter().all(|p| p.exists()) {
            injected.record.name_back_ms = Some(unlinked.elapsed().as_secs_f64() * 1e3);
        } else {
            let missing: Vec<String> = paths
                .iter()
                .filter(|p| !p.exists())
                .map(|p| p.file_name().unwrap_or_default().to_string_lossy().into_owned())
                .collect();
            injected.record.note = format!("not put back within 5 s: {}", missing.join(", "));
        }
        Ok(injected)
    }

    fn cpu_hog(&mut self, index: usize) -> Result<Injected> {
        let threads = 2 * std::thread::available_parallelism().map_or(2, |n| n.get());
        let hold = self.chaos.seconds(2.0, 5.0);
        let mut injected = self.begin(FaultKind::CpuHog, index, format!("{threads} busy threads"));
        let hog = self
            .command("hog.log")?
            .args(["bench-soak-hog", "--threads", &threads.to_string(), "--seconds"])
            .arg(format!("{:.3}", hold.as_secs_f64()))
            .spawn()
            .context("cannot start the CPU hog")?;
        let mut hog = Guarded(hog);
        while hog.0.try_wait()?.is_none() {
            self.idle(Duration::from_millis(5));
        }
        self.end(&mut injected);
        Ok(injected)
    }

    fn foreign_stopped_writers(&mut self, index: usize) -> Result<Injected> {
        const WRITERS: usize = 10;
        let mut child = self
            .command("foreign.log")?
            .args(["bench-soak-foreign", "--channels", &WRITERS.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .context("cannot start the foreign writers")?;
        let stdout = child.stdout.take().context("the foreign writers' output")?;
        let helper = Guarded(child);
        let pid = helper.0.id();
        self.helpers.push(helper);
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = std::io::BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        if rx.recv_timeout(Duration::from_secs(10)).map(|l| l.trim() == "ready").unwrap_or(false) {
            procs::signal(pid, Signal::STOP);
            self.stopped.push(pid);
        } else {
            bail!("the foreign writers did not start within 10 s (see foreign.log)");
        }
        self.idle(Duration::from_millis(500));
        let (name, driver) = self.driver()?;
        let injected = self.begin(
            FaultKind::ForeignStoppedWriters,
            index,
            format!("{WRITERS} writers of skin {FOREIGN_SKIN} stopped, then {name} (pid {driver}) killed"),
        );
        procs::signal(driver, Signal::KILL);
        Ok(injected)
    }
}

/// Matches the browser's stalls (`(ended_ns, ms)`) with the faults: each
/// fault gets the longest that overlapped it, from its injection until a
/// second after every layer and service was back.
fn match_viewer_stalls(report: &mut SoakReport) {
    let Some(stalls) = report.browser.as_ref().and_then(|b| b.get("stalls")).and_then(|s| s.as_array()) else {
        return;
    };
    let stalls: Vec<(u64, f64)> =
        stalls.iter().filter_map(|stall| Some((stall.get(0)?.as_u64()?, stall.get(1)?.as_f64()?))).collect();
    for fault in &mut report.faults {
        let back_ms = fault.services_back_after_end_ms.or(fault.back_after_end_ms).unwrap_or(0.0);
        let until = fault.ended_monotonic_ns + ((back_ms + 1000.0) * 1e6) as u64;
        fault.viewer_longest_wait_ms = stalls
            .iter()
            .filter(|&&(ended, ms)| {
                ended >= fault.injected_monotonic_ns && ended.saturating_sub((ms * 1e6) as u64) <= until
            })
            .map(|&(_, ms)| ms)
            .reduce(f64::max);
    }
}

/// The recovery figures per kind of fault, and whether every layer was back
/// within 1 s of every fault's end.
pub(super) fn summarize_recovery(report: &mut SoakReport) {
    match_viewer_stalls(report);
    for kind in KINDS {
        let faults: Vec<&FaultRecord> =
            report.faults.iter().filter(|f| f.kind == kind.name() && !f.interrupted).collect();
        if faults.is_empty() {
            continue;
        }
        let after_end: Vec<f64> = faults.iter().filter_map(|f| f.back_after_end_ms).collect();
        let after_injection: Vec<f64> = faults.iter().filter_map(|f| f.back_after_injection_ms).collect();
        let services: Vec<f64> = faults.iter().filter_map(|f| f.services_back_after_end_ms).collect();
        report.recovery.insert(
            kind.name().to_owned(),
            Recovery {
                count: faults.len(),
                not_back: faults.len() - after_end.len(),
                after_end_ms: MsStats::of(&after_end),
                after_injection_ms: MsStats::of(&after_injection),
                services_after_end_ms: MsStats::of(&services),
                viewer_longest_wait_ms: faults.iter().filter_map(|f| f.viewer_longest_wait_ms).fold(0.0, f64::max),
            },
        );
    }
    report.every_layer_back_within_1s = !report.faults.is_empty()
        && report.faults.iter().filter(|f| !f.interrupted).all(|f| f.back_after_end_ms.is_some_and(|ms| ms <= 1000.0));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_seed_gives_the_same_faults_and_every_round_has_every_kind() {
        let draw = |seed| {
            let mut chaos = Chaos::new(seed);
            (0..36).map(|_| chaos.next_kind()).collect::<Vec<_>>()
        };
        assert_eq!(draw(7), draw(7));
        assert_ne!(draw(7), draw(8));
        for round in draw(7).chunks(KINDS.len()) {
            let mut names: Vec<&str> = round.iter().map(|k| k.name()).collect();
            names.sort_unstable();
            names.dedup();
            assert_eq!(names.len(), KINDS.len(), "{round:?}");
        }
    }

    #[test]
    fn viewer_stalls_go_to_the_faults_they_overlap() {
        const S: u64 = 1_000_000_000;
        let fault = |index, injected_s: u64, ended_s: u64| FaultRecord {
            index,
            injected_monotonic_ns: injected_s * S,
            ended_monotonic_ns: ended_s * S,
            back_after_end_ms: Some(500.0),
            ..FaultRecord::default()
        };
        let mut report = SoakReport {
            faults: vec![fault(1, 10, 12), fault(2, 30, 30)],
            // Ends inside fault 1; started before fault 2 and ended in it; long after both.
            browser: Some(
                serde_json::json!({"stalls": [[11 * S, 400.0], [31 * S, 2_000.0], [60 * S, 900.0], [11 * S, 350.0]]}),
            ),
            ..SoakReport::default()
        };
        match_viewer_stalls(&mut report);
        assert_eq!(report.faults[0].viewer_longest_wait_ms, Some(400.0));
        assert_eq!(report.faults[1].viewer_longest_wait_ms, Some(2_000.0));
        report.browser = Some(serde_json::json!({"stalls": [[50 * S, 400.0]]}));
        match_viewer_stalls(&mut report);
        assert_eq!(report.faults[0].viewer_longest_wait_ms, None);
    }

    #[test]
    fn clock_is_utc_time_of_day() {
        assert_eq!(clock(86_400.0 * 3.0 + 3_723.456), "01:02:03.456");
    }
}
