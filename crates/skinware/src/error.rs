//! Typed errors of the library. Every variant names the channel it concerns and,
//! where there is one, says what to do about it.

#![forbid(unsafe_code)]

use std::path::PathBuf;

/// Everything that can go wrong when creating, opening, writing or reading a channel.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A skin or channel name that cannot be used as a segment name.
    #[error("invalid {what} name {name:?}: {reason}; use 1 to {max_len} characters from A-Z a-z 0-9 _ -")]
    InvalidName {
        /// "skin" or "channel".
        what: &'static str,
        /// The name as given.
        name: String,
        /// Why it was refused.
        reason: &'static str,
        /// The longest name allowed ([`crate::shm::MAX_NAME_LEN`]).
        max_len: usize,
    },

    /// A layout parameter out of range (zero buffers, an empty frame, sizes too large).
    #[error("invalid layout for channel {channel}: {reason}")]
    InvalidLayout {
        /// `skin/channel`.
        channel: String,
        /// What is wrong and the accepted range.
        reason: String,
    },

    /// No segment with that name exists.
    #[error(
        "channel {channel} does not exist ({path}); start its writer first, or check the skin and channel names with `skin ls`"
    )]
    Missing {
        /// `skin/channel`.
        channel: String,
        /// The segment path that was looked for.
        path: PathBuf,
    },

    /// The file exists but was not written by skinware.
    #[error(
        "{path} is not a skinware channel (bad magic {found:#018x}); it belongs to something else: remove it by hand if it is yours, or pick another name for channel {channel}"
    )]
    NotOurs {
        /// `skin/channel`.
        channel: String,
        /// The segment path.
        path: PathBuf,
        /// The first eight bytes found.
        found: u64,
    },

    /// The segment was made by an incompatible version of skinware.
    #[error(
        "channel {channel} uses ABI version {found}, this program speaks {expected}; rebuild both sides against the same skinware release, or remove the stale channel with `skin clean`"
    )]
    VersionMismatch {
        /// `skin/channel`.
        channel: String,
        /// ABI version in the segment.
        found: u32,
        /// ABI version of this build.
        expected: u32,
    },

    /// The file is shorter than its header says, or than any header.
    #[error(
        "channel {channel} is truncated: {path} has {actual} bytes, at least {needed} are needed; the segment is damaged, remove it with `skin clean --force` and restart its writer"
    )]
    Truncated {
        /// `skin/channel`.
        channel: String,
        /// The segment path.
        path: PathBuf,
        /// Bytes in the file.
        actual: u64,
        /// Bytes required.
        needed: u64,
    },

    /// The header has our magic and version but inconsistent contents.
    #[error(
        "channel {channel} has a corrupt header: {reason}; remove it with `skin clean --force` and restart its writer"
    )]
    Corrupt {
        /// `skin/channel`.
        channel: String,
        /// Which field is inconsistent.
        reason: String,
    },

    /// The header was never finished: its creator died while setting it up.
    #[error(
        "channel {channel} was never finished by its creator (it died while creating it); remove it with `skin clean` and restart its writer"
    )]
    Unfinished {
        /// `skin/channel`.
        channel: String,
    },

    /// The channel exists but no process is writing it.
    #[error(
        "the writer of channel {channel} is gone (process {pid} no longer holds it); restart the writer, or open with `allow_gone` to wait for its revival"
    )]
    WriterGone {
        /// `skin/channel`.
        channel: String,
        /// The last writer's process id.
        pid: u32,
    },

    /// Another live writer already owns the channel.
    #[error("channel {channel} already has a live writer (process {pid}); stop it first, or use another channel name")]
    Busy {
        /// `skin/channel`.
        channel: String,
        /// The live writer's process id.
        pid: u32,
    },

    /// A writer tried to revive a dead writer's channel with a different layout.
    #[error(
        "cannot take over channel {channel}: its layout differs ({field}: the channel has {existing}, the new writer wants {wanted}); remove the stale channel with `skin clean` or keep the old layout"
    )]
    LayoutMismatch {
        /// `skin/channel`.
        channel: String,
        /// The differing field.
        field: &'static str,
        /// Value in the existing channel.
        existing: String,
        /// Value the new writer asked for.
        wanted: String,
    },

    /// A reader expected a different payload schema.
    #[error(
        "channel {channel} carries schema {found:?} version {found_version}, the reader expects {expected:?} version {expected_version}; attach with the matching payload type"
    )]
    SchemaMismatch {
        /// `skin/channel`.
        channel: String,
        /// Schema in the channel.
        found: String,
        /// Its version.
        found_version: u32,
        /// Schema the reader asked for.
        expected: String,
        /// Its version.
        expected_version: u32,
    },

    /// A service channel whose records are not the type the reader asked for.
    #[error(
        "channel {channel} is not a service of {expected}: {reason}; attach with the payload type its service publishes (`skin services` lists them)"
    )]
    NotThisService {
        /// `skin/channel`.
        channel: String,
        /// The payload type asked for (schema name and version).
        expected: String,
        /// What differs.
        reason: String,
    },

    /// A payload larger than the channel's frame.
    #[error("payload of {given} bytes does not fit channel {channel}'s {capacity}-byte frame")]
    PayloadTooLarge {
        /// `skin/channel`.
        channel: String,
        /// Bytes offered.
        given: usize,
        /// Frame capacity.
        capacity: usize,
    },

    /// The writer has not published any frame yet.
    #[error("channel {channel} has no frame yet; its writer has not published")]
    NoFrameYet {
        /// `skin/channel`.
        channel: String,
    },

    /// A blocking call reached its timeout.
    #[error("timed out after {timeout:?} waiting on channel {channel}")]
    Timeout {
        /// `skin/channel`.
        channel: String,
        /// The timeout that elapsed.
        timeout: std::time::Duration,
    },

    /// A blocking call was interrupted by its stop handle.
    #[error("stopped while waiting on channel {channel}")]
    Stopped {
        /// `skin/channel`.
        channel: String,
    },

    /// The reader was lapped by the writer so many times in a row that it gave up.
    #[error(
        "reader of channel {channel} was lapped {retries} times in a row; it is too slow for {slots} buffers: open the channel with more buffers or read less data"
    )]
    Lapped {
        /// `skin/channel`.
        channel: String,
        /// Retries made.
        retries: u32,
        /// Buffers in the channel.
        slots: u32,
    },

    /// An operating-system call failed.
    #[error("{op} failed for {path}: {source}")]
    Os {
        /// The operation, e.g. "mmap".
        op: &'static str,
        /// The file or channel concerned.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
}

/// Result with the library's [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;
