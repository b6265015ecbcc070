//! Services: users of sensor data that publish processed data for others
//! (the paper's definition), through the same exchange as layers.
//!
//! A service's frame is a fixed number of records of one plain-old-data type
//! (for example one record per region). The type names its schema and
//! version ([`ServicePayload`]); a reader that attaches with another type, or
//! another version of it, gets [`Error::SchemaMismatch`] or
//! [`Error::NotThisService`], never misread bytes.
//!
//! ```
//! use skinware_services::framework::{ServiceMode, ServicePayload, ServiceReader, ServiceSpec, ServiceWriter};
//! use skinware::{FrameStatus, WriterOptions};
//!
//! #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
//! #[repr(C)]
//! struct Touch { pressure: f32, taxels: u32 }
//! impl ServicePayload for Touch {
//!     const SCHEMA: &'static str = "example.touch";
//!     const VERSION: u32 = 1;
//! }
//!
//! # let skin = format!("svcdoc{}", std::process::id());
//! let labels = vec!["palm".into(), "finger".into()];
//! let spec = ServiceSpec::new("touch", labels, ServiceMode::Periodic { hz: 50.0 });
//! let mut service = ServiceWriter::<Touch>::create(&skin, &spec, &WriterOptions::default())?;
//! service.publish(&[Touch { pressure: 3.5, taxels: 4 }, Touch { pressure: 0.0, taxels: 0 }], FrameStatus::OK)?;
//!
//! let mut reader = ServiceReader::<Touch>::open(&skin, "touch")?;
//! assert_eq!(reader.labels(), ["palm", "finger"]);
//! let frame = reader.latest()?;
//! assert_eq!(frame.records[0].taxels, 4);
//! # Ok::<(), skinware::Error>(())
//! ```

#![forbid(unsafe_code)]

use skinware::wire::{DecodeError, Decoder, Encoder};
use std::time::Duration;

use skinware::{
    ChannelKind, Error, FrameStatus, Reader, ReaderOptions, Result, Ticker, Writer, WriterOptions, WriterState,
};

const DESCRIPTION_MAGIC: &[u8; 8] = b"SKSERV02";

/// A service's record type: plain old data, with a schema name (at most 32
/// bytes) and a version to bump whenever the layout or meaning changes.
pub trait ServicePayload: bytemuck::Pod {
    /// Schema name, e.g. `"skinware.motion"`.
    const SCHEMA: &'static str;
    /// Schema version.
    const VERSION: u32;
}

/// When a service publishes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ServiceMode {
    /// At a fixed rate, Hz.
    Periodic {
        /// Rate, Hz.
        hz: f64,
    },
    /// When a reader requests a frame.
    Sporadic,
}

/// What a service declares.
#[derive(Clone, Debug, PartialEq)]
pub struct ServiceSpec {
    /// Channel name.
    pub name: String,
    /// Records per frame.
    pub records: usize,
    /// One label per record (e.g. region names), or none.
    pub labels: Vec<String>,
    /// Periodic or sporadic.
    pub mode: ServiceMode,
    /// The channels this service reads, for `skin services`.
    pub inputs: Vec<String>,
}

impl ServiceSpec {
    /// A service called `name` with one record per label.
    pub fn new(name: &str, labels: Vec<String>, mode: ServiceMode) -> ServiceSpec {
        ServiceSpec { name: name.to_owned(), records: labels.len(), labels, mode, inputs: Vec::new() }
    }

    /// A service called `name` with `records` unlabelled records.
    pub fn unlabelled(name: &str, records: usize, mode: ServiceMode) -> ServiceSpec {
        ServiceSpec { name: name.to_owned(), records, labels: Vec::new(), mode, inputs: Vec::new() }
    }

    fn description(&self, schema: &str, version: u32, record_bytes: usize) -> Vec<u8> {
        ServiceInfo {
            schema: (schema.to_owned(), version),
            record_bytes,
            rate_hz: match self.mode {
                ServiceMode::Periodic { hz } => Some(hz),
                ServiceMode::Sporadic => None,
            },
            inputs: self.inputs.clone(),
            labels: self.labels.clone(),
        }
        .encode()
    }
}

/// What a service channel says about itself (its description).
#[derive(Clone, Debug, PartialEq)]
pub struct ServiceInfo {
    /// Schema name and version.
    pub schema: (String, u32),
    /// Bytes per record.
    pub record_bytes: usize,
    /// Periodic rate, or `None` for sporadic.
    pub rate_hz: Option<f64>,
    /// Channels it reads.
    pub inputs: Vec<String>,
    /// One label per record.
    pub labels: Vec<String>,
}

impl ServiceInfo {
    /// The description's encoding (skinware's [`wire`](skinware::wire)
    /// format): `SKSERV02`, schema name and version, record bytes, the mode
    /// (0 sporadic, 1 periodic with its rate), inputs, labels.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Encoder::new(DESCRIPTION_MAGIC);
        out.str(&self.schema.0);
        out.u32(self.schema.1);
        out.count(self.record_bytes);
        match self.rate_hz {
            Some(hz) => {
                out.u32(1);
                out.f64(hz);
            }
            None => out.u32(0),
        }
        out.strs(&self.inputs);
        out.strs(&self.labels);
        out.finish()
    }

    /// Decodes a service channel's description.
    pub fn decode(description: &[u8]) -> Result<ServiceInfo, DecodeError> {
        let mut input = Decoder::new(description, "service description", DESCRIPTION_MAGIC)?;
        let schema = (input.str("schema name")?, input.u32("schema version")?);
        let record_bytes = input.u32("record bytes")? as usize;
        let rate_hz = match input.u32("mode")? {
            0 => None,
            1 => Some(input.f64("rate")?),
            other => {
                return Err(input.invalid("mode", format!("mode {other} is neither 0 (sporadic) nor 1 (periodic)")));
            }
        };
        let inputs = input.strs("inputs")?;
        let labels = input.strs("labels")?;
        input.finish()?;
        Ok(ServiceInfo { schema, record_bytes, rate_hz, inputs, labels })
    }

    /// [`decode`](Self::decode), for callers that only need to know whether
    /// it is a service description.
    pub fn parse(description: &[u8]) -> Option<ServiceInfo> {
        ServiceInfo::decode(description).ok()
    }
}

/// The writing side of a service: publishes `records` records of `T` per frame.
pub struct ServiceWriter<T: ServicePayload> {
    writer: Writer,
    records: usize,
    mode: ServiceMode,
    buffer: Vec<T>,
}

/// What one step of a service loop ([`ServiceWriter::run`]) produced.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepOutcome {
    /// The frame's status (e.g. [`FrameStatus::INPUT_FAULTED`]).
    pub status: FrameStatus,
    /// The acquisition time of the inputs it was computed from, monotonic ns.
    pub acquired_ns: Option<u64>,
}

impl<T: ServicePayload> ServiceWriter<T> {
    /// Creates the service channel (taking over the name of a dead writer's) `skin`/`spec.name`.
    /// `options`' kind, schema and period are set from the spec and `T`.
    pub fn create(skin: &str, spec: &ServiceSpec, options: &WriterOptions) -> Result<ServiceWriter<T>> {
        let writer = create_service_channel(skin, spec, (T::SCHEMA, T::VERSION), std::mem::size_of::<T>(), options)?;
        let records = spec.records;
        Ok(ServiceWriter { writer, records, mode: spec.mode, buffer: vec![T::zeroed(); records] })
    }

    /// Runs the service until the writer's stop signal: periodically at the
    /// declared rate (absolute time), or once per reader request if sporadic.
    /// Each time, `step` fills the records (starting from the previous
    /// frame's) and says their status; its time counts as the frame's write
    /// time. An `Err` publishes nothing, counts a fault and marks the service
    /// faulted until a step succeeds again.
    pub fn run<E, F>(&mut self, mut step: F) -> Result<()>
    where
        E: std::fmt::Display,
        F: FnMut(&mut [T]) -> std::result::Result<StepOutcome, E>,
    {
        let ServiceWriter { writer, buffer, mode, .. } = self;
        let mut fill = |frame: &mut skinware::FrameWriter<'_>| -> std::result::Result<(), String> {
            let outcome = step(buffer).map_err(|e| e.to_string())?;
            frame.write_bytes(0, bytemuck::cast_slice(buffer)).map_err(|e| e.to_string())?;
            frame.set_status(outcome.status);
            if let Some(ns) = outcome.acquired_ns {
                frame.set_acquired_ns(ns);
            }
            Ok(())
        };
        match *mode {
            ServiceMode::Periodic { hz } => writer.run_periodic(Ticker::from_hz(hz), &mut fill),
            ServiceMode::Sporadic => writer.run_sporadic(&mut fill),
        }
    }

    /// Publishes one frame of records with `status` (e.g.
    /// [`FrameStatus::INPUT_FAULTED`] when an input is down). A service that
    /// runs its own loop uses this; [`run`](Self::run) does it for a step.
    pub fn publish(&mut self, records: &[T], status: FrameStatus) -> Result<u64> {
        if records.len() != self.records {
            return Err(Error::InvalidLayout {
                channel: self.writer.label().to_owned(),
                reason: format!("{} records given, the service publishes {}", records.len(), self.records),
            });
        }
        self.writer.publish_bytes(bytemuck::cast_slice(records), status)
    }

    /// Records per frame.
    pub fn records(&self) -> usize {
        self.records
    }

    /// The underlying writer: state, statistics, requests, stop signal.
    pub fn writer(&mut self) -> &mut Writer {
        &mut self.writer
    }
}

/// Creates a service's channel for records of `record_bytes` bytes with
/// schema `(name, version)`: what [`ServiceWriter::create`] does for a
/// record type known at compile time, for records whose layout is known only
/// at run time (the Python bindings' services). Checks the labels and the
/// rate; `options`' kind, schema and period are set from the spec.
pub fn create_service_channel(
    skin: &str,
    spec: &ServiceSpec,
    schema: (&str, u32),
    record_bytes: usize,
    options: &WriterOptions,
) -> Result<Writer> {
    if let Some(label) = spec.labels.iter().find(|l| l.is_empty() || l.chars().any(char::is_whitespace)) {
        return Err(Error::InvalidLayout {
            channel: format!("{skin}/{}", spec.name),
            reason: format!("record label {label:?} must be one word"),
        });
    }
    if !spec.labels.is_empty() && spec.labels.len() != spec.records {
        return Err(Error::InvalidLayout {
            channel: format!("{skin}/{}", spec.name),
            reason: format!("{} labels for {} records", spec.labels.len(), spec.records),
        });
    }
    let period = match spec.mode {
        ServiceMode::Periodic { hz } => match Duration::try_from_secs_f64(1.0 / hz) {
            Ok(period) if hz.is_finite() && hz > 0.0 && period >= Duration::from_micros(1) => Some(period),
            _ => {
                return Err(Error::InvalidLayout {
                    channel: format!("{skin}/{}", spec.name),
                    reason: format!("rate {hz} Hz must be finite, above 0 and at most 1 MHz"),
                });
            }
        },
        ServiceMode::Sporadic => None,
    };
    let options = WriterOptions {
        kind: ChannelKind::Service,
        schema_name: schema.0.to_owned(),
        schema_version: schema.1,
        period,
        // A fast service keeps 20 ms of its records readable, as a fast
        // layer does, so that a reader held up that long (a recorder) misses none.
        slots: options.slots.max(skinware::slots_for_history(period)),
        ..options.clone()
    };
    let description = spec.description(schema.0, schema.1, record_bytes);
    let frame_bytes = spec.records.checked_mul(record_bytes).ok_or_else(|| Error::InvalidLayout {
        channel: format!("{skin}/{}", spec.name),
        reason: format!("{} records of {record_bytes} bytes do not fit in memory", spec.records),
    })?;
    Writer::create(skin, &spec.name, frame_bytes, &description, &options)
}

/// Attaches to service `name` of `skin` and checks that it publishes records
/// of schema `(name, version)` and `record.0` bytes (`record.1` names the
/// record type in errors): what [`ServiceReader::open_with`] does for a
/// record type known at compile time, for the Python bindings' readers.
pub fn open_service_channel(
    skin: &str,
    name: &str,
    schema: (&str, u32),
    record: (usize, &str),
    options: &ReaderOptions,
) -> Result<(Reader, ServiceInfo)> {
    let reader = Reader::open_with(skin, name, &ReaderOptions { expect_schema: None, ..options.clone() })?;
    let mismatch = |reason: String| Error::NotThisService {
        channel: reader.label().to_owned(),
        expected: format!("{} version {}", schema.0, schema.1),
        reason,
    };
    if reader.kind() != ChannelKind::Service {
        return Err(mismatch("it is a layer, not a service".into()));
    }
    let (found, found_version) = reader.schema();
    if found != schema.0 || found_version != schema.1 {
        return Err(Error::SchemaMismatch {
            channel: reader.label().to_owned(),
            found,
            found_version,
            expected: schema.0.to_owned(),
            expected_version: schema.1,
        });
    }
    let info = ServiceInfo::decode(&reader.description())
        .map_err(|e| mismatch(format!("its description is not a service description ({e})")))?;
    let (record_bytes, type_name) = record;
    if info.record_bytes != record_bytes {
        return Err(mismatch(format!("its records are {} bytes, {} is {record_bytes}", info.record_bytes, type_name)));
    }
    let count = reader.payload_bytes() / record_bytes.max(1);
    if count * record_bytes != reader.payload_bytes() {
        return Err(mismatch(format!("its {}-byte frame is not whole records", reader.payload_bytes())));
    }
    Ok((reader, info))
}

/// One service frame as a reader got it.
#[derive(Debug)]
pub struct ServiceFrame<'r, T> {
    /// Sequence number.
    pub seq: u64,
    /// When the service's data was acquired (its inputs' time), monotonic ns.
    pub acquired_ns: u64,
    /// When it was published, monotonic ns.
    pub published_ns: u64,
    /// Status flags.
    pub status: FrameStatus,
    /// Whether this frame is newer than the one this reader read before.
    pub fresh: bool,
    /// The records, one per label.
    pub records: &'r [T],
}

/// The reading side of a service, typed: attaching checks kind, schema,
/// version and record size.
pub struct ServiceReader<T: ServicePayload> {
    reader: Reader,
    info: ServiceInfo,
    records: Vec<T>,
}

impl<T: ServicePayload> ServiceReader<T> {
    /// Attaches to service `name` of `skin`.
    pub fn open(skin: &str, name: &str) -> Result<ServiceReader<T>> {
        ServiceReader::open_with(skin, name, &ReaderOptions::default())
    }

    /// Attaches with reader options (the expected schema is set from `T`).
    pub fn open_with(skin: &str, name: &str, options: &ReaderOptions) -> Result<ServiceReader<T>> {
        let (reader, info) = open_service_channel(
            skin,
            name,
            (T::SCHEMA, T::VERSION),
            (std::mem::size_of::<T>(), std::any::type_name::<T>()),
            options,
        )?;
        let count = reader.payload_bytes() / std::mem::size_of::<T>().max(1);
        Ok(ServiceReader { reader, info, records: vec![T::zeroed(); count] })
    }

    /// One label per record.
    pub fn labels(&self) -> &[String] {
        &self.info.labels
    }

    /// What the service declared.
    pub fn info(&self) -> &ServiceInfo {
        &self.info
    }

    /// The service's writer state.
    pub fn writer_state(&self) -> WriterState {
        self.reader.writer_state()
    }

    /// The untyped reader: statistics, stop signal, writer statistics.
    pub fn reader(&mut self) -> &mut Reader {
        &mut self.reader
    }

    /// The newest frame, now.
    pub fn latest(&mut self) -> Result<ServiceFrame<'_, T>> {
        let frame = self.reader.latest()?;
        Ok(copy_out(&frame, &mut self.records))
    }

    /// The next frame, as soon as it is published.
    pub fn wait_newer(&mut self, timeout: Duration) -> Result<ServiceFrame<'_, T>> {
        let frame = self.reader.wait_newer(timeout)?;
        Ok(copy_out(&frame, &mut self.records))
    }

    /// Asks a sporadic service for a frame and waits for it.
    pub fn request(&mut self, timeout: Duration) -> Result<ServiceFrame<'_, T>> {
        let frame = self.reader.request(timeout)?;
        Ok(copy_out(&frame, &mut self.records))
    }

    /// The newest frame at the ticker's next period.
    pub fn next_periodic(&mut self, ticker: &mut Ticker) -> Result<ServiceFrame<'_, T>> {
        let frame = self.reader.next_periodic(ticker)?;
        Ok(copy_out(&frame, &mut self.records))
    }
}

fn copy_out<'r, T: ServicePayload>(frame: &skinware::Frame<'_>, records: &'r mut [T]) -> ServiceFrame<'r, T> {
    // The frame's bytes may not be aligned for T: copy bytewise into aligned records.
    bytemuck::cast_slice_mut::<T, u8>(records).copy_from_slice(frame.bytes());
    ServiceFrame {
        seq: frame.seq(),
        acquired_ns: frame.acquired_ns(),
        published_ns: frame.published_ns(),
        status: frame.status(),
        fresh: frame.is_fresh(),
        records,
    }
}
