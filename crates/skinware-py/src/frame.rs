//! A frame as Python gets it: a private, read-only copy with its metadata,
//! and the plain copy a read makes without the GIL before it becomes one.

use pyo3::prelude::*;
use skinware::WriterState;

/// One frame: a private, read-only copy of a layer's responses (`uint16`,
/// one per sensor) or of a service's records (a structured array), with its
/// metadata.
#[pyclass(module = "skinware", frozen)]
pub struct Frame {
    pub(crate) data: Py<PyAny>,
    /// Sequence number: 1 for the channel's first frame, +1 per frame.
    #[pyo3(get)]
    pub(crate) seq: u64,
    /// When the data was acquired, CLOCK_MONOTONIC ns (`skinware.monotonic_ns()`).
    #[pyo3(get)]
    pub(crate) acquired_ns: u64,
    /// When the frame was published, CLOCK_MONOTONIC ns.
    #[pyo3(get)]
    pub(crate) published_ns: u64,
    /// Status flags (`skinware.Status`): 0 is a good frame.
    #[pyo3(get)]
    pub(crate) status: u64,
    /// Frames published since this reader's previous frame that it never saw.
    #[pyo3(get)]
    pub(crate) skipped: u64,
    /// Whether the frame is newer than the reader's previous one.
    #[pyo3(get)]
    pub(crate) fresh: bool,
}

#[pymethods]
impl Frame {
    /// The data: the responses of a layer, the records of a service.
    #[getter]
    fn data(&self, py: Python<'_>) -> Py<PyAny> {
        self.data.clone_ref(py)
    }

    /// A layer's responses, one `uint16` per sensor in frame order (read-only).
    #[getter]
    fn responses(&self, py: Python<'_>) -> Py<PyAny> {
        self.data.clone_ref(py)
    }

    /// A service's records, one per label (read-only structured array).
    #[getter]
    fn records(&self, py: Python<'_>) -> Py<PyAny> {
        self.data.clone_ref(py)
    }

    /// Whether the acquisition failed (its data must not be used).
    #[getter]
    fn faulted(&self) -> bool {
        self.status & skinware::FrameStatus::FAULT.0 != 0
    }

    /// numpy's conversion: `np.asarray(frame)` is the data.
    #[pyo3(signature = (dtype = None, copy = None))]
    fn __array__<'py>(
        &self,
        py: Python<'py>,
        dtype: Option<Bound<'py, PyAny>>,
        copy: Option<bool>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let data = self.data.bind(py).clone();
        match (dtype, copy) {
            (None, None | Some(false)) => Ok(data),
            (Some(_), Some(false)) => Err(pyo3::exceptions::PyValueError::new_err(
                "a frame's data converts to another dtype only by copying; allow a copy",
            )),
            (dtype, _) => {
                let dtype = match dtype {
                    Some(dtype) => dtype,
                    None => data.getattr("dtype")?,
                };
                data.call_method1("astype", (dtype,))
            }
        }
    }

    fn __len__(&self, py: Python<'_>) -> PyResult<usize> {
        self.data.bind(py).len()
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let len = self.data.bind(py).len().unwrap_or(0);
        format!(
            "Frame(seq={}, {len} values, status={}, skipped={}, fresh={}, acquired_ns={})",
            self.seq,
            self.status,
            self.skipped,
            if self.fresh { "True" } else { "False" },
            self.acquired_ns
        )
    }
}

/// A frame copied out of the reader's private buffer, without the GIL.
pub(crate) struct Copied {
    pub(crate) seq: u64,
    pub(crate) acquired_ns: u64,
    pub(crate) published_ns: u64,
    pub(crate) status: u64,
    pub(crate) skipped: u64,
    pub(crate) fresh: bool,
    pub(crate) data: Data,
    /// Re-created channels the reader had followed, and the writer's state,
    /// when the frame was read.
    pub(crate) follows: u64,
    pub(crate) state: WriterState,
}

pub(crate) enum Data {
    Responses(Vec<u16>),
    Bytes(Vec<u8>),
    /// Copied into the caller's array (`read_into`).
    Into,
}

impl Copied {
    pub(crate) fn new(frame: &skinware::Frame<'_>, data: Data) -> Copied {
        Copied {
            seq: frame.seq(),
            acquired_ns: frame.acquired_ns(),
            published_ns: frame.published_ns(),
            status: frame.status().0,
            skipped: frame.skipped(),
            fresh: frame.is_fresh(),
            data,
            follows: 0,
            state: WriterState::Running,
        }
    }
}
