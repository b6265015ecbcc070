//! Readers for Python: layers (`Reader`) and services (`ServiceReader`), in
//! the three modes of the exchange, each read a private copy made with the
//! GIL released.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};
use std::time::Duration;

use numpy::{PyArray1, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use skinware::{ChannelKind, ReaderOptions, Stop, WriterState};
use skinware_services::ServiceInfo;

use crate::errors;
use crate::frame::{Copied, Data, Frame};
use crate::stats::writer_stats_dict;
use crate::ticks::{self, SIGNAL_CHECK, Schedule};
use crate::topology::{Topology, readonly};

/// Why a read returned no frame.
enum Failure {
    Closed,
    /// Nothing new before the caller's timeout, the writer alive.
    TimedOut,
    Exchange(skinware::Error),
    Python(PyErr),
}

/// What a reader reads.
enum Kind {
    Layer { topology: Topology },
    Service { info: ServiceInfo, dtype: Py<PyAny> },
}

/// The three read modes.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Latest,
    Newer,
    Request,
}

impl Mode {
    fn parse(py: Python<'_>, mode: &str) -> PyResult<Mode> {
        match mode {
            "latest" => Ok(Mode::Latest),
            "newer" => Ok(Mode::Newer),
            "request" => Ok(Mode::Request),
            other => Err(errors::invalid(py, format!("mode {other:?}: use \"latest\", \"newer\" or \"request\""))),
        }
    }
}

/// A reader of one layer of a running skin.
///
/// Its reads are private copies, made by skinware's lock-free reader with the
/// GIL released: nothing a Python program does, including being killed in
/// the middle of a read, affects the skin's writer or other readers. One
/// reader may be shared by several threads (they take turns).
#[pyclass(module = "skinware", subclass, frozen)]
pub struct Reader {
    core: Mutex<Option<skinware::Reader>>,
    /// Wakes a blocked read when the reader is closed from another thread.
    stop: Stop,
    skin: String,
    channel: String,
    kind: Kind,
    /// Bytes per frame, as the channel had them when the reader attached.
    payload_bytes: usize,
    /// How many re-created channels the reader had followed when it last
    /// checked that their layout is the one `kind` describes.
    follows: AtomicU64,
}

impl Reader {
    fn open(
        py: Python<'_>,
        skin: &str,
        channel: &str,
        allow_gone: bool,
        anticipate: Option<f64>,
        service: Option<(&str, u32, Bound<'_, PyAny>)>,
    ) -> PyResult<Reader> {
        let anticipate = ticks::timeout(py, anticipate)?;
        let options = ReaderOptions { allow_gone, anticipate, ..ReaderOptions::default() };
        let (reader, kind) = match service {
            None => {
                let reader = py.detach(|| skinware::Reader::open_with(skin, channel, &options));
                let reader = reader.map_err(|e| errors::exchange(py, e))?;
                if reader.kind() != ChannelKind::Layer {
                    return Err(errors::raise(
                        py,
                        "SchemaMismatch",
                        format!(
                            "{skin}/{channel} is a service, not a layer; read it with skinware.ServiceReader (or ContactReader, MotionReader)"
                        ),
                    ));
                }
                let topology = reader.topology().map_err(|e| errors::raise(py, "ChannelError", e.to_string()))?;
                if topology.frame_bytes() != reader.payload_bytes() {
                    return Err(errors::raise(
                        py,
                        "ChannelError",
                        format!(
                            "layer {skin}/{channel} has {} sensors but {}-byte frames (2 bytes a sensor); its writer is broken",
                            topology.sensors.len(),
                            reader.payload_bytes()
                        ),
                    ));
                }
                (reader, Kind::Layer { topology: Topology { inner: topology } })
            }
            Some((schema, version, dtype)) => {
                let itemsize: usize = dtype.getattr("itemsize")?.extract()?;
                let type_name = format!("the dtype {}", dtype.str()?);
                let opened = py.detach(|| {
                    skinware_services::framework::open_service_channel(
                        skin,
                        channel,
                        (schema, version),
                        (itemsize, &type_name),
                        &options,
                    )
                });
                let (reader, info) = opened.map_err(|e| errors::exchange(py, e))?;
                (reader, Kind::Service { info, dtype: dtype.unbind() })
            }
        };
        let stop = Stop::new();
        let mut reader = reader;
        reader.set_stop(&stop);
        let payload_bytes = reader.payload_bytes();
        Ok(Reader {
            core: Mutex::new(Some(reader)),
            stop,
            skin: skin.to_owned(),
            channel: channel.to_owned(),
            kind,
            payload_bytes,
            follows: AtomicU64::new(0),
        })
    }

    fn lock(&self) -> MutexGuard<'_, Option<skinware::Reader>> {
        skinware::lock(&self.core)
    }

    /// Runs `f` on the open reader, taking the reader's lock with the GIL
    /// released: a thread holds that lock while it waits for a frame, and
    /// another one must not freeze the interpreter while it queues for it.
    fn peek<T: Send>(&self, py: Python<'_>, f: impl FnOnce(&mut skinware::Reader) -> T + Send) -> Option<T> {
        py.detach(|| self.lock().as_mut().map(f))
    }

    fn closed_error(&self, py: Python<'_>) -> PyErr {
        errors::raise(py, "ReaderClosed", format!("the reader of {}/{} is closed", self.skin, self.channel))
    }

    /// The exception for `error`, telling a channel re-created with another
    /// layout (which this reader cannot follow) from a gone writer.
    fn explain(&self, py: Python<'_>, error: skinware::Error) -> PyErr {
        if let skinware::Error::WriterGone { .. } = error
            && let Some(change) = self.layout_change(py)
        {
            return errors::raise(py, "LayoutChanged", change);
        }
        errors::exchange(py, error)
    }

    /// If a live writer now serves the channel with another layout than this
    /// reader's, what changed.
    fn layout_change(&self, py: Python<'_>) -> Option<String> {
        let (skin, channel) = (&self.skin, &self.channel);
        let successor = py.detach(|| skinware::Reader::open(skin, channel)).ok()?;
        if successor.writer_state() == WriterState::Gone {
            return None;
        }
        let label = format!("{skin}/{channel}");
        let reopen = "open a new reader to read it";
        match &self.kind {
            Kind::Layer { topology } => {
                let now = match successor.topology() {
                    Ok(now) if successor.kind() == ChannelKind::Layer => now,
                    _ => return Some(format!("{label} is no longer a layer; {reopen}")),
                };
                topology_change(&topology.inner, &now)
                    .map(|change| format!("layer {label} was re-created with {change}; {reopen}"))
            }
            Kind::Service { info, .. } => {
                let now = ServiceInfo::parse(&successor.description());
                (now.as_ref() != Some(info) || successor.payload_bytes() != self.payload_bytes()).then(|| {
                    format!("service {label} was re-created with other records (schema, labels or size); {reopen}")
                })
            }
        }
    }

    fn payload_bytes(&self) -> usize {
        self.payload_bytes
    }

    fn copy(&self, frame: &skinware::Frame<'_>) -> Copied {
        let data = match self.kind {
            Kind::Layer { .. } => Data::Responses(frame.responses().to_vec()),
            Kind::Service { .. } => Data::Bytes(frame.bytes().to_vec()),
        };
        Copied::new(frame, data)
    }

    /// One read in `mode`, as blocking calls do it: in slices of at most
    /// [`SIGNAL_CHECK`] without the GIL, with signals checked between them,
    /// until `timeout`.
    fn read(
        &self,
        py: Python<'_>,
        mode: Mode,
        timeout: Option<Duration>,
        into: Option<&mut [u16]>,
    ) -> PyResult<Copied> {
        self.read_raw(py, mode, timeout, into).map_err(|failure| self.failure(py, failure, timeout))
    }

    /// The exception for a failed read.
    fn failure(&self, py: Python<'_>, failure: Failure, timeout: Option<Duration>) -> PyErr {
        match failure {
            Failure::Closed => self.closed_error(py),
            Failure::Python(error) => error,
            Failure::TimedOut => errors::raise(
                py,
                "Timeout",
                format!(
                    "no new frame on channel {}/{} within {} s (its writer is {})",
                    self.skin,
                    self.channel,
                    timeout.map_or(f64::INFINITY, |t| t.as_secs_f64()),
                    self.state_now(py).as_str()
                ),
            ),
            Failure::Exchange(error) => self.explain(py, error),
        }
    }

    /// One read of `mode` that waits at most `slice`, into `into` or a new
    /// array, by `reader` (this reader's, locked).
    fn read_once(
        &self,
        reader: &mut skinware::Reader,
        mode: Mode,
        slice: Duration,
        into: Option<&mut [u16]>,
        requested_after: &mut Option<(u64, u64)>,
    ) -> skinware::Result<Copied> {
        let copy_out = |frame: &skinware::Frame<'_>, into: Option<&mut [u16]>| match into {
            Some(out) => {
                out.copy_from_slice(frame.responses());
                Copied::new(frame, Data::Into)
            }
            None => self.copy(frame),
        };
        let result = match (mode, *requested_after) {
            (Mode::Latest, _) => reader.latest().map(|f| copy_out(&f, into)),
            (Mode::Newer, _) => reader.wait_newer(slice).map(|f| copy_out(&f, into)),
            // A request is made again to a successor (whose numbers
            // start again from 1).
            (Mode::Request, None) => {
                let after = (reader.published_seq(), reader.follows());
                let result = reader.request(slice).map(|f| copy_out(&f, into));
                if result.is_err() {
                    *requested_after = Some(after);
                }
                result
            }
            (Mode::Request, Some((_, follows))) if follows != reader.follows() => {
                *requested_after = None;
                Err(skinware::Error::Timeout { channel: String::new(), timeout: slice })
            }
            (Mode::Request, Some((after, _))) => match reader.wait_newer(slice) {
                Ok(f) if f.seq() > after => Ok(copy_out(&f, into)),
                Ok(_) => Err(skinware::Error::Timeout { channel: String::new(), timeout: slice }),
                Err(e) => Err(e),
            },
        };
        let mut result = result.map(|mut copied| {
            copied.follows = reader.follows();
            copied.state = reader.writer_state();
            copied
        });
        // A writer that died: follow its successor if it has one (the waits
        // do it themselves), so that a caller of `latest()` reads the
        // successor's frames next time.
        if let Ok(copied) = &mut result
            && mode == Mode::Latest
            && !copied.fresh
            && copied.state == WriterState::Gone
            && reader.follow_recreated()
        {
            copied.follows = reader.follows();
        }
        result
    }

    fn read_raw(
        &self,
        py: Python<'_>,
        mode: Mode,
        timeout: Option<Duration>,
        into: Option<&mut [u16]>,
    ) -> Result<Copied, Failure> {
        let deadline = timeout.map(|t| ticks::monotonic_ns().saturating_add(t.as_nanos() as u64));
        let mut into = into;
        // A request is made once; later slices wait for a frame newer than
        // those published when it was made.
        let mut requested_after: Option<(u64, u64)> = None;
        loop {
            let now = ticks::monotonic_ns();
            let slice = match deadline {
                Some(deadline) => Duration::from_nanos(deadline.saturating_sub(now)).min(SIGNAL_CHECK),
                None => SIGNAL_CHECK,
            };
            let into_slice = into.as_deref_mut();
            let result = py.detach(|| {
                let mut guard = self.lock();
                let reader = guard.as_mut()?;
                Some(self.read_once(reader, mode, slice, into_slice, &mut requested_after))
            });
            let error = match result {
                None => return Err(Failure::Closed),
                Some(Ok(copied)) => {
                    self.check_follows(py, copied.follows).map_err(Failure::Python)?;
                    if mode == Mode::Latest
                        && !copied.fresh
                        && copied.state == WriterState::Gone
                        && let Some(change) = self.layout_change(py)
                    {
                        return Err(Failure::Python(errors::raise(py, "LayoutChanged", change)));
                    }
                    return Ok(copied);
                }
                // Closed from another thread while this one waited.
                Some(Err(skinware::Error::Stopped { .. })) => return Err(Failure::Closed),
                Some(Err(error)) => error,
            };
            let retry = mode != Mode::Latest
                && matches!(error, skinware::Error::Timeout { .. } | skinware::Error::WriterGone { .. })
                && deadline.is_none_or(|deadline| ticks::monotonic_ns() < deadline);
            if !retry {
                return Err(match error {
                    skinware::Error::Timeout { .. } => Failure::TimedOut,
                    error => Failure::Exchange(error),
                });
            }
            py.check_signals().map_err(Failure::Python)?;
        }
    }

    /// A reader that followed a re-created channel checks that its layout is
    /// still the one it reads with (a layer's topology can change while its
    /// frame size stays the same).
    fn check_follows(&self, py: Python<'_>, now: u64) -> PyResult<()> {
        let seen = self.follows.load(Ordering::Relaxed);
        if seen == now {
            return Ok(());
        }
        let description = self.peek(py, |r| r.description()).unwrap_or_default();
        let change = match &self.kind {
            Kind::Layer { topology } => match skinware::LayerTopology::decode(&description, &self.channel) {
                Ok(now) => topology_change(&topology.inner, &now),
                Err(e) => Some(format!("a topology that does not decode ({e})")),
            },
            Kind::Service { info, .. } => (ServiceInfo::parse(&description).as_ref() != Some(info))
                .then(|| "other records (schema, labels or size)".to_owned()),
        };
        if let Some(change) = change {
            return Err(errors::raise(
                py,
                "LayoutChanged",
                format!("{}/{} was re-created with {change}; open a new reader to read it", self.skin, self.channel),
            ));
        }
        self.follows.store(now, Ordering::Relaxed);
        Ok(())
    }

    /// [`check_follows`](Self::check_follows) against the reader now.
    fn check_current_follows(&self, py: Python<'_>) -> PyResult<()> {
        match self.peek(py, |r| r.follows()) {
            Some(now) => self.check_follows(py, now),
            None => Err(self.closed_error(py)),
        }
    }

    fn frame(&self, py: Python<'_>, copied: Copied, into: Option<Py<PyAny>>) -> PyResult<Frame> {
        let data: Py<PyAny> = match (copied.data, &self.kind) {
            (Data::Responses(values), _) => readonly(py, values).into_any().unbind(),
            (Data::Bytes(bytes), Kind::Service { dtype, .. }) => {
                readonly(py, bytes).call_method1("view", (dtype.bind(py),))?.unbind()
            }
            (Data::Bytes(bytes), Kind::Layer { .. }) => readonly(py, bytes).into_any().unbind(),
            (Data::Into, _) => into.ok_or_else(|| errors::invalid(py, "read_into lost its array"))?,
        };
        Ok(Frame {
            data,
            seq: copied.seq,
            acquired_ns: copied.acquired_ns,
            published_ns: copied.published_ns,
            status: copied.status,
            skipped: copied.skipped,
            fresh: copied.fresh,
        })
    }

    fn state_now(&self, py: Python<'_>) -> WriterState {
        self.peek(py, |r| r.writer_state()).unwrap_or(WriterState::Gone)
    }
}

#[pymethods]
impl Reader {
    /// Attaches to layer `layer` of skin `skin`.
    ///
    /// `allow_gone` attaches even to a channel whose writer is stopping;
    /// `anticipate` (seconds) makes as-soon-as-available reads of a periodic
    /// layer wake that long before the frame is due and spin, instead of
    /// sleeping until the writer wakes them (lower latency, more CPU).
    #[new]
    #[pyo3(signature = (skin, layer, *, allow_gone = false, anticipate = None))]
    fn new(py: Python<'_>, skin: &str, layer: &str, allow_gone: bool, anticipate: Option<f64>) -> PyResult<Reader> {
        Reader::open(py, skin, layer, allow_gone, anticipate, None)
    }

    /// On request: the newest complete frame, now. Never blocks. A writer
    /// that died is replaced by its successor, if it has one, from the next
    /// read on.
    fn latest(&self, py: Python<'_>) -> PyResult<Frame> {
        let copied = self.read(py, Mode::Latest, None, None)?;
        self.frame(py, copied, None)
    }

    /// As soon as available: waits for a frame newer than the last one this
    /// reader obtained (asleep, without the GIL) and returns it. Raises
    /// `Timeout` after `timeout` seconds (`None`: no limit), or `WriterGone`
    /// if the writer is gone by then.
    #[pyo3(signature = (timeout = 1.0))]
    fn wait_newer(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Frame> {
        let timeout = ticks::timeout(py, timeout)?;
        let copied = self.read(py, Mode::Newer, timeout, None)?;
        self.frame(py, copied, None)
    }

    /// On request: asks the writer for a frame newer than any published now
    /// and waits for it (a sporadic writer acquires one for it).
    #[pyo3(signature = (timeout = 1.0))]
    fn request(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Frame> {
        let timeout = ticks::timeout(py, timeout)?;
        let copied = self.read(py, Mode::Request, timeout, None)?;
        self.frame(py, copied, None)
    }

    /// Reads into `out`, a writeable 1-D `uint16` array of one element per
    /// sensor, instead of a new array: for high rates. `mode` is "latest",
    /// "newer" or "request". The frame returned has `out` as its data.
    #[pyo3(signature = (out, mode = "latest", timeout = 1.0))]
    fn read_into(&self, py: Python<'_>, out: Bound<'_, PyAny>, mode: &str, timeout: Option<f64>) -> PyResult<Frame> {
        let mode = Mode::parse(py, mode)?;
        let timeout = ticks::timeout(py, timeout)?;
        let Kind::Layer { topology } = &self.kind else {
            return Err(errors::invalid(
                py,
                "read_into reads layers; a service's frames come from latest() and the waits",
            ));
        };
        let sensors = topology.inner.sensors.len();
        let array = out.cast::<PyArray1<u16>>().map_err(|_| {
            errors::invalid(
                py,
                format!("read_into needs a 1-D numpy uint16 array of {sensors} elements, e.g. numpy.empty({sensors}, numpy.uint16)"),
            )
        })?;
        if array.len() != sensors || !array.is_contiguous() {
            return Err(errors::invalid(
                py,
                format!(
                    "read_into needs a contiguous array of {sensors} elements (one per sensor), got {} elements",
                    array.len()
                ),
            ));
        }
        let mut writeable = array.try_readwrite().map_err(|e| {
            errors::invalid(py, format!("read_into cannot write the array: {e}; pass a writeable array"))
        })?;
        let slice = writeable.as_slice_mut().map_err(|e| errors::invalid(py, format!("read_into: {e}")))?;
        let copied = self.read(py, mode, timeout, Some(slice))?;
        drop(writeable);
        self.frame(py, copied, Some(out.unbind()))
    }

    /// Periodic: an iterator that yields the newest frame at `hz` (absolute
    /// time, so no drift), fresh or not (`Frame.fresh` tells). It raises
    /// `WriterGone` when the writer has been gone for `gone_timeout` seconds
    /// without a successor, and ends when the reader is closed.
    #[pyo3(signature = (hz, gone_timeout = 2.0))]
    fn periodic(slf: Bound<'_, Self>, hz: f64, gone_timeout: f64) -> PyResult<Periodic> {
        let py = slf.py();
        let period = ticks::period(py, hz, "periodic")?;
        let gone = ticks::timeout(py, Some(gone_timeout))?.unwrap_or_default();
        Ok(Periodic::new(slf.unbind(), Some(period), gone))
    }

    /// As soon as available, as an iterator: every new frame (`wait_newer`),
    /// waiting as long as the writer lives. It raises `WriterGone` when the
    /// writer has been gone for `gone_timeout` seconds without a successor,
    /// and ends when the reader is closed.
    #[pyo3(signature = (gone_timeout = 2.0))]
    fn frames(slf: Bound<'_, Self>, gone_timeout: f64) -> PyResult<Periodic> {
        let py = slf.py();
        let gone = ticks::timeout(py, Some(gone_timeout))?.unwrap_or_default();
        Ok(Periodic::new(slf.unbind(), None, gone))
    }

    /// `iter(reader)` is `reader.frames()`.
    fn __iter__(slf: Bound<'_, Self>) -> PyResult<Periodic> {
        Reader::frames(slf, 2.0)
    }

    /// The writer's state: "running", "paused", "faulted" or "gone".
    #[getter]
    fn state(&self, py: Python<'_>) -> &'static str {
        self.state_now(py).as_str()
    }

    /// The layer's topology.
    #[getter]
    fn topology(&self, py: Python<'_>) -> PyResult<Topology> {
        match &self.kind {
            Kind::Layer { topology } => Ok(Topology { inner: topology.inner.clone() }),
            Kind::Service { .. } => Err(errors::invalid(
                py,
                format!("{}/{} is a service; it has labels, not a topology", self.skin, self.channel),
            )),
        }
    }

    /// The skin's name.
    #[getter]
    fn skin(&self) -> &str {
        &self.skin
    }

    /// The channel's name.
    #[getter]
    fn name(&self) -> &str {
        &self.channel
    }

    /// Values per frame: sensors of a layer, records of a service.
    fn __len__(&self) -> usize {
        match &self.kind {
            Kind::Layer { topology } => topology.inner.sensors.len(),
            Kind::Service { info, .. } => self.payload_bytes / info.record_bytes.max(1),
        }
    }

    /// The sequence number the writer published last (0 before its first frame).
    #[getter]
    fn published_seq(&self, py: Python<'_>) -> PyResult<u64> {
        self.peek(py, |r| r.published_seq()).ok_or_else(|| self.closed_error(py))
    }

    /// The writer's process id.
    #[getter]
    fn writer_pid(&self, py: Python<'_>) -> PyResult<u32> {
        self.peek(py, |r| r.writer_pid()).ok_or_else(|| self.closed_error(py))
    }

    /// How many writers the channel has had (one more after each revival).
    #[getter]
    fn generation(&self, py: Python<'_>) -> PyResult<u64> {
        self.peek(py, |r| r.writer_generation()).ok_or_else(|| self.closed_error(py))
    }

    /// The writer's period in seconds, or `None` for a sporadic writer.
    #[getter]
    fn period(&self, py: Python<'_>) -> PyResult<Option<f64>> {
        self.peek(py, |r| r.writer_period().map(|p| p.as_secs_f64())).ok_or_else(|| self.closed_error(py))
    }

    /// This reader's statistics: reads, retries, skipped, read_ns_min,
    /// read_ns_mean, read_ns_max.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let stats = self.peek(py, |r| r.stats().clone()).ok_or_else(|| self.closed_error(py))?;
        let dict = PyDict::new(py);
        dict.set_item("reads", stats.reads)?;
        dict.set_item("retries", stats.retries)?;
        dict.set_item("skipped", stats.skipped)?;
        dict.set_item("read_ns_min", stats.read_ns_min)?;
        dict.set_item("read_ns_mean", stats.read_ns_mean())?;
        dict.set_item("read_ns_max", stats.read_ns_max)?;
        Ok(dict)
    }

    /// The writer's statistics: frames, overruns, missed_periods, faults,
    /// write_ns_min/mean/max, lateness_ns_mean/max.
    #[getter]
    fn writer_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let stats = self.peek(py, |r| r.writer_stats()).ok_or_else(|| self.closed_error(py))?;
        writer_stats_dict(py, &stats)
    }

    /// Whether the reader is closed.
    #[getter]
    fn closed(&self, py: Python<'_>) -> bool {
        self.peek(py, |_| ()).is_none()
    }

    /// Detaches from the channel. A read blocked in another thread returns
    /// with `ReaderClosed`; iterators end.
    fn close(&self, py: Python<'_>) {
        self.stop.stop();
        let reader = py.detach(|| self.lock().take());
        drop(reader);
    }

    fn __enter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    #[pyo3(signature = (*_args))]
    fn __exit__(&self, py: Python<'_>, _args: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        self.close(py);
        false
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let what = match &self.kind {
            Kind::Layer { topology } => format!("layer, {} sensors", topology.inner.sensors.len()),
            Kind::Service { info, .. } => {
                format!("service {} v{}, {} records", info.schema.0, info.schema.1, self.__len__())
            }
        };
        format!("<{} {}/{} ({what}), {}>", "skinware.Reader", self.skin, self.channel, self.state_now(py).as_str())
    }
}

/// A reader of one service: its frames' data are numpy structured arrays of
/// `dtype`, one record per label. The channel's schema and record size are
/// checked when it is opened (`SchemaMismatch` otherwise).
#[pyclass(module = "skinware", extends = Reader, subclass, frozen)]
pub struct ServiceReader {}

#[pymethods]
impl ServiceReader {
    /// Attaches to service `name` of `skin`, whose records have schema
    /// `schema` (name, version) and the layout of `dtype` (a numpy dtype).
    #[new]
    #[pyo3(signature = (skin, name, dtype, schema, *, allow_gone = false))]
    fn new(
        py: Python<'_>,
        skin: &str,
        name: &str,
        dtype: Bound<'_, PyAny>,
        schema: (String, u32),
        allow_gone: bool,
    ) -> PyResult<PyClassInitializer<ServiceReader>> {
        let numpy = py.import("numpy")?;
        let dtype = numpy.call_method1("dtype", (dtype,))?;
        let reader = Reader::open(py, skin, name, allow_gone, None, Some((&schema.0, schema.1, dtype)))?;
        Ok(PyClassInitializer::from(reader).add_subclass(ServiceReader {}))
    }

    /// One label per record (e.g. region names).
    #[getter]
    fn labels(slf: PyRef<'_, Self>) -> Vec<String> {
        match &slf.as_super().kind {
            Kind::Service { info, .. } => info.labels.clone(),
            Kind::Layer { .. } => Vec::new(),
        }
    }

    /// The records' numpy dtype.
    #[getter]
    fn dtype(slf: PyRef<'_, Self>) -> Option<Py<PyAny>> {
        match &slf.as_super().kind {
            Kind::Service { dtype, .. } => Some(dtype.clone_ref(slf.py())),
            Kind::Layer { .. } => None,
        }
    }

    /// The schema: (name, version).
    #[getter]
    fn schema(slf: PyRef<'_, Self>) -> Option<(String, u32)> {
        match &slf.as_super().kind {
            Kind::Service { info, .. } => Some(info.schema.clone()),
            Kind::Layer { .. } => None,
        }
    }

    /// The channels the service reads.
    #[getter]
    fn inputs(slf: PyRef<'_, Self>) -> Vec<String> {
        match &slf.as_super().kind {
            Kind::Service { info, .. } => info.inputs.clone(),
            Kind::Layer { .. } => Vec::new(),
        }
    }

    /// The service's declared rate, Hz, or `None` if it is sporadic.
    #[getter]
    fn rate_hz(slf: PyRef<'_, Self>) -> Option<f64> {
        match &slf.as_super().kind {
            Kind::Service { info, .. } => info.rate_hz,
            Kind::Layer { .. } => None,
        }
    }
}

/// The iterator of `Reader.periodic()` and `Reader.frames()`.
#[pyclass(module = "skinware", frozen)]
pub struct Periodic {
    reader: Py<Reader>,
    /// `None`: as soon as available.
    schedule: Option<Schedule>,
    gone_timeout_ns: u64,
    gone_since: Mutex<Option<u64>>,
}

impl Periodic {
    fn new(reader: Py<Reader>, period: Option<Duration>, gone_timeout: Duration) -> Periodic {
        Periodic {
            reader,
            schedule: period.map(Schedule::new),
            gone_timeout_ns: gone_timeout.as_nanos() as u64,
            gone_since: Mutex::new(None),
        }
    }

    /// Whether the writer has been gone too long; resets when it is back.
    fn gone_too_long(&self, gone: bool) -> bool {
        let mut since = skinware::lock(&self.gone_since);
        if !gone {
            *since = None;
            return false;
        }
        let now = ticks::monotonic_ns();
        let first = *since.get_or_insert(now);
        now - first >= self.gone_timeout_ns
    }

    fn gone_error(&self, py: Python<'_>, reader: &Reader) -> PyErr {
        if let Some(change) = reader.layout_change(py) {
            return errors::raise(py, "LayoutChanged", change);
        }
        errors::raise(
            py,
            "WriterGone",
            format!(
                "the writer of {}/{} has been gone for {:.1} s and no successor took its place",
                reader.skin,
                reader.channel,
                self.gone_timeout_ns as f64 / 1e9
            ),
        )
    }
}

#[pymethods]
impl Periodic {
    fn __iter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<Frame>> {
        let reader = self.reader.get();
        loop {
            let Some(schedule) = &self.schedule else {
                // As soon as available, in short waits, so that a writer
                // gone for `gone_timeout` is noticed within a quarter second.
                let timeout = Some(Duration::from_millis(250));
                match reader.read_raw(py, Mode::Newer, timeout, None) {
                    Ok(copied) => {
                        self.gone_too_long(false);
                        return reader.frame(py, copied, None).map(Some);
                    }
                    Err(Failure::Closed) => return Ok(None),
                    // A living writer with nothing new: keep waiting.
                    Err(Failure::TimedOut) => {
                        self.gone_too_long(false);
                        continue;
                    }
                    Err(Failure::Exchange(skinware::Error::WriterGone { .. })) => {
                        if self.gone_too_long(true) {
                            return Err(self.gone_error(py, reader));
                        }
                        continue;
                    }
                    Err(failure) => return Err(reader.failure(py, failure, timeout)),
                }
            };
            let reached = schedule.wait(py, &reader.stop)?;
            if reached.is_none() {
                return Ok(None);
            }
            let copied = match reader.read_raw(py, Mode::Latest, None, None) {
                Ok(copied) => copied,
                Err(Failure::Closed) => return Ok(None),
                // Nothing published yet: wait for the next tick.
                Err(Failure::Exchange(skinware::Error::NoFrameYet { .. })) => continue,
                Err(failure) => return Err(reader.failure(py, failure, None)),
            };
            let gone = !copied.fresh && copied.state == WriterState::Gone;
            if gone && reader.peek(py, |r| r.follow_recreated()).unwrap_or(false) {
                reader.check_current_follows(py)?;
            } else if self.gone_too_long(gone) {
                return Err(self.gone_error(py, reader));
            }
            return reader.frame(py, copied, None).map(Some);
        }
    }
}

/// What differs between two layer topologies, as far as a reader cares: the
/// sensors, their modules and patches (not the rate, the name or the type).
fn topology_change(was: &skinware::LayerTopology, now: &skinware::LayerTopology) -> Option<String> {
    if was.sensors.len() != now.sensors.len() {
        return Some(format!("another topology ({} sensors, was {})", now.sensors.len(), was.sensors.len()));
    }
    if was.sensors != now.sensors {
        return Some("other sensor uids or another sensor order".to_owned());
    }
    if was.modules != now.modules || was.patches != now.patches {
        return Some(format!(
            "other modules or patches ({} modules on {} patches, was {} on {})",
            now.modules.len(),
            now.patches.len(),
            was.modules.len(),
            was.patches.len()
        ));
    }
    None
}
