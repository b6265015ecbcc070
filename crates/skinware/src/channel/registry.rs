//! The segment directory as a registry: which channels exist, who writes them,
//! and removing the ones whose writers are dead.

#![forbid(unsafe_code)]

use std::fs::File;
use std::path::{Path, PathBuf};

use super::liveness::remove_if_unowned;
use super::segment;
use super::{ChannelKind, label};
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
    /// The segment file.
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
    /// Writer statistics (default if the segment is invalid).
    pub stats: WriterStats,
    /// Why the segment cannot be used, if it cannot.
    pub problem: Option<String>,
}

/// Lists the channels in `dir` (all skins), sorted by skin and channel.
pub fn list_channels(dir: &Path) -> Result<Vec<ChannelInfo>> {
    let entries = std::fs::read_dir(dir).map_err(|source| Error::Os { op: "list", path: dir.to_owned(), source })?;
    let mut found = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some((skin, channel)) = name.to_str().and_then(shm::parse_segment_name) else {
            continue;
        };
        found.push(inspect(dir, skin, channel));
    }
    found.sort_by(|a, b| (&a.skin, &a.channel).cmp(&(&b.skin, &b.channel)));
    Ok(found)
}

fn inspect(dir: &Path, skin: &str, channel: &str) -> ChannelInfo {
    let path = shm::segment_path(dir, skin, channel);
    let mut info = ChannelInfo {
        skin: skin.to_owned(),
        channel: channel.to_owned(),
        path: path.clone(),
        state: WriterState::Gone,
        kind: None,
        writer_pid: 0,
        payload_bytes: 0,
        slots: 0,
        stats: WriterStats::default(),
        problem: None,
    };
    match segment::open_segment(dir, skin, channel, false) {
        Ok(shared) => {
            let header = shared.header();
            info.state = shared.writer_state();
            info.kind = Some(shared.kind);
            info.writer_pid = header.writer_pid.load(Ordering::Relaxed);
            info.payload_bytes = shared.layout.payload_bytes;
            info.slots = shared.layout.slot_count;
            info.stats = WriterStats::load(&header.stats);
        }
        Err(e) => info.problem = Some(e.to_string()),
    }
    info
}

/// Removes the segments in `dir` that no live writer holds: dead writers'
/// channels, and segments whose creator died before finishing them. With
/// `include_invalid`, also unusable files named like segments (foreign,
/// corrupt, other ABI versions). Returns the removed paths.
///
/// A segment is removed only while holding its writer lock, so a writer that
/// revives it at the same moment is never left with an unlinked file.
pub fn remove_stale_channels(dir: &Path, include_invalid: bool) -> Result<Vec<PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|source| Error::Os { op: "list", path: dir.to_owned(), source })?;
    let mut removed = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(name) = name.to_str() else { continue };
        let path = entry.path();
        let candidate = if let Some((skin, channel)) = shm::parse_segment_name(name) {
            let label = label(skin, channel);
            match File::options().read(true).write(true).open(&path) {
                Ok(file) => match segment::validate(&file, &path, &label) {
                    Ok(_) => true,
                    Err(_) => include_invalid,
                },
                Err(_) => false,
            }
        } else {
            name.starts_with(shm::TEMP_PREFIX)
        };
        if candidate && remove_if_unowned(&path)? {
            removed.push(path);
        }
    }
    removed.sort();
    Ok(removed)
}

/// Removes one segment if no live writer holds it (race-free against a writer
/// reviving it). `Ok(false)` if a writer holds it or it is already gone.
pub fn remove_channel_if_stale(path: &Path) -> Result<bool> {
    remove_if_unowned(path)
}
