//! The segment directory as a registry: which channels exist, who writes them,
//! and removing the ones whose writers are dead.

#![forbid(unsafe_code)]

use std::os::unix::fs::FileTypeExt;
use std::path::{Path, PathBuf};

use super::ChannelKind;
use super::handover::LISTING_ANSWER_TIMEOUT;
use super::liveness::{NameRecord, remove_if_unowned};
use super::segment::{self, Opened};
use crate::error::{Error, Result};
use crate::shm;
use crate::stats::{WriterState, WriterStats};
use crate::sync::Ordering;

/// One channel found in the segment directory.
#[derive(Clone, Debug)]
pub struct ChannelInfo {
    /// Skin name.
    pub skin: String,
    /// Channel name.
    pub channel: String,
    /// The channel's socket.
    pub path: PathBuf,
    /// Running, paused, faulted or gone.
    pub state: WriterState,
    /// What it carries, if the segment is valid.
    pub kind: Option<ChannelKind>,
    /// The current (or last) writer's process id.
    pub writer_pid: u32,
    /// Payload bytes per frame.
    pub payload_bytes: u64,
    /// Frame buffers.
    pub slots: u64,
    /// How many writers the channel name has had.
    pub generation: u64,
    /// Writer statistics (default if the writer is gone or the channel invalid).
    pub stats: WriterStats,
    /// Why the segment cannot be used, if it cannot.
    pub problem: Option<String>,
}

/// Lists the channels in `dir` (all skins), sorted by skin and channel.
///
/// Every writer is asked at once: writers that do not answer (stopped or
/// hung, whoever's they are) cost the listing one wait of at most 200 ms in
/// all, and show with their problem ([`ChannelInfo::problem`]).
pub fn list_channels(dir: &Path) -> Result<Vec<ChannelInfo>> {
    list_channels_where(dir, None, |_| true)
}

/// Lists the channels of `skin` in `dir`, sorted by channel: only that
/// skin's writers are asked, so nothing of another skin can slow it.
pub fn list_skin_channels(dir: &Path, skin: &str) -> Result<Vec<ChannelInfo>> {
    shm::validate_name("skin", skin)?;
    list_channels_where(dir, Some(skin), |_| true)
}

/// What a channel name's lock file says of its current (or last) writer,
/// read without connecting to anyone: for [`list_channels_where`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct WriterRecord {
    /// The writer's process id, as the writer recorded it.
    pub pid: u32,
    /// The user owning the lock file (who wrote the record): a record in a
    /// file of another user is that user's claim.
    pub owner_uid: u32,
}

/// Lists the channels of `skin` (or of every skin) in `dir` whose name
/// record says their current or last writer is one `writer` accepts,
/// asking only those: e.g. a supervisor that must never wait on a process
/// it does not supervise lists only its children's channels (recorded by
/// its own user). The record is read from the name's lock file, without
/// connecting to anyone.
pub fn list_channels_where(
    dir: &Path,
    skin: Option<&str>,
    writer: impl Fn(WriterRecord) -> bool,
) -> Result<Vec<ChannelInfo>> {
    let entries = std::fs::read_dir(dir).map_err(|source| Error::Os { op: "list", path: dir.to_owned(), source })?;
    let mut names: Vec<(String, String, NameRecord)> = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some((found_skin, channel)) = name.to_str().and_then(shm::parse_segment_name) else {
            continue;
        };
        if skin.is_some_and(|skin| skin != found_skin) {
            continue;
        }
        let record = NameRecord::load(dir, found_skin, channel).unwrap_or_default();
        if writer(WriterRecord { pid: record.writer_pid, owner_uid: record.owner_uid }) {
            names.push((found_skin.to_owned(), channel.to_owned(), record));
        }
    }
    names.sort_by(|a, b| (&a.0, &a.1).cmp(&(&b.0, &b.1)));
    let asked: Vec<(&str, &str)> = names.iter().map(|(skin, channel, _)| (skin.as_str(), channel.as_str())).collect();
    let opened = segment::open_segments(dir, &asked, LISTING_ANSWER_TIMEOUT);
    Ok(names
        .iter()
        .zip(opened)
        .map(|((skin, channel, record), opened)| inspect(dir, skin, channel, *record, opened))
        .collect())
}

fn inspect(dir: &Path, skin: &str, channel: &str, record: NameRecord, opened: Result<Opened>) -> ChannelInfo {
    let path = shm::segment_path(dir, skin, channel);
    let mut info = ChannelInfo {
        skin: skin.to_owned(),
        channel: channel.to_owned(),
        path: path.clone(),
        state: WriterState::Gone,
        kind: None,
        writer_pid: record.writer_pid,
        generation: record.generation,
        payload_bytes: 0,
        slots: 0,
        stats: WriterStats::default(),
        problem: None,
    };
    match opened {
        Ok(Opened::Live(shared)) => {
            let header = shared.header();
            info.state = shared.writer_state();
            info.kind = Some(shared.kind);
            info.writer_pid = header.writer_pid.load(Ordering::Relaxed);
            info.generation = header.generation.load(Ordering::Relaxed);
            info.payload_bytes = shared.layout.payload_bytes;
            info.slots = shared.layout.slot_count;
            info.stats = WriterStats::load(&header.stats);
        }
        Ok(Opened::NoWriter) => {}
        Err(e) => info.problem = Some(e.to_string()),
    }
    info
}

/// Removes the channels in `dir` that no live writer holds (their sockets and
/// name locks), and sockets left half-bound by a writer that died binding.
/// With `include_invalid`, also files named like channels that are not
/// channels (files of older skinware versions, or foreign ones). Returns the
/// removed paths.
///
/// A channel is removed only while holding its name lock, so a writer taking
/// the name at the same moment is never left serving an unlinked socket.
pub fn remove_stale_channels(dir: &Path, include_invalid: bool) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|source| Error::Os { op: "list", path: dir.to_owned(), source })?;
    let mut removed = Vec::new();
    let mut sockets: Vec<(String, String, PathBuf)> = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        let path = entry.path();
        let is_socket = entry.file_type().is_ok_and(|t| t.is_socket());
        if let Some((skin, channel)) = shm::parse_segment_name(name) {
            if is_socket {
                sockets.push((skin.to_owned(), channel.to_owned(), path));
            } else if include_invalid && std::fs::remove_file(&path).is_ok() {
                removed.push(path);
            }
        } else if name.starts_with(shm::TEMP_PREFIX) && temp_is_stale(name) && std::fs::remove_file(&path).is_ok() {
            removed.push(path);
        }
    }
    // Every writer asked at once: stopped ones cost one bounded wait in all.
    let asked: Vec<(&str, &str)> = sockets.iter().map(|(skin, channel, _)| (skin.as_str(), channel.as_str())).collect();
    let opened = segment::open_segments(dir, &asked, LISTING_ANSWER_TIMEOUT);
    for ((skin, channel, path), opened) in sockets.iter().zip(opened) {
        // One name that cannot be removed (a lock file planted by someone,
        // say) does not stop the others from being cleaned.
        if matches!(opened, Ok(Opened::NoWriter)) {
            match remove_if_unowned(dir, skin, channel) {
                Ok(true) => removed.push(path.clone()),
                Ok(false) => {}
                Err(e) => {
                    tracing::warn!(channel = %path.display(), error = %e, "cannot remove this dead writer's channel")
                }
            }
        }
    }
    removed.sort();
    Ok(removed)
}

/// A temporary socket is named `.skinware-tmp.<name>.<pid>.<ns>`; it is stale
/// once that process is gone.
fn temp_is_stale(name: &str) -> bool {
    let mut parts = name.rsplit('.');
    let _ns = parts.next();
    match parts.next().and_then(|pid| pid.parse::<i32>().ok()) {
        Some(pid) => !Path::new(&format!("/proc/{pid}")).exists(),
        None => true,
    }
}

/// Removes one channel (its socket and name lock) if no live writer holds it,
/// race-free against a writer taking the name. `Ok(false)` if a writer holds
/// it, `path` is not a channel's socket path, or it is already gone.
pub fn remove_channel_if_stale(path: &Path) -> Result<bool> {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name().and_then(|n| n.to_str())) else {
        return Ok(false);
    };
    let Some((skin, channel)) = shm::parse_segment_name(name) else {
        return Ok(false);
    };
    if !path.exists() {
        return Ok(false);
    }
    match segment::open_segment(dir, skin, channel, LISTING_ANSWER_TIMEOUT) {
        Ok(Opened::Live(shared)) if shared.writer_alive().unwrap_or(true) => Ok(false),
        _ => remove_if_unowned(dir, skin, channel),
    }
}
