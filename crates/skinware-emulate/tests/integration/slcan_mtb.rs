//! End to end without hardware: emulated MTB boards on the device end of an
//! SLCAN pseudo-terminal → the CAN driver (SLCAN codec, MTB decoder) → the
//! exchange → a reader. Every taxel value is checked, then the fault switches.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use skinware::driver::DriverHandler;
use skinware::{HandlerOptions, Reader, ReaderOptions, WriterState};
use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
use skinware_drivers::can::icub_mtb::{Board, BoardSettings};
use skinware_drivers::virtual_skin::BASELINE;
use skinware_emulate::{MtbBoards, MtbFaults, SlcanDevice, run_mtb};

/// Taxel `i` of the bus feels `BASELINE + 100 * (i % 200)`: it reads
/// `240 - i % 200` on the wire (no-load 240) and is published as `15 + i % 200`.
fn pattern(_t: f64, responses: &mut [u16]) {
    for (i, response) in responses.iter_mut().enumerate() {
        *response = BASELINE + 100 * (i % 200) as u16;
    }
}

struct Emulator {
    url: String,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<u64>>,
}

impl Emulator {
    fn start(boards: u8, triangles: u8, faults: MtbFaults) -> Emulator {
        let mut device = SlcanDevice::new().unwrap();
        let url = device.url();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut boards = MtbBoards::new(boards, triangles, Duration::from_millis(20), faults);
            run_mtb(&mut boards, &mut device, &pattern, None, &|| stopped.load(Ordering::Relaxed)).unwrap()
        });
        Emulator { url, stop, thread: Some(thread) }
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn segment_dir(test: &str) -> std::path::PathBuf {
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-emulate-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn driver(url: &str, boards: u8, triangles: u8) -> CanDriver {
    CanDriver::new(CanDriverConfig {
        name: "mtb".into(),
        layer: "skin".into(),
        interface: url.into(),
        protocol: Protocol::IcubMtb {
            boards: (1..=boards).map(|address| Board { address, triangles: (0..triangles).collect() }).collect(),
            settings: BoardSettings { period_ms: 20, no_load: 240, ..BoardSettings::default() },
        },
        rate_hz: 50.0,
        rt: Default::default(),
    })
    .unwrap()
}

fn wait_for(reader: &mut Reader, state: WriterState, within: Duration) -> Duration {
    let started = Instant::now();
    while reader.writer_state() != state {
        assert!(started.elapsed() < within, "{} never became {state} (is {})", reader.label(), reader.writer_state());
        std::thread::sleep(Duration::from_millis(1));
    }
    started.elapsed()
}

#[test]
fn every_taxel_arrives_through_slcan() {
    let emulator = Emulator::start(2, 16, MtbFaults::default());
    let dir = segment_dir("values");
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("mtb", Box::new(driver(&emulator.url, 2, 16)), &options).unwrap();
    let mut reader =
        Reader::open_with("mtb", "skin", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() }).unwrap();
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(5));
    let frame = reader.wait_newer(Duration::from_secs(2)).unwrap();
    let expected: Vec<u16> = (0..2 * 16 * 12).map(|i| 15 + (i % 200) as u16).collect();
    assert_eq!(frame.responses(), &expected[..]);
    // The frames keep coming at the boards' rate.
    let first = frame.seq();
    std::thread::sleep(Duration::from_millis(500));
    let later = reader.latest().unwrap().seq();
    assert!(later - first >= 20, "{} frames in 500 ms at 50 Hz", later - first);
    handler.stop();
    let _ = std::fs::remove_dir_all(&dir);
}

fn handler_and_reader(test: &str, url: &str, boards: u8, triangles: u8) -> (DriverHandler, Reader, std::path::PathBuf) {
    let dir = segment_dir(test);
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("mtb", Box::new(driver(url, boards, triangles)), &options).unwrap();
    let reader =
        Reader::open_with("mtb", "skin", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() }).unwrap();
    (handler, reader, dir)
}

/// Milliseconds from the newest good frame to the fault being seen.
fn detection_ms(reader: &mut Reader, within: Duration) -> f64 {
    wait_for(reader, WriterState::Faulted, within);
    let seen = skinware::os::monotonic_ns();
    let last_good = reader.latest().map(|f| f.published_ns()).unwrap_or(seen);
    (seen - last_good) as f64 / 1e6
}

#[test]
fn a_silent_board_faults_the_layer_within_two_periods() {
    let silence = MtbFaults { silence_after: Some(Duration::from_millis(600)), ..MtbFaults::default() };
    let emulator = Emulator::start(1, 4, silence);
    let (handler, mut reader, dir) = handler_and_reader("silence", &emulator.url, 1, 4);
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(5));
    let detected = detection_ms(&mut reader, Duration::from_secs(5));
    println!("silence: faulted {detected:.1} ms after the last good frame (period 20 ms)");
    assert!(detected < 200.0, "{detected} ms");
    handler.stop();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn missing_tails_and_error_reports_fault_the_layer() {
    for (name, faults) in [
        ("drop-tails", MtbFaults { drop_tails: true, ..MtbFaults::default() }),
        ("error-nibble", MtbFaults { error_nibble: Some(2), ..MtbFaults::default() }),
    ] {
        let emulator = Emulator::start(1, 4, faults);
        let (handler, mut reader, dir) = handler_and_reader(name, &emulator.url, 1, 4);
        // Frames flow, yet the layer never publishes one: no triangle is ever
        // whole (faulted after the first-frame grace of 1 s) or healthy.
        wait_for(&mut reader, WriterState::Faulted, Duration::from_secs(10));
        let started = std::time::Instant::now();
        while reader.writer_stats().faults <= 10 {
            assert!(started.elapsed() < Duration::from_secs(10), "{name}: acquisitions should keep failing");
            std::thread::sleep(Duration::from_millis(10));
        }
        assert_eq!(reader.writer_stats().frames, 0, "{name}: a frame was published");
        handler.stop();
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// Killing the boards is a cable pull; bringing them back recovers, with the
/// same reader. Over cannelloni, whose address survives the restart.
#[test]
fn boards_killed_and_restarted_over_cannelloni() {
    let (device_port, host_port) = (free_udp_port(), free_udp_port());
    let device_url = format!("cannelloni://127.0.0.1:{device_port}?peer=127.0.0.1:{host_port}");
    let host_url = format!("cannelloni://127.0.0.1:{host_port}?peer=127.0.0.1:{device_port}");
    let start = |url: &str| {
        let mut link = skinware_drivers::can::open(url).unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut boards = MtbBoards::new(2, 8, Duration::from_millis(20), MtbFaults::default());
            run_mtb(&mut boards, &mut link, &pattern, None, &|| stopped.load(Ordering::Relaxed)).unwrap()
        });
        (stop, thread)
    };
    let (stop, thread) = start(&device_url);
    let (handler, mut reader, dir) = handler_and_reader("cannelloni", &host_url, 2, 8);
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(5));
    let frame = reader.wait_newer(Duration::from_secs(1)).unwrap();
    let expected: Vec<u16> = (0..2 * 8 * 12).map(|i| 15 + (i % 200) as u16).collect();
    assert_eq!(frame.responses(), &expected[..]);
    stop.store(true, Ordering::Relaxed);
    thread.join().unwrap();
    let detected = detection_ms(&mut reader, Duration::from_secs(5));
    let (stop, thread) = start(&device_url);
    let restarted = Instant::now();
    wait_for(&mut reader, WriterState::Running, Duration::from_secs(5));
    let recovered = restarted.elapsed();
    println!(
        "cannelloni: boards killed: faulted {detected:.1} ms after the last good frame; restarted: running again after {:.0} ms",
        recovered.as_secs_f64() * 1e3
    );
    assert!(reader.wait_newer(Duration::from_secs(1)).unwrap().responses() == &expected[..]);
    stop.store(true, Ordering::Relaxed);
    thread.join().unwrap();
    handler.stop();
    let _ = std::fs::remove_dir_all(&dir);
}

fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}
