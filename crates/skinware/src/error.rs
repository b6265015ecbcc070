//! Typed errors of the library. Every variant names the channel it concerns and,
//! where there is one, says what to do about it.

#![forbid(unsafe_code)]

use std::path::PathBuf;

/// Everything that can go wrong when creating, opening, writing or reading a channel.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A caller's buffer too small for the channel's frames.
    #[error(
        "a buffer of {given} bytes cannot hold a frame of channel {channel}, which has {needed}-byte frames; give a buffer of at least {needed} bytes (the reader's payload size)"
    )]
    BufferTooSmall {
        /// `skin/channel`.
        channel: String,
        /// Bytes per frame.
        needed: usize,
        /// Bytes given.
        given: usize,
    },

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

    /// No channel with that name exists.
    #[error(
        "channel {channel} does not exist ({path}); start its writer first, or check the skin and channel names with `skin ls`"
    )]
    Missing {
        /// `skin/channel`.
        channel: String,
        /// The socket path that was looked for.
        path: PathBuf,
    },

    /// The file exists but was not written by skinware.
    #[error(
        "{path} does not serve a skinware channel (bad magic {found:#018x}); it belongs to something else: stop it, or pick another name for channel {channel}"
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

    /// The channel's memory is shorter than its header says, or than any header.
    #[error(
        "channel {channel} is truncated: the memory handed over at {path} has {actual} bytes, at least {needed} are needed; its writer is not skinware, or not this version"
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
        "channel {channel} is corrupt: {reason}; restart its writer (a writer of another skinware version, or not skinware at all, answers there)"
    )]
    Corrupt {
        /// `skin/channel`.
        channel: String,
        /// Which field is inconsistent.
        reason: String,
    },

    /// A file under a channel's name that is not a channel's socket.
    #[error(
        "{path} is a {found}, not the socket of a skinware channel; it may be a channel file of an older skinware (remove it with `skin clean --force`) or belong to something else: remove it by hand if it is yours, or pick another name for channel {channel}"
    )]
    NotAChannel {
        /// `skin/channel`.
        channel: String,
        /// The path.
        path: PathBuf,
        /// What it is.
        found: &'static str,
    },

    /// A file at one of a channel's paths that skinware will not open: a
    /// symbolic link, a FIFO, a device, or a name lock owned by another user.
    /// The segment directory is world-writable, so any local user can put one
    /// there; opening it could follow a link to another file or block forever.
    #[error(
        "{path}: {reason}; skinware does not open it (a local user may have put it there). Remove it if it is stale \
         (`skin clean --force`), or give the skin a directory only trusted users can write: SKINWARE_SHM_DIR (channel {channel})"
    )]
    UntrustedFile {
        /// `skin/channel`.
        channel: String,
        /// The path.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },

    /// The reader may not read the channel.
    #[error(
        "no permission to read channel {channel} ({path}); start its writer with `access = \"group\"` (and be in its group) or `access = \"everyone\"`, or read as the writer's user"
    )]
    AccessDenied {
        /// `skin/channel`.
        channel: String,
        /// The channel's socket.
        path: PathBuf,
    },

    /// The channel's writer accepted the connection but handed nothing over.
    #[error(
        "the writer of channel {channel} accepted the connection at {path} but handed nothing over in time; it is stopped (SIGSTOP) or hung: check it with `skin ls`"
    )]
    NotAnswering {
        /// `skin/channel`.
        channel: String,
        /// The channel's socket.
        path: PathBuf,
    },

    /// Memory handed over that someone could shrink under the reader.
    #[error(
        "channel {channel}'s {what} memory is not sealed against shrinking, so its writer could kill readers with SIGBUS: refused; the writer is not skinware, or not this version"
    )]
    Unsealed {
        /// `skin/channel`.
        channel: String,
        /// "frames" or "doorbell".
        what: &'static str,
    },

    /// The channel exists but no process is writing it.
    #[error(
        "the writer of channel {channel} is gone (last writer: process {pid}); restart it: readers already attached follow the new writer, others can attach again"
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
