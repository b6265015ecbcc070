//! How a driver's or a service's process runs: real-time settings of its
//! writer threads and its restart policy.

use anyhow::{Result, bail};
use serde::Deserialize;

/// Real-time settings of a driver's writer threads.
#[derive(Debug, Deserialize, Default, Clone)]
#[serde(deny_unknown_fields)]
pub struct RtConfig {
    /// SCHED_FIFO priority (1-99); the default scheduler if absent.
    pub fifo_priority: Option<u8>,
    /// Lock the process's memory (mlockall).
    #[serde(default)]
    pub lock_memory: bool,
    /// CPUs the threads may run on; any if empty.
    #[serde(default)]
    pub cpus: Vec<usize>,
    /// Keep idle CPUs able to wake within this many µs while the process
    /// runs (0: polling); see `skinware::RtOptions::cpu_wake_latency_us`.
    pub cpu_wake_latency_us: Option<u32>,
    /// Which thread wakes readers asleep for the writer's frames:
    /// `"lookout"`, `"ringer"` or `"writer"` (see `skinware::ReaderWake`);
    /// the library's default if absent.
    pub reader_wake: Option<ReaderWakeConfig>,
}

/// `reader_wake` in `[driver.rt]` and `[service.rt]`.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ReaderWakeConfig {
    /// `skinware::ReaderWake::Lookout`.
    Lookout,
    /// `skinware::ReaderWake::Ringer`.
    Ringer,
    /// `skinware::ReaderWake::Writer`.
    Writer,
}

impl From<ReaderWakeConfig> for skinware::ReaderWake {
    fn from(config: ReaderWakeConfig) -> Self {
        match config {
            ReaderWakeConfig::Lookout => skinware::ReaderWake::Lookout,
            ReaderWakeConfig::Ringer => skinware::ReaderWake::Ringer,
            ReaderWakeConfig::Writer => skinware::ReaderWake::Writer,
        }
    }
}

impl RtConfig {
    /// The library's form of these settings.
    pub(super) fn options(&self) -> skinware::RtOptions {
        skinware::RtOptions {
            fifo_priority: self.fifo_priority,
            lock_memory: self.lock_memory,
            cpus: self.cpus.clone(),
            cpu_wake_latency_us: self.cpu_wake_latency_us,
            reader_wake: self.reader_wake.map(Into::into).unwrap_or_default(),
        }
    }
}

/// Restart policy of a driver process.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct RestartConfig {
    /// Wait before the first restart, seconds; it doubles with each quick death.
    pub min_backoff_s: f64,
    /// Longest wait before a restart, seconds.
    pub max_backoff_s: f64,
}

impl Default for RestartConfig {
    fn default() -> Self {
        RestartConfig { min_backoff_s: 0.2, max_backoff_s: 5.0 }
    }
}

impl RestartConfig {
    /// Refuses backoffs that are not positive, not ordered, or above an hour.
    pub(super) fn check(&self) -> Result<()> {
        let RestartConfig { min_backoff_s: min, max_backoff_s: max } = *self;
        if !(min.is_finite() && max.is_finite() && min > 0.0 && min <= max && max <= 3600.0) {
            bail!("restart backoff [{min}, {max}] s must satisfy 0 < min_backoff_s <= max_backoff_s <= 3600");
        }
        Ok(())
    }
}
