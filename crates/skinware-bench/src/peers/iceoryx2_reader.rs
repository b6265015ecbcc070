//! iceoryx2's reader in `skin bench peers` (cargo feature `iceoryx2`):
//! waiting for every frame.

use std::time::Duration;

use anyhow::Result;

use super::setup::{PeerReaderSamples, SENSORS};

/// Waits for every frame while `running`: its latency and the copy's own
/// time (and, if `busy`, counts it as a read).
pub(super) fn read_waiting(
    name: &str,
    busy: bool,
    running: impl Fn() -> bool,
    samples: &mut PeerReaderSamples,
) -> Result<()> {
    let reader = crate::iceoryx2_peer::IceoryxReader::open(name)?;
    let mut copy = vec![0u16; SENSORS];
    while running() {
        if let Some((published_ns, copy_ns)) = reader.wait_newer(&mut copy, Duration::from_millis(100))? {
            std::hint::black_box(&mut copy);
            let holding = skinware::os::monotonic_ns();
            samples.latency_ns.push(holding.saturating_sub(published_ns));
            samples.copy_ns.push(copy_ns);
            samples.reads += usize::from(busy);
        }
    }
    Ok(())
}
