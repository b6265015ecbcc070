//! Opening a channel whose segment holds arbitrary bytes (a foreign, damaged
//! or hostile file under a channel's name), then using every read the reader
//! offers: a typed error or a value, never a panic or a fault.
#![no_main]

use std::path::PathBuf;
use std::sync::OnceLock;
use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use skinware::{Reader, ReaderOptions};

fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = if std::path::Path::new("/dev/shm").is_dir() { "/dev/shm".into() } else { std::env::temp_dir() };
        let dir = base.join(format!("skinware-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("fuzz segment directory");
        dir
    })
}

fuzz_target!(|bytes: &[u8]| {
    let path = dir().join("skinware.fuzz.layer");
    std::fs::write(&path, bytes).expect("write the segment");
    let options = ReaderOptions { dir: Some(dir().clone()), allow_gone: true, ..ReaderOptions::default() };
    if let Ok(mut reader) = Reader::open_with("fuzz", "layer", &options) {
        let _ = reader.topology();
        let _ = reader.schema();
        let _ = reader.writer_state();
        let _ = reader.writer_stats();
        let _ = reader.latest().map(|frame| frame.responses().len());
        let _ = reader.wait_newer(Duration::ZERO).map(|frame| frame.seq());
    }
    let _ = skinware::list_channels(dir());
});
