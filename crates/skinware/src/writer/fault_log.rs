//! How a writer tells the log about its faults: once, then in summaries.
//!
//! A source that fails and recovers every few frames (a CAN bus losing a
//! frame now and then, an EtherCAT segment at 1 kHz with a flaky cable)
//! would otherwise log two lines per flap: thousands a minute. Within a
//! [`SUMMARY_EVERY`] window the first failure and the first recovery are
//! logged in full; what follows is counted and said in one summary line when
//! the window is over (at the next frame after it, good or bad).

#![forbid(unsafe_code)]

use std::fmt::Write as _;

/// The longest a repeated fault goes unsaid.
pub(crate) const SUMMARY_EVERY_NS: u64 = 10_000_000_000;

/// What to log after a frame, if anything.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum FaultLine<'a> {
    /// The acquisition failed and the channel is now faulted.
    Failed {
        /// The source's error.
        error: &'a str,
    },
    /// The channel is running again.
    Recovered,
    /// What was not said since the window began.
    Summary {
        /// The window's length, ns.
        window_ns: u64,
        /// Acquisitions that failed.
        failed: u64,
        /// Times the channel became faulted.
        faulted: u64,
        /// Times it recovered.
        recovered: u64,
        /// The newest error not said.
        last_error: &'a str,
    },
}

/// A writer's fault-logging state: two integers and a reused text buffer on
/// the path of a failed frame, one comparison on the path of a good one.
#[derive(Debug, Default)]
pub(crate) struct FaultLog {
    /// Start of the current window (ns), or `None` between windows.
    window_start_ns: Option<u64>,
    failed: u64,
    faulted: u64,
    recovered: u64,
    said_failed: bool,
    said_recovered: bool,
    last_error: String,
    /// A summary is due once this passes (`u64::MAX` when none is pending).
    summary_due_ns: u64,
}

impl FaultLog {
    /// A failed acquisition at `now_ns`; `became_faulted` if the channel was
    /// not faulted before it.
    pub(crate) fn failed(
        &mut self,
        now_ns: u64,
        became_faulted: bool,
        error: &dyn std::fmt::Display,
    ) -> Vec<FaultLine<'_>> {
        let mut lines = self.close_window_if_over(now_ns);
        let start = *self.window_start_ns.get_or_insert(now_ns);
        if became_faulted && !self.said_failed {
            self.said_failed = true;
            self.last_error.clear();
            let _ = write!(self.last_error, "{error}");
            lines.push(FaultLine::Failed { error: "" });
        } else {
            self.failed += 1;
            self.faulted += u64::from(became_faulted);
            self.last_error.clear();
            let _ = write!(self.last_error, "{error}");
            self.summary_due_ns = start.saturating_add(SUMMARY_EVERY_NS);
        }
        self.fill_errors(lines)
    }

    /// A good frame at `now_ns`; `recovered` if the channel was faulted.
    pub(crate) fn succeeded(&mut self, now_ns: u64, recovered: bool) -> Vec<FaultLine<'_>> {
        if !recovered && now_ns < self.summary_due_ns {
            return Vec::new();
        }
        let mut lines = self.close_window_if_over(now_ns);
        if recovered {
            let start = *self.window_start_ns.get_or_insert(now_ns);
            if self.said_recovered {
                self.recovered += 1;
                self.summary_due_ns = start.saturating_add(SUMMARY_EVERY_NS);
            } else {
                self.said_recovered = true;
                lines.push(FaultLine::Recovered);
            }
        }
        self.fill_errors(lines)
    }

    /// The summary of a window that is over, and a fresh start.
    fn close_window_if_over(&mut self, now_ns: u64) -> Vec<FaultLine<'static>> {
        let Some(start) = self.window_start_ns else { return Vec::new() };
        if now_ns.saturating_sub(start) < SUMMARY_EVERY_NS {
            return Vec::new();
        }
        let pending = self.failed + self.faulted + self.recovered > 0;
        let summary = pending.then(|| FaultLine::Summary {
            window_ns: now_ns.saturating_sub(start),
            failed: self.failed,
            faulted: self.faulted,
            recovered: self.recovered,
            last_error: "",
        });
        // A window with something to say is followed by another at once,
        // so that a fault that goes on is summarised again, not re-said.
        self.window_start_ns = pending.then_some(now_ns);
        self.said_failed = pending;
        self.said_recovered = pending;
        self.failed = 0;
        self.faulted = 0;
        self.recovered = 0;
        self.summary_due_ns = u64::MAX;
        summary.into_iter().collect()
    }

    /// Points the lines' error texts at the stored one.
    fn fill_errors(&self, lines: Vec<FaultLine<'static>>) -> Vec<FaultLine<'_>> {
        lines
            .into_iter()
            .map(|line| match line {
                FaultLine::Failed { .. } => FaultLine::Failed { error: &self.last_error },
                FaultLine::Summary { window_ns, failed, faulted, recovered, .. } => {
                    FaultLine::Summary { window_ns, failed, faulted, recovered, last_error: &self.last_error }
                }
                other => other,
            })
            .collect()
    }
}

/// Says `line` about `channel` in the log.
pub(crate) fn log(channel: &str, line: &FaultLine<'_>) {
    match line {
        FaultLine::Failed { error } => {
            tracing::warn!(channel, error, "acquisition failed; channel faulted");
        }
        FaultLine::Recovered => tracing::info!(channel, "acquisition recovered"),
        FaultLine::Summary { window_ns, failed, faulted, recovered, last_error } => {
            tracing::warn!(
                channel,
                window_s = format_args!("{:.1}", *window_ns as f64 * 1e-9),
                failed,
                faulted,
                recovered,
                last_error,
                "acquisition faults since the last line (repeats are summarised every {} s)",
                SUMMARY_EVERY_NS / 1_000_000_000
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{FaultLine, FaultLog, SUMMARY_EVERY_NS};

    const MS: u64 = 1_000_000;

    /// A source that fails every other frame at 1 kHz for `seconds`, as the
    /// log sees it: every line it would print.
    fn flapping(log: &mut FaultLog, from_ns: u64, seconds: u64) -> Vec<String> {
        let mut said = Vec::new();
        for k in 0..seconds * 1000 {
            let now = from_ns + k * MS;
            let lines = if k % 2 == 0 { log.failed(now, true, &"bus error") } else { log.succeeded(now, true) };
            said.extend(lines.iter().map(|line| format!("{line:?}")));
        }
        said
    }

    #[test]
    #[cfg_attr(
        miri,
        ignore = "arithmetic over tens of thousands of frames: nothing for Miri to check, minutes under it"
    )]
    fn a_flapping_source_is_said_once_then_summarised_every_window() {
        let mut log = FaultLog::default();
        let said = flapping(&mut log, 1_000 * MS, 30);
        // 30,000 transitions: the first failure and recovery in full, then
        // one summary per 10 s window.
        assert_eq!(said.len(), 2 + 2, "{said:#?}");
        assert_eq!(said[0], r#"Failed { error: "bus error" }"#);
        assert_eq!(said[1], "Recovered");
        assert!(
            said[2].starts_with("Summary { window_ns: 10000000000, failed: 4999, faulted: 4999, recovered: 4999"),
            "{}",
            said[2]
        );
        assert!(
            said[3].starts_with("Summary { window_ns: 10000000000, failed: 5000, faulted: 5000, recovered: 5000"),
            "{}",
            said[3]
        );
    }

    #[test]
    #[cfg_attr(
        miri,
        ignore = "arithmetic over tens of thousands of frames: nothing for Miri to check, minutes under it"
    )]
    fn a_fault_after_a_quiet_window_is_said_in_full_again() {
        let mut log = FaultLog::default();
        assert_eq!(log.failed(0, true, &"cable pulled"), vec![FaultLine::Failed { error: "cable pulled" }]);
        assert_eq!(log.succeeded(5 * MS, true), vec![FaultLine::Recovered]);
        // Good frames for longer than a window: nothing pending, nothing said.
        for k in 6..=11_000 {
            assert!(log.succeeded(k * MS, false).is_empty());
        }
        assert_eq!(
            log.failed(12_000 * MS, true, &"cable pulled again"),
            vec![FaultLine::Failed { error: "cable pulled again" }]
        );
    }

    #[test]
    #[cfg_attr(
        miri,
        ignore = "arithmetic over tens of thousands of frames: nothing for Miri to check, minutes under it"
    )]
    fn a_lasting_fault_is_summarised_with_its_newest_error() {
        let mut log = FaultLog::default();
        assert_eq!(log.failed(0, true, &"no answer").len(), 1);
        let mut summaries = Vec::new();
        for k in 1..=25_000 {
            for line in log.failed(k * MS, false, &format_args!("no answer for {k} ms")) {
                summaries.push(format!("{line:?}"));
            }
        }
        assert_eq!(summaries.len(), 2, "{summaries:#?}");
        assert!(summaries[0].contains("failed: 9999, faulted: 0, recovered: 0"), "{}", summaries[0]);
        assert!(summaries[0].contains("no answer for 10000 ms"), "{}", summaries[0]);
        const { assert!(SUMMARY_EVERY_NS == 10_000 * MS) };
    }
}
