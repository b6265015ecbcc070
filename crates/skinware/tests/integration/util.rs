//! Helpers shared by the integration tests (and the stress harness).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use skinware::{ReaderOptions, WriterOptions};

/// A private segment directory under /dev/shm (real tmpfs shared memory),
/// removed with everything in it when dropped.
pub struct SegmentDir {
    pub path: PathBuf,
}

impl SegmentDir {
    pub fn new(test: &str) -> SegmentDir {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let base = if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let path =
            base.join(format!("skinware-test-{}-{}-{test}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)));
        std::fs::create_dir_all(&path).unwrap();
        SegmentDir { path }
    }

    pub fn writer(&self) -> WriterOptions {
        WriterOptions { dir: Some(self.path.clone()), ..WriterOptions::default() }
    }

    pub fn reader(&self) -> ReaderOptions {
        ReaderOptions { dir: Some(self.path.clone()), ..ReaderOptions::default() }
    }

    pub fn segment(&self, skin: &str, channel: &str) -> PathBuf {
        self.path.join(format!("skinware.{skin}.{channel}"))
    }

    /// Names of the files left in the directory.
    pub fn files(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&self.path)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

impl Drop for SegmentDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}
