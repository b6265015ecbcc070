//! python-can, an independent implementation of SLCAN, sends iCub MTB frames
//! (built by the Python script from the protocol's description) through a
//! pair of pseudo-terminals joined like a null-modem cable into skinware's
//! CAN driver; every published response is checked.
//!
//! Needs a Python with python-can: `$SKINWARE_PYTHON` (`.ci/run` makes a
//! venv), else `python3`. Without it the test says so and skips, except under
//! `CI=true`, where it fails.

use std::io::{Read, Write};
use std::process::Command;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};
use skinware::driver::DriverHandler;
use skinware::{HandlerOptions, Reader, ReaderOptions, WriterState};
use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
use skinware_drivers::can::icub_mtb::{Board, BoardSettings};

fn python() -> Option<String> {
    let python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
    let found = Command::new(&python).args(["-c", "import can, serial"]).output().ok()?;
    found.status.success().then_some(python)
}

/// Two pseudo-terminals whose masters are joined: what one's slave writes,
/// the other's slave reads. Returns the two slave paths.
fn null_modem(stop: Arc<AtomicBool>) -> (String, String) {
    let (first, first_slave) = TTYPort::pair().unwrap();
    let (second, second_slave) = TTYPort::pair().unwrap();
    let paths = (first_slave.name().unwrap(), second_slave.name().unwrap());
    drop((first_slave, second_slave));
    let copy = |mut from: TTYPort, mut to: TTYPort, stop: Arc<AtomicBool>| {
        std::thread::spawn(move || {
            let mut buffer = [0u8; 4096];
            let _ = from.set_timeout(Duration::from_millis(10));
            while !stop.load(Ordering::Relaxed) {
                match from.read(&mut buffer) {
                    Ok(n) if n > 0 => {
                        let _ = to.write_all(&buffer[..n]);
                    }
                    Ok(_) => {}
                    // No one holds the slave yet (EIO), or nothing to read.
                    Err(_) => std::thread::sleep(Duration::from_millis(2)),
                }
            }
        })
    };
    let (first_copy, second_copy) = (first.try_clone_native().unwrap(), second.try_clone_native().unwrap());
    copy(first, second_copy, stop.clone());
    copy(second, first_copy, stop);
    paths
}

#[test]
#[cfg_attr(
    skip_no_python_can,
    ignore = "needs python-can and pyserial in $SKINWARE_PYTHON or python3: pip install python-can pyserial"
)]
fn python_can_frames_arrive_value_by_value() {
    let Some(python) = python() else {
        let reason = "no Python with python-can and pyserial (set SKINWARE_PYTHON, or pip install python-can pyserial)";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "{reason}: CI must run this oracle");
        println!("SKIPPED: {reason}");
        return;
    };
    let stop = Arc::new(AtomicBool::new(false));
    let (ours, theirs) = null_modem(stop.clone());
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-python-can-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let triangles = 6u8;
    let driver = CanDriver::new(CanDriverConfig {
        name: "mtb".into(),
        layer: "skin".into(),
        interface: format!("slcan://{ours}?bitrate=1000000"),
        protocol: Protocol::IcubMtb {
            boards: vec![Board { address: 3, triangles: (0..triangles).collect() }],
            settings: BoardSettings { period_ms: 20, no_load: 240, ..BoardSettings::default() },
        },
        rate_hz: 50.0,
        rt: Default::default(),
    })
    .unwrap();
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("oracle", Box::new(driver), &options).unwrap();
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python/send_icub_frames.py");
    let sender = Command::new(&python).args([script, &theirs, "3", &triangles.to_string(), "3"]).spawn().unwrap();
    let mut reader =
        Reader::open_with("oracle", "skin", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() }).unwrap();
    let started = Instant::now();
    while reader.writer_state() != WriterState::Running {
        assert!(started.elapsed() < Duration::from_secs(10), "the layer never ran: {}", reader.writer_state());
        std::thread::sleep(Duration::from_millis(5));
    }
    // The first frame comes once the Python sender runs: its start (a fresh
    // venv compiles python-can's modules on first import) took over 2 s on a
    // loaded CI machine. A wait, not a timing assertion.
    let frame = reader.wait_newer(Duration::from_secs(30)).unwrap();
    let expected: Vec<u16> = (0..u16::from(triangles) * 12).map(|i| 15 + i).collect();
    assert_eq!(frame.responses(), &expected[..]);
    let output = sender.wait_with_output().unwrap();
    assert!(output.status.success(), "the python-can sender failed");
    handler.stop();
    stop.store(true, Ordering::Relaxed);
    let _ = std::fs::remove_dir_all(&dir);
}

/// The other direction: python-can is the host of emulated boards (our
/// SLCAN device end and MTB model) and checks what they stream.
#[test]
#[cfg_attr(
    skip_no_python_can,
    ignore = "needs python-can and pyserial in $SKINWARE_PYTHON or python3: pip install python-can pyserial"
)]
fn python_can_reads_the_emulated_boards() {
    let Some(python) = python() else {
        let reason = "no Python with python-can and pyserial (set SKINWARE_PYTHON, or pip install python-can pyserial)";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "{reason}: CI must run this oracle");
        println!("SKIPPED: {reason}");
        return;
    };
    let mut device = skinware_emulate::SlcanDevice::new().unwrap();
    let path = device.path().to_owned();
    let stop = Arc::new(AtomicBool::new(false));
    let stopped = stop.clone();
    let emulator = std::thread::spawn(move || {
        let mut boards = skinware_emulate::MtbBoards::new(2, 3, Duration::from_millis(40), Default::default());
        let touch = |_t: f64, responses: &mut [u16]| {
            for (i, response) in responses.iter_mut().enumerate() {
                *response = skinware_drivers::virtual_skin::BASELINE + 100 * i as u16;
            }
        };
        skinware_emulate::run_mtb(&mut boards, &mut device, &touch, None, &|| stopped.load(Ordering::Relaxed)).unwrap()
    });
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/python/receive_icub_frames.py");
    let output = Command::new(&python).args([script, &path, "1"]).output().unwrap();
    stop.store(true, Ordering::Relaxed);
    emulator.join().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let seen: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    // Only board 1 was started: its 3 triangles, about 50 pairs each in 1 s at 20 ms.
    let keys: Vec<&String> = seen.as_object().unwrap().keys().collect();
    assert_eq!(keys, ["1.0", "1.1", "1.2"], "{seen}");
    for triangle in 0..3u64 {
        let entry = &seen[format!("1.{triangle}")];
        let (heads, tails) = (entry["heads"].as_u64().unwrap(), entry["tails"].as_u64().unwrap());
        assert!(heads >= 30 && heads.abs_diff(tails) <= 1, "triangle {triangle}: {heads} heads, {tails} tails");
        // Taxel i of the bus feels 100 * i: one count below no-load (240) per 100.
        let raw: Vec<u64> = entry["raw"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
        let expected: Vec<u64> = (0..12).map(|k| 240 - (12 * triangle + k)).collect();
        assert_eq!(raw, expected, "triangle {triangle}");
    }
}
