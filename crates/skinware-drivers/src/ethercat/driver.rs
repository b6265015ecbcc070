//! The EtherCAT skin driver: a bus thread runs ethercrab (bring-up to OP,
//! then one process-data exchange per segment and cycle) and keeps each
//! segment's newest inputs; each layer's acquisition copies its segment's.
//!
//! Faults, and what they fault:
//! * a segment's frame lost, its working counter wrong, or its state not
//!   OP: that segment's layer, from the cycle it is seen; a segment in
//!   SAFE-OP with its error flag set is asked back to OP (acknowledging the
//!   error) at most every 100 ms;
//! * every frame lost for a while (a pulled cable), the frame I/O ending, a
//!   segment fallen back to INIT or PRE-OP (it lost its configuration), or a
//!   bring-up that fails: every layer, and the bus is brought up again from
//!   scratch, with backoff.

use std::cell::Cell;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::task::Poll;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ethercrab::error::Error as EthercrabError;
use ethercrab::subdevice_group::{Op, PreOp};
use ethercrab::{
    DefaultLock, MainDevice, MainDeviceConfig, PduStorage, RetryBehaviour, SubDeviceGroup, SubDeviceState, Timeouts,
};
use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::{FrameWriter, LayerTopology};

use super::config::{EthercatDriverConfig, expected_working_counter};
use super::link::{self, FrameLink};
use super::{
    COMMAND_ACQUIRE, CONFIG_BASELINE, INPUTS_HEADER_BYTES, MAX_SEGMENTS, MAX_TAXELS, OUTPUTS_BYTES, STATUS_ACQUIRING,
    STATUS_UNKNOWN_COMMAND,
};

/// Frames in flight at most.
const FRAMES: usize = 16;
/// Process data per frame: a full 1,500-byte Ethernet payload less the
/// EtherCAT header (2), one datagram header (10) and working counter (2).
const FRAME_PROCESS_DATA: usize = 1486;
const FRAME_BYTES: usize = PduStorage::element_size(FRAME_PROCESS_DATA);
/// A group's process image: one segment's inputs and outputs.
const GROUP_PDI: usize = INPUTS_HEADER_BYTES + 2 * MAX_TAXELS + OUTPUTS_BYTES;
/// ethercrab's SubDevice capacity at bring-up (a power of two, as its map needs).
const INIT_CAPACITY: usize = MAX_SEGMENTS;
/// A segment in SAFE-OP with an error is asked back to OP at most this often.
const ACKNOWLEDGE_EVERY: Duration = Duration::from_millis(100);
/// The bus counts as down when every frame is lost for this many periods
/// (and at least `LINK_DOWN_MIN`).
const LINK_DOWN_PERIODS: u32 = 10;
const LINK_DOWN_MIN: Duration = Duration::from_millis(20);
const MIN_BACKOFF: Duration = Duration::from_millis(100);
const MAX_BACKOFF: Duration = Duration::from_secs(2);
/// How often a wait that stop cuts short looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(5);
/// A layer whose segment has given nothing new for this many periods fails.
const STALE_PERIODS: u32 = 2;

type PreOpGroup = SubDeviceGroup<1, GROUP_PDI, DefaultLock, PreOp>;
type OpGroup = SubDeviceGroup<1, GROUP_PDI, DefaultLock, Op>;

/// What the driver knows of one segment, for status displays.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SegmentStatus {
    /// Vendor ID, product code, revision and serial it reported, once seen.
    pub identity: Option<[u32; 4]>,
    /// Its name (the SII's order code).
    pub name: String,
    /// Its AL state as last seen (`INIT`, `PRE-OP`, `SAFE-OP`, `OP`, …).
    pub state: String,
    /// Why its layer is faulted, if it is.
    pub fault: Option<String>,
    /// Cycles whose data it delivered.
    pub cycles: u64,
    /// Its last sample counter.
    pub counter: u16,
    /// Faults it has had: lost frames, wrong working counters, states
    /// other than OP (a fault lasting several cycles counts once).
    pub faults: u64,
    /// When its newest good sample arrived, CLOCK_MONOTONIC ns; 0 before
    /// the first. A bus that has stopped cycling shows here, whatever the
    /// state last seen says.
    pub newest_sample_ns: u64,
}

/// One segment's newest inputs.
struct SegmentImage {
    values: Vec<u16>,
    /// When they arrived, CLOCK_MONOTONIC ns (0: never).
    acquired_ns: u64,
    status: SegmentStatus,
    /// Faults begun so far, and the newest one's reason: a fault that is
    /// over before the layer's writer looks (one cycle long, with the writer
    /// not scheduled in that period) is still reported, once.
    faults_begun: u64,
    newest_fault: String,
}

/// What the bus thread shares with the layers.
struct Shared {
    segments: Vec<Mutex<SegmentImage>>,
    /// One per segment: notified when its image has a new cycle or a new
    /// fault, or the bus a new fault.
    news: Vec<Condvar>,
    /// Why the whole bus is down, while it is.
    bus_fault: Mutex<Option<String>>,
    /// One per segment: where its layer writer is, for the schedule of the
    /// segment's cycles.
    writers: Vec<WriterFollow>,
}

/// What a segment's layer writer tells the bus thread, so that each cycle
/// ends just before the acquisition that takes its sample.
#[derive(Debug, Default)]
struct WriterFollow {
    /// Period deadline of its newest acquisition, CLOCK_MONOTONIC ns; 0
    /// before the first.
    deadline_ns: AtomicU64,
    /// Whether it is in an acquisition now.
    acquiring: AtomicBool,
    /// The cycle whose sample it took last.
    taken_cycle: AtomicU64,
}

impl WriterFollow {
    fn view(&self) -> WriterView {
        // Acquire: pairs with the Release stores of `acquiring`, so that the
        // deadline read is at least the one stored before it.
        let acquiring = self.acquiring.load(Ordering::Acquire);
        WriterView {
            deadline_ns: self.deadline_ns.load(Ordering::Relaxed),
            acquiring,
            taken_cycle: self.taken_cycle.load(Ordering::Relaxed),
        }
    }
}

/// A look at a [`WriterFollow`] (the three may be from moments a few
/// nanoseconds apart: a mistimed cycle is the worst that comes of it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct WriterView {
    deadline_ns: u64,
    acquiring: bool,
    taken_cycle: u64,
}

impl Shared {
    fn segment(&self, position: usize) -> std::sync::MutexGuard<'_, SegmentImage> {
        skinware::lock(&self.segments[position])
    }

    fn set_bus_fault(&self, fault: Option<String>) {
        let mut bus = skinware::lock(&self.bus_fault);
        if *bus != fault {
            match &fault {
                Some(why) => tracing::warn!(error = %why, "EtherCAT bus down"),
                None => tracing::info!("EtherCAT bus up"),
            }
            *bus = fault;
            drop(bus);
            self.news.iter().for_each(Condvar::notify_all);
        }
    }

    fn set_fault(&self, position: usize, fault: Option<String>) {
        let mut image = self.segment(position);
        if image.status.fault != fault {
            match &fault {
                Some(why) => tracing::warn!(segment = position, error = %why, "segment faulted"),
                None => tracing::info!(segment = position, "segment running"),
            }
            if let Some(why) = &fault {
                image.faults_begun += 1;
                image.newest_fault.clone_from(why);
            }
            image.status.fault = fault;
            drop(image);
            self.news[position].notify_all();
        }
    }
}

/// The EtherCAT skin driver: one layer per segment.
pub struct EthercatDriver {
    config: EthercatDriverConfig,
    link: FrameLink,
    topologies: Vec<LayerTopology>,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl EthercatDriver {
    /// Checks the settings and builds the layers' topologies; nothing is
    /// opened yet.
    pub fn new(config: EthercatDriverConfig, link: FrameLink) -> Result<EthercatDriver, super::EthercatConfigError> {
        config.check()?;
        let topologies = (0..config.segments.len()).map(|p| config.topology(p)).collect::<Result<Vec<_>, _>>()?;
        let shared = Arc::new(Shared {
            segments: config
                .segments
                .iter()
                .map(|s| {
                    Mutex::new(SegmentImage {
                        values: vec![0; s.taxels],
                        acquired_ns: 0,
                        status: SegmentStatus::default(),
                        faults_begun: 0,
                        newest_fault: String::new(),
                    })
                })
                .collect(),
            news: config.segments.iter().map(|_| Condvar::new()).collect(),
            bus_fault: Mutex::new(Some("not brought up yet".into())),
            writers: config.segments.iter().map(|_| WriterFollow::default()).collect(),
        });
        Ok(EthercatDriver { config, link, topologies, shared, stop: Arc::new(AtomicBool::new(false)), thread: None })
    }

    /// A handle on the segments' status that outlives handing the driver to
    /// a driver handler (for `skin ls`, for tests).
    pub fn status_handle(&self) -> EthercatStatus {
        EthercatStatus::new(self.shared.clone())
    }
}

/// What an EtherCAT driver knows of its bus, readable from any thread.
///
/// The bus and layer threads hold the locks it reads at real-time priority,
/// so it never waits for them: it only tries each lock, and a segment that
/// is busy at that moment keeps its previous snapshot.
#[derive(Clone)]
pub struct EthercatStatus {
    shared: Arc<Shared>,
    snapshot: Arc<Mutex<StatusSnapshot>>,
}

/// The newest status an [`EthercatStatus`] could read.
#[derive(Default)]
struct StatusSnapshot {
    segments: Vec<SegmentStatus>,
    bus_fault: Option<String>,
}

impl EthercatStatus {
    fn new(shared: Arc<Shared>) -> EthercatStatus {
        let snapshot = StatusSnapshot {
            segments: vec![SegmentStatus::default(); shared.segments.len()],
            bus_fault: Some("not brought up yet".into()),
        };
        EthercatStatus { shared, snapshot: Arc::new(Mutex::new(snapshot)) }
    }

    /// Each segment's identity, state, fault and newest sample, in ring order.
    pub fn segments(&self) -> Vec<SegmentStatus> {
        let mut snapshot = skinware::lock(&self.snapshot);
        for (position, segment) in self.shared.segments.iter().enumerate() {
            let image = match segment.try_lock() {
                Ok(image) => image,
                Err(std::sync::TryLockError::Poisoned(poisoned)) => poisoned.into_inner(),
                Err(std::sync::TryLockError::WouldBlock) => continue,
            };
            let mut status = image.status.clone();
            status.faults = image.faults_begun;
            status.newest_sample_ns = image.acquired_ns;
            drop(image);
            snapshot.segments[position] = status;
        }
        snapshot.segments.clone()
    }

    /// Why the whole bus is down, if it is.
    pub fn bus_fault(&self) -> Option<String> {
        let mut snapshot = skinware::lock(&self.snapshot);
        match self.shared.bus_fault.try_lock() {
            Ok(fault) => snapshot.bus_fault.clone_from(&fault),
            Err(std::sync::TryLockError::Poisoned(poisoned)) => snapshot.bus_fault.clone_from(&poisoned.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => {}
        }
        snapshot.bus_fault.clone()
    }
}

impl Driver for EthercatDriver {
    fn name(&self) -> &str {
        &self.config.name
    }

    fn layers(&self) -> Vec<LayerSpec> {
        self.topologies
            .iter()
            .map(|topology| LayerSpec { topology: topology.clone(), rt: self.config.rt.clone() })
            .collect()
    }

    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError> {
        self.stop.store(false, Ordering::Relaxed);
        let bus = Bus {
            config: self.config.clone(),
            link: self.link.clone(),
            shared: self.shared.clone(),
            stop: self.stop.clone(),
        };
        self.thread = Some(
            std::thread::Builder::new()
                .name(format!("ethercat-{}", self.config.name))
                .spawn(move || bus.run())
                .map_err(|e| format!("cannot start the EtherCAT bus thread: {e}"))?,
        );
        let stale_after = self.config.period() * STALE_PERIODS;
        Ok((0..self.config.segments.len())
            .map(|position| {
                Box::new(SegmentLayer {
                    shared: self.shared.clone(),
                    position,
                    stale_after,
                    last_cycle: 0,
                    faults_reported: 0,
                }) as Box<dyn LayerSource>
            })
            .collect())
    }

    fn stop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// A layer's acquisition: its segment's inputs of the next cycle, so that
/// every frame is a new sample (the writer's ticks and the bus cycles run at
/// the same rate but not in step).
struct SegmentLayer {
    shared: Arc<Shared>,
    position: usize,
    stale_after: Duration,
    /// The bus cycle whose data the last frame carried.
    last_cycle: u64,
    /// The segment's faults begun that a frame of this layer reported.
    faults_reported: u64,
}

impl LayerSource for SegmentLayer {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let shared = self.shared.clone();
        let follow = &shared.writers[self.position];
        if let Some(deadline) = frame.period_deadline_ns() {
            follow.deadline_ns.store(deadline, Ordering::Relaxed);
            follow.acquiring.store(true, Ordering::Release);
        }
        let result = self.take_sample(frame);
        follow.acquiring.store(false, Ordering::Release);
        result
    }
}

impl SegmentLayer {
    /// The acquisition: the segment's newest sample if this layer has not
    /// published it yet, else the next one (up to the staleness limit).
    fn take_sample(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let started = Instant::now();
        let mut image = self.shared.segment(self.position);
        loop {
            if let Some(why) = skinware::lock(&self.shared.bus_fault).as_ref() {
                // The bus fault covers the segments' faults before it.
                self.faults_reported = image.faults_begun;
                return Err(why.clone().into());
            }
            let unreported = image.faults_begun > self.faults_reported;
            self.faults_reported = image.faults_begun;
            if let Some(why) = &image.status.fault {
                return Err(format!("segment {}: {why}", self.position).into());
            }
            if unreported {
                return Err(format!("segment {}: {} (for a cycle or two)", self.position, image.newest_fault).into());
            }
            if image.status.cycles > self.last_cycle && image.acquired_ns != 0 {
                break;
            }
            // The layer fails once its newest data is 2 periods old (from
            // when this acquisition started if there is none yet), not 2
            // periods after this acquisition began waiting.
            let left = if image.acquired_ns == 0 {
                self.stale_after.saturating_sub(started.elapsed())
            } else {
                let age = skinware::os::monotonic_ns().saturating_sub(image.acquired_ns);
                Duration::from_nanos((self.stale_after.as_nanos() as u64).saturating_sub(age))
            };
            if left.is_zero() {
                let what = if image.acquired_ns == 0 { "no data yet".to_string() } else { "no new data".to_string() };
                return Err(
                    format!("segment {}: {what} within {} ms", self.position, self.stale_after.as_millis()).into()
                );
            }
            image = self.shared.news[self.position].wait_timeout(image, left).unwrap_or_else(|p| p.into_inner()).0;
        }
        self.last_cycle = image.status.cycles;
        self.shared.writers[self.position].taken_cycle.store(self.last_cycle, Ordering::Relaxed);
        frame.write_responses(0, &image.values)?;
        frame.set_acquired_ns(image.acquired_ns);
        Ok(())
    }
}

/// Lead of a cycle over the writer's deadline beyond twice the exchange's
/// own time: the bus thread's wake-up from its timer (a halted vCPU of a VM
/// takes 90-150 µs to run again).
const CYCLE_LEAD_MARGIN_NS: u64 = 150_000;

/// When a segment's cycles start: each one ends just before the layer
/// writer's acquisition that takes its sample, so that the acquisition finds
/// the sample waiting instead of waiting for the bus, and the sample is as
/// young as the bus allows. Without a periodic writer to follow, `None`: the
/// caller cycles on its own.
#[derive(Debug)]
struct CycleSchedule {
    period_ns: u64,
    /// Smoothed duration of one exchange (frame out and back), ns.
    exchange_ns: u64,
}

impl CycleSchedule {
    fn new(period: Duration) -> CycleSchedule {
        CycleSchedule { period_ns: (period.as_nanos() as u64).max(1), exchange_ns: 0 }
    }

    /// How far ahead of the writer's deadline a cycle starts.
    fn lead_ns(&self) -> u64 {
        (2 * self.exchange_ns + CYCLE_LEAD_MARGIN_NS).min(self.period_ns / 2)
    }

    /// The start of the next cycle, decided when the previous one, started
    /// at `started_ns`, has ended at `now_ns` (`answered`: its frame came
    /// back) and the segment has delivered `cycles` samples so far.
    fn next_start_ns(
        &mut self,
        started_ns: u64,
        now_ns: u64,
        answered: bool,
        writer: WriterView,
        cycles: u64,
    ) -> Option<u64> {
        // A lost frame's timeout is not the bus's usual time.
        if answered {
            let took = now_ns.saturating_sub(started_ns);
            self.exchange_ns = if self.exchange_ns == 0 { took } else { (7 * self.exchange_ns + took) / 8 };
        }
        // A writer not seen for a few periods (stopped, not started, not
        // periodic) is not followed.
        if writer.deadline_ns == 0 || now_ns.saturating_sub(writer.deadline_ns) > 4 * self.period_ns {
            return None;
        }
        let sample_waiting = cycles > writer.taken_cycle;
        // The period deadline whose acquisition the next sample is for.
        let serves = match (writer.acquiring, sample_waiting) {
            // It waits for a sample now: at once (a lost frame, a late bus).
            (true, false) => return Some(now_ns),
            // It is taking the one waiting, or took one for its deadline.
            (true, true) | (false, false) => writer.deadline_ns + self.period_ns,
            // The one waiting is for its next deadline.
            (false, true) => writer.deadline_ns + 2 * self.period_ns,
        };
        Some(serves.saturating_sub(self.lead_ns()).max(now_ns))
    }
}

/// The bus thread.
struct Bus {
    config: EthercatDriverConfig,
    link: FrameLink,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
}

impl Bus {
    fn run(self) {
        // The bus thread paces the acquisition: it runs with the layers'
        // real-time settings.
        for refused in self.config.rt.apply() {
            tracing::warn!(driver = %self.config.name, "bus thread: {refused}");
        }
        let mut backoff = MIN_BACKOFF;
        while !self.stop.load(Ordering::Relaxed) {
            let started = Instant::now();
            match self.session() {
                Ok(()) => {}
                Err(why) => {
                    for position in 0..self.config.segments.len() {
                        self.shared.segment(position).status.state = "unknown".into();
                    }
                    self.shared.set_bus_fault(Some(why));
                }
            }
            if started.elapsed() > MAX_BACKOFF * 4 {
                backoff = MIN_BACKOFF;
            }
            let until = Instant::now() + backoff;
            while !self.stop.load(Ordering::Relaxed) && Instant::now() < until {
                std::thread::sleep(Duration::from_millis(10));
            }
            backoff = (backoff * 2).min(MAX_BACKOFF);
        }
    }

    /// One life of the bus: ethercrab's storage, MainDevice and frame I/O,
    /// bring-up, then cycles until stopped or the bus fails.
    fn session(&self) -> Result<(), String> {
        let storage: Box<PduStorage<FRAMES, FRAME_BYTES>> = Box::new(PduStorage::new());
        let (tx, rx, pdu_loop) =
            storage.try_split().map_err(|()| "internal: EtherCAT frame storage split twice".to_string())?;
        let timeouts = Timeouts {
            pdu: self.config.frame_timeout(),
            // ethercrab's 10 ms bounds a whole SII round trip, which a loaded
            // host can exceed.
            eeprom: Duration::from_millis(200),
            state_transition: Duration::from_secs(5),
            ..Timeouts::default()
        };
        // No retries: a frame lost is a fault to report, not to hide.
        let config = MainDeviceConfig { retry_behaviour: RetryBehaviour::None, ..MainDeviceConfig::default() };
        let maindevice = MainDevice::new(pdu_loop, timeouts, config);
        let io_stop = AtomicBool::new(false);
        let io_ended = AtomicBool::new(false);
        std::thread::scope(|scope| {
            let io = std::thread::Builder::new()
                .name(format!("ethercat-io-{}", self.config.name))
                .spawn_scoped(scope, || {
                    let result = link::run(&self.link, tx, rx, &io_stop);
                    io_ended.store(true, Ordering::Release);
                    result
                })
                .map_err(|e| format!("cannot start the EtherCAT I/O thread: {e}"))?;
            let result = async_io::block_on(self.control(&maindevice, &io_ended));
            io_stop.store(true, Ordering::Release);
            io.thread().unpark();
            let io_result = io.join().unwrap_or_else(|_| Err("the EtherCAT I/O thread panicked".into()));
            // The frame I/O's own error first: a socket that could not open
            // (no CAP_NET_RAW) makes the bring-up time out, and that timeout
            // would hide the reason the user can act on.
            io_result.and(result)
        })
    }

    /// Brings the bus up, then cycles each segment in a loop of its own (all
    /// on this thread), so that a segment's lost frame stalls only its own
    /// cycles; a watcher ends the session when no segment answers any more.
    async fn control(&self, maindevice: &MainDevice<'_>, io_ended: &AtomicBool) -> Result<(), String> {
        // Raced against stop: a step of the bring-up may wait seconds (a
        // state transition, a frame timeout), and stop is not to wait with it.
        let bring_up = async { Some(self.bring_up(maindevice).await) };
        let stopped = async {
            self.stopped().await;
            None
        };
        let Some(groups) = futures_lite::future::or(bring_up, stopped).await else {
            return Ok(());
        };
        let groups = groups?;
        self.shared.set_bus_fault(None);
        let answered: Vec<Cell<Instant>> = groups.iter().map(|_| Cell::new(Instant::now())).collect();
        let mut tasks: Vec<Task<'_>> = groups
            .iter()
            .enumerate()
            .map(|(position, group)| {
                Box::pin(self.cycle_segment(maindevice, position, group, &answered[position])) as Pin<Box<_>>
            })
            .collect();
        tasks.push(Box::pin(self.watch_link(io_ended, &answered)));
        first_error(tasks).await
    }

    /// Ready once the driver is asked to stop.
    async fn stopped(&self) {
        while !self.stop.load(Ordering::Relaxed) {
            async_io::Timer::after(STOP_POLL).await;
        }
    }

    /// The cycles of one segment until stopped: outputs out, inputs in, its
    /// faults judged; `answered` is when its frame last came back.
    async fn cycle_segment(
        &self,
        maindevice: &MainDevice<'_>,
        position: usize,
        group: &OpGroup,
        answered: &Cell<Instant>,
    ) -> Result<(), String> {
        let segment = &self.config.segments[position];
        let expected = expected_working_counter(segment.taxels, FRAME_PROCESS_DATA);
        let period = self.config.period();
        let mut acknowledged_at: Option<Instant> = None;
        let mut last_state = SubDeviceState::Op;
        let mut next = Instant::now();
        let mut schedule = CycleSchedule::new(period);
        let subdevice = group.subdevice(maindevice, 0).map_err(|e| format!("segment {position}: {e}"))?;
        loop {
            if self.stop.load(Ordering::Relaxed) {
                // Farewell: stop acquiring, and back to INIT.
                subdevice.outputs_raw_mut()[..2].copy_from_slice(&0u16.to_le_bytes());
                let _ = group.tx_rx(maindevice).await;
                let _ = subdevice.register_write(0x0120u16, 0x0001u16).await;
                return Ok(());
            }
            {
                let mut outputs = subdevice.outputs_raw_mut();
                let config = if segment.baseline { CONFIG_BASELINE } else { 0 };
                outputs[..2].copy_from_slice(&COMMAND_ACQUIRE.to_le_bytes());
                outputs[2..4].copy_from_slice(&config.to_le_bytes());
            }
            let cycle_started_ns = skinware::os::monotonic_ns();
            let response = group.tx_rx(maindevice).await;
            let now_ns = skinware::os::monotonic_ns();
            let came_back = response.is_ok();
            match response {
                Err(EthercrabError::Timeout(_)) => {
                    let timeout = self.config.frame_timeout().as_secs_f64() * 1e3;
                    self.shared.set_fault(position, Some(format!("frame lost (no answer in {timeout:.1} ms)")));
                }
                Err(e) => self.shared.set_fault(position, Some(format!("process data exchange failed: {e}"))),
                Ok(response) => {
                    answered.set(Instant::now());
                    let state = response.subdevice_states.first().copied().unwrap_or(SubDeviceState::None);
                    if state != last_state {
                        // Only on a change: the cycle allocates nothing otherwise.
                        last_state = state;
                        self.shared.segment(position).status.state = state_name(state);
                    }
                    if state == SubDeviceState::Op {
                        if response.working_counter == expected {
                            self.take_inputs(position, &subdevice.inputs_raw(), now_ns);
                        } else {
                            self.shared.set_fault(
                                position,
                                Some(format!(
                                    "working counter {} instead of {expected}: the segment did not exchange its process data",
                                    response.working_counter
                                )),
                            );
                        }
                    } else {
                        self.shared.set_fault(position, Some(format!("in {} instead of OP", state_name(state))));
                        if state != SubDeviceState::SafeOp {
                            return Err(format!(
                                "segment {position} fell back to {}: configuring the bus again",
                                state_name(state)
                            ));
                        }
                        if acknowledged_at.is_none_or(|at| at.elapsed() >= ACKNOWLEDGE_EVERY) {
                            acknowledged_at = Some(Instant::now());
                            // OP, with the error acknowledged (bit 4).
                            let _ = subdevice.register_write(0x0120u16, 0x0018u16).await;
                        }
                    }
                }
            }
            let writer = self.shared.writers[position].view();
            let cycles = self.shared.segment(position).status.cycles;
            let now_ns = skinware::os::monotonic_ns();
            next = match schedule.next_start_ns(cycle_started_ns, now_ns, came_back, writer, cycles) {
                Some(start_ns) => Instant::now() + Duration::from_nanos(start_ns.saturating_sub(now_ns)),
                None => {
                    // No writer to follow (yet): cycle on our own.
                    let free = next + period;
                    let now = Instant::now();
                    // Late: skip the cycles missed rather than run them back to back.
                    if free < now { now } else { free }
                }
            };
            async_io::Timer::at(next).await;
        }
    }

    /// Takes one cycle's inputs of segment `position` into its image, or
    /// faults it if the segment says they are not good.
    fn take_inputs(&self, position: usize, inputs: &[u8], now_ns: u64) {
        let word = |k: usize| u16::from_le_bytes([inputs[2 * k], inputs[2 * k + 1]]);
        let (counter, status) = (word(0), word(1));
        let fault = if status & STATUS_UNKNOWN_COMMAND != 0 {
            Some(format!("the segment refused its command (status {status:#06x})"))
        } else if status & STATUS_ACQUIRING == 0 {
            Some("the segment is not acquiring (yet)".to_string())
        } else {
            None
        };
        {
            let mut image = self.shared.segment(position);
            if fault.is_none() {
                for (k, value) in image.values.iter_mut().enumerate() {
                    *value = word(2 + k);
                }
                image.acquired_ns = now_ns;
                image.status.cycles += 1;
            }
            image.status.counter = counter;
        }
        self.shared.set_fault(position, fault);
        self.shared.news[position].notify_all();
    }

    /// Ends the session when no segment has answered for a while (a pulled
    /// cable) or the frame I/O ended.
    async fn watch_link(&self, io_ended: &AtomicBool, answered: &[Cell<Instant>]) -> Result<(), String> {
        let period = self.config.period();
        let link_down_after = (period * LINK_DOWN_PERIODS).max(LINK_DOWN_MIN).max(self.config.frame_timeout() * 2);
        loop {
            if self.stop.load(Ordering::Relaxed) {
                return Ok(());
            }
            if io_ended.load(Ordering::Acquire) {
                return Err("the frame I/O ended".into());
            }
            let quiet = answered.iter().map(|at| at.get().elapsed()).min().unwrap_or_default();
            if quiet >= link_down_after {
                return Err(format!("no frame came back for {} ms: link down or cable pulled", quiet.as_millis()));
            }
            async_io::Timer::after(period.max(Duration::from_millis(1))).await;
        }
    }

    /// Init, identity and PDO checks, then OP; one ethercrab group per
    /// segment so that a fault is the segment's own.
    async fn bring_up(&self, maindevice: &MainDevice<'_>) -> Result<Vec<OpGroup>, String> {
        let segments = &self.config.segments;
        let groups: Vec<PreOpGroup> = (0..segments.len()).map(|_| SubDeviceGroup::default()).collect();
        let next = Cell::new(0usize);
        let too_many = Cell::new(false);
        let groups = maindevice
            .init::<INIT_CAPACITY, _>(
                || 0,
                groups,
                |groups: &Vec<PreOpGroup>, _subdevice| match groups.get(next.get()) {
                    Some(group) => {
                        next.set(next.get() + 1);
                        Ok(group)
                    }
                    None => {
                        too_many.set(true);
                        Err(EthercrabError::UnknownSubDevice)
                    }
                },
            )
            .await
            .map_err(|e| {
                if too_many.get() {
                    format!(
                        "the bus has more SubDevices than the {} segments configured; list them all",
                        segments.len()
                    )
                } else {
                    format!("bringing the bus up failed: {e}")
                }
            })?;
        let found = maindevice.num_subdevices();
        if found < segments.len() {
            return Err(format!("the bus has {found} SubDevices but {} segments are configured", segments.len()));
        }
        for (position, (group, segment)) in groups.iter().zip(segments).enumerate() {
            let subdevice = group.subdevice(maindevice, 0).map_err(|e| format!("segment {position}: {e}"))?;
            let identity = subdevice.identity();
            {
                let mut image = self.shared.segment(position);
                image.status.identity =
                    Some([identity.vendor_id, identity.product_id, identity.revision, identity.serial]);
                image.status.name = subdevice.name().to_string();
                image.status.state = "PRE-OP".into();
            }
            if (identity.vendor_id, identity.product_id) != (segment.vendor_id, segment.product_code) {
                return Err(format!(
                    "segment {position}: the SubDevice there is {} (vendor {:#010x}, product {:#010x}), \
                     but the config expects vendor {:#010x}, product {:#010x}",
                    subdevice.name(),
                    identity.vendor_id,
                    identity.product_id,
                    segment.vendor_id,
                    segment.product_code
                ));
            }
        }
        let mut operational = Vec::with_capacity(groups.len());
        for (position, (group, segment)) in groups.into_iter().zip(segments).enumerate() {
            let group = group.into_pre_op_pdi(maindevice).await.map_err(|e| format!("segment {position}: {e}"))?;
            {
                let subdevice = group.subdevice(maindevice, 0).map_err(|e| format!("segment {position}: {e}"))?;
                let (inputs, outputs) = (subdevice.inputs_raw().len(), subdevice.outputs_raw().len());
                if inputs != INPUTS_HEADER_BYTES + 2 * segment.taxels || outputs != OUTPUTS_BYTES {
                    return Err(format!(
                        "segment {position} ({}): its PDOs are {inputs} bytes of inputs and {outputs} of outputs, \
                         but {} taxels need {} and {OUTPUTS_BYTES}: check `taxels`",
                        subdevice.name(),
                        segment.taxels,
                        INPUTS_HEADER_BYTES + 2 * segment.taxels
                    ));
                }
            }
            let group = group.into_op(maindevice).await.map_err(|e| format!("segment {position}: to OP: {e}"))?;
            self.shared.segment(position).status.state = "OP".into();
            operational.push(group);
        }
        Ok(operational)
    }
}

fn state_name(state: SubDeviceState) -> String {
    match state {
        SubDeviceState::Init => "INIT".into(),
        SubDeviceState::PreOp => "PRE-OP".into(),
        SubDeviceState::SafeOp => "SAFE-OP".into(),
        SubDeviceState::Op => "OP".into(),
        SubDeviceState::Bootstrap => "BOOT".into(),
        SubDeviceState::None => "no state".into(),
        SubDeviceState::Other(code) => format!("state {code:#04x}"),
    }
}

/// One of the bus thread's concurrent loops.
type Task<'a> = Pin<Box<dyn Future<Output = Result<(), String>> + 'a>>;

/// Runs `tasks` together; ends with the first error, or when all are done.
async fn first_error(mut tasks: Vec<Task<'_>>) -> Result<(), String> {
    let mut done = vec![false; tasks.len()];
    std::future::poll_fn(|context| {
        let mut pending = false;
        for (task, done) in tasks.iter_mut().zip(done.iter_mut()) {
            if *done {
                continue;
            }
            match task.as_mut().poll(context) {
                Poll::Ready(Err(e)) => return Poll::Ready(Err(e)),
                Poll::Ready(Ok(())) => *done = true,
                Poll::Pending => pending = true,
            }
        }
        if pending { Poll::Pending } else { Poll::Ready(Ok(())) }
    })
    .await
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    /// A writer on time at every deadline (`deadline + lateness`), and a
    /// bus whose exchanges take `exchange` except the cycles `stalls` names
    /// (by index), which take that much longer; returns how long each of the
    /// writer's acquisitions waited for its sample.
    fn simulate(ticks: u64, lateness: u64, exchange: u64, stalls: &[(u64, u64)]) -> Vec<u64> {
        const PERIOD: u64 = MS;
        let mut schedule = CycleSchedule::new(Duration::from_nanos(PERIOD));
        let mut writer = WriterView::default();
        let (mut cycles, mut cycle_index) = (0u64, 0u64);
        let mut cycle_start = 0u64;
        let mut waits = Vec::new();
        let mut waiting_since = None;
        let mut next_tick = 10 * PERIOD;
        while waits.len() < ticks as usize {
            let stall = stalls.iter().find(|(k, _)| *k == cycle_index).map_or(0, |(_, s)| *s);
            let cycle_end = cycle_start + exchange + stall;
            if next_tick + lateness < cycle_end {
                // The writer's acquisition, before the cycle under way ends.
                writer.deadline_ns = next_tick;
                if cycles > writer.taken_cycle {
                    writer.taken_cycle = cycles;
                    waits.push(0);
                } else {
                    writer.acquiring = true;
                    waiting_since = Some(next_tick + lateness);
                }
                next_tick += PERIOD;
                continue;
            }
            // The cycle ends: the bus decides its next one before the
            // waiting writer wakes (as the bus thread runs on).
            cycles += 1;
            cycle_index += 1;
            let start = schedule.next_start_ns(cycle_start, cycle_end, true, writer, cycles);
            if let Some(since) = waiting_since.take() {
                writer.taken_cycle = cycles;
                writer.acquiring = false;
                waits.push(cycle_end - since);
            }
            cycle_start = start.unwrap_or(cycle_end + PERIOD / 3).max(cycle_end);
        }
        waits
    }

    #[test]
    fn after_a_stall_of_the_bus_the_writer_finds_its_sample_waiting_again() {
        // 150 µs exchanges, a writer 60 µs late at each deadline: once
        // followed, no acquisition waits.
        let waits = simulate(400, 60_000, 150_000, &[]);
        assert!(waits[20..].iter().all(|&w| w == 0), "{waits:?}");
        // A cycle 1.4 ms longer, then one 0.7 ms longer: a wait or two each,
        // then none again (a schedule that skipped a slot after a late
        // cycle would leave every later acquisition waiting).
        let waits = simulate(400, 60_000, 150_000, &[(100, 1_400_000), (200, 700_000)]);
        let waited: Vec<usize> = (20..waits.len()).filter(|&k| waits[k] > 0).collect();
        assert!(!waited.is_empty() && waited.len() <= 4, "acquisitions {waited:?} waited: {waits:?}");
    }

    #[test]
    fn cycles_end_just_before_the_acquisition_that_takes_them() {
        let mut schedule = CycleSchedule::new(Duration::from_millis(1));
        let writer = |deadline_ns, acquiring, taken_cycle| WriterView { deadline_ns, acquiring, taken_cycle };
        // No writer yet, or one not seen for a while: cycle on our own.
        assert_eq!(schedule.next_start_ns(100 * MS, 100 * MS + 60_000, true, WriterView::default(), 1), None);
        assert_eq!(schedule.next_start_ns(100 * MS, 100 * MS + 60_000, true, writer(90 * MS, false, 0), 1), None);
        let lead = 2 * 60_000 + CYCLE_LEAD_MARGIN_NS;
        assert_eq!(schedule.lead_ns(), lead);
        // The sample just delivered is for the writer's next deadline
        // (101.2 ms): the cycle after it ends before the one after (102.2).
        let d = 100 * MS + 200_000;
        let start = schedule.next_start_ns(101 * MS, 101 * MS + 60_000, true, writer(d, false, 7), 8).unwrap();
        assert_eq!(start, d + 2 * MS - lead);
        // The writer is taking it now: the next is for its next deadline.
        let start = schedule.next_start_ns(d - 10_000, d + 50_000, true, writer(d, true, 7), 8).unwrap();
        assert_eq!(start, d + MS - lead);
        // The writer waits for a sample (a lost frame, a late cycle): at once.
        let now = 101 * MS + 60_000;
        assert_eq!(schedule.next_start_ns(101 * MS, now, false, writer(d, true, 8), 8), Some(now));
        // That slot already passed: at once, not a period later.
        let late = d + MS - 10_000;
        assert_eq!(schedule.next_start_ns(late - 60_000, late, true, writer(d, false, 8), 8), Some(late));
    }

    #[test]
    fn a_lost_frame_is_not_the_bus_usual_time_and_the_lead_is_at_most_half_a_period() {
        let mut schedule = CycleSchedule::new(Duration::from_millis(1));
        schedule.next_start_ns(0, 50_000, true, WriterView::default(), 0);
        assert_eq!(schedule.exchange_ns, 50_000);
        // A lost frame, however short its timeout.
        schedule.next_start_ns(MS, MS + 400_000, false, WriterView::default(), 0);
        assert_eq!(schedule.exchange_ns, 50_000);
        // A slow bus: the lead stops at half a period.
        let mut slow = CycleSchedule::new(Duration::from_millis(1));
        slow.next_start_ns(0, 900_000, true, WriterView::default(), 0);
        assert_eq!(slow.lead_ns(), MS / 2);
    }

    fn one_segment(taxels: usize) -> Arc<Shared> {
        Arc::new(Shared {
            segments: vec![Mutex::new(SegmentImage {
                values: vec![7; taxels],
                acquired_ns: 0,
                status: SegmentStatus::default(),
                faults_begun: 0,
                newest_fault: String::new(),
            })],
            news: vec![Condvar::new()],
            bus_fault: Mutex::new(None),
            writers: vec![WriterFollow::default()],
        })
    }

    fn deliver_a_cycle(shared: &Shared) {
        let mut image = shared.segment(0);
        image.acquired_ns = skinware::os::monotonic_ns();
        image.status.cycles += 1;
    }

    #[test]
    fn a_fault_over_before_the_layer_looks_is_reported_once() {
        let taxels = 4;
        let shared = one_segment(taxels);
        let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let options = skinware::WriterOptions { dir: Some(dir.clone()), ..skinware::WriterOptions::default() };
        let mut writer = skinware::Writer::create("unit", "seg", 2 * taxels, b"", &options).unwrap();
        let mut layer = SegmentLayer {
            shared: shared.clone(),
            position: 0,
            stale_after: Duration::from_secs(1),
            last_cycle: 0,
            faults_reported: 0,
        };
        deliver_a_cycle(&shared);
        assert!(layer.acquire(&mut writer.begin()).is_ok());
        // A fault for one cycle, over before the layer's writer looks.
        shared.set_fault(0, Some("working counter 1 instead of 3".into()));
        shared.set_fault(0, None);
        deliver_a_cycle(&shared);
        let reported = layer.acquire(&mut writer.begin()).unwrap_err().to_string();
        assert!(reported.contains("working counter 1 instead of 3"), "{reported}");
        // Once: the next cycle is a frame again.
        deliver_a_cycle(&shared);
        assert!(layer.acquire(&mut writer.begin()).is_ok());
        drop(writer);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
