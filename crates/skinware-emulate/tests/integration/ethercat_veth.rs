//! The EtherCAT driver and simulated segments on the two ends of a veth pair,
//! in a network namespace of the test's own (`unshare -rn`, no privileges
//! needed where user namespaces are allowed): ethercrab's raw socket on one
//! end, the ESC model on an AF_PACKET socket on the other, readers on the
//! exchange. Skipped, with the reason printed, where the machine forbids
//! namespaces or has no `ip`.

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use skinware::driver::DriverHandler;
use skinware::{HandlerOptions, Reader, ReaderOptions, WriterState};
use skinware_drivers::ethercat::{
    EthercatDriver, EthercatDriverConfig, EthercatStatus, FrameExchange, FrameLink, SegmentConfig,
};
use skinware_emulate::ethercat::tactile::{EMULATED_PRODUCT_CODE, EMULATED_VENDOR_ID};
use skinware_emulate::ethercat::{Segment, TactileConfig, TactileSubDevice, serve_interface};

/// Set in the copy of the test that runs inside the namespace.
const INSIDE: &str = "SKINWARE_ETHERCAT_NETNS";
const DRIVER_END: &str = "ecat-drv";
const SEGMENT_END: &str = "ecat-emu";

/// Whether this is the copy inside a namespace of its own. The first call
/// runs the test again in one and checks that it passed.
fn in_own_namespace(test: &str) -> bool {
    if std::env::var_os(INSIDE).is_some() {
        return true;
    }
    match Command::new("unshare").args(["-rn", "true"]).output() {
        Ok(out) if out.status.success() => {}
        Ok(out) => {
            let why = String::from_utf8_lossy(&out.stderr);
            println!("skipped: `unshare -rn` fails here ({}): no user and network namespaces", why.trim());
            return false;
        }
        Err(e) => {
            println!("skipped: cannot run unshare: {e}");
            return false;
        }
    }
    let exe = std::env::current_exe().unwrap();
    // The test's full name in the test binary: this module's path without the crate.
    let test = format!("{}::{test}", module_path!().split_once("::").map_or("", |(_, module)| module));
    let status = Command::new("unshare")
        .arg("-rn")
        .arg(exe)
        .args([test.as_str(), "--exact", "--nocapture", "--test-threads=1"])
        .env(INSIDE, "1")
        .status()
        .unwrap();
    assert!(status.success(), "{test} inside its network namespace: {status}");
    false
}

fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip").args(args).output().map_err(|e| format!("cannot run ip: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!("ip {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim()))
    }
}

fn taxel_value(segment: usize, sample: u64, k: usize) -> u16 {
    (sample as u16).wrapping_add(3 * k as u16).wrapping_add(1000 * segment as u16)
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

/// The driver's view of emulated segments of `taxels` each: layers `seg0`,
/// `seg1`, ..., modules of 12.
fn segment_configs(taxels: &[usize]) -> Vec<SegmentConfig> {
    taxels
        .iter()
        .enumerate()
        .map(|(position, &count)| SegmentConfig {
            layer: format!("seg{position}"),
            vendor_id: EMULATED_VENDOR_ID,
            product_code: EMULATED_PRODUCT_CODE,
            taxels: count,
            modules: vec![12; count / 12],
            patch: position as u32 + 1,
            baseline: false,
        })
        .collect()
}

fn wait_for(reader: &mut Reader, state: WriterState, within: Duration) -> Duration {
    let started = Instant::now();
    while reader.writer_state() != state {
        assert!(started.elapsed() < within, "{} never became {state} (is {})", reader.label(), reader.writer_state());
        std::thread::sleep(Duration::from_millis(1));
    }
    started.elapsed()
}

/// Runs the calling emulator thread at SCHED_FIFO, just below the driver's
/// threads, as hardware answers whatever the host is doing.
fn emulator_priority() {
    for refused in (skinware::RtOptions { fifo_priority: Some(70), ..Default::default() }).apply() {
        println!("emulator thread: {refused}");
    }
}

/// Waits until the driver's status says the bus is up and every segment has
/// cycled at least once.
fn wait_for_bus_up(status: &EthercatStatus, within: Duration) {
    let started = Instant::now();
    while status.bus_fault().is_some() || status.segments().iter().any(|s| s.cycles == 0) {
        assert!(started.elapsed() < within, "never up: {:?}, segments {:?}", status.bus_fault(), status.segments());
        std::thread::sleep(Duration::from_millis(1));
    }
}

#[test]
fn driver_and_segments_over_veth() {
    if !in_own_namespace("driver_and_segments_over_veth") || !veth_pair_up() {
        return;
    }
    let taxels = [708, 708, 708];
    let segment = Arc::new(Mutex::new(emulated(&taxels)));
    let stop = Arc::new(AtomicBool::new(false));
    let frames = Arc::new(Mutex::new(0u64));
    let emulator = {
        let (segment, stop, frames) = (segment.clone(), stop.clone(), frames.clone());
        std::thread::spawn(move || {
            emulator_priority();
            let mut count = |_: &[u8], _: Option<&[u8]>| *frames.lock().unwrap() += 1;
            serve_interface(&segment, SEGMENT_END, &|| stop.load(Ordering::Relaxed), Some(&mut count))
        })
    };

    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-veth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (handler, status, mut readers) = start_driver(&dir, &taxels, Duration::from_millis(20));
    let started = Instant::now();
    for reader in &mut readers {
        wait_for(reader, WriterState::Running, Duration::from_secs(10));
    }
    println!("veth: 3 segments of 708 taxels running {:.0} ms after start", started.elapsed().as_secs_f64() * 1e3);
    // The status handle never waits for a segment's lock: a segment busy at
    // the first look keeps its blank initial snapshot until a later one.
    let looked = Instant::now();
    while !status.segments().iter().all(|s| s.state == "OP") {
        assert!(looked.elapsed() < Duration::from_secs(2), "not every segment in OP: {:?}", status.segments());
        std::thread::sleep(Duration::from_millis(5));
    }
    check_frames(&mut readers, 100);
    pull_the_cable(&mut readers, &status);
    let plugged = Instant::now();
    ip(&["link", "set", SEGMENT_END, "up"]).unwrap();
    while readers.iter().any(|r| r.writer_state() != WriterState::Running) {
        if emulator.is_finished() {
            panic!("the emulator ended: {:?}", emulator.join());
        }
        assert!(
            plugged.elapsed() < Duration::from_secs(15),
            "not running again 15 s after the link came back: bus {:?}, segments {:?}",
            status.bus_fault(),
            status.segments(),
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    println!("veth: link up: every layer running after {:.0} ms", plugged.elapsed().as_secs_f64() * 1e3);

    handler.stop();
    stop.store(true, Ordering::Relaxed);
    let stats = emulator.join().unwrap().unwrap();
    assert!(stats.answered > 100, "{stats:?}");
    assert_eq!(stats.frames, *frames.lock().unwrap());
    let _ = std::fs::remove_dir_all(&dir);
}

/// The driver at 200 Hz on the driver's end of the pair, with a reader of
/// each segment's layer. A shared machine (2 cores, builds running) stalls
/// threads for milliseconds; the layers fail on data 2 periods old.
fn start_driver(
    dir: &std::path::Path,
    taxels: &[usize],
    frame_timeout: Duration,
) -> (DriverHandler, EthercatStatus, Vec<Reader>) {
    let segments = segment_configs(taxels);
    let config = EthercatDriverConfig {
        name: "ecat".into(),
        segments: segments.clone(),
        rate_hz: 200.0,
        frame_timeout: Some(frame_timeout),
        rt: crate::driver_rt(),
    };
    let driver = EthercatDriver::new(config, FrameLink::Interface(DRIVER_END.into())).unwrap();
    let status = driver.status_handle();
    let options = HandlerOptions { dir: Some(dir.to_owned()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("ecat", Box::new(driver), &options).unwrap();
    let readers = segments
        .iter()
        .map(|s| {
            Reader::open_with("ecat", &s.layer, &ReaderOptions { dir: Some(dir.to_owned()), ..Default::default() })
                .unwrap()
        })
        .collect();
    (handler, status, readers)
}

/// Makes the veth pair and brings both ends up; `false` (and says why) where
/// the namespace allows no veth pair.
fn veth_pair_up() -> bool {
    let veth = ip(&["link", "add", DRIVER_END, "type", "veth", "peer", "name", SEGMENT_END])
        .and_then(|()| ip(&["link", "set", DRIVER_END, "up"]))
        .and_then(|()| ip(&["link", "set", SEGMENT_END, "up"]));
    if let Err(why) = veth {
        println!("skipped: no veth pair: {why}");
        return false;
    }
    true
}

/// Reads `frames` frames of every layer and checks every taxel.
fn check_frames(readers: &mut [Reader], frames: usize) {
    for _ in 0..frames {
        for (position, reader) in readers.iter_mut().enumerate() {
            let frame = reader.wait_newer(Duration::from_secs(1)).unwrap();
            let responses = frame.responses();
            let sample = responses[0].wrapping_sub(1000 * position as u16);
            for (k, &value) in responses.iter().enumerate() {
                assert_eq!(value, taxel_value(position, u64::from(sample), k), "segment {position} taxel {k}");
            }
        }
    }
}

/// Faults begun, per segment, as seen by polling the driver's status for
/// `how_long` (a short one may be missed); asserts meanwhile that the bus
/// stays up, every segment in OP, and that every fault is a lost frame.
fn segment_faults_for(status: &EthercatStatus, how_long: Duration) -> [u64; 3] {
    let started = Instant::now();
    let mut faults_seen = [0u64; 3];
    let mut faulted = [false; 3];
    while started.elapsed() < how_long {
        assert_eq!(status.bus_fault(), None, "late answers brought the bus down; segments {:?}", status.segments());
        for (position, s) in status.segments().iter().enumerate() {
            assert_eq!(s.state, "OP", "segment {position}: {:?}", status.segments());
            if let Some(why) = &s.fault {
                assert!(why.contains("frame lost"), "segment {position}: {why}");
                if !faulted[position] {
                    faults_seen[position] += 1;
                }
            }
            faulted[position] = s.fault.is_some();
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    faults_seen
}

/// Takes the segment's end of the pair down: every layer faults, then the
/// driver counts the bus as down.
fn pull_the_cable(readers: &mut [Reader], status: &EthercatStatus) {
    for reader in readers.iter_mut() {
        // Running (a stall of this loaded VM may fault a layer for a cycle).
        wait_for(reader, WriterState::Running, Duration::from_secs(5));
        println!("veth: {}: {} faults before the cable pull", reader.label(), reader.writer_stats().faults);
    }
    let pulled = Instant::now();
    ip(&["link", "set", SEGMENT_END, "down"]).unwrap();
    for reader in readers.iter_mut() {
        wait_for(reader, WriterState::Faulted, Duration::from_secs(5));
    }
    println!("veth: link down: every layer faulted after {:.1} ms", pulled.elapsed().as_secs_f64() * 1e3);
    // Long enough for the driver to declare the bus down and start again.
    while status.bus_fault().is_none() {
        assert!(pulled.elapsed() < Duration::from_secs(5), "the bus never counted as down");
        std::thread::sleep(Duration::from_millis(1));
    }
    println!(
        "veth: link down: bus down after {:.1} ms: {:?}",
        pulled.elapsed().as_secs_f64() * 1e3,
        status.bus_fault()
    );
    std::thread::sleep(Duration::from_millis(300));
}

/// The golden capture: a veth run of one 12-taxel segment, bring-up and
/// cycles, recorded on the segment's end (regenerate it by running
/// `the_veth_run_is_captured_and_replays_through_the_model` with
/// `SKINWARE_ETHERCAT_CAPTURE` set to this path).
const GOLDEN: &str = "tests/data/ethercat-veth-1x12.pcapng";

/// Replays a capture through a fresh segment: it must answer every request
/// byte for byte as captured. Returns (requests, process-data requests).
fn replay_capture(path: &std::path::Path) -> (usize, usize) {
    let capture = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let frames = skinware_emulate::ethercat::pcapng::read_frames(&capture).unwrap();
    let requests = skinware_emulate::ethercat::pcapng::replay(&frames, &mut emulated(&[12]))
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    // LRW (command 0x0C) as the first datagram: a cycle's process data.
    let cycles = frames.iter().filter(|f| f.len() > 16 && f[6] & 0x02 == 0 && f[16] == 0x0C).count();
    (requests, cycles)
}

#[test]
fn golden_capture_replays_through_the_model() {
    let (requests, cycles) = replay_capture(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(GOLDEN));
    println!("golden capture: {requests} requests answered as captured, {cycles} of them process data");
    assert!(requests > 100 && cycles >= 50, "{requests} requests, {cycles} cycles");
}

/// The golden capture reads the same with pcap-file (what ethercrab's own
/// replay tests use) as with our reader: what we write is pcapng.
#[test]
fn golden_capture_is_pcapng_to_an_independent_reader() {
    let bytes = std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(GOLDEN)).unwrap();
    let ours = skinware_emulate::ethercat::pcapng::read_frames(&bytes).unwrap();
    let mut reader = pcap_file::pcapng::PcapNgReader::new(&bytes[..]).unwrap();
    let mut theirs = Vec::new();
    let mut interfaces = 0;
    while let Some(block) = reader.next_block() {
        match block.unwrap() {
            pcap_file::pcapng::Block::EnhancedPacket(packet) => theirs.push(packet.data.to_vec()),
            pcap_file::pcapng::Block::InterfaceDescription(interface) => {
                assert_eq!(interface.linktype, pcap_file::DataLink::ETHERNET);
                interfaces += 1;
            }
            other => panic!("unexpected block {other:?}"),
        }
    }
    assert_eq!(interfaces, 1);
    assert_eq!(theirs, ours);
}

#[test]
fn the_veth_run_is_captured_and_replays_through_the_model() {
    if !in_own_namespace("the_veth_run_is_captured_and_replays_through_the_model") {
        return;
    }
    let veth = ip(&["link", "add", DRIVER_END, "type", "veth", "peer", "name", SEGMENT_END])
        .and_then(|()| ip(&["link", "set", DRIVER_END, "up"]))
        .and_then(|()| ip(&["link", "set", SEGMENT_END, "up"]));
    if let Err(why) = veth {
        println!("skipped: no veth pair: {why}");
        return;
    }
    let path = std::env::var_os("SKINWARE_ETHERCAT_CAPTURE")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| std::env::temp_dir().join(format!("skinware-ethercat-{}.pcapng", std::process::id())));
    let segment = Arc::new(Mutex::new(emulated(&[12])));
    let stop = Arc::new(AtomicBool::new(false));
    let emulator = {
        let (segment, stop, path) = (segment.clone(), stop.clone(), path.clone());
        std::thread::spawn(move || {
            let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
            let mut capture = skinware_emulate::ethercat::pcapng::PcapngWriter::new(file).unwrap();
            let started = Instant::now();
            let mut record = |request: &[u8], answer: Option<&[u8]>| {
                let at = started.elapsed().as_nanos() as u64;
                capture.write_frame(at, request).unwrap();
                if let Some(answer) = answer {
                    capture.write_frame(at, answer).unwrap();
                }
            };
            let stats = serve_interface(&segment, SEGMENT_END, &|| stop.load(Ordering::Relaxed), Some(&mut record));
            capture.finish().unwrap();
            stats
        })
    };
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-capture-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // One 12-taxel segment: the same driver as `start_driver` builds.
    let (handler, _status, readers) = start_driver(&dir, &[12], Duration::from_millis(20));
    let mut reader = readers.into_iter().next().unwrap();
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(10));
    for _ in 0..60 {
        reader.wait_newer(Duration::from_secs(1)).unwrap();
    }
    handler.stop();
    stop.store(true, Ordering::Relaxed);
    emulator.join().unwrap().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let (requests, cycles) = replay_capture(&path);
    println!(
        "veth capture {}: {requests} requests answered as captured, {cycles} of them process data",
        path.display()
    );
    if std::env::var_os("SKINWARE_ETHERCAT_CAPTURE").is_none() {
        let _ = std::fs::remove_file(&path);
    }
    assert!(cycles >= 50, "{cycles} cycles captured");
}

/// The segment (driver's position) a process-data frame belongs to, told by
/// its LRW's length: the segments' taxel counts differ.
fn segment_of_lrw(frame: &[u8], taxels: &[usize]) -> Option<usize> {
    let datagrams = skinware_emulate::ethercat::datagrams(frame)?;
    let lrw = datagrams.iter().find(|d| d.command == skinware_emulate::ethercat::Command::Lrw)?;
    taxels.iter().position(|&n| lrw.data.len() == 4 + 2 * n + 4)
}

/// Late answers (after the driver's frame timeout) reach ethercrab, which
/// refuses them: the frame they answer is lost to its segment's layer for a
/// cycle, but the link goes on. ethercrab's own `tx_rx_task` ended on the
/// first one, and the whole bus was brought up again.
#[test]
fn late_answers_fault_only_their_segment_and_never_the_bus() {
    if !in_own_namespace("late_answers_fault_only_their_segment_and_never_the_bus") || !veth_pair_up() {
        return;
    }
    // Different sizes, so that a frame's length tells its segment.
    let taxels = [12, 24, 36];
    const LATE_EVERY: u64 = 10;
    let segment = Arc::new(Mutex::new(emulated(&taxels)));
    let stop = Arc::new(AtomicBool::new(false));
    let late_phase = Arc::new(AtomicBool::new(false));
    // The segments whose frames were answered late, counted as the model
    // counts them: every LATE_EVERY-th process-data frame.
    let hit = Arc::new(Mutex::new([0u64; 3]));
    let emulator = {
        let (segment, stop, late_phase, hit) = (segment.clone(), stop.clone(), late_phase.clone(), hit.clone());
        std::thread::spawn(move || {
            // The segments answer as real ones do, however busy the host:
            // only the answers held back on purpose are late.
            emulator_priority();
            let mut process_data = 0u64;
            let mut observe = |request: &[u8], _: Option<&[u8]>| {
                if let Some(position) = segment_of_lrw(request, &taxels) {
                    process_data += 1;
                    if late_phase.load(Ordering::Relaxed) && process_data.is_multiple_of(LATE_EVERY) {
                        hit.lock().unwrap()[position] += 1;
                    }
                }
            };
            serve_interface(&segment, SEGMENT_END, &|| stop.load(Ordering::Relaxed), Some(&mut observe))
        })
    };
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-late-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let frame_timeout = Duration::from_millis(20);
    let (handler, status, mut readers) = start_driver(&dir, &taxels, frame_timeout);
    for reader in &mut readers {
        wait_for(reader, WriterState::Running, Duration::from_secs(10));
    }
    // The status is a snapshot that the bus thread's lock may leave at "not
    // brought up yet" for a while on a loaded host: the late answers start
    // only once it says the bus is up.
    wait_for_bus_up(&status, Duration::from_secs(10));
    // The process-data frames counted so far, the model's and the observer's
    // alike (both count every one from the start).
    {
        let mut segment = segment.lock().unwrap();
        late_phase.store(true, Ordering::Relaxed);
        let faults = segment.faults_mut();
        faults.late_every_nth_frame = std::num::NonZeroU64::new(LATE_EVERY);
        faults.late_by = frame_timeout * 2;
    }
    let faults_seen = segment_faults_for(&status, Duration::from_secs(1));
    let late = {
        let mut segment = segment.lock().unwrap();
        segment.faults_mut().late_every_nth_frame = None;
        late_phase.store(false, Ordering::Relaxed);
        segment.stats().late
    };
    let hit = *hit.lock().unwrap();
    println!(
        "late answers: {late} held back {:?}, by segment {hit:?}; segment faults seen {faults_seen:?}",
        frame_timeout * 2
    );
    assert!(late >= 10, "{late} late answers");
    assert!(faults_seen.iter().any(|&f| f > 0), "no segment was seen faulted by {late} late answers");
    for position in 0..3 {
        assert!(
            faults_seen[position] <= hit[position],
            "segment {position} faulted {} times, but only {} of its frames were late",
            faults_seen[position],
            hit[position]
        );
    }
    for reader in &mut readers {
        wait_for(reader, WriterState::Running, Duration::from_secs(5));
    }
    check_frames(&mut readers, 1);
    assert_eq!(status.bus_fault(), None);
    handler.stop();
    stop.store(true, Ordering::Relaxed);
    emulator.join().unwrap().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

/// A request with its datagrams' PDU indices zeroed: how a request of the
/// capture and one of the driver are matched (ethercrab numbers its PDUs as
/// it sends them, so a replay's indices differ from the capture's).
fn without_indices(frame: &[u8]) -> Vec<u8> {
    let mut frame = frame.to_vec();
    for start in datagram_starts(&frame) {
        frame[start + 1] = 0;
    }
    frame
}

/// Where each datagram's header starts; none for a frame that is not
/// EtherCAT.
fn datagram_starts(frame: &[u8]) -> Vec<usize> {
    let Ok(layout) = skinware_emulate::ethercat::check_frame(frame) else { return Vec::new() };
    let mut starts = Vec::new();
    let mut offset = layout.payload_start;
    while let Some(datagram) = skinware_emulate::ethercat::Datagram::at(frame, offset, layout.payload_end) {
        starts.push(datagram.start);
        if !datagram.more_follows {
            break;
        }
        offset = datagram.end;
    }
    starts
}

/// A bus made of a capture: each request the driver sends is answered with
/// the captured answer to the equal request (equal but for PDU indices; the
/// equal requests' answers in capture order, the last one again once they
/// run out), its indices set to the request's. A request the capture never
/// saw is lost.
struct CaptureReplay {
    answers: std::collections::HashMap<Vec<u8>, std::collections::VecDeque<Vec<u8>>>,
    last: std::collections::HashMap<Vec<u8>, Vec<u8>>,
    unknown: Arc<Mutex<Vec<Vec<u8>>>>,
}

impl CaptureReplay {
    fn new(frames: &[Vec<u8>]) -> CaptureReplay {
        let is_answer = |f: &Vec<u8>| f.len() > 6 && f[6] & 0x02 != 0;
        let mut answers: std::collections::HashMap<_, std::collections::VecDeque<_>> = Default::default();
        for pair in frames.windows(2) {
            if !is_answer(&pair[0]) && is_answer(&pair[1]) {
                answers.entry(without_indices(&pair[0])).or_default().push_back(pair[1].clone());
            }
        }
        CaptureReplay { answers, last: Default::default(), unknown: Default::default() }
    }
}

impl FrameExchange for CaptureReplay {
    fn exchange(&mut self, frame: &mut Vec<u8>) -> bool {
        let key = without_indices(frame);
        let answer = match self.answers.get_mut(&key).and_then(|queue| queue.pop_front()) {
            Some(answer) => {
                self.last.insert(key, answer.clone());
                answer
            }
            None => match self.last.get(&key) {
                Some(answer) => answer.clone(),
                None => {
                    self.unknown.lock().unwrap().push(frame.clone());
                    return false;
                }
            },
        };
        let indices: Vec<u8> = datagram_starts(frame).into_iter().map(|start| frame[start + 1]).collect();
        *frame = answer;
        for (start, index) in datagram_starts(frame).into_iter().zip(indices) {
            frame[start + 1] = index;
        }
        true
    }
}

/// The golden capture drives the real driver: the bring-up reaches OP on
/// the captured answers alone, and readers get the captured taxels.
#[test]
fn golden_capture_drives_the_driver_to_op_and_its_taxels_to_readers() {
    let bytes = std::fs::read(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(GOLDEN)).unwrap();
    let frames = skinware_emulate::ethercat::pcapng::read_frames(&bytes).unwrap();
    // Every cycle's taxels, from the captured answers' LRW inputs.
    let taxels = 12;
    let captured: std::collections::HashSet<Vec<u16>> = frames
        .iter()
        .filter(|f| f[6] & 0x02 != 0)
        .filter_map(|f| skinware_emulate::ethercat::datagrams(f))
        .flat_map(|d| d.into_iter())
        .filter(|d| d.command == skinware_emulate::ethercat::Command::Lrw && d.data.len() == 4 + 2 * taxels + 4)
        .map(|d| d.data[4..4 + 2 * taxels].chunks(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect())
        .collect();
    assert!(captured.len() >= 50, "{} cycles' taxels in the capture", captured.len());
    let replay = CaptureReplay::new(&frames);
    let unknown = replay.unknown.clone();
    let bus: Arc<Mutex<dyn FrameExchange>> = Arc::new(Mutex::new(replay));

    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-golden-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // The capture's driver settings (see the_veth_run_is_captured_and_replays_through_the_model).
    let config = EthercatDriverConfig {
        name: "ecat".into(),
        segments: vec![SegmentConfig {
            layer: "seg0".into(),
            vendor_id: EMULATED_VENDOR_ID,
            product_code: EMULATED_PRODUCT_CODE,
            taxels,
            modules: vec![12],
            patch: 1,
            baseline: false,
        }],
        rate_hz: 200.0,
        frame_timeout: Some(Duration::from_millis(20)),
        rt: crate::driver_rt(),
    };
    let driver = EthercatDriver::new(config, FrameLink::InProcess(bus)).unwrap();
    let status = driver.status_handle();
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("ecat", Box::new(driver), &options).unwrap();
    let mut reader =
        Reader::open_with("ecat", "seg0", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() }).unwrap();
    let started = Instant::now();
    while status.segments()[0].cycles == 0 {
        assert!(
            started.elapsed() < Duration::from_secs(10),
            "the replayed bring-up never reached OP: bus {:?}, {:?}; {} requests not in the capture, the first: {:02x?}",
            status.bus_fault(),
            status.segments(),
            unknown.lock().unwrap().len(),
            unknown.lock().unwrap().first(),
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    println!("golden replay: OP, cycling {:.0} ms after start", started.elapsed().as_secs_f64() * 1e3);
    let segment = &status.segments()[0];
    assert_eq!(segment.identity, Some([EMULATED_VENDOR_ID, EMULATED_PRODUCT_CODE, 1, 1]));
    assert_eq!(segment.state, "OP");
    let mut samples = Vec::new();
    for _ in 0..20 {
        let frame = reader.wait_newer(Duration::from_secs(1)).unwrap();
        let responses = frame.responses().to_vec();
        assert!(captured.contains(&responses), "published taxels not in the capture: {responses:?}");
        samples.push(responses[0]);
    }
    println!("golden replay: samples {samples:?}; {} requests not in the capture", unknown.lock().unwrap().len());
    // The captured cycles in their order (a reader may skip some).
    assert!(samples.windows(2).all(|w| w[1] > w[0]), "{samples:?}");
    // Every request the driver sent was one the capture has: its bring-up
    // and cycles are still the captured ones.
    assert!(unknown.lock().unwrap().is_empty(), "first unknown request: {:02x?}", unknown.lock().unwrap().first());
    handler.stop();
    let _ = std::fs::remove_dir_all(&dir);
}

/// The driver's own interface going down is a socket error, not a late or
/// lost frame: the link ends with an error naming the interface, and the
/// bus comes back once the interface is up again.
#[test]
fn the_drivers_interface_going_down_ends_the_link_naming_it() {
    if !in_own_namespace("the_drivers_interface_going_down_ends_the_link_naming_it") {
        return;
    }
    let veth = ip(&["link", "add", DRIVER_END, "type", "veth", "peer", "name", SEGMENT_END])
        .and_then(|()| ip(&["link", "set", DRIVER_END, "up"]))
        .and_then(|()| ip(&["link", "set", SEGMENT_END, "up"]));
    if let Err(why) = veth {
        println!("skipped: no veth pair: {why}");
        return;
    }
    let segment = Arc::new(Mutex::new(emulated(&[12])));
    let stop = Arc::new(AtomicBool::new(false));
    let emulator = {
        let (segment, stop) = (segment.clone(), stop.clone());
        std::thread::spawn(move || serve_interface(&segment, SEGMENT_END, &|| stop.load(Ordering::Relaxed), None))
    };
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-ecat-ifdown-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // One 12-taxel segment: the same driver as `start_driver` builds.
    let (handler, status, readers) = start_driver(&dir, &[12], Duration::from_millis(20));
    let mut reader = readers.into_iter().next().unwrap();
    wait_for_bus_up(&status, Duration::from_secs(10));
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(10));
    let down = Instant::now();
    ip(&["link", "set", DRIVER_END, "down"]).unwrap();
    let why = loop {
        if let Some(why) = status.bus_fault() {
            break why;
        }
        assert!(down.elapsed() < Duration::from_secs(5), "the bus never counted as down");
        std::thread::sleep(Duration::from_millis(1));
    };
    println!("interface down: bus down after {:.1} ms: {why}", down.elapsed().as_secs_f64() * 1e3);
    assert!(why.contains(DRIVER_END), "{why}");
    ip(&["link", "set", DRIVER_END, "up"]).unwrap();
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(15));
    handler.stop();
    stop.store(true, Ordering::Relaxed);
    emulator.join().unwrap().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}
