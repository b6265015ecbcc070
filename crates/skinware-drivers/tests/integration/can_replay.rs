//! The CySkin and XELA decoders on the driver path, fed by `candump -l` logs
//! (what a user records from a real skin once and replays forever): every
//! published response is checked against the log.

use std::time::Duration;

use skinware::{DriverHandler, HandlerOptions, Reader, ReaderOptions, WriterState};
use skinware_drivers::can::candump::{LogRecord, format_line};
use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
use skinware_drivers::can::{CanFrame, cyskin, xela};

struct Replayed {
    dir: std::path::PathBuf,
    handler: Option<DriverHandler>,
    reader: Reader,
}

impl Drop for Replayed {
    fn drop(&mut self) {
        if let Some(handler) = self.handler.take() {
            handler.stop();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// Writes `frames` as a log, 1 ms apart and looping, and runs a driver on it.
fn replay(test: &str, frames: &[CanFrame], protocol: Protocol) -> Replayed {
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-replay-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log: String = frames
        .iter()
        .enumerate()
        .map(|(i, frame)| {
            let record =
                LogRecord { time_us: 1_700_000_000_000_000 + 1000 * i as u64, interface: "can0".into(), frame: *frame };
            format_line(&record) + "\n"
        })
        .collect();
    let path = dir.join("skin.log");
    std::fs::write(&path, log).unwrap();
    let driver = CanDriver::new(CanDriverConfig {
        name: test.into(),
        layer: "skin".into(),
        interface: format!("candump://{}?loop=true", path.display()),
        protocol,
        rate_hz: 50.0,
        rt: Default::default(),
    })
    .unwrap();
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start(test, Box::new(driver), &options).unwrap();
    let mut reader =
        Reader::open_with(test, "skin", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() }).unwrap();
    // The first acquisitions may come before the first whole sample.
    let started = std::time::Instant::now();
    while reader.wait_newer(Duration::from_millis(200)).is_err() {
        assert!(started.elapsed() < Duration::from_secs(5), "no frame from the replay");
    }
    // Running (one acquisition may find a module late on a loaded machine: allow it to settle).
    while reader.writer_state() != WriterState::Running {
        assert!(started.elapsed() < Duration::from_secs(5), "the replayed layer is {}", reader.writer_state());
        std::thread::sleep(Duration::from_millis(5));
    }
    Replayed { dir, handler: Some(handler), reader }
}

#[test]
fn cyskin_patches_from_a_log() {
    let bases = [0x405u16, 0x505];
    let samples: Vec<[u16; cyskin::TAXELS]> =
        bases.iter().enumerate().map(|(p, _)| std::array::from_fn(|t| 1000 * (p as u16 + 1) + t as u16)).collect();
    let frames: Vec<CanFrame> =
        bases.iter().zip(&samples).flat_map(|(&base, taxels)| cyskin::sample_frames(base, taxels)).collect();
    let mut replayed = replay("cyskin", &frames, Protocol::CySkin { base_ids: bases.to_vec() });
    let frame = replayed.reader.wait_newer(Duration::from_secs(1)).unwrap();
    let expected: Vec<u16> = samples.concat();
    assert_eq!(frame.responses(), &expected[..]);
}

#[test]
fn xela_taxels_from_a_log() {
    let taxels = 16;
    let axes: Vec<[u16; 3]> = (0..taxels).map(|t| [100 + t as u16, 200 + t as u16, 300 + t as u16]).collect();
    let frames: Vec<CanFrame> = axes.iter().enumerate().map(|(t, &a)| xela::answer(t, a).unwrap()).collect();
    let mut replayed = replay("xela", &frames, Protocol::Xela { board: 1, taxels });
    let frame = replayed.reader.wait_newer(Duration::from_secs(1)).unwrap();
    // Three responses per taxel: X, Y, Z.
    let expected: Vec<u16> = axes.concat();
    assert_eq!(frame.responses(), &expected[..]);
    assert_eq!(replayed.reader.topology().unwrap().modules.len(), taxels);
}
