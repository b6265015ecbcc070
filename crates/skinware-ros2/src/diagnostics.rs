//! The skin's health on `/diagnostics`: one `diagnostic_msgs/DiagnosticStatus`
//! per layer and service, as `rqt_robot_monitor` and Foxglove's diagnostics
//! panels show it.
//!
//! | level | when |
//! |---|---|
//! | OK | running at no less than 80 % of its nominal rate |
//! | WARN | running slower than that, or paused |
//! | ERROR | faulted, or its writer is gone |
//!
//! The figures (state, rates, frames, faults, missed periods, restarts) are
//! key-value pairs, the numbers as plain decimal text.

use skinware::{WriterState, WriterStats};

use crate::cdr::{EncodeError, encode};
use crate::messages::{Header, Time};
use crate::standard::{DIAGNOSTIC_ERROR, DIAGNOSTIC_OK, DIAGNOSTIC_WARN, DiagnosticArray, DiagnosticStatus, KeyValue};

/// Below this fraction of its nominal rate a running channel is a warning.
pub const SLOW_FRACTION: f64 = 0.8;

/// What is known of one channel's health.
#[derive(Clone, Debug, PartialEq)]
pub struct ChannelHealth {
    /// The channel (layer or service) name.
    pub channel: String,
    /// Who writes it, as far as the publisher knows (`hardware_id`).
    pub writer: String,
    /// Its writer's state.
    pub state: WriterState,
    /// Frames per second measured over the last interval.
    pub rate_hz: f64,
    /// The rate it should run at (0: none, a service publishing on input).
    pub nominal_hz: f64,
    /// The writer's counters.
    pub stats: WriterStats,
    /// How often its process was restarted, if a supervisor says.
    pub restarts: Option<u64>,
}

impl ChannelHealth {
    /// The level and the one-line message of this health.
    pub fn level(&self) -> (u8, String) {
        let slow = self.nominal_hz > 0.0 && self.rate_hz < SLOW_FRACTION * self.nominal_hz;
        match self.state {
            WriterState::Running if slow => {
                (DIAGNOSTIC_WARN, format!("running slow: {:.1} Hz of {:.1} Hz nominal", self.rate_hz, self.nominal_hz))
            }
            WriterState::Running => (DIAGNOSTIC_OK, format!("running at {:.1} Hz", self.rate_hz)),
            WriterState::Paused => (DIAGNOSTIC_WARN, "paused".into()),
            WriterState::Faulted => (DIAGNOSTIC_ERROR, format!("faulted ({} faults)", self.stats.faults)),
            WriterState::Gone => (DIAGNOSTIC_ERROR, "gone: no process writes it".into()),
        }
    }

    fn status(&self, skin: &str) -> DiagnosticStatus {
        let (level, message) = self.level();
        let pair = |key: &str, value: String| KeyValue { key: key.into(), value };
        let mut values = vec![
            pair("state", self.state.to_string()),
            pair("rate_hz", format!("{:.2}", self.rate_hz)),
            pair("nominal_hz", format!("{:.2}", self.nominal_hz)),
            pair("frames", self.stats.frames.to_string()),
            pair("faults", self.stats.faults.to_string()),
            pair("missed_periods", self.stats.missed_periods.to_string()),
            pair("overruns", self.stats.overruns.to_string()),
            pair("write_us_max", format!("{:.1}", self.stats.write_ns_max as f64 / 1e3)),
        ];
        if let Some(restarts) = self.restarts {
            values.push(pair("restarts", restarts.to_string()));
        }
        DiagnosticStatus {
            level,
            name: format!("skin/{skin}/{}", self.channel),
            message,
            hardware_id: self.writer.clone(),
            values,
        }
    }
}

/// Encodes the health of every channel of skin `skin` as one `DiagnosticArray`.
pub fn diagnostics(skin: &str, channels: &[ChannelHealth], stamp: Time) -> Result<Vec<u8>, EncodeError> {
    encode(&diagnostic_array(skin, channels, stamp), 64 + 512 * channels.len())
}

/// The message [`diagnostics`] encodes.
pub fn diagnostic_array(skin: &str, channels: &[ChannelHealth], stamp: Time) -> DiagnosticArray {
    let status: Vec<DiagnosticStatus> = channels.iter().map(|c| c.status(skin)).collect();
    DiagnosticArray { header: Header { stamp, frame_id: String::new() }, status }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cdr::decode;
    use crate::standard::DIAGNOSTIC_ARRAY;

    fn health(state: WriterState, rate_hz: f64) -> ChannelHealth {
        ChannelHealth {
            channel: "virtual-0".into(),
            writer: "virtual".into(),
            state,
            rate_hz,
            nominal_hz: 50.0,
            stats: WriterStats { frames: 10, faults: 2, ..WriterStats::default() },
            restarts: Some(1),
        }
    }

    #[test]
    fn levels_follow_the_state_and_the_rate() {
        assert_eq!(health(WriterState::Running, 49.0).level().0, DIAGNOSTIC_OK);
        assert_eq!(health(WriterState::Running, 30.0).level().0, DIAGNOSTIC_WARN);
        assert_eq!(health(WriterState::Paused, 0.0).level().0, DIAGNOSTIC_WARN);
        assert_eq!(health(WriterState::Faulted, 50.0).level().0, DIAGNOSTIC_ERROR);
        assert_eq!(health(WriterState::Gone, 0.0).level().0, DIAGNOSTIC_ERROR);
        let mut service = health(WriterState::Running, 0.0);
        service.nominal_hz = 0.0;
        assert_eq!(service.level().0, DIAGNOSTIC_OK, "a service without a nominal rate is not slow");
    }

    #[test]
    fn every_channel_is_a_named_status_with_its_figures() {
        let bytes = diagnostics(
            "default",
            &[health(WriterState::Running, 49.0), health(WriterState::Gone, 0.0)],
            Time::default(),
        )
        .unwrap();
        let array: DiagnosticArray = decode(&bytes, DIAGNOSTIC_ARRAY).unwrap();
        assert_eq!(array.status.len(), 2);
        let first = &array.status[0];
        assert_eq!((first.name.as_str(), first.hardware_id.as_str()), ("skin/default/virtual-0", "virtual"));
        let value = |key: &str| first.values.iter().find(|v| v.key == key).map(|v| v.value.clone());
        assert_eq!(value("faults").as_deref(), Some("2"));
        assert_eq!(value("restarts").as_deref(), Some("1"));
        assert_eq!(array.status[1].level, DIAGNOSTIC_ERROR);
    }
}
