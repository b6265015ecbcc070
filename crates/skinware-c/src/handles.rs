//! What the C API's handles hold, and everything they do, in safe Rust. The
//! `api` modules only turn C's pointers into the arguments of these.

#![forbid(unsafe_code)]

use std::ffi::CString;
use std::sync::Mutex;
use std::time::Duration;

use skinware::{
    Access, ChannelKind, FrameInfo, LayerTopology, ReaderOptions, Stop, Ticker, WriterOptions, WriterState,
};
use skinware_geometry::SkinGeometry;
use skinware_services::ServiceInfo;

use crate::status::Failure;
use crate::status::skinware_status::*;

/// A name from C as a `CString` for C to read back (names never hold NUL:
/// they came from C strings or were checked by skinware).
pub(crate) fn c_string(text: &str) -> CString {
    CString::new(text.replace('\0', "")).unwrap_or_default()
}

/// The longest wait a caller can ask for: a day. Longer waits are cut to it
/// (a caller that waits forever loops).
const LONGEST_WAIT: Duration = Duration::from_secs(86_400);

/// A timeout in nanoseconds from C.
pub(crate) fn timeout(ns: u64) -> Duration {
    Duration::from_nanos(ns).min(LONGEST_WAIT)
}

/// What a reader reads.
pub(crate) enum ReaderKind {
    Layer { topology: LayerTopology, sensor_type: CString },
    Service { info: ServiceInfo, schema_name: CString, labels: Vec<CString> },
}

/// An open reader (opaque to C).
pub(crate) struct ReaderHandle {
    pub(crate) core: Mutex<skinware::Reader>,
    /// Wakes a call blocked in another thread (`skinware_reader_stop`).
    pub(crate) stop: Stop,
    pub(crate) skin: CString,
    pub(crate) name: CString,
    pub(crate) kind: ReaderKind,
    /// When the kernel was last asked whether the writer lives (CLOCK_MONOTONIC
    /// ns), and what it said: asked at most once a millisecond.
    liveness: Mutex<(u64, WriterState)>,
    /// The stop of the ticker a periodic read is waiting on, if one is: a
    /// stop of the reader stops it too, so that either wakes that wait.
    periodic_wait: Mutex<Option<Stop>>,
}

/// How often a reader re-reading a stale frame asks the kernel whether its
/// writer still lives: a system call that would otherwise cost every
/// `skinware_reader_latest()` in a tight loop as much as half a frame's copy.
const LIVENESS_CHECK_NS: u64 = 1_000_000;

/// The read modes.
#[derive(Clone, Copy, Debug)]
pub(crate) enum ReadMode {
    Latest,
    Newer(Duration),
    Request(Duration),
}

/// A read's frame metadata and the writer's state.
pub(crate) struct Read {
    pub(crate) info: FrameInfo,
    pub(crate) state: WriterState,
}

/// A service to check at open: schema name, version and record size.
pub(crate) struct ServiceCheck<'a> {
    pub(crate) schema: &'a str,
    pub(crate) version: u32,
    pub(crate) record_bytes: usize,
    pub(crate) record_type: &'a str,
}

impl ReaderHandle {
    pub(crate) fn open(
        skin: &str,
        channel: &str,
        options: &ReaderOptions,
        service: Option<ServiceCheck<'_>>,
    ) -> Result<ReaderHandle, Failure> {
        let (mut reader, kind) = match service {
            Some(check) => {
                let (reader, info) = skinware_services::framework::open_service_channel(
                    skin,
                    channel,
                    (check.schema, check.version),
                    (check.record_bytes, check.record_type),
                    options,
                )?;
                (reader, service_kind(info))
            }
            None => {
                let reader = skinware::Reader::open_with(skin, channel, options)?;
                let kind = match reader.kind() {
                    ChannelKind::Layer => layer_kind(&reader)?,
                    ChannelKind::Service => {
                        let info = ServiceInfo::decode(&reader.description()).map_err(|e| {
                            Failure::new(
                                SKINWARE_E_CHANNEL,
                                format!("{skin}/{channel} is a service whose description cannot be read: {e}"),
                            )
                        })?;
                        service_kind(info)
                    }
                };
                (reader, kind)
            }
        };
        let stop = Stop::new();
        reader.set_stop(&stop);
        Ok(ReaderHandle {
            core: Mutex::new(reader),
            stop,
            skin: c_string(skin),
            name: c_string(channel),
            kind,
            liveness: Mutex::new((0, WriterState::Running)),
            periodic_wait: Mutex::new(None),
        })
    }

    pub(crate) fn label(&self) -> String {
        format!("{}/{}", self.skin.to_string_lossy(), self.name.to_string_lossy())
    }

    /// Reads in `mode` into `out` (at least the payload's bytes).
    pub(crate) fn read(&self, mode: ReadMode, out: &mut [u8]) -> Result<Read, Failure> {
        if !matches!(mode, ReadMode::Latest) {
            self.check_buffer(out)?;
        }
        let mut reader = skinware::lock(&self.core);
        let info = match mode {
            ReadMode::Latest => reader.latest_into(out)?,
            ReadMode::Newer(timeout) => reader.wait_newer_into(timeout, out)?,
            ReadMode::Request(timeout) => reader.request_into(timeout, out)?,
        };
        Ok(Read { info, state: self.state_after(&reader, &info) })
    }

    /// Waits for `ticker`'s next tick, then reads the newest frame into `out`.
    pub(crate) fn read_periodic(&self, ticker: &TickerHandle, out: &mut [u8]) -> Result<(Read, Tick), Failure> {
        self.check_buffer(out)?;
        let mut clock = skinware::lock(&ticker.core);
        // The wait watches the ticker's stop; `stop` below stops it too while
        // the wait lasts, so the reader's stop and the ticker's both end it.
        *skinware::lock(&self.periodic_wait) = Some(ticker.stop.clone());
        if self.stop.is_stopped() {
            ticker.stop.stop();
        }
        let tick = clock.wait(&ticker.stop);
        *skinware::lock(&self.periodic_wait) = None;
        let tick = tick.ok_or_else(|| {
            Failure::new(
                SKINWARE_E_STOPPED,
                format!("the periodic read of {} was stopped (its reader or its ticker)", self.label()),
            )
        })?;
        if self.stop.is_stopped() {
            return Err(Failure::new(SKINWARE_E_STOPPED, format!("the reader of {} was stopped", self.label())));
        }
        let mut reader = skinware::lock(&self.core);
        let info = reader.latest_into(out)?;
        Ok((Read { info, state: self.state_after(&reader, &info) }, Tick::from(tick)))
    }

    /// Stops every wait of this reader, now and later, and the ticker of a
    /// periodic read in progress.
    pub(crate) fn stop_all(&self) {
        self.stop.stop();
        if let Some(ticker) = skinware::lock(&self.periodic_wait).as_ref() {
            ticker.stop();
        }
    }

    /// Refuses a buffer smaller than a frame before any wait (a request
    /// would otherwise make a sporadic writer acquire for nothing).
    fn check_buffer(&self, out: &[u8]) -> Result<(), Failure> {
        let needed = self.payload_bytes();
        if out.len() < needed {
            return Err(skinware::Error::BufferTooSmall { channel: self.label(), needed, given: out.len() }.into());
        }
        Ok(())
    }

    pub(crate) fn payload_bytes(&self) -> usize {
        skinware::lock(&self.core).payload_bytes()
    }
}

impl ReaderHandle {
    /// The writer's state as a read leaves it: what the writer stored while
    /// its frames are new or at most two periods old (it was alive then);
    /// for an older frame, what the kernel says about its process, asked at
    /// most once a millisecond.
    fn state_after(&self, reader: &skinware::Reader, info: &FrameInfo) -> WriterState {
        if info.fresh {
            return reader.stored_writer_state();
        }
        let now = skinware::os::monotonic_ns();
        let period = reader.writer_period().map_or(0, |p| p.as_nanos().min(u128::from(u64::MAX)) as u64);
        if now.saturating_sub(info.published_ns) <= period.saturating_mul(2) {
            return reader.stored_writer_state();
        }
        let mut liveness = skinware::lock(&self.liveness);
        if now.saturating_sub(liveness.0) >= LIVENESS_CHECK_NS {
            *liveness = (now, reader.writer_state());
        }
        liveness.1
    }
}

fn layer_kind(reader: &skinware::Reader) -> Result<ReaderKind, Failure> {
    let label = reader.label().to_owned();
    let topology = reader.topology().map_err(|e| {
        Failure::new(SKINWARE_E_CHANNEL, format!("layer {label} has a topology that cannot be read: {e}"))
    })?;
    if topology.frame_bytes() != reader.payload_bytes() {
        return Err(Failure::new(
            SKINWARE_E_CHANNEL,
            format!(
                "layer {label} has {} sensors but {}-byte frames (2 bytes a sensor); its writer is broken",
                topology.sensors.len(),
                reader.payload_bytes()
            ),
        ));
    }
    let sensor_type = c_string(&topology.sensor_type);
    Ok(ReaderKind::Layer { topology, sensor_type })
}

fn service_kind(info: ServiceInfo) -> ReaderKind {
    let schema_name = c_string(&info.schema.0);
    let labels = info.labels.iter().map(|l| c_string(l)).collect();
    ReaderKind::Service { info, schema_name, labels }
}

/// A periodic schedule on absolute time (opaque to C).
pub(crate) struct TickerHandle {
    pub(crate) core: Mutex<Ticker>,
    pub(crate) stop: Stop,
}

/// One tick of a ticker, as C sees it.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Tick {
    pub(crate) deadline_ns: u64,
    pub(crate) lateness_ns: u64,
    pub(crate) missed: u64,
    pub(crate) overrun: bool,
}

impl From<skinware::Tick> for Tick {
    fn from(tick: skinware::Tick) -> Tick {
        Tick {
            deadline_ns: tick.deadline_ns,
            lateness_ns: tick.lateness_ns,
            missed: tick.missed,
            overrun: tick.overrun,
        }
    }
}

/// The shortest period a ticker takes: 1 µs (1 MHz).
pub(crate) const MIN_PERIOD_NS: u64 = 1_000;
/// The longest: a day.
pub(crate) const MAX_PERIOD_NS: u64 = 86_400_000_000_000;

impl TickerHandle {
    pub(crate) fn new(period_ns: u64, function: &str) -> Result<TickerHandle, Failure> {
        if !(MIN_PERIOD_NS..=MAX_PERIOD_NS).contains(&period_ns) {
            return Err(Failure::invalid(
                function,
                format_args!(
                    "a period of {period_ns} ns; give {MIN_PERIOD_NS} ns (1 MHz) to {MAX_PERIOD_NS} ns (a day), e.g. 1000000 for 1 kHz"
                ),
            ));
        }
        Ok(TickerHandle { core: Mutex::new(Ticker::new(Duration::from_nanos(period_ns))), stop: Stop::new() })
    }

    pub(crate) fn wait(&self) -> Result<Tick, Failure> {
        let mut ticker = skinware::lock(&self.core);
        ticker
            .wait(&self.stop)
            .map(Tick::from)
            .ok_or_else(|| Failure::new(SKINWARE_E_STOPPED, "the ticker was stopped (skinware_ticker_stop)"))
    }
}

/// A layer's topology (opaque to C).
pub(crate) struct TopologyHandle {
    pub(crate) inner: LayerTopology,
    pub(crate) name: CString,
    pub(crate) sensor_type: CString,
}

impl TopologyHandle {
    pub(crate) fn new(inner: LayerTopology) -> TopologyHandle {
        let (name, sensor_type) = (c_string(&inner.name), c_string(&inner.sensor_type));
        TopologyHandle { inner, name, sensor_type }
    }
}

/// A topology being built by a C driver (opaque to C).
pub(crate) struct BuilderHandle {
    pub(crate) inner: Mutex<(skinware::TopologyBuilder, Option<u32>)>,
}

impl BuilderHandle {
    pub(crate) fn add_module(&self, patch_id: u32, module_id: u32, uids: &[u32]) {
        let mut guard = skinware::lock(&self.inner);
        let (builder, current_patch) = &mut *guard;
        if *current_patch != Some(patch_id) {
            builder.patch(patch_id);
            *current_patch = Some(patch_id);
        }
        builder.module(module_id, uids.iter().copied());
    }

    pub(crate) fn build(&self) -> Result<TopologyHandle, Failure> {
        let guard = skinware::lock(&self.inner);
        let topology = guard.0.build().map_err(|e| Failure::invalid("skinware_topology_builder_build", e))?;
        Ok(TopologyHandle::new(topology))
    }
}

/// Checks a layer's rate as C gave it.
pub(crate) fn rate(hz: f64, function: &str) -> Result<f64, Failure> {
    if hz.is_finite() && (hz == 0.0 || (0.001..=1e6).contains(&hz)) {
        Ok(hz)
    } else {
        Err(Failure::invalid(function, format_args!("a rate of {hz} Hz; give 0 (sporadic) or 0.001 to 1000000 Hz")))
    }
}

/// A layer's writer (opaque to C).
pub(crate) struct WriterHandle {
    pub(crate) core: Mutex<skinware::Writer>,
    pub(crate) stop: Stop,
    pub(crate) topology: LayerTopology,
    pub(crate) period: Option<Duration>,
    pub(crate) label: String,
}

/// Options of a writer, checked.
pub(crate) struct WriterChoices {
    pub(crate) slots: usize,
    pub(crate) access: Access,
}

impl WriterHandle {
    pub(crate) fn create(
        skin: &str,
        layer: &str,
        topology: &LayerTopology,
        choices: WriterChoices,
    ) -> Result<WriterHandle, Failure> {
        let mut layout = topology.clone();
        layout.name = layer.to_owned();
        // A topology copied from another writer's channel carries whatever
        // rate that channel says: checked again here.
        layout.rate_hz = rate(layout.rate_hz, "skinware_writer_create")?;
        let period = (layout.rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / layout.rate_hz));
        let options =
            WriterOptions { slots: choices.slots, period, access: choices.access, ..WriterOptions::default() };
        let mut writer = skinware::Writer::create(skin, layer, layout.frame_bytes(), &layout.encode(), &options)?;
        let stop = Stop::new();
        writer.set_stop(&stop);
        let label = writer.label().to_owned();
        Ok(WriterHandle { core: Mutex::new(writer), stop, topology: layout, period, label })
    }

    pub(crate) fn publish(&self, responses: &[u16], status: u64, acquired_ns: u64) -> Result<u64, Failure> {
        let sensors = self.topology.sensors.len();
        if responses.len() != sensors {
            return Err(Failure::invalid(
                "skinware_writer_publish",
                format_args!("layer {} has {sensors} sensors, {} responses given", self.label, responses.len()),
            ));
        }
        let mut writer = skinware::lock(&self.core);
        let mut frame = writer.begin();
        frame.write_responses(0, responses)?;
        frame.set_status(skinware::FrameStatus(status));
        if acquired_ns != 0 {
            frame.set_acquired_ns(acquired_ns);
        }
        Ok(frame.publish())
    }

    pub(crate) fn wait_request(&self, timeout: Duration) -> Result<bool, Failure> {
        let mut writer = skinware::lock(&self.core);
        Ok(writer.wait_request(timeout)?)
    }
}

/// The skin's geometry (opaque to C).
pub(crate) struct GeometryHandle {
    pub(crate) inner: SkinGeometry,
    pub(crate) skin: CString,
    pub(crate) layer_names: Vec<CString>,
    pub(crate) link_names: Vec<CString>,
    pub(crate) region_names: Vec<CString>,
}

impl GeometryHandle {
    pub(crate) fn open(skin: &str) -> Result<GeometryHandle, Failure> {
        let inner = SkinGeometry::open(skin)?;
        Ok(GeometryHandle {
            skin: c_string(&inner.skin),
            layer_names: inner.layers.iter().map(|l| c_string(&l.name)).collect(),
            link_names: inner.links.iter().map(|l| c_string(l)).collect(),
            region_names: inner.regions.names.iter().map(|n| c_string(n)).collect(),
            inner,
        })
    }
}

/// One channel as `skin ls` lists it, with its names kept for C.
pub(crate) struct ListedChannel {
    pub(crate) info: skinware::ChannelInfo,
    pub(crate) skin: CString,
    pub(crate) name: CString,
    pub(crate) problem: Option<CString>,
}

/// A listing of channels (opaque to C).
pub(crate) struct ChannelList {
    pub(crate) channels: Vec<ListedChannel>,
}

impl ChannelList {
    pub(crate) fn list(skin: Option<&str>) -> Result<ChannelList, Failure> {
        let dir = skinware::shm::segment_dir();
        let listed = skinware::list_channels_where(&dir, skin, |_| true)?;
        let channels = listed
            .into_iter()
            .filter(|c| skin.is_none_or(|s| s == c.skin))
            .map(|info| ListedChannel {
                skin: c_string(&info.skin),
                name: c_string(&info.channel),
                problem: info.problem.as_deref().map(c_string),
                info,
            })
            .collect();
        Ok(ChannelList { channels })
    }
}

/// Checks a number of frame buffers from C (0: the default).
pub(crate) fn slots(slots: usize) -> Result<usize, Failure> {
    match slots {
        0 => Ok(skinware::DEFAULT_SLOTS),
        s if (skinware::MIN_SLOTS..=skinware::MAX_SLOTS).contains(&s) => Ok(s),
        s => Err(Failure::invalid(
            "skinware_writer_create",
            format_args!("{s} slots; give 0 (the default, 3) or {} to {}", skinware::MIN_SLOTS, skinware::MAX_SLOTS),
        )),
    }
}

/// The sensors of a uniform topology, checked.
pub(crate) fn uniform_sensors(patches: u32, modules: u32, sensors: u32) -> Result<u128, Failure> {
    // u128: three u32 factors cannot overflow it.
    let total = u128::from(patches) * u128::from(modules) * u128::from(sensors);
    if total == 0 || total > 1 << 24 {
        return Err(Failure::invalid(
            "skinware_topology_uniform",
            format_args!(
                "{total} sensors; give at least one patch, module and sensor, and at most 16777216 sensors in all"
            ),
        ));
    }
    Ok(total)
}

/// The writer states C may set, from their codes.
pub(crate) fn settable_state(code: i32) -> Result<WriterState, Failure> {
    match code {
        0 => Ok(WriterState::Running),
        1 => Ok(WriterState::Paused),
        2 => Ok(WriterState::Faulted),
        other => Err(Failure::invalid(
            "skinware_writer_set_state",
            format_args!(
                "state {other}; a writer can be SKINWARE_STATE_RUNNING (0), SKINWARE_STATE_PAUSED (1) or SKINWARE_STATE_FAULTED (2)"
            ),
        )),
    }
}

/// The access modes, from their codes.
pub(crate) fn access(code: i32) -> Result<Access, Failure> {
    match code {
        0 => Ok(Access::Owner),
        1 => Ok(Access::Group),
        2 => Ok(Access::Everyone),
        other => Err(Failure::invalid(
            "skinware_writer_create",
            format_args!(
                "access {other}; give SKINWARE_ACCESS_OWNER (0), SKINWARE_ACCESS_GROUP (1) or SKINWARE_ACCESS_EVERYONE (2)"
            ),
        )),
    }
}

/// A name not found among `names`, and what the names are.
pub(crate) fn unknown(what: &str, name: &str, of: &str, names: impl Iterator<Item = String>) -> Failure {
    let names: Vec<String> = names.collect();
    Failure::not_found(format!("{of} has no {what} {name:?}; its {what}s are {names:?}"))
}

/// An index past the end.
pub(crate) fn out_of_range(what: &str, index: usize, count: usize, of: &str) -> Failure {
    Failure::not_found(format!("{what} {index}: {of} has {count} (indices 0 to {})", count.saturating_sub(1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tickers_refuse_periods_outside_a_microsecond_to_a_day() {
        assert!(TickerHandle::new(999, "t").is_err());
        assert!(TickerHandle::new(MAX_PERIOD_NS + 1, "t").is_err());
        assert!(TickerHandle::new(1_000_000, "t").is_ok());
    }

    #[test]
    fn rates_slots_states_and_access_are_checked() {
        assert!(rate(f64::NAN, "f").is_err());
        assert!(rate(-1.0, "f").is_err());
        assert!(rate(1e7, "f").is_err());
        assert_eq!(rate(0.0, "f").unwrap(), 0.0);
        assert_eq!(slots(0).unwrap(), skinware::DEFAULT_SLOTS);
        assert!(slots(1).is_err());
        assert!(settable_state(3).is_err(), "gone is not a state a writer sets");
        assert!(access(-1).is_err());
        assert!(uniform_sensors(0, 1, 1).is_err());
        assert!(uniform_sensors(u32::MAX, u32::MAX, u32::MAX).is_err());
    }
}
