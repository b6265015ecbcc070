//! The result of one configuration of `skin bench paper`, shared by the run
//! ([`crate::paper`]) and its plot, so that neither imports the other.

use serde::Serialize;

use crate::measure::Percentiles;

/// One configuration's result.
#[derive(Debug, Serialize)]
pub struct PaperRecord {
    /// Layers the 30,848 sensors were split over.
    pub layers: usize,
    /// Application processes.
    pub apps: usize,
    /// Writers' execution time per frame (all layers pooled, frames begun
    /// while every application was up and reading), ns.
    pub writer_ns: Percentiles,
    /// Readers' time to obtain one frame of a layer (all apps and layers pooled), ns.
    pub reader_ns: Percentiles,
    /// The layers' acquisition rates, Hz.
    pub writer_rates_hz: Vec<f64>,
}
