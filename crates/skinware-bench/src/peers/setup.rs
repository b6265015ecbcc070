//! What `skin bench peers` compares and how: the frame, its rate, the
//! systems, the options of the run and of its reader processes, and what a
//! reader process hands back.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Sensors of the whole skin.
pub const SENSORS: usize = 30_848;
pub(super) const FRAME_BYTES: usize = SENSORS * 2;
/// The systems compared (iceoryx2 with the cargo feature `iceoryx2`).
/// `skinware-spin` is skinware with readers that anticipate each frame
/// ([`skinware::ReaderOptions::anticipate`]).
#[cfg(feature = "iceoryx2")]
pub const SYSTEMS: &[&str] = &["skinware", "skinware-spin", "rwlock", "iceoryx2"];
/// The systems compared (iceoryx2 with the cargo feature `iceoryx2`).
#[cfg(not(feature = "iceoryx2"))]
pub const SYSTEMS: &[&str] = &["skinware", "skinware-spin", "rwlock"];
/// How long before each frame is due an anticipating reader starts spinning.
pub const ANTICIPATE: Duration = Duration::from_micros(250);
/// Frames per second delivered.
pub const RATE_HZ: f64 = 200.0;

/// Frames of the same-run baselines that mimic a waiting reader: one every
/// 5 ms, as in the comparison itself, so the reader's CPU idles in between.
pub(super) fn woken_rounds(quick: bool) -> u32 {
    if quick { 100 } else { 1_000 }
}

/// What a peer reader process measured.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct PeerReaderSamples {
    /// Publish-to-holding latencies, ns.
    pub latency_ns: Vec<u64>,
    /// Time to copy the frame out once woken, ns.
    pub copy_ns: Vec<u64>,
    /// Frames copied in the busy mode.
    pub reads: usize,
}

/// Arguments of the peer reader role (`bench-peer-reader`).
#[derive(Clone, Debug, clap::Args)]
pub struct PeerReaderArgs {
    /// `skinware` or `rwlock`.
    #[arg(long)]
    pub system: String,
    /// Channel name.
    #[arg(long)]
    pub name: String,
    /// How long to read.
    #[arg(long, value_parser = crate::run_options::parse_helper_seconds)]
    pub seconds: f64,
    /// `wait` (for every frame) or `busy` (back to back, on request).
    #[arg(long, default_value = "wait")]
    pub mode: String,
    /// Where to write the samples.
    #[arg(long)]
    pub out: PathBuf,
}
