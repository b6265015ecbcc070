//! Faults: cable pulls (on a schedule or on command) and faulty taxels
//! (dead, or stuck at saturation).

use std::path::PathBuf;
use std::time::{Duration, Instant};

/// A scheduled disconnection of one layer: from `at_s` seconds after start,
/// for `duration_s` seconds, repeating every `every_s` seconds if given.
#[derive(Clone, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CablePull {
    /// Layer name.
    pub layer: String,
    /// Seconds after the driver starts.
    pub at_s: f64,
    /// Seconds the cable stays out.
    pub duration_s: f64,
    /// Period of repetition, seconds.
    #[serde(default)]
    pub every_s: Option<f64>,
}

impl CablePull {
    fn pulled_at(&self, elapsed_s: f64) -> bool {
        if elapsed_s < self.at_s {
            return false;
        }
        let since = elapsed_s - self.at_s;
        let phase = match self.every_s {
            Some(every) if every > 0.0 => since % every,
            _ => since,
        };
        phase < self.duration_s
    }
}

/// The faults of one layer.
pub(super) struct LayerFaults {
    /// Local indices of dead and stuck taxels.
    pub(super) dead: Vec<usize>,
    pub(super) stuck: Vec<usize>,
    pub(super) pulls: Vec<CablePull>,
    pub(super) pull_file: Option<PathBuf>,
    /// When the pull file was last checked, and whether it existed.
    pub(super) pull_file_seen: (Instant, bool),
}

impl LayerFaults {
    pub(super) fn cable_pulled(&mut self, elapsed_s: f64) -> bool {
        if let Some(file) = &self.pull_file {
            // A stat at most every 50 ms: this is the simulated bus, not the exchange.
            if self.pull_file_seen.0.elapsed() >= Duration::from_millis(50) {
                self.pull_file_seen = (Instant::now(), file.exists());
            }
        }
        self.pull_file_seen.1 || self.pulls.iter().any(|p| p.pulled_at(elapsed_s))
    }

    /// Overrides the responses of the dead and stuck taxels.
    pub(super) fn apply_to(&self, responses: &mut [u16]) {
        for &k in &self.dead {
            responses[k] = 1000;
        }
        for &k in &self.stuck {
            responses[k] = u16::MAX;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cable_pull_schedule() {
        let pull = CablePull { layer: "x".into(), at_s: 2.0, duration_s: 1.0, every_s: Some(5.0) };
        assert!(!pull.pulled_at(1.9));
        assert!(pull.pulled_at(2.5));
        assert!(!pull.pulled_at(3.5));
        assert!(pull.pulled_at(7.2));
    }
}
