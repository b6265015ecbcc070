//! The EtherCAT skin driver end to end, in one process and without
//! privileges: simulated tactile segments (the ESC model) as the bus →
//! ethercrab → the driver → the exchange → readers, one layer per segment.
//! Every taxel of what readers get is checked, then each fault switch's
//! effect on the layers: only the faulty segment's layer for a segment fault,
//! every layer for a pulled cable, and recovery with the same readers.

use std::num::NonZeroU64;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use skinware::driver::DriverHandler;
use skinware::{HandlerOptions, Reader, ReaderOptions, WriterState};
use skinware_drivers::ethercat::{
    EthercatDriver, EthercatDriverConfig, EthercatStatus, FrameExchange, FrameLink, INPUTS_HEADER_BYTES, OUTPUTS_BYTES,
    SegmentConfig,
};
use skinware_emulate::ethercat::tactile::{EMULATED_PRODUCT_CODE, EMULATED_VENDOR_ID};
use skinware_emulate::ethercat::{
    Command, Datagram, LeaveOp, Segment, TactileConfig, TactileSubDevice, check_frame as check_frame_layout, datagrams,
};

const RATE_HZ: f64 = 200.0;

/// Taxel `k` of segment `segment` in sample `sample`: the first taxel gives
/// the sample away, so a reader can check that a frame is one whole sample.
fn taxel_value(segment: usize, sample: u64, k: usize) -> u16 {
    (sample as u16).wrapping_add(3 * k as u16).wrapping_add(1000 * segment as u16)
}

struct Rig {
    segment: Arc<Mutex<Segment>>,
    status: EthercatStatus,
    handler: Option<DriverHandler>,
    readers: Vec<Reader>,
    dir: std::path::PathBuf,
}

impl Drop for Rig {
    fn drop(&mut self) {
        if let Some(handler) = self.handler.take() {
            handler.stop();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn layer(position: usize) -> String {
    format!("seg{position}")
}

fn segment_config(position: usize, taxels: usize) -> SegmentConfig {
    SegmentConfig {
        layer: layer(position),
        vendor_id: EMULATED_VENDOR_ID,
        product_code: EMULATED_PRODUCT_CODE,
        taxels,
        modules: vec![12; taxels / 12],
        patch: position as u32 + 1,
        baseline: false,
    }
}

fn emulated(taxels: &[usize]) -> Segment {
    Segment::new(
        taxels
            .iter()
            .enumerate()
            .map(|(segment, &count)| {
                let source = move |sample: u64, values: &mut [u16]| {
                    for (k, value) in values.iter_mut().enumerate() {
                        *value = taxel_value(segment, sample, k);
                    }
                };
                TactileSubDevice::new(TactileConfig::new(count, segment as u32 + 1), source).unwrap()
            })
            .collect(),
    )
}

impl Rig {
    fn start(test: &str, taxels: &[usize], configured: Vec<SegmentConfig>) -> Rig {
        Rig::start_with(test, taxels, configured, |_| {})
    }

    /// As [`Rig::start`], with the segments' faults set before the driver starts.
    fn start_with(
        test: &str,
        taxels: &[usize],
        configured: Vec<SegmentConfig>,
        faults: impl FnOnce(&mut Segment),
    ) -> Rig {
        let mut segments = emulated(taxels);
        faults(&mut segments);
        Rig::start_around(test, segments, configured, |segment| segment)
    }

    /// As [`Rig::start`], with the driver's bus made around the segments.
    fn start_on(
        test: &str,
        taxels: &[usize],
        configured: Vec<SegmentConfig>,
        bus: impl FnOnce(Arc<Mutex<Segment>>) -> Arc<Mutex<dyn FrameExchange>>,
    ) -> Rig {
        Rig::start_around(test, emulated(taxels), configured, bus)
    }

    fn start_around(
        test: &str,
        segments: Segment,
        configured: Vec<SegmentConfig>,
        bus: impl FnOnce(Arc<Mutex<Segment>>) -> Arc<Mutex<dyn FrameExchange>>,
    ) -> Rig {
        let segment = Arc::new(Mutex::new(segments));
        let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-{}-{test}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let bus = bus(segment.clone());
        let config = EthercatDriverConfig {
            name: "ecat".into(),
            segments: configured.clone(),
            rate_hz: RATE_HZ,
            // Generous: the machine is shared; lost frames are lost on purpose.
            frame_timeout: Some(Duration::from_millis(50)),
            rt: crate::driver_rt(),
        };
        let driver = EthercatDriver::new(config, FrameLink::InProcess(bus)).unwrap();
        let status = driver.status_handle();
        let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
        let handler = DriverHandler::start("ecat", Box::new(driver), &options).unwrap();
        let readers = configured
            .iter()
            .map(|s| {
                Reader::open_with("ecat", &s.layer, &ReaderOptions { dir: Some(dir.clone()), ..Default::default() })
                    .unwrap()
            })
            .collect();
        Rig { segment, status, handler: Some(handler), readers, dir }
    }

    /// Why the bus did not come up: the first fault after "not brought up yet",
    /// however long the bring-up takes on a loaded machine.
    fn bring_up_refusal(&self) -> String {
        let started = Instant::now();
        loop {
            match self.status.bus_fault() {
                Some(why) if why != "not brought up yet" => return why,
                None => panic!("the bus came up: {:?}", self.status.segments()),
                Some(_) => {}
            }
            assert!(started.elapsed() < Duration::from_secs(10), "the bring-up never ended");
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// Waits (up to 5 s) until segment `faulty`'s status names `says`;
    /// checks on the way that no other segment's does.
    fn wait_for_segment_fault(&self, faulty: usize, says: &str) {
        let started = Instant::now();
        loop {
            let statuses = self.status.segments();
            for (position, status) in statuses.iter().enumerate() {
                let names_it = status.fault.as_deref().is_some_and(|why| why.contains(says));
                if position != faulty {
                    assert!(!names_it, "segment {position} has segment {faulty}'s fault: {statuses:?}");
                } else if names_it {
                    return;
                }
            }
            assert!(started.elapsed() < Duration::from_secs(5), "segment {faulty} never said {says:?}: {statuses:?}");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    fn wait_all(&mut self, state: WriterState, within: Duration) -> Duration {
        let started = Instant::now();
        for reader in &mut self.readers {
            wait_for(reader, state, within.saturating_sub(started.elapsed()));
        }
        started.elapsed()
    }
}

fn wait_for(reader: &mut Reader, state: WriterState, within: Duration) -> Duration {
    let started = Instant::now();
    while reader.writer_state() != state {
        assert!(started.elapsed() < within, "{} never became {state} (is {})", reader.label(), reader.writer_state());
        std::thread::sleep(Duration::from_millis(1));
    }
    started.elapsed()
}

/// Checks that a frame of segment `segment` is one whole sample, and returns
/// the sample's number (low 16 bits).
fn check_frame(segment: usize, responses: &[u16]) -> u16 {
    let sample = responses[0].wrapping_sub(1000 * segment as u16);
    for (k, &value) in responses.iter().enumerate() {
        assert_eq!(value, taxel_value(segment, u64::from(sample), k), "segment {segment} taxel {k}");
    }
    sample
}

#[test]
fn every_taxel_of_every_segment_reaches_its_readers() {
    let taxels = [708, 240, 708];
    let configured = taxels.iter().enumerate().map(|(p, &n)| segment_config(p, n)).collect();
    let mut rig = Rig::start("values", &taxels, configured);
    rig.wait_all(WriterState::Running, Duration::from_secs(10));
    let mut last = vec![None; taxels.len()];
    for _ in 0..50 {
        for (segment, reader) in rig.readers.iter_mut().enumerate() {
            let frame = reader.wait_newer(Duration::from_secs(1)).unwrap();
            assert_eq!(frame.responses().len(), taxels[segment]);
            let sample = check_frame(segment, frame.responses());
            if let Some(previous) = last[segment] {
                assert_ne!(sample, previous, "segment {segment}: a new frame is a new sample");
            }
            last[segment] = Some(sample);
        }
    }
}

#[test]
fn a_wrong_identity_or_taxel_count_is_refused_with_its_reason() {
    let mut wrong_product = segment_config(0, 24);
    wrong_product.product_code = 0xDEAD;
    let rig = Rig::start("identity", &[24], vec![wrong_product]);
    let why = rig.bring_up_refusal();
    assert_eq!(rig.readers[0].writer_state(), WriterState::Faulted);
    assert!(why.contains("SKIN-T24") && why.contains("expects vendor") && why.contains("0x0000dead"), "{why}");
    // What it found is on show all the same.
    let found = &rig.status.segments()[0];
    assert_eq!(found.identity, Some([EMULATED_VENDOR_ID, EMULATED_PRODUCT_CODE, 1, 1]));
    drop(rig);
    let rig = Rig::start("taxels", &[24], vec![segment_config(0, 36)]);
    let why = rig.bring_up_refusal();
    assert_eq!(rig.readers[0].writer_state(), WriterState::Faulted);
    assert!(why.contains("52 bytes of inputs") && why.contains("36 taxels need 76"), "{why}");
    drop(rig);
    let rig = Rig::start("count", &[24], vec![segment_config(0, 24), segment_config(1, 24)]);
    let why = rig.bring_up_refusal();
    assert!(why.contains("1 SubDevices but 2 segments"), "{why}");
}

#[test]
fn segments_show_their_identity_and_state() {
    let mut rig = Rig::start("status", &[24, 36], vec![segment_config(0, 24), segment_config(1, 36)]);
    rig.wait_all(WriterState::Running, Duration::from_secs(10));
    // A moment with the bus up and no segment faulted (a stalled test
    // thread on a loaded machine can make a frame late for a cycle or two).
    let started = std::time::Instant::now();
    while rig.status.bus_fault().is_some() || rig.status.segments().iter().any(|s| s.fault.is_some()) {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "{:?} {:?}",
            rig.status.bus_fault(),
            rig.status.segments()
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    for (position, status) in rig.status.segments().into_iter().enumerate() {
        assert_eq!(status.identity, Some([EMULATED_VENDOR_ID, EMULATED_PRODUCT_CODE, 1, position as u32 + 1]));
        assert_eq!(status.name, format!("SKIN-T{}", [24, 36][position]));
        assert_eq!(status.state, "OP");
        assert!(status.cycles > 0);
    }
}

/// Each segment fault faults its own layer within 2 periods of the last good
/// frame (plus the frame timeout where a frame is lost), leaves the other
/// layers running, and is recovered from once the fault goes.
#[test]
fn segment_faults_fault_only_their_layer_and_recover() {
    let taxels = [24, 24];
    let configured = taxels.iter().enumerate().map(|(p, &n)| segment_config(p, n)).collect();
    let mut rig = Rig::start("segment-faults", &taxels, configured);
    rig.wait_all(WriterState::Running, Duration::from_secs(10));
    let period_ms = 1e3 / RATE_HZ;

    type Fault = fn(&mut Segment, bool);
    // Each fault, and what the faulted segment's status then says.
    let faults: [(&str, Fault, &str); 2] = [
        (
            "wrong working counter",
            |s, on| s.subdevice_mut(1).unwrap().faults_mut().wrong_working_counter = on,
            "working counter",
        ),
        (
            "leave OP",
            |s, on| s.subdevice_mut(1).unwrap().faults_mut().leave_op = on.then_some(LeaveOp::AfterCycles(1)),
            "instead of OP",
        ),
    ];
    for (name, fault, says) in faults {
        fault(&mut rig.segment.lock().unwrap(), true);
        let detected = detection_ms(&mut rig.readers[1], Duration::from_secs(5));
        // Times are printed, not asserted: this VM stalls for more than a
        // 5 ms period now and then. What is asserted is what was found, and where.
        println!("{name}: layer faulted {detected:.1} ms after its last good frame (period {period_ms} ms)");
        rig.wait_for_segment_fault(1, says);
        let frame = rig.readers[0].wait_newer(Duration::from_secs(1)).unwrap();
        check_frame(0, frame.responses());
        fault(&mut rig.segment.lock().unwrap(), false);
        let recovered = wait_for(&mut rig.readers[1], WriterState::Running, Duration::from_secs(5));
        println!("{name}: running again {:.1} ms after the fault went", recovered.as_secs_f64() * 1e3);
        let frame = rig.readers[1].wait_newer(Duration::from_secs(1)).unwrap();
        check_frame(1, frame.responses());
    }
}

/// Loses every `every`-th process-data frame of one segment only (told by
/// its LRW's length; the segments' sizes differ), while `every` is not 0.
struct LoseFramesOf {
    segment: Arc<Mutex<Segment>>,
    lrw_len: usize,
    every: Arc<std::sync::atomic::AtomicU64>,
    seen: u64,
}

impl FrameExchange for LoseFramesOf {
    fn exchange(&mut self, frame: &mut Vec<u8>) -> bool {
        let every = self.every.load(std::sync::atomic::Ordering::Relaxed);
        let is_victims = datagrams(frame)
            .is_some_and(|d| d.iter().any(|d| d.command == Command::Lrw && d.data.len() == self.lrw_len));
        if every > 0 && is_victims {
            self.seen += 1;
            if self.seen.is_multiple_of(every) {
                return false;
            }
        }
        self.segment.lock().unwrap().exchange(frame)
    }
}

/// Frames lost on one segment of three fault that segment's layer only:
/// the other two keep running with fresh frames all along.
#[test]
fn lost_frames_fault_the_layers_they_belong_to() {
    let taxels = [24, 36, 48];
    let configured = taxels.iter().enumerate().map(|(p, &n)| segment_config(p, n)).collect();
    let every = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let victim = 1;
    let mut rig = Rig::start_on("lost", &taxels, configured, |segment| {
        // A segment's LRW carries its inputs and outputs.
        let lrw_len = INPUTS_HEADER_BYTES + 2 * taxels[victim] + OUTPUTS_BYTES;
        Arc::new(Mutex::new(LoseFramesOf { segment, lrw_len, every: every.clone(), seen: 0 }))
    });
    rig.wait_all(WriterState::Running, Duration::from_secs(10));
    let faults_before: Vec<u64> = rig.readers.iter().map(|r| r.writer_stats().faults).collect();
    every.store(2, std::sync::atomic::Ordering::Relaxed);
    // Every other cycle's frame of the victim is lost: its layer keeps faulting.
    let detected = detection_ms(&mut rig.readers[victim], Duration::from_secs(5));
    println!("every 2nd frame of segment {victim} lost: faulted {detected:.1} ms after its last good frame");
    rig.wait_for_segment_fault(victim, "frame lost");
    // Meanwhile, the others deliver new samples, whole.
    for _ in 0..40 {
        for position in [0, 2] {
            assert_eq!(
                rig.readers[position].writer_state(),
                WriterState::Running,
                "segment {position}: bus {:?}, segments {:?}, layer faults {:?}",
                rig.status.bus_fault(),
                rig.status.segments(),
                rig.readers.iter().map(|r| r.writer_stats().faults).collect::<Vec<_>>(),
            );
            let frame = rig.readers[position].wait_newer(Duration::from_secs(1)).unwrap();
            check_frame(position, frame.responses());
        }
        let statuses = rig.status.segments();
        for position in [0, 2] {
            assert!(statuses[position].fault.is_none(), "segment {position}: {statuses:?}");
        }
    }
    let faults_after: Vec<u64> = rig.readers.iter().map(|r| r.writer_stats().faults).collect();
    // Printed: a stall of this loaded VM may fault a layer for a cycle.
    println!("layer faults before {faults_before:?}, after {faults_after:?}");
    assert!(faults_after[victim] > faults_before[victim]);
    every.store(0, std::sync::atomic::Ordering::Relaxed);
    wait_for(&mut rig.readers[victim], WriterState::Running, Duration::from_secs(5));
    let frame = rig.readers[victim].wait_newer(Duration::from_secs(1)).unwrap();
    check_frame(victim, frame.responses());
}

/// A small N loses only process-data frames: the bring-up's all arrive, the
/// bus reaches OP, and then every Nth cycle frame is lost.
#[test]
fn a_small_drop_every_still_reaches_op_then_loses_every_nth_cycle_frame() {
    let mut rig = Rig::start_with("drop-small", &[24], vec![segment_config(0, 24)], |s| {
        s.faults_mut().drop_every_nth_frame = NonZeroU64::new(5);
    });
    let started = Instant::now();
    while rig.status.segments()[0].cycles == 0 {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "never reached OP with every 5th process-data frame lost: bus {:?}, {:?}",
            rig.status.bus_fault(),
            rig.status.segments()
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    println!("drop every 5th: cycling {:.0} ms after start", started.elapsed().as_secs_f64() * 1e3);
    rig.wait_for_segment_fault(0, "frame lost");
    let frame = rig.readers[0].wait_newer(Duration::from_secs(5)).unwrap();
    check_frame(0, frame.responses());
    let stats = rig.segment.lock().unwrap().stats();
    println!("drop every 5th: {stats:?}");
    assert_eq!(stats.dropped, stats.process_data / 5, "{stats:?}");
    assert!(stats.dropped >= 1 && stats.frames > stats.process_data, "{stats:?}");
    assert_eq!(rig.status.segments()[0].state, "OP");
}

#[test]
fn a_pulled_cable_faults_every_layer_and_the_bus_comes_back_on_its_own() {
    let taxels = [24, 36];
    let configured = taxels.iter().enumerate().map(|(p, &n)| segment_config(p, n)).collect();
    let mut rig = Rig::start("cable", &taxels, configured);
    rig.wait_all(WriterState::Running, Duration::from_secs(10));
    rig.segment.lock().unwrap().faults_mut().link_down = true;
    let faulted = rig.wait_all(WriterState::Faulted, Duration::from_secs(5));
    println!("cable pulled: every layer faulted after {:.1} ms", faulted.as_secs_f64() * 1e3);
    // Plugged back in, with segments that powered up again (in INIT).
    *rig.segment.lock().unwrap() = emulated(&taxels);
    let recovered = rig.wait_all(WriterState::Running, Duration::from_secs(10));
    println!("cable back: every layer running after {:.0} ms", recovered.as_secs_f64() * 1e3);
    for (segment, reader) in rig.readers.iter_mut().enumerate() {
        let frame = reader.wait_newer(Duration::from_secs(1)).unwrap();
        check_frame(segment, frame.responses());
    }
}

/// A bus that takes every frame and answers none.
struct Silent;

impl FrameExchange for Silent {
    fn exchange(&mut self, _frame: &mut Vec<u8>) -> bool {
        false
    }
}

/// Segments whose every request for SAFE-OP is turned, on the wire, into
/// one for PRE-OP: the bring-up waits out its state-transition timeout.
struct NeverSafeOp(Segment);

impl FrameExchange for NeverSafeOp {
    fn exchange(&mut self, frame: &mut Vec<u8>) -> bool {
        if let Ok(layout) = check_frame_layout(frame) {
            let mut offset = layout.payload_start;
            while let Some(datagram) = Datagram::at(frame, offset, layout.payload_end) {
                let writes = matches!(datagram.command(frame), Command::Fpwr | Command::Apwr | Command::Bwr);
                // AL control, register 0x0120 (the address's high half).
                if writes && datagram.address(frame) >> 16 == 0x0120 && datagram.data_len > 0 {
                    let state = &mut frame[datagram.data_range().start];
                    if *state & 0x0F == 0x04 {
                        *state = (*state & 0xF0) | 0x02;
                    }
                }
                if !datagram.more_follows {
                    break;
                }
                offset = datagram.end;
            }
        }
        self.0.exchange(frame)
    }
}

/// Starts the driver on `bus`, asks it to stop 100 ms later (in the middle
/// of its bring-up) and returns how long the stop took, and the segment's
/// state then.
fn stop_during_bring_up(bus: Arc<Mutex<dyn FrameExchange>>, frame_timeout: Duration) -> (Duration, String) {
    use skinware::driver::Driver;
    let config = EthercatDriverConfig {
        name: "stop".into(),
        segments: vec![segment_config(0, 24)],
        rate_hz: RATE_HZ,
        frame_timeout: Some(frame_timeout),
        rt: crate::driver_rt(),
    };
    let mut driver = EthercatDriver::new(config, FrameLink::InProcess(bus)).unwrap();
    let status = driver.status_handle();
    let _layers = driver.start().unwrap();
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(status.bus_fault().as_deref(), Some("not brought up yet"), "the bring-up was over before the stop");
    let state = status.segments()[0].state.clone();
    let asked = Instant::now();
    driver.stop();
    (asked.elapsed(), state)
}

#[test]
fn stop_during_the_bring_up_is_prompt() {
    // Frames that time out after 5 s, on a bus that never answers.
    let (silent, _) = stop_during_bring_up(Arc::new(Mutex::new(Silent)), Duration::from_secs(5));
    println!("stop while the bring-up waits for an answer: {:.1} ms", silent.as_secs_f64() * 1e3);
    // A segment that never reaches SAFE-OP: ethercrab waits out its 5 s
    // state-transition timeout.
    let (stuck, state) =
        stop_during_bring_up(Arc::new(Mutex::new(NeverSafeOp(emulated(&[24])))), Duration::from_millis(50));
    println!("stop while the bring-up waits for SAFE-OP (segment in {state}): {:.1} ms", stuck.as_secs_f64() * 1e3);
    assert_eq!(state, "PRE-OP", "the bring-up had not found the segment yet");
    // Generous: what is checked is that stop does not wait out the 5 s.
    assert!(silent < Duration::from_secs(2) && stuck < Duration::from_secs(2), "{silent:?} {stuck:?}");
}

/// Milliseconds from the newest good frame to the fault being seen.
fn detection_ms(reader: &mut Reader, within: Duration) -> f64 {
    wait_for(reader, WriterState::Faulted, within);
    let seen = skinware::os::monotonic_ns();
    let last_good = reader.latest().map(|f| f.published_ns()).unwrap_or(seen);
    (seen - last_good) as f64 / 1e6
}

/// `skin emulate ethercat`'s segments, whose taxels feel the virtual body,
/// through the driver: every response is a virtual-skin response (about
/// BASELINE untouched), not a blank.
#[test]
fn the_emulated_skin_reaches_readers_with_the_virtual_bodys_responses() {
    let emulation = skinware_emulate::ethercat::EthercatEmulation {
        segments: 2,
        taxels: 60,
        interface: String::new(),
        seed: 7,
        faults: Default::default(),
        fifo_priority: None,
        capture: None,
    };
    let segment = Arc::new(Mutex::new(emulation.segment().unwrap()));
    let bus: Arc<Mutex<dyn FrameExchange>> = segment.clone();
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-{}-body", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = EthercatDriverConfig {
        name: "body".into(),
        segments: vec![segment_config(0, 60), segment_config(1, 60)],
        rate_hz: RATE_HZ,
        frame_timeout: Some(Duration::from_millis(50)),
        rt: crate::driver_rt(),
    };
    let driver = EthercatDriver::new(config, FrameLink::InProcess(bus)).unwrap();
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("body", Box::new(driver), &options).unwrap();
    for layer in ["seg0", "seg1"] {
        let mut reader =
            Reader::open_with("body", layer, &ReaderOptions { dir: Some(dir.clone()), ..Default::default() }).unwrap();
        wait_for(&mut reader, WriterState::Running, Duration::from_secs(10));
        let frame = reader.wait_newer(Duration::from_secs(1)).unwrap();
        let baseline = skinware_drivers::virtual_skin::BASELINE;
        assert!(frame.responses().iter().all(|&r| r >= baseline / 2), "{layer}: {:?}", frame.responses());
    }
    handler.stop();
    let _ = std::fs::remove_dir_all(&dir);
}
