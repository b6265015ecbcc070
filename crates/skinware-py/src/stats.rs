//! A writer's statistics as Python sees them.

use pyo3::prelude::*;
use pyo3::types::PyDict;

/// A writer's statistics as Python sees them, from a reader or the writer.
pub fn writer_stats_dict<'py>(py: Python<'py>, stats: &skinware::WriterStats) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    dict.set_item("frames", stats.frames)?;
    dict.set_item("overruns", stats.overruns)?;
    dict.set_item("missed_periods", stats.missed_periods)?;
    dict.set_item("faults", stats.faults)?;
    dict.set_item("write_ns_min", stats.write_ns_min)?;
    dict.set_item("write_ns_mean", stats.write_ns_mean)?;
    dict.set_item("write_ns_max", stats.write_ns_max)?;
    dict.set_item("lateness_ns_mean", stats.lateness_ns_mean)?;
    dict.set_item("lateness_ns_max", stats.lateness_ns_max)?;
    Ok(dict)
}
