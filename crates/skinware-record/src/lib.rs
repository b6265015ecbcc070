//! Recording skinware channels to MCAP files, and replaying them.
//!
//! A recording uses MCAP's `ros2` profile: every schema is a `ros2msg` text
//! embedded in the file and every message is CDR, so Foxglove, the ROS 2 tools
//! and Python's `mcap-ros2-support` read it without any package of ours.
//! `docs/recording.md` lists the topics and schemas; the messages, their
//! `.msg` texts and topic names are `skinware-ros2`'s, shared with the bridge.
//!
//! * [`Recorder`] reads every chosen layer and service as soon as each frame is
//!   published (an ordinary reader, so it cannot slow acquisition), writes one
//!   `skinware_msgs/msg/SkinFrame` per frame, counts and records every frame it
//!   missed, and finishes a chunk every second, so that a recorder killed at any
//!   moment leaves a file readable up to its last second.
//! * [`scan`] reads a file from start to end (a finished one or not) and says
//!   what it holds; [`recover`] rewrites an unfinished one as a finished file.
//! * [`Replay`] recreates the recorded channels, with their names, frame
//!   sizes, descriptions and the skin's geometry, and publishes the frames at
//!   their recorded times.

#![forbid(unsafe_code)]

mod error;
pub mod file;
pub mod recorder;
pub mod replay;

pub use error::RecordError;
pub use file::{ChannelSummary, RecordingInfo, recover, scan};
/// The MCAP crate this one writes with, for readers of its records.
pub use mcap;
pub use recorder::{Compression, Progress, RecordOptions, RecordSummary, Recorder, ServiceChoice, Split, part_path};
pub use replay::{AtEnd, Replay, ReplayOptions, ReplayReport, recording_parts};

/// The recording format this crate writes (metadata `skinware.recording`,
/// key `format_version`). A file with a higher number was written by a newer
/// skinware and is refused, not misread.
pub const FORMAT_VERSION: u32 = 1;

/// Schema encoding of every schema in a recording (MCAP's `ros2` profile).
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding of every channel in a recording.
pub const MESSAGE_ENCODING: &str = "cdr";

/// MCAP metadata record describing the recording.
pub const RECORDING_METADATA: &str = "skinware.recording";
/// MCAP metadata record written when the recorder finishes.
pub const SUMMARY_METADATA: &str = "skinware.summary";
/// MCAP metadata record with a readable outline of the skin's layers.
pub const LAYOUT_METADATA: &str = "skin.layout";
/// Attachment holding the skin's published geometry file (topology of every
/// layer, calibration, regions, neighbour graph, 2-D map), byte for byte.
pub const GEOMETRY_ATTACHMENT: &str = "skinware/geometry";
/// Attachments holding each channel's description (a layer's topology, a
/// service's record labels): `skinware/description/<channel>`.
pub const DESCRIPTION_ATTACHMENT_PREFIX: &str = "skinware/description/";

/// Channel metadata keys: the skinware channel a topic records.
pub mod channel_keys {
    /// The channel's name (topics replace characters ROS forbids).
    pub const CHANNEL: &str = "skinware.channel";
    /// `layer` or `service`.
    pub const KIND: &str = "skinware.kind";
    /// Frame size in bytes.
    pub const PAYLOAD_BYTES: &str = "skinware.payload_bytes";
    /// Frame buffers of the writer.
    pub const SLOTS: &str = "skinware.slots";
    /// The writer's period in ns, or 0 for a sporadic writer.
    pub const PERIOD_NS: &str = "skinware.period_ns";
    /// Payload schema name.
    pub const SCHEMA_NAME: &str = "skinware.schema_name";
    /// Payload schema version.
    pub const SCHEMA_VERSION: &str = "skinware.schema_version";
}
