//! One point of `skin bench scale`, shared by the run ([`crate::scale`])
//! and its plot, so that neither imports the other.

use serde::Serialize;

use crate::measure::Percentiles;

/// One point of the sweep.
#[derive(Clone, Debug, Serialize)]
pub struct ScalePoint {
    /// Taxels (the frame holds 2 bytes each).
    pub taxels: usize,
    /// Frame bytes.
    pub frame_bytes: usize,
    /// The writer's rate, Hz.
    pub rate_hz: f64,
    /// Reader processes.
    pub readers: usize,
    /// Periods in the measured window.
    pub periods: u64,
    /// Periods the writer missed in it.
    pub missed_periods: u64,
    /// Of those, the periods missed because the frame before took longer
    /// than a period to publish (the rest: the writer woke late).
    pub overrun_missed: u64,
    /// Periods missed by overruns beyond the control's (readers 0) at the
    /// same size and rate, scaled to this point's window: those the readers
    /// caused.
    pub reader_caused_missed: u64,
    /// The writer's publish (begin, copy in, publish, wake), ns.
    pub publish_ns: Percentiles,
    /// A `memcpy` of the same frame by the writer's thread, ns.
    pub memcpy_ns: Percentiles,
    /// Publish p50 over memcpy p50.
    pub publish_over_memcpy_p50: f64,
    /// Publish p99 over memcpy p99.
    pub publish_over_memcpy_p99: f64,
    /// Readers that wait for every frame: the copy of one frame, ns.
    pub waiting_copy_ns: Percentiles,
    /// Readers that read periodically: `latest()`, ns.
    pub periodic_copy_ns: Percentiles,
    /// Waiting readers' copy p50 over memcpy p50.
    pub reader_copy_over_memcpy_p50: f64,
    /// Acquisition to a waiting reader holding its copy, ns.
    pub waiting_latency_ns: Percentiles,
    /// Acquisition to a periodic reader holding its copy (with the frame's age), ns.
    pub periodic_latency_ns: Percentiles,
    /// Of the frames published in the window, the share the waiting readers missed.
    pub waiting_missed_share: f64,
    /// CPU of the writer's thread, % of one core.
    pub writer_thread_cpu_percent: f64,
    /// CPU of the writer's helper threads (its ringer), % of one core.
    pub writer_helpers_cpu_percent: f64,
    /// CPU of all reader processes, % of one core.
    pub readers_cpu_percent: f64,
}
