//! Liveness and revival: who owns a channel, how readers tell a dead writer,
//! and how a new writer takes over a dead writer's channel without readers
//! re-attaching.
//!
//! Two open-file-description locks on the segment file say everything
//! ([`crate::os`] makes the calls):
//!
//! * the **liveness lock** (byte 0) is held by the live writer for its whole
//!   life. The kernel drops it when the writer's process dies, however it dies,
//!   so "alive" is a question to the kernel (`F_OFD_GETLK`), never a heartbeat
//!   a crashed process could leave behind;
//! * the **reviver's lock** (byte 1) makes one would-be writer the only one
//!   that may prepare a dead channel, and is also held for the writer's life.
//!
//! Revival takes them in that order: the reviver's lock, then (once the
//! header names the new writer, its pid, period and state) the liveness lock.
//! Until then readers see the channel gone, never "running" with the dead
//! writer's pid. A cleaner takes the same two locks in the same order before
//! it unlinks a segment, so a reviver is never left writing an unlinked file.
//!
//! The writer's *state* (running, paused, faulted, stopped) is a word in the
//! header that only the live writer stores; readers combine it with the
//! liveness lock ([`WriterState::from_code`]).

#![forbid(unsafe_code)]

use std::fs::File;
use std::io;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

use super::layout::{self, Header, Layout};
use super::segment::{self, SegmentInit, Shared};
use crate::error::{Error, Result};
use crate::os;
use crate::stats::{self, WriterState};
use crate::sync::Ordering;

/// The identity of a file: (device, inode).
pub(crate) type FileIdentity = (u64, u64);

/// The identity of an open file.
pub(crate) fn file_identity(file: &File, path: &Path) -> Result<FileIdentity> {
    let meta = file.metadata().map_err(|source| Error::Os { op: "stat", path: path.to_owned(), source })?;
    Ok((meta.dev(), meta.ino()))
}

/// The identity of whatever file `path` names now, if any.
pub(crate) fn path_identity(path: &Path) -> Option<FileIdentity> {
    std::fs::metadata(path).ok().map(|meta| (meta.dev(), meta.ino()))
}

impl Shared {
    /// Whether a live process holds this segment's liveness lock. It only
    /// asks, so probing can never get in a reviving writer's way.
    pub fn writer_alive(&self) -> io::Result<bool> {
        os::writer_lock_held(&self.file)
    }

    /// The writer's state as readers see it: its last word, unless it is dead.
    pub fn writer_state(&self) -> WriterState {
        let alive = self.writer_alive().unwrap_or(false);
        WriterState::from_code(self.header().state.load(Ordering::Acquire), alive)
    }

    /// The state the live writer last stored (not combined with liveness).
    pub fn stored_state(&self) -> WriterState {
        WriterState::from_code(self.header().state.load(Ordering::Acquire), true)
    }
}

/// Stores the writer's state for readers, stamping the time of a change. Only
/// the live writer (or a handle it gave out) calls it.
pub(crate) fn set_state(header: &Header, state: WriterState) {
    if header.state.swap(state.code(), Ordering::Release) != state.code() {
        header.state_changed_ns.store(os::monotonic_ns(), Ordering::Relaxed);
    }
}

/// Writes the new writer's name into the header (pid, period, generation),
/// then its running state. Called holding the reviver's lock but before the
/// liveness lock, so readers never see the channel alive with stale details.
pub(crate) fn introduce_writer(header: &Header, period_ns: u64) {
    header.writer_pid.store(std::process::id(), Ordering::Relaxed);
    header.period_ns.store(period_ns, Ordering::Relaxed);
    stats::bump(&header.generation, 1);
    header.state_changed_ns.store(os::monotonic_ns(), Ordering::Relaxed);
    header.state.store(WriterState::RUNNING, Ordering::Release);
}

/// Marks the writer stopped, the last thing it does before it lets go.
pub(crate) fn retire_writer(header: &Header) {
    header.state.store(WriterState::STOPPED, Ordering::Release);
    header.state_changed_ns.store(os::monotonic_ns(), Ordering::Relaxed);
}

/// Takes the liveness lock of a segment prepared for revival. `Ok(false)` if
/// someone else holds it: only a cleaner that is unlinking the dead segment
/// can, and the caller must then create a new one.
pub(crate) fn go_live(shared: &Shared) -> Result<bool> {
    os::try_lock_writer(&shared.file).map_err(|source| Error::Os { op: "lock", path: shared.path.clone(), source })
}

/// Takes over the segment at `path` if its writer is dead and its layout,
/// kind, schema and description match what the new writer wants, holding the
/// reviver's lock (not yet the liveness lock: see [`go_live`]). `Ok(None)` if
/// there is no segment there (any more).
pub(crate) fn claim_dead_segment(
    path: &Path,
    label: &str,
    layout: &Layout,
    init: &SegmentInit<'_>,
) -> Result<Option<Shared>> {
    let file = match File::options().read(true).write(true).open(path) {
        Ok(file) => file,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(Error::Os { op: "open", path: path.to_owned(), source }),
    };
    let lock_error = |source| Error::Os { op: "lock", path: path.to_owned(), source };
    let reviver = os::try_lock_reviver(&file).map_err(lock_error)?;
    if !reviver || os::writer_lock_held(&file).map_err(lock_error)? {
        let pid = segment::map_validated(label.to_owned(), path.to_owned(), file, false)
            .map(|shared| shared.header().writer_pid.load(Ordering::Relaxed))
            .unwrap_or(0);
        return Err(Error::Busy { channel: label.to_owned(), pid });
    }
    // A cleaner may have unlinked the file between our open and our lock.
    if path_identity(path) != Some(file_identity(&file, path)?) {
        return Ok(None);
    }
    let shared = segment::map_validated(label.to_owned(), path.to_owned(), file, true)?;
    check_same_channel(&shared, label, layout, init)?;
    Ok(Some(shared))
}

/// A revived channel must look exactly as it did to the readers still attached.
fn check_same_channel(shared: &Shared, label: &str, layout: &Layout, init: &SegmentInit<'_>) -> Result<()> {
    let mismatch = |field: &'static str, existing: String, wanted: String| Error::LayoutMismatch {
        channel: label.to_owned(),
        field,
        existing,
        wanted,
    };
    let existing = shared.layout;
    if existing.payload_bytes != layout.payload_bytes {
        return Err(mismatch("frame bytes", existing.payload_bytes.to_string(), layout.payload_bytes.to_string()));
    }
    if existing.slot_count != layout.slot_count {
        return Err(mismatch("frame buffers", existing.slot_count.to_string(), layout.slot_count.to_string()));
    }
    if shared.kind != init.kind {
        return Err(mismatch("kind", format!("{:?}", shared.kind), format!("{:?}", init.kind)));
    }
    let header = shared.header();
    let schema = layout::decode_schema(&header.schema_name);
    let schema_version = header.schema_version.load(Ordering::Relaxed);
    if schema != init.schema_name || schema_version != init.schema_version {
        return Err(mismatch(
            "schema",
            format!("{schema} v{schema_version}"),
            format!("{} v{}", init.schema_name, init.schema_version),
        ));
    }
    if shared.description() != init.description {
        return Err(mismatch(
            "description (topology)",
            format!("{} bytes", existing.description_bytes),
            format!("{} different bytes", init.description.len()),
        ));
    }
    Ok(())
}

/// Removes one segment if no live writer holds it, race-free against a
/// writer reviving it. `Ok(false)` if a writer holds it or it is already gone.
pub(crate) fn remove_if_unowned(path: &Path) -> Result<bool> {
    let file = match File::options().read(true).write(true).open(path) {
        Ok(file) => file,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(false),
        Err(source) => return Err(Error::Os { op: "open", path: path.to_owned(), source }),
    };
    // The reviver's lock first, as a reviving writer takes it: a segment being
    // revived (liveness lock not yet taken) is not stale.
    let lock_error = |source| Error::Os { op: "lock", path: path.to_owned(), source };
    if !os::try_lock_reviver(&file).map_err(lock_error)? || !os::try_lock_writer(&file).map_err(lock_error)? {
        return Ok(false);
    }
    let ours = file.metadata().ok().map(|m| (m.dev(), m.ino()));
    if ours.is_none() || ours != path_identity(path) {
        return Ok(false);
    }
    std::fs::remove_file(path).map_err(|source| Error::Os { op: "remove", path: path.to_owned(), source })?;
    Ok(true)
}
