//! skinware's errors as Python exceptions. The classes live in
//! `skinware/_errors.py`, where they can also derive from Python's own
//! (`Timeout` is a `TimeoutError`, `ChannelMissing` a `LookupError`, ...), so
//! that `except TimeoutError:` works as a Python user expects.

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyType;

/// An exception of class `name` from `skinware._errors`, with `message`.
pub fn raise(py: Python<'_>, name: &str, message: impl Into<String>) -> PyErr {
    let message = message.into();
    match py.import("skinware._errors").and_then(|module| module.getattr(name)) {
        Ok(class) => match class.cast_into::<PyType>() {
            Ok(class) => PyErr::from_type(class, message),
            Err(_) => PyRuntimeError::new_err(message),
        },
        // The package was not imported (the native module used on its own):
        // the message still says everything.
        Err(_) => PyRuntimeError::new_err(message),
    }
}

/// The Python exception for an exchange error.
pub fn exchange(py: Python<'_>, error: skinware::Error) -> PyErr {
    use skinware::Error as E;
    let class = match &error {
        E::Missing { .. } => "ChannelMissing",
        E::WriterGone { .. } => "WriterGone",
        E::Timeout { .. } => "Timeout",
        E::NoFrameYet { .. } => "NoFrameYet",
        E::Stopped { .. } => "ReaderClosed",
        E::AccessDenied { .. } => "AccessDenied",
        E::Busy { .. } => "ChannelBusy",
        E::SchemaMismatch { .. } | E::NotThisService { .. } => "SchemaMismatch",
        E::InvalidName { .. } | E::InvalidLayout { .. } | E::PayloadTooLarge { .. } => "InvalidArgument",
        _ => "ChannelError",
    };
    raise(py, class, error.to_string())
}

/// The Python exception for a geometry error.
pub fn geometry(py: Python<'_>, error: skinware_geometry::GeometryError) -> PyErr {
    raise(py, "GeometryError", error.to_string())
}

/// `InvalidArgument` (a `ValueError`) for bad input from Python.
pub fn invalid(py: Python<'_>, message: impl Into<String>) -> PyErr {
    raise(py, "InvalidArgument", message)
}
