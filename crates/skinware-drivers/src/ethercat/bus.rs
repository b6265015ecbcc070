//! The EtherCAT bus thread: it runs ethercrab (bring-up to OP, then one
//! process-data exchange per segment and cycle, timed to end just before
//! each layer writer's acquisition) and keeps each segment's newest inputs
//! in [`super::shared::Shared`] for the layers.

use std::cell::Cell;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::task::Poll;
use std::time::{Duration, Instant};

use ethercrab::error::Error as EthercrabError;
use ethercrab::subdevice_group::{Op, PreOp};
use ethercrab::{
    DefaultLock, MainDevice, MainDeviceConfig, PduStorage, RetryBehaviour, SubDeviceGroup, SubDeviceState, Timeouts,
};

use super::config::{EthercatDriverConfig, expected_working_counter};
use super::link::{self, FrameLink};
use super::shared::{Shared, WriterView};
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

type PreOpGroup = SubDeviceGroup<1, GROUP_PDI, DefaultLock, PreOp>;
type OpGroup = SubDeviceGroup<1, GROUP_PDI, DefaultLock, Op>;

/// Lead of a cycle over the writer's deadline beyond twice the exchange's
/// own time: the bus thread's wake-up from its timer (a halted vCPU of a VM
/// takes 90-150 µs to run again).
pub(super) const CYCLE_LEAD_MARGIN_NS: u64 = 150_000;

/// When a segment's cycles start: each one ends just before the layer
/// writer's acquisition that takes its sample, so that the acquisition finds
/// the sample waiting instead of waiting for the bus, and the sample is as
/// young as the bus allows. Without a periodic writer to follow, `None`: the
/// caller cycles on its own.
#[derive(Debug)]
pub(super) struct CycleSchedule {
    period_ns: u64,
    /// Smoothed duration of one exchange (frame out and back), ns.
    pub(super) exchange_ns: u64,
}

impl CycleSchedule {
    pub(super) fn new(period: Duration) -> CycleSchedule {
        CycleSchedule { period_ns: (period.as_nanos() as u64).max(1), exchange_ns: 0 }
    }

    /// How far ahead of the writer's deadline a cycle starts.
    pub(super) fn lead_ns(&self) -> u64 {
        (2 * self.exchange_ns + CYCLE_LEAD_MARGIN_NS).min(self.period_ns / 2)
    }

    /// The start of the next cycle, decided when the previous one, started
    /// at `started_ns`, has ended at `now_ns` (`answered`: its frame came
    /// back) and the segment has delivered `cycles` samples so far.
    pub(super) fn next_start_ns(
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
pub(super) struct Bus {
    pub(super) config: EthercatDriverConfig,
    pub(super) link: FrameLink,
    pub(super) shared: Arc<Shared>,
    pub(super) stop: Arc<AtomicBool>,
}

impl Bus {
    pub(super) fn run(self) {
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
