//! skinware's reader modes in `skin bench peers`: reading back to back on
//! request (`busy`), and waiting for every frame, plainly (`skinware`) or
//! anticipating it (`skinware-spin`).

use std::time::Duration;

use anyhow::Result;
use skinware::Reader;

use super::setup::{ANTICIPATE, PeerReaderSamples};

/// Reads the newest frame back to back while `running`, counting the reads.
pub(super) fn read_busy(name: &str, running: impl Fn() -> bool, samples: &mut PeerReaderSamples) -> Result<()> {
    let mut reader = Reader::open(name, "frame")?;
    while running() {
        if reader.latest().is_ok() {
            samples.reads += 1;
        }
    }
    Ok(())
}

/// Waits for every frame while `running`: its latency and the read's own time.
pub(super) fn read_waiting(
    system: &str,
    name: &str,
    running: impl Fn() -> bool,
    samples: &mut PeerReaderSamples,
) -> Result<()> {
    let anticipate = (system == "skinware-spin").then_some(ANTICIPATE);
    let options = skinware::ReaderOptions { anticipate, ..skinware::ReaderOptions::default() };
    let mut reader = Reader::open_with(name, "frame", &options)?;
    while running() {
        if let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) {
            let holding = skinware::os::monotonic_ns();
            samples.latency_ns.push(holding.saturating_sub(frame.published_ns()));
            samples.copy_ns.push(reader.stats().read_ns_last);
        }
    }
    Ok(())
}
