//! The lock-based baseline's readers in `skin bench peers`: reading back to
//! back on request (`busy`), and waiting for every frame.

use anyhow::Result;

use super::setup::{FRAME_BYTES, PeerReaderSamples};
use crate::rwlock_peer::RwLockChannel;

/// Reads the newest frame back to back while `running`, counting the reads.
pub(super) fn read_busy(name: &str, running: impl Fn() -> bool, samples: &mut PeerReaderSamples) -> Result<()> {
    let path = skinware::shm::segment_dir().join(format!("skinware-bench-rwlock.{name}"));
    let channel = RwLockChannel::open(&path, FRAME_BYTES)?;
    let mut copy = vec![0u8; FRAME_BYTES];
    while running() {
        channel.read_latest(&mut copy)?;
        // Keep the copy observable, or the compiler may drop it.
        std::hint::black_box(&mut copy);
        samples.reads += 1;
    }
    Ok(())
}

/// Waits for every frame while `running` (never past `deadline`): its
/// latency and the copy's own time.
pub(super) fn read_waiting(
    name: &str,
    deadline: u64,
    running: impl Fn() -> bool,
    samples: &mut PeerReaderSamples,
) -> Result<()> {
    let path = skinware::shm::segment_dir().join(format!("skinware-bench-rwlock.{name}"));
    let channel = RwLockChannel::open(&path, FRAME_BYTES)?;
    let mut copy = vec![0u8; FRAME_BYTES];
    let mut last = 0;
    while running() {
        let until = (skinware::os::monotonic_ns() + 100_000_000).min(deadline);
        if let Some((seq, published_ns, copy_ns)) = channel.wait_newer(last, &mut copy, until)? {
            std::hint::black_box(&mut copy);
            let holding = skinware::os::monotonic_ns();
            last = seq;
            samples.latency_ns.push(holding.saturating_sub(published_ns));
            samples.copy_ns.push(copy_ns);
        }
    }
    Ok(())
}
