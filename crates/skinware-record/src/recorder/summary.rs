//! What a recording counts while it runs, and what it reports: its progress,
//! and the summary of a finished file.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

use serde::Serialize;
use skinware::{ChannelKind, Reader};

/// Counters of one recorded channel, shared by its reader thread and the rest.
#[derive(Default)]
pub(super) struct Counters {
    pub(super) frames: AtomicU64,
    pub(super) lost: AtomicU64,
    pub(super) gaps: AtomicU64,
    pub(super) faulted: AtomicU64,
    pub(super) latency_ns: AtomicU64,
    /// The writer's state, by its number ([`WriterState::code`]; 0 until read).
    pub(super) state: AtomicU32,
    /// Times the reader found the file's queue full and waited.
    pub(super) file_waits: AtomicU64,
    /// Whether the reader thread runs in SCHED_FIFO.
    pub(super) realtime: AtomicBool,
}

/// One recorded channel and its counters.
#[derive(Clone)]
pub(super) struct Recorded {
    pub(super) name: String,
    pub(super) kind: ChannelKind,
    pub(super) counters: Arc<Counters>,
}

impl Recorded {
    pub(super) fn of(reader: &Reader) -> Recorded {
        Recorded { name: channel_name(reader), kind: reader.kind(), counters: Arc::new(Counters::default()) }
    }

    pub(super) fn report(&self) -> ChannelReport {
        let counters = &self.counters;
        ChannelReport {
            kind: self.kind.as_str(),
            frames: counters.frames.load(Ordering::Relaxed),
            lost: counters.lost.load(Ordering::Relaxed),
            gaps: counters.gaps.load(Ordering::Relaxed),
            faulted: counters.faulted.load(Ordering::Relaxed),
            file_waits: counters.file_waits.load(Ordering::Relaxed),
            realtime: counters.realtime.load(Ordering::Relaxed),
        }
    }
}

/// The channel a reader reads (its label is `skin/channel`).
pub(super) fn channel_name(reader: &Reader) -> String {
    reader.label().rsplit('/').next().unwrap_or_default().to_owned()
}

/// Progress of a recording.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Progress {
    /// Since the start.
    pub seconds: f64,
    /// Frames written.
    pub frames: u64,
    /// Frames missed.
    pub lost: u64,
    /// Message bytes handed to the file (before compression).
    pub message_bytes: u64,
    /// The recording's size on disk now: every part's, if it is split.
    pub file_bytes: u64,
}

/// One channel in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct ChannelReport {
    /// Layer or service.
    pub kind: &'static str,
    /// Frames written.
    pub frames: u64,
    /// Frames missed.
    pub lost: u64,
    /// Runs of missed frames.
    pub gaps: u64,
    /// Frames with a fault status.
    pub faulted: u64,
    /// Times its reader found the file's queue full and waited for the
    /// disk or the compression (frames it missed meanwhile are in `lost`).
    pub file_waits: u64,
    /// Whether its reader thread ran in SCHED_FIFO.
    pub realtime: bool,
}

/// What a finished recording holds.
#[derive(Clone, Debug, Serialize)]
pub struct RecordSummary {
    /// The file (the first part of a split recording).
    pub path: PathBuf,
    /// Every file written, in order: `path` alone unless the recording was split.
    pub parts: Vec<PathBuf>,
    /// The skin.
    pub skin: String,
    /// Recording time.
    pub seconds: f64,
    /// Frames written.
    pub frames: u64,
    /// Frames missed.
    pub lost: u64,
    /// Message bytes (before compression).
    pub message_bytes: u64,
    /// The finished recording's size: every part's, if it is split.
    pub file_bytes: u64,
    /// Frames per second.
    pub frames_per_s: f64,
    /// Message MB per second (before compression).
    pub mb_per_s: f64,
    /// Map images written.
    pub images: u64,
    /// Per channel.
    pub channels: BTreeMap<String, ChannelReport>,
    /// The compression.
    pub compression: String,
    /// The SCHED_FIFO priority the reader threads asked for (0: none).
    pub reader_priority: u8,
    /// Whether every reader thread got it.
    pub readers_realtime: bool,
    /// Frames the queue between the readers and the file holds at most.
    pub queue_frames: usize,
}
