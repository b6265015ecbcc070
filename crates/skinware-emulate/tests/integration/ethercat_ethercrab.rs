//! ethercrab, as MainDevice, against simulated tactile segments in the same
//! process: its `PduTx`/`PduRx` frame I/O is wired to a [`Segment`] on a
//! thread, so every frame ethercrab sends goes through the ESC model as bytes.
//! No privileges, no network interface.
//!
//! Each test brings segments up to OP the way a driver would, then checks
//! what ethercrab sees: identities, PDO sizes, every taxel of every cycle,
//! and each fault switch's effect.

use std::num::NonZeroU64;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Wake, Waker};
use std::thread::{self, JoinHandle, Thread};
use std::time::Duration;

use ethercrab::error::Error;
use ethercrab::{
    AlStatusCode, DcSupport, MainDevice, MainDeviceConfig, PduStorage, RetryBehaviour, SubDeviceGroup, SubDeviceState,
    Timeouts, subdevice_group::Op,
};
use futures_lite::future::block_on;
use skinware_emulate::ethercat::tactile::{
    COMMAND_ACQUIRE, CONFIG_BASELINE, EMULATED_PRODUCT_CODE, EMULATED_VENDOR_ID, STATUS_ACQUIRING, STATUS_BASELINE,
};
use skinware_emulate::ethercat::{AlState, Fate, LeaveOp, Segment, TactileConfig, TactileSubDevice};

/// Full-size Ethernet frames: 1500 bytes of payload.
const FRAME_DATA: usize = PduStorage::element_size(1486);
const FRAMES: usize = 16;
const MAX_SUBDEVICES: usize = 4;
const MAX_PDI: usize = 8192;

/// PDU timeout where no frame is lost on purpose.
const RELIABLE: Duration = Duration::from_secs(2);
/// PDU timeout where frames are lost on purpose: each loss costs this long.
const LOSSY: Duration = Duration::from_millis(250);

type Group = SubDeviceGroup<MAX_SUBDEVICES, MAX_PDI, ethercrab::DefaultLock, Op>;

/// What segment `segment`'s taxel `k` reads in sample `sample`: every taxel
/// of every segment differs, and changes every sample.
fn taxel_value(segment: usize, sample: u64, k: usize) -> u16 {
    (sample as u16).wrapping_mul(31).wrapping_add(k as u16 * 7).wrapping_add(segment as u16 * 1000)
}

/// The working counter ethercrab reports for one `tx_rx` of a group of
/// segments with these many taxels. Its process image is every segment's
/// inputs, then every segment's outputs; it sends it as LRWs of at most
/// `FRAME_DATA - 28` bytes, one per frame, and sums their working counters.
/// A segment counts +1 in each LRW that reads some of its inputs and +2 in
/// each that writes some of its outputs, so one whose inputs straddle two
/// frames counts twice: the expected value is not simply 3 per segment.
fn expected_working_counter(taxels: &[usize]) -> u16 {
    let chunk = FRAME_DATA - 28;
    let mut ranges = Vec::new();
    let mut offset = 0;
    for &count in taxels {
        ranges.push((offset..offset + 4 + 2 * count, 1));
        offset += 4 + 2 * count;
    }
    for _ in taxels {
        ranges.push((offset..offset + 4, 2));
        offset += 4;
    }
    (0..offset)
        .step_by(chunk)
        .map(|start| {
            let end = (start + chunk).min(offset);
            ranges.iter().filter(|(range, _)| range.start < end && start < range.end).map(|(_, w)| w).sum::<u16>()
        })
        .sum()
}

#[test]
fn expected_working_counter_is_three_per_segment_in_one_frame() {
    assert_eq!(expected_working_counter(&[12, 12, 12]), 9);
    assert_eq!(expected_working_counter(&[708]), 3);
    // 1,420 + 1,420 + 1,420 + 12 bytes in LRWs of 1,486: the second and the
    // third segment's inputs straddle frames.
    assert_eq!(expected_working_counter(&[708, 708, 708]), 2 + 2 + 7);
}

/// Wakes the network thread when ethercrab has a frame to send.
struct ThreadWaker(Thread);

impl Wake for ThreadWaker {
    fn wake(self: Arc<Self>) {
        self.0.unpark();
    }
}

/// The simulated segment on ethercrab's frame I/O, on its own thread.
struct Bus {
    segment: Arc<Mutex<Segment>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for Bus {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(thread) = self.thread.take() {
            thread.thread().unpark();
            let _ = thread.join();
        }
    }
}

impl Bus {
    /// Segments of these many taxels, in this order.
    fn with_segments(taxels: &[usize]) -> Bus {
        let subdevices = taxels
            .iter()
            .enumerate()
            .map(|(segment, &count)| {
                let source = move |sample: u64, taxels: &mut [u16]| {
                    for (k, taxel) in taxels.iter_mut().enumerate() {
                        *taxel = taxel_value(segment, sample, k);
                    }
                };
                TactileSubDevice::new(TactileConfig::new(count, 100 + segment as u32), source).unwrap()
            })
            .collect();
        Bus::new(Segment::new(subdevices))
    }

    fn new(segment: Segment) -> Bus {
        Bus { segment: Arc::new(Mutex::new(segment)), stop: Arc::new(AtomicBool::new(false)), thread: None }
    }

    /// Starts the network thread and returns ethercrab's MainDevice on it.
    /// Frames lost to a fault time out after `pdu_timeout`: long enough that
    /// a frame that is not lost never times out on a loaded machine.
    fn main_device(&mut self, pdu_timeout: Duration) -> MainDevice<'static> {
        // Each test needs its own storage for the life of the process.
        let storage: &'static PduStorage<FRAMES, FRAME_DATA> = Box::leak(Box::new(PduStorage::new()));
        let (mut tx, mut rx, pdu_loop) = storage.try_split().expect("fresh storage splits");
        let segment = self.segment.clone();
        let stop = self.stop.clone();
        self.thread = Some(thread::spawn(move || {
            let waker = Waker::from(Arc::new(ThreadWaker(thread::current())));
            let mut buffer = Vec::with_capacity(1600);
            while !stop.load(Ordering::Acquire) {
                tx.replace_waker(&waker);
                let mut sent = false;
                while let Some(frame) = tx.next_sendable_frame() {
                    sent = true;
                    buffer.clear();
                    frame
                        .send_blocking(|bytes| {
                            buffer.extend_from_slice(bytes);
                            Ok(bytes.len())
                        })
                        .expect("the segment takes every frame");
                    let fate = segment.lock().unwrap().process(&mut buffer);
                    if let Ok(Fate::Returned) = fate {
                        rx.receive_frame(&buffer).expect("ethercrab takes the answer");
                    }
                }
                if !sent {
                    thread::park_timeout(Duration::from_millis(1));
                }
            }
        }));
        // The EEPROM timeout bounds a whole SII round trip through this
        // thread, not only the ESC's busy time: on a loaded machine (two
        // cores shared with builds) ethercrab's 10 ms default times out.
        let timeouts = Timeouts {
            pdu: pdu_timeout,
            eeprom: Duration::from_secs(1),
            state_transition: Duration::from_secs(5),
            ..Timeouts::default()
        };
        let config = MainDeviceConfig { retry_behaviour: RetryBehaviour::None, ..MainDeviceConfig::default() };
        MainDevice::new(pdu_loop, timeouts, config)
    }

    fn with_segment<T>(&self, f: impl FnOnce(&mut Segment) -> T) -> T {
        f(&mut self.segment.lock().unwrap())
    }
}

/// Brings every SubDevice to OP in one group, as a driver would.
async fn bring_up(maindevice: &MainDevice<'static>) -> Group {
    let group = maindevice.init_single_group::<MAX_SUBDEVICES, MAX_PDI>(|| 0).await.expect("init to PRE-OP");
    group.into_op(maindevice).await.expect("PRE-OP to OP")
}

/// Sets every segment's command and config words.
fn command_all(group: &Group, maindevice: &MainDevice<'static>, command: u16, config: u16) {
    for subdevice in group.iter(maindevice) {
        let mut outputs = subdevice.outputs_raw_mut();
        outputs[..2].copy_from_slice(&command.to_le_bytes());
        outputs[2..4].copy_from_slice(&config.to_le_bytes());
    }
}

/// `(counter, status, taxels)` of every segment, as ethercrab holds them.
fn inputs(group: &Group, maindevice: &MainDevice<'static>) -> Vec<(u16, u16, Vec<u16>)> {
    group
        .iter(maindevice)
        .map(|subdevice| {
            let raw = subdevice.inputs_raw();
            let word = |k: usize| u16::from_le_bytes([raw[2 * k], raw[2 * k + 1]]);
            let taxels = (2..raw.len() / 2).map(word).collect();
            (word(0), word(1), taxels)
        })
        .collect()
}

#[test]
fn one_to_three_segments_come_up_to_op_with_their_identity_and_pdo_sizes() {
    for taxels in [&[12][..], &[708, 36], &[708, 240, 708]] {
        let mut bus = Bus::with_segments(taxels);
        let maindevice = bus.main_device(RELIABLE);
        block_on(async {
            let group = maindevice.init_single_group::<MAX_SUBDEVICES, MAX_PDI>(|| 0).await.expect("init");
            assert_eq!(group.len(), taxels.len());
            for (position, subdevice) in group.iter(&maindevice).enumerate() {
                let identity = subdevice.identity();
                assert_eq!(identity.vendor_id, EMULATED_VENDOR_ID);
                assert_eq!(identity.product_id, EMULATED_PRODUCT_CODE);
                assert_eq!(identity.revision, 1);
                assert_eq!(identity.serial, 100 + position as u32);
                assert_eq!(subdevice.name(), format!("SKIN-T{}", taxels[position]));
                assert_eq!(subdevice.dc_support(), DcSupport::None);
                assert_eq!(subdevice.configured_address(), 0x1000 + position as u16);
            }
            assert!(bus.with_segment(|s| s.subdevices().iter().all(|d| d.state() == AlState::PreOp)));
            let group = group.into_op(&maindevice).await.expect("to OP");
            for (position, subdevice) in group.iter(&maindevice).enumerate() {
                assert_eq!(subdevice.inputs_raw().len(), 4 + 2 * taxels[position], "SM3: counter, status, taxels");
                assert_eq!(subdevice.outputs_raw().len(), 4, "SM2: command, config");
            }
            let response = group.tx_rx(&maindevice).await.expect("a cycle");
            assert!(response.all_op());
            assert_eq!(response.working_counter, expected_working_counter(taxels));
            assert!(bus.with_segment(|s| s.subdevices().iter().all(|d| d.state() == AlState::Op)));
        });
    }
}

#[test]
fn ten_thousand_cycles_deliver_every_taxel_of_every_sample() {
    // 3 × 708 taxels: 4,272 bytes of process data, so every cycle spans
    // several frames and a segment's inputs can straddle two of them.
    let taxels = [708, 708, 708];
    let mut bus = Bus::with_segments(&taxels);
    let maindevice = bus.main_device(RELIABLE);
    block_on(async {
        let group = bring_up(&maindevice).await;
        command_all(&group, &maindevice, COMMAND_ACQUIRE, 0);
        // The command reaches a segment in the first cycle; from the next one
        // on, every cycle must bring exactly the next sample.
        group.tx_rx(&maindevice).await.expect("first cycle");
        let mut previous: Vec<u16> = inputs(&group, &maindevice).iter().map(|(counter, ..)| *counter).collect();
        let cycles = 10_000;
        for cycle in 0..cycles {
            let response = group.tx_rx(&maindevice).await.expect("a cycle");
            assert_eq!(response.working_counter, expected_working_counter(&taxels), "cycle {cycle}");
            assert!(response.all_op(), "cycle {cycle}");
            for (segment, (counter, status, values)) in inputs(&group, &maindevice).into_iter().enumerate() {
                assert_eq!(counter, previous[segment].wrapping_add(1), "segment {segment} cycle {cycle}");
                assert_eq!(status, STATUS_ACQUIRING);
                assert_eq!(values.len(), taxels[segment]);
                for (k, value) in values.into_iter().enumerate() {
                    assert_eq!(value, taxel_value(segment, u64::from(counter), k), "segment {segment} taxel {k}");
                }
                previous[segment] = counter;
            }
        }
        let samples: Vec<u64> = bus.with_segment(|s| s.subdevices().iter().map(|d| d.samples()).collect());
        for (segment, samples) in samples.into_iter().enumerate() {
            assert_eq!(samples, u64::from(previous[segment]), "the segment took no sample ethercrab did not see");
        }
    });
}

#[test]
fn stop_and_baseline_commands_reach_the_segment() {
    let mut bus = Bus::with_segments(&[24]);
    let maindevice = bus.main_device(RELIABLE);
    block_on(async {
        let group = bring_up(&maindevice).await;
        command_all(&group, &maindevice, COMMAND_ACQUIRE, 0);
        for _ in 0..5 {
            group.tx_rx(&maindevice).await.unwrap();
        }
        let (counter, ..) = inputs(&group, &maindevice)[0].clone();
        // Stop: the counter and taxels hold. The frame that carries the
        // command still brings a sample: the ESC reads the inputs out (they
        // come first in the process image) before it takes the outputs.
        command_all(&group, &maindevice, 0, 0);
        group.tx_rx(&maindevice).await.unwrap();
        let (last, status, _) = inputs(&group, &maindevice)[0].clone();
        assert_eq!((last, status & STATUS_ACQUIRING), (counter.wrapping_add(1), STATUS_ACQUIRING));
        group.tx_rx(&maindevice).await.unwrap();
        let held = inputs(&group, &maindevice)[0].clone();
        for _ in 0..3 {
            group.tx_rx(&maindevice).await.unwrap();
            assert_eq!(inputs(&group, &maindevice)[0], held);
        }
        assert_eq!(held.1 & STATUS_ACQUIRING, 0);
        assert_eq!(held.0, last);
        assert_eq!(bus.with_segment(|s| s.subdevices()[0].command_and_config()), (0, 0));
        // Baseline: the first sample after the switch (in the cycle after
        // the one carrying it) is the tare, so it reads zero, and later ones
        // read their difference from it.
        command_all(&group, &maindevice, COMMAND_ACQUIRE, CONFIG_BASELINE);
        group.tx_rx(&maindevice).await.unwrap();
        assert_eq!(inputs(&group, &maindevice)[0], held, "the command's own frame reads the inputs before it");
        group.tx_rx(&maindevice).await.unwrap();
        let (tare_counter, status, values) = inputs(&group, &maindevice)[0].clone();
        assert_eq!(status, STATUS_ACQUIRING | STATUS_BASELINE);
        assert!(values.iter().all(|&v| v == 0), "{values:?}");
        group.tx_rx(&maindevice).await.unwrap();
        let (counter, _, values) = inputs(&group, &maindevice)[0].clone();
        assert_eq!(counter, tare_counter.wrapping_add(1));
        for (k, value) in values.into_iter().enumerate() {
            let expected =
                taxel_value(0, u64::from(counter), k).saturating_sub(taxel_value(0, u64::from(tare_counter), k));
            assert_eq!(value, expected);
        }
    });
}

#[test]
fn a_wrong_working_counter_is_seen_and_goes_away_with_the_fault() {
    let mut bus = Bus::with_segments(&[12, 12, 12]);
    let maindevice = bus.main_device(RELIABLE);
    block_on(async {
        let group = bring_up(&maindevice).await;
        assert_eq!(group.tx_rx(&maindevice).await.unwrap().working_counter, 9);
        bus.with_segment(|s| s.subdevice_mut(1).unwrap().faults_mut().wrong_working_counter = true);
        for _ in 0..3 {
            let response = group.tx_rx(&maindevice).await.unwrap();
            assert_eq!(response.working_counter, 6, "short by the faulty segment's 3");
            assert!(response.all_op(), "its state says nothing is wrong: only the counter does");
        }
        bus.with_segment(|s| s.subdevice_mut(1).unwrap().faults_mut().wrong_working_counter = false);
        assert_eq!(group.tx_rx(&maindevice).await.unwrap().working_counter, 9);
    });
}

#[test]
fn every_nth_frame_lost_is_a_timeout_in_exactly_those_cycles() {
    let mut bus = Bus::with_segments(&[12]);
    let maindevice = bus.main_device(LOSSY);
    block_on(async {
        let group = bring_up(&maindevice).await;
        command_all(&group, &maindevice, COMMAND_ACQUIRE, 0);
        // One small segment: one frame per cycle.
        let before = bus.with_segment(|s| s.stats().process_data);
        group.tx_rx(&maindevice).await.unwrap();
        assert_eq!(bus.with_segment(|s| s.stats().process_data), before + 1);
        bus.with_segment(|s| s.faults_mut().drop_every_nth_frame = NonZeroU64::new(5));
        let first = bus.with_segment(|s| s.stats().process_data) + 1;
        let mut lost = Vec::new();
        for cycle in 0..20u64 {
            match group.tx_rx(&maindevice).await {
                Ok(response) => assert_eq!(response.working_counter, 3),
                Err(Error::Timeout(_)) => lost.push(cycle),
                Err(other) => panic!("cycle {cycle}: {other}"),
            }
        }
        let expected: Vec<u64> = (0..20).filter(|c| (first + c).is_multiple_of(5)).collect();
        assert_eq!(lost, expected);
        // The samples of the lost cycles were never taken: the ring lost the
        // frame on its way out, so the counter goes on without a gap.
        let counter_before = inputs(&group, &maindevice)[0].0;
        bus.with_segment(|s| s.faults_mut().drop_every_nth_frame = None);
        group.tx_rx(&maindevice).await.unwrap();
        assert_eq!(inputs(&group, &maindevice)[0].0, counter_before.wrapping_add(1));
    });
}

#[test]
fn a_segment_leaving_op_is_seen_in_the_cycle_it_leaves_and_recovers_on_acknowledge() {
    let mut bus = Bus::with_segments(&[12, 12]);
    let maindevice = bus.main_device(RELIABLE);
    let leave_after = 40;
    bus.with_segment(|s| {
        s.subdevice_mut(1).unwrap().faults_mut().leave_op = Some(LeaveOp::AfterCycles(leave_after));
    });
    block_on(async {
        let group = bring_up(&maindevice).await;
        for cycle in 1..=leave_after {
            let response = group.tx_rx(&maindevice).await.unwrap();
            if cycle < leave_after {
                assert!(response.all_op(), "cycle {cycle}");
            } else {
                // The state checks ride behind the process data in the same
                // frame, so the very cycle that tripped it reports it.
                assert_eq!(response.subdevice_states.as_slice(), [SubDeviceState::Op, SubDeviceState::SafeOp]);
                assert!(!response.all_op());
            }
        }
        let subdevice = group.subdevice(&maindevice, 1).unwrap();
        match subdevice.status().await {
            Err(Error::SubDevice(code)) => assert_eq!(code, AlStatusCode::SyncManagerWatchdog),
            other => panic!("expected the watchdog's code, got {other:?}"),
        }
        // Asking for OP again without acknowledging the error does nothing…
        subdevice.register_write(0x0120u16, 0x0008u16).await.unwrap();
        assert!(!group.tx_rx(&maindevice).await.unwrap().all_op());
        // …with the acknowledge bit it goes back to OP (and the fault, once
        // per entry into OP, counts again from there).
        bus.with_segment(|s| s.subdevice_mut(1).unwrap().faults_mut().leave_op = None);
        subdevice.register_write(0x0120u16, 0x0018u16).await.unwrap();
        assert!(group.tx_rx(&maindevice).await.unwrap().all_op());
        assert_eq!(subdevice.status().await.unwrap(), (SubDeviceState::Op, AlStatusCode::NoError));
    });
}

#[test]
fn link_down_times_out_every_cycle_until_the_link_is_back() {
    let mut bus = Bus::with_segments(&[12, 12]);
    let maindevice = bus.main_device(LOSSY);
    block_on(async {
        let group = bring_up(&maindevice).await;
        bus.with_segment(|s| s.faults_mut().link_down = true);
        for _ in 0..3 {
            assert!(matches!(group.tx_rx(&maindevice).await, Err(Error::Timeout(_))));
        }
        bus.with_segment(|s| s.faults_mut().link_down = false);
        let response = group.tx_rx(&maindevice).await.unwrap();
        assert!(response.all_op());
        assert_eq!(response.working_counter, 6);
    });
}

#[test]
fn a_segment_leaving_op_after_a_time_does_so_no_sooner() {
    let mut bus = Bus::with_segments(&[12]);
    let maindevice = bus.main_device(RELIABLE);
    let after = Duration::from_millis(150);
    bus.with_segment(|s| s.subdevice_mut(0).unwrap().faults_mut().leave_op = Some(LeaveOp::AfterTime(after)));
    block_on(async {
        // OP is entered after this instant, so the segment must still be in
        // OP `after` from here: a bound that holds however slow the machine.
        let before_op = std::time::Instant::now();
        let group = bring_up(&maindevice).await;
        assert!(group.tx_rx(&maindevice).await.unwrap().all_op());
        let left = loop {
            let response = group.tx_rx(&maindevice).await.unwrap();
            if !response.all_op() {
                break before_op.elapsed();
            }
            assert!(before_op.elapsed() < after + Duration::from_secs(5), "never left OP");
            thread::sleep(Duration::from_millis(2));
        };
        assert!(left >= after, "left OP {left:?} after the bring-up started, asked {after:?} in OP");
        assert_eq!(bus.with_segment(|s| s.subdevices()[0].error()), Some(0x001B));
    });
}
