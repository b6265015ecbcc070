//! Writers for Python: a layer (a driver prototyped in Python) and a service
//! (the paper's application-based service). Publishing copies the caller's
//! array into the channel with the GIL released.

use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyTuple};
use skinware::{Access, FrameStatus, Stop, WriterOptions, WriterState};
use skinware_services::{ServiceMode, ServiceSpec};

use crate::errors;
use crate::stats::writer_stats_dict;
use crate::ticks::{self, Schedule};
use crate::topology::Topology;

fn access(py: Python<'_>, access: &str) -> PyResult<Access> {
    match access {
        "owner" => Ok(Access::Owner),
        "group" => Ok(Access::Group),
        "everyone" => Ok(Access::Everyone),
        other => Err(errors::invalid(py, format!("access {other:?}: use \"owner\", \"group\" or \"everyone\""))),
    }
}

fn writer_state(py: Python<'_>, state: &str) -> PyResult<WriterState> {
    // "gone" is a state readers see, never one a writer sets.
    match state.parse::<WriterState>() {
        Ok(state) if state != WriterState::Gone => Ok(state),
        _ => {
            Err(errors::invalid(py, format!("state {state:?}: a writer can be \"running\", \"paused\" or \"faulted\"")))
        }
    }
}

fn slots(py: Python<'_>, slots: usize) -> PyResult<usize> {
    if (skinware::MIN_SLOTS..=skinware::MAX_SLOTS).contains(&slots) {
        Ok(slots)
    } else {
        Err(errors::invalid(py, format!("slots {slots}: use {} to {}", skinware::MIN_SLOTS, skinware::MAX_SLOTS)))
    }
}

/// What both writers share (the base class of `Writer` and
/// `ServiceWriter`): the channel's writer, its periods and requests, its
/// state, statistics and `close()`.
#[pyclass(module = "skinware", subclass, frozen)]
pub struct ChannelWriter {
    writer: Mutex<Option<skinware::Writer>>,
    stop: Stop,
    label: String,
    period: Option<Duration>,
}

impl ChannelWriter {
    fn new(mut writer: skinware::Writer, period: Option<Duration>) -> ChannelWriter {
        let stop = Stop::new();
        writer.set_stop(&stop);
        let label = writer.label().to_owned();
        ChannelWriter { writer: Mutex::new(Some(writer)), stop, label, period }
    }

    fn lock(&self) -> MutexGuard<'_, Option<skinware::Writer>> {
        skinware::lock(&self.writer)
    }

    /// Runs `f` on the open writer, taking the lock with the GIL released (a
    /// thread may hold it while it waits for a request).
    fn peek<T: Send>(&self, py: Python<'_>, f: impl FnOnce(&mut skinware::Writer) -> T + Send) -> Option<T> {
        py.detach(|| self.lock().as_mut().map(f))
    }

    fn closed(&self, py: Python<'_>) -> PyErr {
        errors::raise(py, "WriterClosed", format!("the writer of {} is closed", self.label))
    }

    /// Runs `f` on the open writer, without the GIL.
    fn with<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut skinware::Writer) -> Result<T, skinware::Error> + Send,
    ) -> PyResult<T> {
        match py.detach(|| self.lock().as_mut().map(f)) {
            None => Err(self.closed(py)),
            Some(result) => result.map_err(|e| errors::exchange(py, e)),
        }
    }

    fn close_impl(&self, py: Python<'_>) {
        self.stop.stop();
        let writer = py.detach(|| self.lock().take());
        drop(writer);
    }

    fn ticks_impl(&self, py: Python<'_>, hz: Option<f64>) -> PyResult<Ticks> {
        let period = match (hz, self.period) {
            (Some(hz), _) => ticks::period(py, hz, "ticks")?,
            (None, Some(period)) => period,
            (None, None) => {
                return Err(errors::invalid(
                    py,
                    format!("{} is sporadic: give ticks(hz), or answer requests with wait_request()", self.label),
                ));
            }
        };
        Ok(Ticks { schedule: Schedule::new(period), stop: self.stop.clone() })
    }

    fn wait_request_impl(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<bool> {
        let timeout = ticks::timeout(py, timeout)?;
        let deadline = timeout.map(|t| ticks::monotonic_ns().saturating_add(t.as_nanos() as u64));
        loop {
            let slice = match deadline {
                Some(deadline) => {
                    Duration::from_nanos(deadline.saturating_sub(ticks::monotonic_ns())).min(ticks::SIGNAL_CHECK)
                }
                None => ticks::SIGNAL_CHECK,
            };
            if self.stop.is_stopped() {
                return Ok(false);
            }
            match py.detach(|| self.lock().as_mut().map(|w| w.wait_request(slice))) {
                Some(Ok(true)) => return Ok(true),
                Some(Ok(false)) => {}
                // Closed, possibly by another thread while this one waited.
                None | Some(Err(skinware::Error::Stopped { .. })) => return Ok(false),
                Some(Err(e)) => return Err(errors::exchange(py, e)),
            }
            if self.stop.is_stopped() || deadline.is_some_and(|d| ticks::monotonic_ns() >= d) {
                return Ok(false);
            }
            py.check_signals()?;
        }
    }

    fn stats_impl<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let stats = self.peek(py, |w| w.stats()).ok_or_else(|| self.closed(py))?;
        writer_stats_dict(py, &stats)
    }

    fn state_impl(&self, py: Python<'_>) -> PyResult<&'static str> {
        self.peek(py, |w| w.state().as_str()).ok_or_else(|| self.closed(py))
    }

    fn set_state_impl(&self, py: Python<'_>, state: &str) -> PyResult<()> {
        let state = writer_state(py, state)?;
        self.peek(py, |w| w.set_state(state)).ok_or_else(|| self.closed(py))
    }
}

#[pymethods]
impl ChannelWriter {
    /// An iterator of the channel's periods (at `hz`, default its rate), on
    /// an absolute-time grid: each item is `(deadline_ns, missed)`, `missed`
    /// counting the periods skipped because the loop ran late. It ends when
    /// the writer is closed.
    #[pyo3(signature = (hz = None))]
    fn ticks(&self, py: Python<'_>, hz: Option<f64>) -> PyResult<Ticks> {
        self.ticks_impl(py, hz)
    }

    /// A sporadic channel: waits (without the GIL) until a reader requests a
    /// frame; `False` after `timeout` seconds (`None`: no limit) or when the
    /// writer is closed.
    #[pyo3(signature = (timeout = None))]
    fn wait_request(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<bool> {
        self.wait_request_impl(py, timeout)
    }

    /// The state readers see: "running", "paused" or "faulted". A driver
    /// whose sensors fail sets "faulted" (and publishes frames with
    /// `Status.FAULT`), and "running" once they answer again.
    #[getter]
    fn state(&self, py: Python<'_>) -> PyResult<&'static str> {
        self.state_impl(py)
    }

    #[setter]
    fn set_state(&self, py: Python<'_>, state: &str) -> PyResult<()> {
        self.set_state_impl(py, state)
    }

    /// `skin/channel`.
    #[getter]
    fn label(&self) -> &str {
        &self.label
    }

    /// The writer's statistics: frames, overruns, missed_periods, faults,
    /// write_ns_min/mean/max, lateness_ns_mean/max.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        self.stats_impl(py)
    }

    /// Removes the channel; readers see it gone.
    fn close(&self, py: Python<'_>) {
        self.close_impl(py);
    }

    fn __enter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, PyTuple>) -> bool {
        self.close_impl(py);
        false
    }
}

/// The writer of one layer: a driver written in Python. It creates the
/// layer's channel (publishing its topology) and publishes frames of one
/// `uint16` response per sensor. Readers in any process, `skin ls`, the
/// services and the viewer see it as any other layer.
#[pyclass(module = "skinware", extends = ChannelWriter, frozen)]
pub struct Writer {
    topology: skinware::LayerTopology,
}

#[pymethods]
impl Writer {
    /// Creates layer `layer` of skin `skin` with `topology`, at `rate_hz`
    /// (default: the topology's rate; 0 for a sporadic layer, which
    /// publishes when it wants or on request).
    #[new]
    #[pyo3(signature = (skin, layer, topology, rate_hz = None, *, slots = 3, access = "owner"))]
    fn new(
        py: Python<'_>,
        skin: &str,
        layer: &str,
        topology: &Topology,
        rate_hz: Option<f64>,
        slots: usize,
        access: &str,
    ) -> PyResult<PyClassInitializer<Writer>> {
        let mut layout = topology.inner.clone();
        layout.name = layer.to_owned();
        if let Some(hz) = rate_hz {
            if !(hz.is_finite() && hz >= 0.0) {
                return Err(errors::invalid(py, format!("layer {layer}: rate {hz} Hz must be >= 0 (0 for sporadic)")));
            }
            layout.rate_hz = hz;
        }
        let period = (layout.rate_hz > 0.0).then(|| ticks::period(py, layout.rate_hz, "rate")).transpose()?;
        let options = WriterOptions {
            slots: self::slots(py, slots)?,
            period,
            access: self::access(py, access)?,
            ..WriterOptions::default()
        };
        let description = layout.encode();
        let bytes = layout.frame_bytes();
        let created = py.detach(|| skinware::Writer::create(skin, layer, bytes, &description, &options));
        let writer = created.map_err(|e| errors::exchange(py, e))?;
        Ok(PyClassInitializer::from(ChannelWriter::new(writer, period)).add_subclass(Writer { topology: layout }))
    }

    /// Publishes one frame: `responses` is a 1-D `uint16` array of one value
    /// per sensor, in frame order. `status` is `skinware.Status` flags;
    /// `acquired_ns` the acquisition time (`skinware.monotonic_ns()`
    /// clock; default: now). Returns the frame's sequence number.
    #[pyo3(signature = (responses, status = 0, acquired_ns = None))]
    fn publish(
        slf: &Bound<'_, Self>,
        responses: Bound<'_, PyAny>,
        status: u64,
        acquired_ns: Option<u64>,
    ) -> PyResult<u64> {
        let py = slf.py();
        let this = slf.get();
        let sensors = this.topology.sensors.len();
        let array = responses.cast::<PyArray1<u16>>().map_err(|_| {
            let found = responses.getattr("dtype").map(|d| d.to_string()).unwrap_or_else(|_| responses.get_type().to_string());
            errors::invalid(
                py,
                format!(
                    "publish needs a 1-D numpy uint16 array of {sensors} responses, got {found}; convert with numpy.asarray(values, dtype=numpy.uint16) after checking the range"
                ),
            )
        })?;
        if array.len() != sensors {
            return Err(errors::invalid(
                py,
                format!("layer {} has {sensors} sensors, the array has {} responses", this.topology.name, array.len()),
            ));
        }
        let readonly =
            array.try_readonly().map_err(|e| errors::invalid(py, format!("publish cannot read the array: {e}")))?;
        let copied;
        let values: &[u16] = match readonly.as_slice() {
            Ok(values) => values,
            Err(_) => {
                copied = readonly.as_array().to_vec();
                &copied
            }
        };
        slf.as_super().get().with(py, |writer| {
            let mut frame = writer.begin();
            frame.write_responses(0, values)?;
            frame.set_status(FrameStatus(status));
            if let Some(ns) = acquired_ns {
                frame.set_acquired_ns(ns);
            }
            Ok(frame.publish())
        })
    }

    /// The layer's topology.
    #[getter]
    fn topology(&self) -> Topology {
        Topology { inner: self.topology.clone() }
    }

    /// Sensors per frame.
    fn __len__(&self) -> usize {
        self.topology.sensors.len()
    }

    /// Whether the channel took over the name of a writer that died.
    #[getter]
    fn revived(slf: &Bound<'_, Self>) -> PyResult<bool> {
        let (py, core) = (slf.py(), slf.as_super().get());
        core.peek(py, |w| w.revived()).ok_or_else(|| core.closed(py))
    }

    fn __repr__(slf: &Bound<'_, Self>) -> String {
        let this = slf.get();
        let label = &slf.as_super().get().label;
        format!("<skinware.Writer {label} ({} sensors, {} Hz)>", this.topology.sensors.len(), this.topology.rate_hz)
    }
}

/// The writer of a service published from Python (the paper's
/// application-based service): frames of `records` records of a numpy
/// structured `dtype`, with a schema name and version that readers check.
#[pyclass(module = "skinware", extends = ChannelWriter, frozen)]
pub struct ServiceWriter {
    dtype: Py<PyAny>,
    records: usize,
}

#[pymethods]
impl ServiceWriter {
    /// Creates service `name` of skin `skin`. Its frames hold one record of
    /// `dtype` per label (or `records` unlabelled records); `schema` is
    /// (name of at most 32 bytes, version). `rate_hz` makes it periodic
    /// (`None`: sporadic, answering readers' requests). `inputs` names the
    /// channels it reads, for `skin services`.
    #[new]
    #[pyo3(signature = (skin, name, dtype, schema, labels = None, records = None, rate_hz = None, inputs = None, *, access = "owner"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        skin: &str,
        name: &str,
        dtype: Bound<'_, PyAny>,
        schema: (String, u32),
        labels: Option<Vec<String>>,
        records: Option<usize>,
        rate_hz: Option<f64>,
        inputs: Option<Vec<String>>,
        access: &str,
    ) -> PyResult<PyClassInitializer<ServiceWriter>> {
        let dtype = py.import("numpy")?.call_method1("dtype", (dtype,))?;
        let record_bytes: usize = dtype.getattr("itemsize")?.extract()?;
        if record_bytes == 0 {
            return Err(errors::invalid(
                py,
                format!("service {name}: records of dtype {} have no bytes", dtype.str()?),
            ));
        }
        if let Some(hz) = rate_hz {
            ticks::period(py, hz, "rate")?;
        }
        let mode = match rate_hz {
            Some(hz) => ServiceMode::Periodic { hz },
            None => ServiceMode::Sporadic,
        };
        let mut spec = match (labels, records) {
            (Some(labels), None) => ServiceSpec::new(name, labels, mode),
            (None, Some(records)) => ServiceSpec::unlabelled(name, records, mode),
            (Some(labels), Some(records)) if labels.len() == records => ServiceSpec::new(name, labels, mode),
            _ => {
                return Err(errors::invalid(
                    py,
                    format!("service {name}: give labels (one per record), or a number of records"),
                ));
            }
        };
        if spec.records == 0 {
            return Err(errors::invalid(py, format!("service {name}: a frame needs at least one record")));
        }
        spec.inputs = inputs.unwrap_or_default();
        let options = WriterOptions { access: self::access(py, access)?, ..WriterOptions::default() };
        let records = spec.records;
        let created = py.detach(|| {
            skinware_services::framework::create_service_channel(
                skin,
                &spec,
                (&schema.0, schema.1),
                record_bytes,
                &options,
            )
        });
        let writer = created.map_err(|e| errors::exchange(py, e))?;
        let period = rate_hz.map(|hz| ticks::period(py, hz, "rate")).transpose()?;
        Ok(PyClassInitializer::from(ChannelWriter::new(writer, period))
            .add_subclass(ServiceWriter { dtype: dtype.unbind(), records }))
    }

    /// Publishes one frame: `records`, a numpy array of the service's dtype
    /// with one record per label. Returns the frame's sequence number.
    #[pyo3(signature = (records, status = 0, acquired_ns = None))]
    fn publish(
        slf: &Bound<'_, Self>,
        records: Bound<'_, PyAny>,
        status: u64,
        acquired_ns: Option<u64>,
    ) -> PyResult<u64> {
        let py = slf.py();
        let this = slf.get();
        let core = slf.as_super().get();
        let dtype = this.dtype.bind(py);
        let given = records.getattr("dtype").ok();
        if !given.as_ref().is_some_and(|g| g.eq(dtype).unwrap_or(false)) {
            let found = given.map(|g| g.to_string()).unwrap_or_else(|| records.get_type().to_string());
            return Err(errors::invalid(
                py,
                format!("service {}: publish needs an array of dtype {dtype}, got {found}", core.label),
            ));
        }
        let count: usize = records.len()?;
        if count != this.records {
            return Err(errors::invalid(
                py,
                format!("service {} publishes {} records per frame, {count} given", core.label, this.records),
            ));
        }
        let bytes = records.call_method0("tobytes")?;
        let bytes = bytes.cast::<PyBytes>()?.as_bytes();
        core.with(py, |writer| {
            let mut frame = writer.begin();
            frame.write_bytes(0, bytes)?;
            frame.set_status(FrameStatus(status));
            if let Some(ns) = acquired_ns {
                frame.set_acquired_ns(ns);
            }
            Ok(frame.publish())
        })
    }

    /// A zeroed array of the records of one frame, to fill and publish.
    fn empty<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        py.import("numpy")?.call_method1("zeros", (self.records, self.dtype.bind(py)))
    }

    /// The records' dtype.
    #[getter]
    fn dtype(&self, py: Python<'_>) -> Py<PyAny> {
        self.dtype.clone_ref(py)
    }

    /// Records per frame.
    fn __len__(&self) -> usize {
        self.records
    }

    fn __repr__(slf: &Bound<'_, Self>) -> String {
        let label = &slf.as_super().get().label;
        format!("<skinware.ServiceWriter {label} ({} records)>", slf.get().records)
    }
}

/// The periods of a writer: `(deadline_ns, missed)` on an absolute-time grid.
#[pyclass(module = "skinware", frozen)]
pub struct Ticks {
    schedule: Schedule,
    stop: Stop,
}

#[pymethods]
impl Ticks {
    fn __iter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<(u64, u64)>> {
        Ok(self.schedule.wait(py, &self.stop)?.map(|r| (r.deadline_ns, r.missed)))
    }
}
