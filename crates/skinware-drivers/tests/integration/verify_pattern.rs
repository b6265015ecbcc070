//! The virtual skin's verification pattern on the driver path: every frame a
//! reader gets from a patterned layer matches the pattern of its own
//! sequence number (and not that of its neighbour), cable pulls included.

use std::time::Duration;

use skinware::{DriverHandler, HandlerOptions, Reader, ReaderOptions};
use skinware_drivers::virtual_skin::pattern::{PATTERN_BASE, pattern_mismatch};
use skinware_drivers::{Rate, VirtualSkin, VirtualSkinConfig};

#[test]
fn every_frame_of_a_patterned_layer_checks_against_its_own_number() {
    let dir = std::path::PathBuf::from("/dev/shm").join(format!("skinware-pattern-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let pull = dir.join("pulled");
    let config = VirtualSkinConfig {
        name: "pattern".into(),
        sensors: 1_200,
        layers: 2,
        rate: Rate::Fixed(200.0),
        verify_pattern: true,
        pull_files: Some(vec![pull.clone(), dir.join("never")]),
        ..VirtualSkinConfig::default()
    };
    let driver = VirtualSkin::new(config).unwrap();
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("pattern", Box::new(driver), &options).unwrap();
    let mut reader =
        Reader::open_with("pattern", "pattern-0", &ReaderOptions { dir: Some(dir.clone()), ..Default::default() })
            .unwrap();
    let mut checked = 0;
    let mut pulled_at = None;
    while checked < 60 {
        let frame = reader.wait_newer(Duration::from_secs(2)).expect("a frame within 2 s");
        let responses = frame.responses();
        assert_eq!(responses.len(), 600);
        assert_eq!(pattern_mismatch(frame.seq(), responses), None, "frame {}", frame.seq());
        assert!(pattern_mismatch(frame.seq() + 1, responses).is_some(), "frame {} passes as the next", frame.seq());
        assert!(responses.iter().all(|&r| (PATTERN_BASE..PATTERN_BASE + 32).contains(&r)));
        checked += 1;
        // Halfway, pull the cable for a while: the frames after it check too.
        if checked == 30 {
            std::fs::write(&pull, b"").unwrap();
            pulled_at = Some(frame.seq());
            std::thread::sleep(Duration::from_millis(300));
            std::fs::remove_file(&pull).unwrap();
        }
    }
    assert!(reader.writer_stats().faults > 0, "the cable pull was not seen (pulled after frame {pulled_at:?})");
    handler.stop();
    let _ = std::fs::remove_dir_all(&dir);
}
