//! The supervisor's log of layer states: a change is said once; a layer that
//! keeps changing (a flaky bus faulting and recovering every few frames) is
//! summarised every [`SUMMARY_EVERY`] instead of a line per change.

use std::collections::HashMap;
use std::time::{Duration, Instant};

/// The longest repeated changes of a layer go unsaid.
pub const SUMMARY_EVERY: Duration = Duration::from_secs(10);

/// Changes said in full per layer and window before the rest are counted.
const SAID_PER_WINDOW: u32 = 2;

/// One line for the log.
#[derive(Debug, PartialEq, Eq)]
pub enum StateLine {
    /// A change said in full.
    Changed {
        /// The layer (channel) name.
        layer: String,
        /// Its previous state (`absent` before it was first seen).
        from: &'static str,
        /// Its state now.
        to: &'static str,
    },
    /// Changes not said since the window began.
    Summary {
        /// The layer (channel) name.
        layer: String,
        /// The changes counted, by the state changed to, in name order.
        counts: Vec<(&'static str, u32)>,
        /// Its state now.
        now: &'static str,
        /// The window's length.
        window: Duration,
    },
}

#[derive(Debug)]
struct LayerLog {
    state: &'static str,
    window_start: Option<Instant>,
    said: u32,
    unsaid: HashMap<&'static str, u32>,
}

/// Every layer's last state and what of its changes was said.
#[derive(Debug, Default)]
pub struct StateLog {
    layers: HashMap<String, LayerLog>,
}

impl StateLog {
    /// The layers' states seen at `now`: the lines to log.
    pub fn observe<'a>(
        &mut self,
        now: Instant,
        seen: impl IntoIterator<Item = (&'a str, &'static str)>,
    ) -> Vec<StateLine> {
        let mut lines = Vec::new();
        for (layer, state) in seen {
            let log = self.layers.entry(layer.to_owned()).or_insert_with(|| LayerLog {
                state: "absent",
                window_start: None,
                said: 0,
                unsaid: HashMap::new(),
            });
            if let Some(start) = log.window_start
                && now.duration_since(start) >= SUMMARY_EVERY
            {
                if !log.unsaid.is_empty() {
                    let mut counts: Vec<_> = log.unsaid.drain().collect();
                    counts.sort();
                    lines.push(StateLine::Summary {
                        layer: layer.to_owned(),
                        counts,
                        now: state,
                        window: now.duration_since(start),
                    });
                    log.window_start = Some(now);
                } else {
                    log.window_start = None;
                    log.said = 0;
                }
            }
            if log.state == state {
                continue;
            }
            let from = std::mem::replace(&mut log.state, state);
            log.window_start.get_or_insert(now);
            if log.said < SAID_PER_WINDOW && log.unsaid.is_empty() {
                log.said += 1;
                lines.push(StateLine::Changed { layer: layer.to_owned(), from, to: state });
            } else {
                *log.unsaid.entry(state).or_default() += 1;
            }
        }
        lines
    }
}

/// Says `line` in the log.
pub fn log(line: &StateLine) {
    match line {
        StateLine::Changed { layer, from, to } => tracing::info!(layer = %layer, from, to, "layer state"),
        StateLine::Summary { layer, counts, now, window } => {
            let changes = counts.iter().map(|(to, n)| format!("{n} to {to}")).collect::<Vec<_>>().join(", ");
            tracing::warn!(
                layer = %layer,
                now,
                "layer state changed {} times in the last {:.0} s ({changes}); repeats are summarised every {} s",
                counts.iter().map(|(_, n)| n).sum::<u32>(),
                window.as_secs_f64(),
                SUMMARY_EVERY.as_secs()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{StateLine, StateLog};
    use std::time::{Duration, Instant};

    #[test]
    fn a_flapping_layer_is_said_twice_then_summarised_each_window() {
        let mut log = StateLog::default();
        let start = Instant::now();
        let mut lines = Vec::new();
        // Polled every 100 ms for 25 s, faulted on every other poll.
        for k in 0..250u64 {
            let state = if k % 2 == 1 { "faulted" } else { "running" };
            lines.extend(log.observe(start + Duration::from_millis(100 * k), [("torso", state)]));
        }
        let changed = lines.iter().filter(|l| matches!(l, StateLine::Changed { .. })).count();
        let summaries: Vec<_> = lines.iter().filter(|l| matches!(l, StateLine::Summary { .. })).collect();
        assert_eq!(changed, 2, "{lines:#?}");
        assert_eq!(summaries.len(), 2, "{lines:#?}");
        let StateLine::Summary { counts, .. } = summaries[0] else { unreachable!() };
        assert_eq!(counts, &vec![("faulted", 49), ("running", 49)]);
    }

    #[test]
    fn a_change_after_a_quiet_window_is_said_in_full() {
        let mut log = StateLog::default();
        let start = Instant::now();
        let at = |s: u64| start + Duration::from_secs(s);
        assert_eq!(log.observe(at(0), [("arm", "running")]).len(), 1);
        assert_eq!(log.observe(at(1), [("arm", "faulted")]).len(), 1);
        assert!(log.observe(at(2), [("arm", "faulted")]).is_empty());
        assert!(log.observe(at(12), [("arm", "faulted")]).is_empty(), "nothing unsaid: no summary");
        assert_eq!(
            log.observe(at(13), [("arm", "running")]),
            vec![StateLine::Changed { layer: "arm".into(), from: "faulted", to: "running" }]
        );
    }
}
