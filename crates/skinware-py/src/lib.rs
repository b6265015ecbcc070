//! The `skinware._skinware` extension module: the Python bindings' native
//! half. The package `skinware` (in `python/skinware/`) re-exports it and adds
//! what is easier in Python: the structured dtypes of the services, the
//! exceptions' class tree, `Status` flags.
//!
//! Every read copies the frame with the lock-free reader while the GIL is
//! released, into memory Python then owns: Python never sees live shared
//! memory, and a Python thread blocked in a wait lets the others run. Long
//! waits are cut into slices so that Ctrl-C (a pending signal) interrupts
//! them.

#![forbid(unsafe_code)]

mod errors;
mod frame;
mod geometry;
mod listing;
mod reader;
mod stats;
mod ticks;
mod topology;
mod writer;

use pyo3::prelude::*;

/// The native module. Its classes are documented in `skinware/_skinware.pyi`.
#[pymodule]
fn _skinware(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("ABI_VERSION", skinware::ABI_VERSION)?;
    m.add_class::<frame::Frame>()?;
    m.add_class::<reader::Reader>()?;
    m.add_class::<reader::ServiceReader>()?;
    m.add_class::<reader::Periodic>()?;
    m.add_class::<topology::Topology>()?;
    m.add_class::<writer::ChannelWriter>()?;
    m.add_class::<writer::Writer>()?;
    m.add_class::<writer::ServiceWriter>()?;
    m.add_class::<writer::Ticks>()?;
    m.add_class::<geometry::Geometry>()?;
    m.add_class::<listing::ChannelInfo>()?;
    m.add_function(wrap_pyfunction!(listing::channels, m)?)?;
    m.add_function(wrap_pyfunction!(listing::segment_dir, m)?)?;
    m.add_function(wrap_pyfunction!(ticks::monotonic_ns, m)?)?;
    Ok(())
}
