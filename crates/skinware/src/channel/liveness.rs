//! Liveness and succession: who owns a channel's name, how readers tell a
//! dead writer, and how a new writer takes over a dead writer's name so that
//! readers follow it.
//!
//! Two open-file-description locks say everything ([`crate::os`] makes the
//! calls); the kernel drops both when the writer's process dies, however it
//! dies, so "alive" is a question to the kernel (`F_OFD_GETLK`), never a
//! heartbeat a crashed process could leave behind:
//!
//! * the **liveness lock** on the channel's data memory file, held by the
//!   writer for its whole life. Readers ask it through their own (read-only)
//!   descriptor of the same file;
//! * the **name lock** on `<dir>/.skinware-lock.<skin>.<channel>`, which makes
//!   one writer at a time the owner of a channel name. The file also keeps the
//!   name's record: how many writers it has had (the generation) and the last
//!   one's process id. A cleaner takes the same lock before it removes a name.
//!
//! A channel's memory dies with its last reader; it is never revived in
//! place. A new writer creates new memory under the same name, and attached
//! readers follow it ([`crate::Reader::follow_recreated`]).
//!
//! The writer's *state* (running, paused, faulted, stopped) is a word in the
//! header that only the live writer stores; readers combine it with the
//! liveness lock ([`WriterState::from_code`]).

#![forbid(unsafe_code)]

use std::fs::File;
use std::io;
use std::os::unix::fs::{FileExt, MetadataExt};
use std::path::{Path, PathBuf};

use super::layout::Header;
use crate::error::{Error, Result};
use crate::os;
use crate::shm;
use crate::stats::WriterState;
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
    std::fs::symlink_metadata(path).ok().map(|meta| (meta.dev(), meta.ino()))
}

/// The name lock's file of `skin`/`channel`.
pub(crate) fn name_lock_path(dir: &Path, skin: &str, channel: &str) -> PathBuf {
    dir.join(format!("{}{skin}.{channel}", shm::LOCK_PREFIX))
}

/// What a channel name's lock file records.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct NameRecord {
    /// How many writers the name has had.
    pub generation: u64,
    /// The current (or last) writer's process id.
    pub writer_pid: u32,
    /// Who owns the lock file: who wrote the record.
    pub owner_uid: u32,
}

impl NameRecord {
    const BYTES: usize = 16;

    fn read(file: &File) -> NameRecord {
        let mut bytes = [0u8; NameRecord::BYTES];
        match file.read_exact_at(&mut bytes, 0) {
            Ok(()) => NameRecord {
                generation: u64::from_le_bytes(bytes[..8].try_into().unwrap_or_default()),
                writer_pid: u32::from_le_bytes(bytes[8..12].try_into().unwrap_or_default()),
                owner_uid: file.metadata().map_or(u32::MAX, |meta| meta.uid()),
            },
            Err(_) => NameRecord::default(),
        }
    }

    /// The record of a channel name, if its lock file can be read.
    /// It is only read if it is a regular file: a FIFO there would block
    /// the open, a symbolic link lead anywhere ([`shm::open_regular`]).
    pub fn load(dir: &Path, skin: &str, channel: &str) -> Option<NameRecord> {
        shm::open_regular(&name_lock_path(dir, skin, channel), false).ok().map(|file| NameRecord::read(&file))
    }
}

/// The name locks held by live writers of this process, by path.
fn held_here() -> std::sync::MutexGuard<'static, Vec<PathBuf>> {
    static HELD: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());
    crate::lock(&HELD)
}

/// The longest a new writer waits for a name lock that only a fork of this
/// process still holds (see [`held_by_a_fork_of_ours`]).
const FORK_COPY_WAIT_NS: u64 = 2_000_000_000;

/// Whether a name lock that is held, last recorded as taken by `pid`, can
/// only be held by a child of this process between its fork and its exec: a
/// child gets a copy of every descriptor, the lock's open file description
/// with them, and keeps it until its exec closes it. If this process wrote
/// the record and no live writer of this process holds the name, that is
/// the case, and the lock is free in a moment (a writer restarted in the
/// process that another thread spawns programs from would otherwise be told
/// that its own dead predecessor is busy).
fn held_by_a_fork_of_ours(pid: u32, path: &Path) -> bool {
    pid == std::process::id() && !held_here().iter().any(|held| held == path)
}

/// Whether a writer still owns its channel's name ([`NameLock::keep_in_place`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kept {
    /// The lock file is in place, or was put back.
    Held,
    /// Another live writer took the name.
    Lost,
    /// The lock file could not be put back yet; nobody else holds the name.
    NotYet,
}

/// Ownership of a channel name, for a writer's life.
pub(crate) struct NameLock {
    file: File,
    path: PathBuf,
    /// What this writer recorded, to record again if the file is replaced.
    written: NameRecord,
}

impl NameLock {
    /// Takes the name of `skin`/`channel`, or fails with [`Error::Busy`] if a
    /// live writer holds it. The lock file must be a regular file owned by
    /// this process's user ([`Error::UntrustedFile`] otherwise): one planted
    /// by another user could be held locked by them, or rewritten.
    pub fn acquire(dir: &Path, skin: &str, channel: &str, label: &str) -> Result<NameLock> {
        NameLock::acquire_checked(dir, skin, channel, label, true)
    }

    /// As [`acquire`](Self::acquire); a cleaner (`own_only` false) may take
    /// a lock file of another user, to remove a dead writer's name.
    fn acquire_checked(dir: &Path, skin: &str, channel: &str, label: &str, own_only: bool) -> Result<NameLock> {
        let path = name_lock_path(dir, skin, channel);
        let os_error = |op, source| Error::Os { op, path: path.clone(), source };
        let started = os::monotonic_ns();
        // Each pass either takes the lock, loses a race with a cleaner that
        // unlinked the file between our open and our lock, or finds the lock
        // held by a copy of a descriptor this process has closed.
        let mut races = 0;
        while races < 16 {
            let Some(file) = open_lock_file(&path, label, own_only)? else {
                races += 1;
                continue;
            };
            if !os::try_lock_writer(&file).map_err(|e| os_error("lock", e))? {
                let pid = NameRecord::read(&file).writer_pid;
                if held_by_a_fork_of_ours(pid, &path) && os::monotonic_ns().saturating_sub(started) < FORK_COPY_WAIT_NS
                {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                    continue;
                }
                return Err(Error::Busy { channel: label.to_owned(), pid });
            }
            if path_identity(&path) == Some(file_identity(&file, &path)?) {
                held_here().push(path.clone());
                return Ok(NameLock { file, path, written: NameRecord::default() });
            }
            races += 1;
        }
        Err(os_error("lock", io::ErrorKind::ResourceBusy.into()))
    }

    /// The name's record as the previous writer left it.
    pub fn record(&self) -> NameRecord {
        NameRecord::read(&self.file)
    }

    /// Records the new writer.
    pub fn write_record(&mut self, record: NameRecord) -> Result<()> {
        self.written = record;
        let mut bytes = [0u8; NameRecord::BYTES];
        bytes[..8].copy_from_slice(&record.generation.to_le_bytes());
        bytes[8..12].copy_from_slice(&record.writer_pid.to_le_bytes());
        self.file.write_all_at(&bytes, 0).map_err(|source| Error::Os {
            op: "write the channel's name record",
            path: self.path.clone(),
            source,
        })
    }

    /// Puts the lock file back if someone removed or replaced it (the lock
    /// on an unlinked file keeps nobody out), and takes it again. Says
    /// whether this writer still owns the name: [`Kept::Lost`] only when
    /// another live writer holds it now; a lock file that cannot be put
    /// back for another reason (no room, something planted at its path) is
    /// [`Kept::NotYet`], tried again at the next look.
    pub fn keep_in_place(&mut self) -> Kept {
        if self.is_in_place() {
            return Kept::Held;
        }
        let Some(dir) = self.path.parent() else { return Kept::NotYet };
        let Some(name) = self.path.file_name().and_then(|n| n.to_str()) else { return Kept::NotYet };
        let Some((skin, channel)) = name.strip_prefix(shm::LOCK_PREFIX).and_then(|rest| rest.split_once('.')) else {
            return Kept::NotYet;
        };
        match NameLock::acquire(dir, skin, channel, &super::label(skin, channel)) {
            Ok(mut again) => {
                let _ = again.write_record(self.written);
                *self = again;
                Kept::Held
            }
            Err(Error::Busy { .. }) => Kept::Lost,
            Err(e) => {
                tracing::warn!(path = %self.path.display(), error = %e, "cannot put the channel's name lock back; trying again");
                Kept::NotYet
            }
        }
    }

    /// Whether the file at the lock's path is still the one this writer locked.
    fn is_in_place(&self) -> bool {
        match file_identity(&self.file, &self.path) {
            Ok(ours) => path_identity(&self.path) == Some(ours),
            Err(_) => false,
        }
    }

    /// Removes the name (the socket bound as `socket`, and the lock file)
    /// while still holding it; only what is still this writer's: a writer
    /// that lost its name must not remove its successor's.
    pub fn remove(self, socket: &Path, socket_identity: Option<FileIdentity>) {
        if socket_identity.is_some() && path_identity(socket) == socket_identity {
            let _ = std::fs::remove_file(socket);
        }
        if self.is_in_place() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

impl Drop for NameLock {
    fn drop(&mut self) {
        let mut held = held_here();
        if let Some(index) = held.iter().position(|held| *held == self.path) {
            held.swap_remove(index);
        }
    }
}

/// Opens (creating it if need be) the name lock's file at `path`: a regular
/// file, never a link followed or a FIFO opened ([`shm::open_regular`]),
/// and with `own_only` one owned by this process's user. `None` if it
/// vanished between two looks (a cleaner): try again.
fn open_lock_file(path: &Path, label: &str, own_only: bool) -> Result<Option<File>> {
    use rustix::fs::{Mode, OFlags};
    let untrusted = |reason: String| Error::UntrustedFile { channel: label.to_owned(), path: path.to_owned(), reason };
    let os_error = |source| Error::Os { op: "open the channel's name lock", path: path.to_owned(), source };
    let create = OFlags::RDWR | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC;
    match rustix::fs::open(path, create, Mode::from_raw_mode(0o644)) {
        Ok(fd) => return Ok(Some(File::from(fd))),
        Err(rustix::io::Errno::EXIST) => {}
        Err(e) => return Err(os_error(e.into())),
    }
    // A writer's lock file must be its user's, of one name and at most a
    // record long: a hard link planted here to another file of that user
    // (root's geometry, say) would otherwise get the record written into it.
    let expected = own_only
        .then(|| shm::Expected { owner: rustix::process::geteuid().as_raw(), max_bytes: NameRecord::BYTES as u64 });
    match shm::open_regular_as(path, true, expected) {
        Ok(file) => Ok(Some(file)),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(e) if e.kind() == io::ErrorKind::InvalidData => Err(untrusted(e.to_string())),
        Err(e) => Err(os_error(e)),
    }
}

/// Stores the writer's state for readers, stamping the time of a change. Only
/// the live writer (or a handle it gave out) calls it.
pub(crate) fn set_state(header: &Header, state: WriterState) {
    if header.state.swap(state.code(), Ordering::Release) != state.code() {
        header.state_changed_ns.store(os::monotonic_ns(), Ordering::Relaxed);
    }
}

/// Writes the new writer's details into the header (pid, period, generation),
/// then its running state, before any reader can reach the channel.
pub(crate) fn introduce_writer(header: &Header, period_ns: u64, generation: u64) {
    header.writer_pid.store(std::process::id(), Ordering::Relaxed);
    header.period_ns.store(period_ns, Ordering::Relaxed);
    header.generation.store(generation, Ordering::Relaxed);
    header.state_changed_ns.store(os::monotonic_ns(), Ordering::Relaxed);
    header.state.store(WriterState::RUNNING, Ordering::Release);
}

/// Marks the writer stopped, the last thing it does before it lets go.
pub(crate) fn retire_writer(header: &Header) {
    header.state.store(WriterState::STOPPED, Ordering::Release);
    header.state_changed_ns.store(os::monotonic_ns(), Ordering::Relaxed);
}

/// Removes a channel name (its socket and lock file) if no live writer holds
/// it, race-free against a writer taking it at the same moment. `Ok(false)` if
/// a writer holds it.
pub(crate) fn remove_if_unowned(dir: &Path, skin: &str, channel: &str) -> Result<bool> {
    let label = super::label(skin, channel);
    match NameLock::acquire_checked(dir, skin, channel, &label, false) {
        Ok(lock) => {
            let socket = shm::segment_path(dir, skin, channel);
            let identity = path_identity(&socket);
            lock.remove(&socket, identity);
            Ok(true)
        }
        Err(Error::Busy { .. }) => Ok(false),
        Err(e) => Err(e),
    }
}
