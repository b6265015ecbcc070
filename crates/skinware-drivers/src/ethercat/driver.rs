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

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::{FrameWriter, LayerTopology};

use super::bus::Bus;
use super::config::EthercatDriverConfig;
use super::link::FrameLink;
use super::shared::{SegmentImage, SegmentStatus, Shared, WriterFollow};

/// A layer whose segment has given nothing new for this many periods fails.
const STALE_PERIODS: u32 = 2;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ethercat::bus::{CYCLE_LEAD_MARGIN_NS, CycleSchedule};
    use crate::ethercat::shared::WriterView;

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
