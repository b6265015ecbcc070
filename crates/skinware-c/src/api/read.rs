//! Readers (layers and services, every mode), tickers, and the listing of
//! channels.

use skinware::{ChannelKind, ReaderOptions, WriterState};
use skinware_services::framework::ServicePayload;
use skinware_services::{MotionRecord, RegionContacts};
use std::ffi::{c_char, c_void};

use super::*;
use crate::handles::{self, ReadMode, ReaderKind, ServiceCheck, Tick};

/// The state of a channel's writer.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum skinware_writer_state {
    /// Alive and publishing.
    SKINWARE_STATE_RUNNING = 0,
    /// Alive, not publishing on purpose.
    SKINWARE_STATE_PAUSED = 1,
    /// Alive, its source failed: frames carry `SKINWARE_FRAME_FAULT`.
    SKINWARE_STATE_FAULTED = 2,
    /// Its process is gone (readers keep the last frames and follow a successor).
    SKINWARE_STATE_GONE = 3,
}

impl From<WriterState> for skinware_writer_state {
    fn from(state: WriterState) -> skinware_writer_state {
        match state {
            WriterState::Running => skinware_writer_state::SKINWARE_STATE_RUNNING,
            WriterState::Paused => skinware_writer_state::SKINWARE_STATE_PAUSED,
            WriterState::Faulted => skinware_writer_state::SKINWARE_STATE_FAULTED,
            WriterState::Gone => skinware_writer_state::SKINWARE_STATE_GONE,
        }
    }
}

/// What a channel carries.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum skinware_channel_kind {
    /// A layer: one `uint16_t` response per sensor.
    SKINWARE_KIND_LAYER = 0,
    /// A service: records of its schema, one per label.
    SKINWARE_KIND_SERVICE = 1,
    /// A channel that cannot be read (`problem` says why).
    SKINWARE_KIND_UNREADABLE = 2,
}

impl From<Option<ChannelKind>> for skinware_channel_kind {
    fn from(kind: Option<ChannelKind>) -> skinware_channel_kind {
        match kind {
            Some(ChannelKind::Layer) => skinware_channel_kind::SKINWARE_KIND_LAYER,
            Some(ChannelKind::Service) => skinware_channel_kind::SKINWARE_KIND_SERVICE,
            None => skinware_channel_kind::SKINWARE_KIND_UNREADABLE,
        }
    }
}

/// A frame's status bit: the data is not valid (the driver failed).
pub const SKINWARE_FRAME_FAULT: u64 = 1;
/// A frame's status bit: part of the data is missing.
pub const SKINWARE_FRAME_PARTIAL: u64 = 2;
/// A frame's status bit (services): one of the service's inputs is faulted.
pub const SKINWARE_FRAME_INPUT_FAULTED: u64 = 4;

// The header's constants are literals (cbindgen writes what it reads); these
// keep them the exchange's.
const _: () = {
    assert!(SKINWARE_FRAME_FAULT == skinware::FrameStatus::FAULT.0);
    assert!(SKINWARE_FRAME_PARTIAL == skinware::FrameStatus::PARTIAL.0);
    assert!(SKINWARE_FRAME_INPUT_FAULTED == skinware::FrameStatus::INPUT_FAULTED.0);
};

/// How a reader attaches. A NULL options pointer means all zero.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_reader_options {
    /// Non-zero: attach even while the writer is stopping.
    pub allow_gone: i32,
    /// As-soon-as-available reads of a periodic writer wake this many ns
    /// before the next frame is due and spin until it is published, instead
    /// of sleeping until the writer wakes them; 0 (the default) never spins.
    /// At most 1 s (1000000000); tens of microseconds is usual.
    pub anticipate_ns: u64,
}

/// What a read says about the frame it copied.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_frame_info {
    /// Sequence number: 1 for the channel's first frame, +1 per frame.
    pub seq: u64,
    /// When the data was acquired (CLOCK_MONOTONIC ns, `skinware_monotonic_ns`).
    pub acquired_ns: u64,
    /// When the frame was published (CLOCK_MONOTONIC ns).
    pub published_ns: u64,
    /// Status bits: `SKINWARE_FRAME_FAULT`, ... (0: a good frame).
    pub status: u64,
    /// Frames published between this reader's previous frame and this one.
    pub skipped: u64,
    /// False when this is the frame the reader got last time.
    pub fresh: bool,
    /// The writer's state as of this read.
    pub writer_state: skinware_writer_state,
}

/// One tick of a ticker.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_tick {
    /// The deadline this tick stands for (CLOCK_MONOTONIC ns).
    pub deadline_ns: u64,
    /// How late after its deadline the wait returned, ns.
    pub lateness_ns: u64,
    /// Deadlines skipped because the caller was late.
    pub missed: u64,
    /// True if the caller came back after the deadline (an overrun).
    pub overrun: bool,
}

impl From<Tick> for skinware_tick {
    fn from(tick: Tick) -> skinware_tick {
        skinware_tick {
            deadline_ns: tick.deadline_ns,
            lateness_ns: tick.lateness_ns,
            missed: tick.missed,
            overrun: tick.overrun,
        }
    }
}

/// Everything a reader knows about its channel. The strings belong to the
/// reader and stay valid until it is closed.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_channel_description {
    /// The skin's name.
    pub skin: *const c_char,
    /// The channel's name (the layer or service).
    pub name: *const c_char,
    /// A layer or a service.
    pub kind: skinware_channel_kind,
    /// Bytes per frame: the buffer size reads need.
    pub payload_bytes: usize,
    /// Values per frame: a layer's sensors, a service's records.
    pub values: usize,
    /// Bytes per value: 2 for a layer (`uint16_t`), the record size for a service.
    pub value_bytes: usize,
    /// A layer's sensor type ("pressure"); NULL for a service.
    pub sensor_type: *const c_char,
    /// A service's schema name ("skinware.contacts"); NULL for a layer.
    pub schema_name: *const c_char,
    /// A service's schema version; 0 for a layer.
    pub schema_version: u32,
    /// A service's labels (one per record, `skinware_reader_label`); 0 for a layer.
    pub labels: usize,
    /// The writer's period, ns; 0 for a sporadic writer.
    pub period_ns: u64,
    /// Frame buffers in the channel.
    pub slots: usize,
    /// The writer's process id.
    pub writer_pid: u32,
    /// How many writers the channel has had (one more after each revival).
    pub generation: u64,
    /// The sequence number published last (0 before the first frame).
    pub published_seq: u64,
    /// The writer's state now.
    pub state: skinware_writer_state,
}

/// A reader's own statistics.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_reader_stats {
    /// Reads that returned a frame.
    pub reads: u64,
    /// Copies discarded because the writer lapped them.
    pub retries: u64,
    /// Frames skipped between reads.
    pub skipped: u64,
    /// Shortest read, ns.
    pub read_ns_min: u64,
    /// Mean read, ns.
    pub read_ns_mean: u64,
    /// Longest read, ns.
    pub read_ns_max: u64,
}

/// A writer's statistics, as the channel shows them to everyone.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_writer_stats {
    /// Frames published since the channel was created.
    pub frames: u64,
    /// Periods whose work did not finish before the next deadline.
    pub overruns: u64,
    /// Deadlines skipped because of overruns.
    pub missed_periods: u64,
    /// Faulted frames or failed acquisitions.
    pub faults: u64,
    /// Shortest time to fill and publish a frame, ns.
    pub write_ns_min: u64,
    /// Mean time to fill and publish a frame, ns.
    pub write_ns_mean: u64,
    /// Longest time to fill and publish a frame, ns.
    pub write_ns_max: u64,
    /// Mean lateness of a periodic writer's wake-up, ns.
    pub lateness_ns_mean: u64,
    /// Worst lateness of a periodic writer's wake-up, ns.
    pub lateness_ns_max: u64,
}

impl From<skinware::WriterStats> for skinware_writer_stats {
    fn from(s: skinware::WriterStats) -> skinware_writer_stats {
        skinware_writer_stats {
            frames: s.frames,
            overruns: s.overruns,
            missed_periods: s.missed_periods,
            faults: s.faults,
            write_ns_min: s.write_ns_min,
            write_ns_mean: s.write_ns_mean,
            write_ns_max: s.write_ns_max,
            lateness_ns_mean: s.lateness_ns_mean,
            lateness_ns_max: s.lateness_ns_max,
        }
    }
}

/// The longest anticipation a reader takes: it spins up to three times it per frame.
const MAX_ANTICIPATE_NS: u64 = 1_000_000_000;

fn reader_options(options: Option<&skinware_reader_options>, function: &str) -> Result<ReaderOptions, Failure> {
    let options = options.copied().unwrap_or_default();
    if options.anticipate_ns > MAX_ANTICIPATE_NS {
        return Err(Failure::invalid(
            function,
            format_args!(
                "anticipate_ns {}: give 0 (no spinning) or at most {MAX_ANTICIPATE_NS} ns; a reader spins up to three times it per frame (tens of microseconds is usual)",
                options.anticipate_ns
            ),
        ));
    }
    Ok(ReaderOptions {
        allow_gone: options.allow_gone != 0,
        anticipate: (options.anticipate_ns > 0).then(|| handles::timeout(options.anticipate_ns)),
        ..ReaderOptions::default()
    })
}

/// Opens a reader and hands it to C.
fn open_reader(
    function: &str,
    (skin, channel): (*const c_char, *const c_char),
    options: *const skinware_reader_options,
    service: Option<ServiceCheck<'_>>,
    reader: *mut *mut skinware_reader,
) -> skinware_status {
    entry(|| {
        let out = Out::new(reader, function, "reader")?;
        let skin = text(skin, function, "skin")?;
        let channel = text(channel, function, "channel")?;
        let options = reader_options(input(options, function, "options")?, function)?;
        let opened = ReaderHandle::open(skin, channel, &options, service)?;
        out.put(register(&READERS, opened, "reader")?);
        Ok(())
    })
}

/// Attaches to channel `channel` of skin `skin`, a layer or a service, whose
/// writer must be alive. `options` may be NULL. On success `*reader` is a new
/// reader: close it with `skinware_reader_close`. A missing channel is
/// `SKINWARE_E_NOT_FOUND`, with the names to check (`skin ls`).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_open(
    skin: *const c_char,
    channel: *const c_char,
    options: *const skinware_reader_options,
    reader: *mut *mut skinware_reader,
) -> skinware_status {
    open_reader("skinware_reader_open", (skin, channel), options, None, reader)
}

/// Attaches to service `name` of `skin` and checks that its records have
/// schema `schema` version `version` and `record_bytes` bytes each
/// (`SKINWARE_E_SCHEMA_MISMATCH` otherwise). For services skinware has no
/// type for; `skinware_contacts_open` and `skinware_motion_open` are this for
/// the contact and motion services.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_service_open(
    skin: *const c_char,
    name: *const c_char,
    schema: *const c_char,
    version: u32,
    record_bytes: usize,
    options: *const skinware_reader_options,
    reader: *mut *mut skinware_reader,
) -> skinware_status {
    let function = "skinware_service_open";
    let schema = match text(schema, function, "schema") {
        Ok(schema) => schema,
        Err(failure) => return guard(|| Err(failure)),
    };
    if record_bytes == 0 {
        return guard(|| Err(Failure::invalid(function, "record_bytes is 0; give the size of one record")));
    }
    let check = ServiceCheck { schema, version, record_bytes, record_type: "the caller's record" };
    open_reader(function, (skin, name), options, Some(check), reader)
}

/// Attaches to a contact service (`skin run`'s is named "contact"): its
/// frames are `skinware_region_contacts` records, one per region.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_contacts_open(
    skin: *const c_char,
    name: *const c_char,
    options: *const skinware_reader_options,
    reader: *mut *mut skinware_reader,
) -> skinware_status {
    let check = ServiceCheck {
        schema: RegionContacts::SCHEMA,
        version: RegionContacts::VERSION,
        record_bytes: size_of::<RegionContacts>(),
        record_type: "skinware_region_contacts",
    };
    open_reader("skinware_contacts_open", (skin, name), options, Some(check), reader)
}

/// Attaches to a motion service (`skin run`'s is named "motion"): its frames
/// are `skinware_motion_record` records, one per region.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_motion_open(
    skin: *const c_char,
    name: *const c_char,
    options: *const skinware_reader_options,
    reader: *mut *mut skinware_reader,
) -> skinware_status {
    let check = ServiceCheck {
        schema: MotionRecord::SCHEMA,
        version: MotionRecord::VERSION,
        record_bytes: size_of::<MotionRecord>(),
        record_type: "skinware_motion_record",
    };
    open_reader("skinware_motion_open", (skin, name), options, Some(check), reader)
}

/// Stops `reader` from any thread: a wait blocked in another thread returns
/// `SKINWARE_E_STOPPED` at once, and so does every later wait. A periodic
/// read in progress is woken by stopping its ticker too. Then close it.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_stop(reader: *const skinware_reader) -> skinware_status {
    entry(|| {
        live(&READERS, reader, "skinware_reader_stop", "reader")?.stop_all();
        Ok(())
    })
}

/// Detaches and frees `reader` (NULL is ignored). A call blocked on it in
/// another thread is stopped first and returns `SKINWARE_E_STOPPED`. The
/// handle is dead afterwards: using it again is refused with
/// `SKINWARE_E_INVALID_ARGUMENT`, and so is a second close.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_close(reader: *mut skinware_reader) -> skinware_status {
    entry(|| {
        if let Some(reader) = release(&READERS, reader, "skinware_reader_close", "reader")? {
            reader.stop_all();
        }
        Ok(())
    })
}

/// The reads' common part: checks, reads, fills `info`.
fn read_into(
    function: &str,
    reader: *const skinware_reader,
    mode: ReadMode,
    (buffer, buffer_bytes): (*mut c_void, usize),
    info: *mut skinware_frame_info,
) -> skinware_status {
    entry(|| {
        let info = Out::optional(info, function, "info")?;
        let reader = live(&READERS, reader, function, "reader")?;
        let buffer = super::buffer(buffer, buffer_bytes, function)?;
        let read = reader.read(mode, buffer)?;
        if let Some(info) = info {
            info.put(frame_info(&read.info, read.state));
        }
        Ok(())
    })
}

fn frame_info(info: &skinware::FrameInfo, state: WriterState) -> skinware_frame_info {
    skinware_frame_info {
        seq: info.seq,
        acquired_ns: info.acquired_ns,
        published_ns: info.published_ns,
        status: info.status.0,
        skipped: info.skipped,
        fresh: info.fresh,
        writer_state: state.into(),
    }
}

/// On request, now: copies the newest complete frame into `buffer` (at
/// least `payload_bytes` bytes; a layer's frame is one `uint16_t` per
/// sensor) and describes it in `*info` (NULL if not wanted). Lock-free
/// towards the writer: it never waits for it, and the writer never waits for
/// it (calls on one handle from several threads take turns). The buffer is
/// not to be touched by another thread during the call.
/// `SKINWARE_E_NO_FRAME_YET` before the first frame. After an error `buffer`
/// may hold a partial copy.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_latest(
    reader: *mut skinware_reader,
    buffer: *mut c_void,
    buffer_bytes: usize,
    info: *mut skinware_frame_info,
) -> skinware_status {
    read_into("skinware_reader_latest", reader, ReadMode::Latest, (buffer, buffer_bytes), info)
}

/// As soon as available: sleeps (on a futex, no spinning unless the reader
/// anticipates) until a frame newer than this reader's last one is
/// published, at most `timeout_ns`, then copies it as `skinware_reader_latest`
/// does. At the timeout: `SKINWARE_E_TIMEOUT` if the writer lives but
/// published nothing, `SKINWARE_E_WRITER_GONE` if it is gone (a successor
/// that appears meanwhile is followed, and its frame returned).
/// `SKINWARE_E_STOPPED` at once after `skinware_reader_stop`. A buffer
/// smaller than a frame is refused before the wait. Waits longer than a day
/// are cut to a day.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_wait_newer(
    reader: *mut skinware_reader,
    timeout_ns: u64,
    buffer: *mut c_void,
    buffer_bytes: usize,
    info: *mut skinware_frame_info,
) -> skinware_status {
    let mode = ReadMode::Newer(handles::timeout(timeout_ns));
    read_into("skinware_reader_wait_newer", reader, mode, (buffer, buffer_bytes), info)
}

/// On request, fresh: asks the writer for a frame newer than any published
/// now (a sporadic writer acquires one; a periodic writer's next frame
/// answers) and waits for it as `skinware_reader_wait_newer` does.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_request(
    reader: *mut skinware_reader,
    timeout_ns: u64,
    buffer: *mut c_void,
    buffer_bytes: usize,
    info: *mut skinware_frame_info,
) -> skinware_status {
    let mode = ReadMode::Request(handles::timeout(timeout_ns));
    read_into("skinware_reader_request", reader, mode, (buffer, buffer_bytes), info)
}

/// Periodic: sleeps until `ticker`'s next deadline (absolute time, no
/// drift), then copies the newest frame, fresh or not (`info->fresh`
/// tells), as `skinware_reader_latest` does. `*tick` (NULL if not wanted)
/// tells the deadline and how late the wake-up was. `skinware_reader_stop`
/// wakes it with `SKINWARE_E_STOPPED`. A gone writer is not an error here:
/// `info->writer_state` is `SKINWARE_STATE_GONE` and the frames are stale
/// until a successor publishes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_next_periodic(
    reader: *mut skinware_reader,
    ticker: *mut skinware_ticker,
    buffer: *mut c_void,
    buffer_bytes: usize,
    info: *mut skinware_frame_info,
    tick: *mut skinware_tick,
) -> skinware_status {
    let function = "skinware_reader_next_periodic";
    entry(|| {
        let info = Out::optional(info, function, "info")?;
        let tick = Out::optional(tick, function, "tick")?;
        let reader = live(&READERS, reader, function, "reader")?;
        let ticker = live(&TICKERS, ticker, function, "ticker")?;
        let buffer = super::buffer(buffer, buffer_bytes, function)?;
        let (read, reached) = reader.read_periodic(&ticker, buffer)?;
        if let Some(info) = info {
            info.put(frame_info(&read.info, read.state));
        }
        if let Some(tick) = tick {
            tick.put(reached.into());
        }
        Ok(())
    })
}

/// Describes the reader's channel in `*description`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_describe(
    reader: *const skinware_reader,
    description: *mut skinware_channel_description,
) -> skinware_status {
    let function = "skinware_reader_describe";
    entry(|| {
        let out = Out::new(description, function, "description")?;
        let reader = live(&READERS, reader, function, "reader")?;
        let core = skinware::lock(&reader.core);
        let payload_bytes = core.payload_bytes();
        let (kind, value_bytes, sensor_type, schema_name, schema_version, labels) = match &reader.kind {
            ReaderKind::Layer { sensor_type, .. } => {
                (skinware_channel_kind::SKINWARE_KIND_LAYER, 2, sensor_type.as_ptr(), std::ptr::null(), 0, 0)
            }
            ReaderKind::Service { info, schema_name, labels } => (
                skinware_channel_kind::SKINWARE_KIND_SERVICE,
                info.record_bytes.max(1),
                std::ptr::null(),
                schema_name.as_ptr(),
                info.schema.1,
                labels.len(),
            ),
        };
        out.put(skinware_channel_description {
            skin: reader.skin.as_ptr(),
            name: reader.name.as_ptr(),
            kind,
            payload_bytes,
            values: payload_bytes / value_bytes,
            value_bytes,
            sensor_type,
            schema_name,
            schema_version,
            labels,
            period_ns: core.writer_period().map_or(0, |p| p.as_nanos().min(u128::from(u64::MAX)) as u64),
            slots: core.slots(),
            writer_pid: core.writer_pid(),
            generation: core.writer_generation(),
            published_seq: core.published_seq(),
            state: core.writer_state().into(),
        });
        Ok(())
    })
}

/// The bytes a read's buffer needs (`payload_bytes`), in `*bytes`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_payload_bytes(
    reader: *const skinware_reader,
    bytes: *mut usize,
) -> skinware_status {
    let function = "skinware_reader_payload_bytes";
    entry(|| {
        let out = Out::new(bytes, function, "bytes")?;
        out.put(live(&READERS, reader, function, "reader")?.payload_bytes());
        Ok(())
    })
}

/// Label `index` of a service's records (e.g. a region's name) in `*label`,
/// valid until the reader is closed. `SKINWARE_E_NOT_FOUND` past the last.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_label(
    reader: *const skinware_reader,
    index: usize,
    label: *mut *const c_char,
) -> skinware_status {
    let function = "skinware_reader_label";
    entry(|| {
        let out = Out::new(label, function, "label")?;
        let reader = live(&READERS, reader, function, "reader")?;
        let ReaderKind::Service { labels, .. } = &reader.kind else {
            return Err(Failure::invalid(
                function,
                format_args!("{} is a layer; layers have no labels", reader.label()),
            ));
        };
        let found =
            labels.get(index).ok_or_else(|| handles::out_of_range("label", index, labels.len(), &reader.label()))?;
        out.put(found.as_ptr());
        Ok(())
    })
}

/// A layer reader's topology, as a new `skinware_topology` in `*topology`
/// (free it with `skinware_topology_free`; it outlives the reader).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_topology(
    reader: *const skinware_reader,
    topology: *mut *mut skinware_topology,
) -> skinware_status {
    let function = "skinware_reader_topology";
    entry(|| {
        let out = Out::new(topology, function, "topology")?;
        let reader = live(&READERS, reader, function, "reader")?;
        let ReaderKind::Layer { topology, .. } = &reader.kind else {
            return Err(Failure::invalid(
                function,
                format_args!("{} is a service; it has labels, not a topology", reader.label()),
            ));
        };
        out.put(register(&TOPOLOGIES, TopologyHandle::new(topology.clone()), "topology")?);
        Ok(())
    })
}

/// This reader's statistics in `*stats`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_get_stats(
    reader: *const skinware_reader,
    stats: *mut skinware_reader_stats,
) -> skinware_status {
    let function = "skinware_reader_get_stats";
    entry(|| {
        let out = Out::new(stats, function, "stats")?;
        let reader = live(&READERS, reader, function, "reader")?;
        let s = skinware::lock(&reader.core).stats().clone();
        out.put(skinware_reader_stats {
            reads: s.reads,
            retries: s.retries,
            skipped: s.skipped,
            read_ns_min: s.read_ns_min,
            read_ns_mean: s.read_ns_mean(),
            read_ns_max: s.read_ns_max,
        });
        Ok(())
    })
}

/// The channel's writer's statistics in `*stats`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_reader_get_writer_stats(
    reader: *const skinware_reader,
    stats: *mut skinware_writer_stats,
) -> skinware_status {
    let function = "skinware_reader_get_writer_stats";
    entry(|| {
        let out = Out::new(stats, function, "stats")?;
        let reader = live(&READERS, reader, function, "reader")?;
        out.put(skinware::lock(&reader.core).writer_stats().into());
        Ok(())
    })
}

/// A new ticker with period `period_ns` (1 µs to a day; 1000000 is 1 kHz),
/// whose first deadline is now. Free it with `skinware_ticker_free`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_ticker_new(period_ns: u64, ticker: *mut *mut skinware_ticker) -> skinware_status {
    let function = "skinware_ticker_new";
    entry(|| {
        let out = Out::new(ticker, function, "ticker")?;
        out.put(register(&TICKERS, TickerHandle::new(period_ns, function)?, "ticker")?);
        Ok(())
    })
}

/// Sleeps until the ticker's next deadline (for a writer's loop; readers use
/// `skinware_reader_next_periodic`). Deadlines already past are skipped and
/// counted in `tick->missed`. `*tick` may be NULL.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_ticker_wait(
    ticker: *mut skinware_ticker,
    tick: *mut skinware_tick,
) -> skinware_status {
    let function = "skinware_ticker_wait";
    entry(|| {
        let out = Out::optional(tick, function, "tick")?;
        let reached = live(&TICKERS, ticker, function, "ticker")?.wait()?;
        if let Some(out) = out {
            out.put(reached.into());
        }
        Ok(())
    })
}

/// Stops `ticker` from any thread: a `skinware_ticker_wait` or
/// `skinware_reader_next_periodic` blocked on it, and every later one, returns
/// `SKINWARE_E_STOPPED`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_ticker_stop(ticker: *const skinware_ticker) -> skinware_status {
    entry(|| {
        live(&TICKERS, ticker, "skinware_ticker_stop", "ticker")?.stop.stop();
        Ok(())
    })
}

/// Frees `ticker` (NULL is ignored); a wait blocked on it (either kind) is
/// stopped and returns `SKINWARE_E_STOPPED`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_ticker_free(ticker: *mut skinware_ticker) -> skinware_status {
    entry(|| {
        if let Some(ticker) = release(&TICKERS, ticker, "skinware_ticker_free", "ticker")? {
            ticker.stop.stop();
        }
        Ok(())
    })
}

/// One channel of a listing. The strings belong to the listing.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_channel_info {
    /// The skin's name.
    pub skin: *const c_char,
    /// The channel's name.
    pub name: *const c_char,
    /// A layer, a service, or unreadable (see `problem`).
    pub kind: skinware_channel_kind,
    /// The writer's state.
    pub state: skinware_writer_state,
    /// A layer's sensors; 0 for services.
    pub sensors: usize,
    /// Bytes per frame.
    pub payload_bytes: u64,
    /// Frames published.
    pub frames: u64,
    /// The current (or last) writer's process id.
    pub writer_pid: u32,
    /// How many writers the channel has had.
    pub generation: u64,
    /// Why the channel cannot be read; NULL if it can.
    pub problem: *const c_char,
}

/// Lists the channels of skin `skin`, or of every skin if `skin` is NULL,
/// sorted by skin and name, as `skin ls` does. Free `*list` with
/// `skinware_channel_list_free`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_list_channels(
    skin: *const c_char,
    list: *mut *mut skinware_channel_list,
) -> skinware_status {
    let function = "skinware_list_channels";
    entry(|| {
        let out = Out::new(list, function, "list")?;
        let skin = optional_text(skin, function, "skin")?;
        out.put(register(&LISTS, ChannelList::list(skin)?, "channel list")?);
        Ok(())
    })
}

/// The number of channels in `list`, in `*count`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_channel_list_len(
    list: *const skinware_channel_list,
    count: *mut usize,
) -> skinware_status {
    let function = "skinware_channel_list_len";
    entry(|| {
        let out = Out::new(count, function, "count")?;
        out.put(live(&LISTS, list, function, "channel list")?.channels.len());
        Ok(())
    })
}

/// Channel `index` of `list` in `*info`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_channel_list_get(
    list: *const skinware_channel_list,
    index: usize,
    info: *mut skinware_channel_info,
) -> skinware_status {
    let function = "skinware_channel_list_get";
    entry(|| {
        let out = Out::new(info, function, "info")?;
        let list = live(&LISTS, list, function, "channel list")?;
        let channel = list
            .channels
            .get(index)
            .ok_or_else(|| handles::out_of_range("channel", index, list.channels.len(), "the list"))?;
        let c = &channel.info;
        out.put(skinware_channel_info {
            skin: channel.skin.as_ptr(),
            name: channel.name.as_ptr(),
            kind: c.kind.into(),
            state: c.state.into(),
            sensors: if c.kind == Some(ChannelKind::Layer) { (c.payload_bytes / 2) as usize } else { 0 },
            payload_bytes: c.payload_bytes,
            frames: c.stats.frames,
            writer_pid: c.writer_pid,
            generation: c.generation,
            problem: channel.problem.as_ref().map_or(std::ptr::null(), |p| p.as_ptr()),
        });
        Ok(())
    })
}

/// Frees `list` (NULL is ignored) and the strings it lent.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_channel_list_free(list: *mut skinware_channel_list) -> skinware_status {
    entry(|| release(&LISTS, list, "skinware_channel_list_free", "channel list").map(drop))
}

/// A reasonable timeout for blocking calls, 1 s (the examples use it).
pub const SKINWARE_DEFAULT_TIMEOUT_NS: u64 = 1_000_000_000;
