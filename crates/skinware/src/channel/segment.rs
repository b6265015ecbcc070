//! A channel's memory: creating it (two sealed memory files, complete before
//! any reader can reach them), receiving and validating it (nothing in it is
//! trusted before it has been checked), and the typed views of its parts
//! ([`Shared`]).
//!
//! **Why sealed memory files.** A mapping of a file that someone truncates
//! kills whoever touches the missing pages with SIGBUS. The data and the
//! doorbell are therefore `memfd`s sealed with `F_SEAL_SHRINK | F_SEAL_GROW`
//! (and `F_SEAL_SEAL`, so the seals stay): the kernel refuses every change of
//! their size, to every process, the writer included. They have no name, so
//! nobody can unlink or replace them either; readers receive them from the
//! writer ([`super::handover`]). The data is also sealed `F_SEAL_FUTURE_WRITE`
//! once the writer has mapped it: no process, whatever its descriptor, can
//! write it or map it writable again, and readers get it opened read-only.
//! A reader refuses memory that is not sealed against shrinking.

use std::fs::File;
use std::io;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

use rustix::fs::{MemfdFlags, SealFlags};

use super::ChannelKind;
use super::handover::{self, Fetched};
use super::layout::{ABI_VERSION, Doorbell, Header, Layout, MAGIC, PAGE};
use super::ring::{self, Ring};
use crate::error::{Error, Result};
use crate::os;
use crate::shm::{self, Mapping};
use crate::stats::WriterState;
use crate::sync::{AtomicU64, Ordering};

/// The seals every channel memory file must carry before a reader maps it.
const REQUIRED_SEALS: SealFlags = SealFlags::SHRINK;

/// A mapped, validated channel. Shared (through `Arc`) by a reader or writer
/// and the stop handles that can wake it.
pub(crate) struct Shared {
    /// `skin/channel`, for messages.
    pub label: String,
    /// The channel's socket, where readers ask for it.
    pub path: PathBuf,
    /// The data memory file: read-write for the writer (which holds its
    /// liveness lock on it), read-only for readers.
    pub data: File,
    pub layout: Layout,
    pub kind: ChannelKind,
    /// The header, description and ring: read-only for readers.
    map: Mapping,
    /// The doorbell page, read-write for everybody.
    doorbell: Mapping,
    /// Keeps the doorbell's memory file open (the writer hands it over).
    bell: File,
}

impl Shared {
    pub fn header(&self) -> &Header {
        // SAFETY: the mapping is at least 1 page (checked when validating) and
        // offset 0 of a page-aligned mapping is aligned for Header, which is
        // SharedMemorySafe.
        unsafe { self.map.get(0) }
    }

    pub fn doorbell(&self) -> &Doorbell {
        // SAFETY: the doorbell mapping is one page, page-aligned; Doorbell is
        // SharedMemorySafe.
        unsafe { self.doorbell.get(0) }
    }

    pub fn ring(&self) -> Ring<'_> {
        let count = self.layout.slot_count as usize;
        // SAFETY: `file_bytes = ring_offset + count * slot_bytes` was validated
        // against the mapping's length, and ring_offset is page-aligned.
        let slots = unsafe { self.map.words(self.layout.ring_offset as usize, count * self.layout.slot_words()) };
        Ring::new(&self.header().published.0, slots, count)
    }

    /// The description bytes, copied out.
    pub fn description(&self) -> Vec<u8> {
        let words = (self.layout.description_bytes as usize).div_ceil(8);
        // SAFETY: the description area lies within the mapping (validated layout)
        // and its offset is page-aligned.
        let area = unsafe { self.map.words(self.layout.description_offset as usize, words) };
        let mut bytes: Vec<u8> = area.iter().flat_map(|w| w.load(Ordering::Relaxed).to_ne_bytes()).collect();
        bytes.truncate(self.layout.description_bytes as usize);
        bytes
    }

    /// The description area as words, for the creator to fill.
    pub fn description_words(&self) -> &[AtomicU64] {
        let words = (self.layout.description_bytes as usize).div_ceil(8);
        // SAFETY: as in `description`.
        unsafe { self.map.words(self.layout.description_offset as usize, words) }
    }

    /// The doorbell's memory file.
    pub fn bell(&self) -> &File {
        &self.bell
    }

    /// The identity of the data memory file: a new writer's channel has another.
    pub fn identity(&self) -> Option<(u64, u64)> {
        use std::os::unix::fs::MetadataExt;
        self.data.metadata().ok().map(|meta| (meta.dev(), meta.ino()))
    }
}

/// `skin/channel`, the way channels are named in messages.
pub(crate) fn label(skin: &str, channel: &str) -> String {
    format!("{skin}/{channel}")
}

fn os_error<'p>(op: &'static str, path: &'p Path) -> impl FnOnce(io::Error) -> Error + 'p {
    move |source| Error::Os { op, path: path.to_owned(), source }
}

/// What opening a channel found.
pub(crate) enum Opened {
    /// Its memory, validated and mapped.
    Live(Shared),
    /// Its socket, with nobody answering: the writer is dead or was dropped.
    NoWriter,
}

/// Asks the writer of `skin`/`channel` for the channel's memory, then
/// validates and maps it (the data read-only).
pub(crate) fn open_segment(dir: &Path, skin: &str, channel: &str, answer_timeout: Duration) -> Result<Opened> {
    shm::validate_name("skin", skin)?;
    shm::validate_name("channel", channel)?;
    let path = shm::segment_path(dir, skin, channel);
    let label = label(skin, channel);
    match handover::fetch(&path, &label, answer_timeout)? {
        Fetched::NoWriter => Ok(Opened::NoWriter),
        Fetched::Memory { data, bell } => map_received(label, path, data, bell).map(Opened::Live),
    }
}

/// [`open_segment`] of several channels of `dir`, in the same order: all the
/// writers are asked at once and answer within one `answer_timeout`
/// ([`handover::fetch_all`]), so that a stopped writer costs a listing one
/// bounded wait, not one per channel.
pub(crate) fn open_segments(dir: &Path, channels: &[(&str, &str)], answer_timeout: Duration) -> Vec<Result<Opened>> {
    let named: Vec<(PathBuf, String)> =
        channels.iter().map(|&(skin, channel)| (shm::segment_path(dir, skin, channel), label(skin, channel))).collect();
    let asked: Vec<(&Path, &str)> = named.iter().map(|(path, label)| (path.as_path(), label.as_str())).collect();
    let mut fetched = handover::fetch_all(&asked, answer_timeout).into_iter();
    channels
        .iter()
        .zip(named)
        .map(|(&(skin, channel), (path, label))| {
            shm::validate_name("skin", skin)?;
            shm::validate_name("channel", channel)?;
            match fetched.next() {
                Some(Ok(Fetched::Memory { data, bell })) => map_received(label, path, data, bell).map(Opened::Live),
                Some(Ok(Fetched::NoWriter)) => Ok(Opened::NoWriter),
                Some(Err(e)) => Err(e),
                None => Err(Error::NotAnswering { channel: label, path }),
            }
        })
        .collect()
}

/// Validates memory received from a writer (or anyone claiming to be one)
/// and maps it: the data read-only, the doorbell read-write.
pub(crate) fn map_received(label: String, path: PathBuf, data: OwnedFd, bell: OwnedFd) -> Result<Shared> {
    for (what, fd) in [("frames", &data), ("doorbell", &bell)] {
        let seals = rustix::fs::fcntl_get_seals(fd).unwrap_or(SealFlags::empty());
        if !seals.contains(REQUIRED_SEALS) {
            return Err(Error::Unsealed { channel: label, what });
        }
    }
    let data = File::from(data);
    let bell = File::from(bell);
    let (layout, kind) = validate(&data, &path, &label)?;
    let bell_bytes = bell.metadata().map_err(os_error("stat", &path))?.len();
    if bell_bytes < PAGE {
        return Err(Error::Truncated { channel: label, path, actual: bell_bytes, needed: PAGE });
    }
    Shared::map(label, path, data, bell, layout, kind, false)
}

/// Validates the header of an open segment file and returns its layout.
pub(crate) fn validate(file: &File, path: &Path, label: &str) -> Result<(Layout, ChannelKind)> {
    let size = file.metadata().map_err(os_error("stat", path))?.len();
    let truncated =
        |needed| Error::Truncated { channel: label.to_owned(), path: path.to_owned(), actual: size, needed };
    if size < 8 {
        return Err(truncated(PAGE));
    }
    // One page is always safe to map once the file has a byte in it: the part
    // of the page past the end of the file reads as zeros.
    let first_page = Mapping::map(file, path, 0, PAGE as usize, false)?;
    // SAFETY: one page is mapped, page-aligned; Header is SharedMemorySafe and fits a page.
    let header: &Header = unsafe { first_page.get(0) };
    let magic = header.magic.load(Ordering::Relaxed);
    if magic != MAGIC {
        return Err(Error::NotOurs { channel: label.to_owned(), path: path.to_owned(), found: magic });
    }
    if size < PAGE {
        return Err(truncated(PAGE));
    }
    // Acquire: pairs with the creator's Release store of the version, which it
    // makes after every other header field.
    match header.abi_version.load(Ordering::Acquire) {
        ABI_VERSION => {}
        found => {
            return Err(Error::VersionMismatch { channel: label.to_owned(), found, expected: ABI_VERSION });
        }
    }
    let corrupt = |reason: String| Error::Corrupt { channel: label.to_owned(), reason };
    let layout = Layout::from_header(header).map_err(corrupt)?;
    let kind_code = header.kind.load(Ordering::Relaxed);
    let kind = ChannelKind::from_code(kind_code).ok_or_else(|| corrupt(format!("unknown channel kind {kind_code}")))?;
    if size < layout.file_bytes {
        return Err(truncated(layout.file_bytes));
    }
    // Sequence numbers count frames; anything near 2^62 is a damaged header
    // (and would overflow the stamp arithmetic).
    let published = header.published.0.load(Ordering::Relaxed);
    if published >= 1 << 62 {
        return Err(corrupt(format!("published sequence number {published} is implausible")));
    }
    Ok((layout, kind))
}

impl Shared {
    /// Maps a validated layout of `data`, and the doorbell.
    fn map(
        label: String,
        path: PathBuf,
        data: File,
        bell: File,
        layout: Layout,
        kind: ChannelKind,
        writable: bool,
    ) -> Result<Shared> {
        let map = Mapping::map(&data, &path, 0, layout.file_bytes as usize, writable)?;
        let doorbell = Mapping::map(&bell, &path, 0, PAGE as usize, true)?;
        Ok(Shared { label, path, data, layout, kind, map, doorbell, bell })
    }
}

/// A sealable memory file of `bytes`, every page allocated now (so that a
/// full tmpfs is this error rather than a SIGBUS on a later write).
fn memory_file(label: &str, path: &Path, what: &str, bytes: u64, mode: u32) -> Result<File> {
    let name = format!("skinware:{label}:{what}");
    let fd = rustix::fs::memfd_create(name.as_str(), MemfdFlags::CLOEXEC | MemfdFlags::ALLOW_SEALING)
        .map_err(|e| Error::Os { op: "memfd_create", path: path.to_owned(), source: e.into() })?;
    rustix::fs::fchmod(&fd, rustix::fs::Mode::from_raw_mode(mode)).map_err(|e| Error::Os {
        op: "chmod",
        path: path.to_owned(),
        source: e.into(),
    })?;
    rustix::fs::ftruncate(&fd, bytes).map_err(|e| Error::Os {
        op: "allocate (is shared memory full?)",
        path: path.to_owned(),
        source: e.into(),
    })?;
    rustix::fs::fallocate(&fd, rustix::fs::FallocateFlags::empty(), 0, bytes).map_err(|e| Error::Os {
        op: "allocate (is shared memory full?)",
        path: path.to_owned(),
        source: e.into(),
    })?;
    Ok(File::from(fd))
}

fn seal(file: &File, path: &Path, seals: SealFlags) -> Result<()> {
    rustix::fs::fcntl_add_seals(file, seals).map_err(|e| Error::Os {
        op: "seal",
        path: path.to_owned(),
        source: e.into(),
    })
}

/// A descriptor of the data opened anew, read-only: readers get this one, not
/// the writer's (whose open file carries the liveness lock).
pub(crate) fn reopen_read_only(shared: &Shared) -> Result<OwnedFd> {
    let proc_path = format!("/proc/self/fd/{}", shared.data.as_fd().as_raw_fd());
    rustix::fs::open(
        proc_path.as_str(),
        rustix::fs::OFlags::RDONLY | rustix::fs::OFlags::CLOEXEC,
        rustix::fs::Mode::empty(),
    )
    .map_err(|e| Error::Os {
        op: "reopen the frames read-only (is /proc mounted?)",
        path: shared.path.clone(),
        source: e.into(),
    })
}

/// Creates a channel's memory, complete, sealed, and mapped read-write for the
/// caller (the new writer). Readers can reach it only once the caller hands
/// it over.
pub(crate) fn create_segment(path: &Path, label: String, layout: Layout, init: &SegmentInit<'_>) -> Result<Shared> {
    let data = memory_file(&label, path, "frames", layout.file_bytes, init.data_mode)?;
    let bell = memory_file(&label, path, "doorbell", PAGE, init.bell_mode)?;
    seal(&data, path, SealFlags::SHRINK | SealFlags::GROW)?;
    seal(&bell, path, SealFlags::SHRINK | SealFlags::GROW | SealFlags::SEAL)?;
    let shared = Shared::map(label, path.to_owned(), data, bell, layout, init.kind, true)?;
    // The writer's own mapping stays writable; from now on no other can be made.
    seal(&shared.data, path, SealFlags::FUTURE_WRITE | SealFlags::SEAL)?;
    let header = shared.header();
    header.magic.store(MAGIC, Ordering::Relaxed);
    header.kind.store(init.kind as u32, Ordering::Relaxed);
    header.file_bytes.store(layout.file_bytes, Ordering::Relaxed);
    header.description_offset.store(layout.description_offset, Ordering::Relaxed);
    header.description_bytes.store(layout.description_bytes, Ordering::Relaxed);
    header.ring_offset.store(layout.ring_offset, Ordering::Relaxed);
    header.slot_count.store(layout.slot_count, Ordering::Relaxed);
    header.slot_bytes.store(layout.slot_bytes, Ordering::Relaxed);
    header.payload_bytes.store(layout.payload_bytes, Ordering::Relaxed);
    for (word, value) in header.schema_name.iter().zip(super::layout::encode_schema(init.schema_name)) {
        word.store(value, Ordering::Relaxed);
    }
    header.schema_version.store(init.schema_version, Ordering::Relaxed);
    header.created_ns.store(crate::os::monotonic_ns(), Ordering::Relaxed);
    header.stats.write_ns_min.store(u64::MAX, Ordering::Relaxed);
    ring::store_bytes(shared.description_words(), 0, init.description);
    // Release: publishes every store above to an opener's Acquire load of the version.
    header.abi_version.store(ABI_VERSION, Ordering::Release);
    Ok(shared)
}

/// What a creator puts into a new segment besides its layout.
pub(crate) struct SegmentInit<'a> {
    pub kind: ChannelKind,
    pub description: &'a [u8],
    pub schema_name: &'a str,
    pub schema_version: u32,
    /// Permissions of the data memory file.
    pub data_mode: u32,
    /// Permissions of the doorbell memory file.
    pub bell_mode: u32,
}

// A segment's liveness: the writer holds a lock on its data for as long as
// it lives ([`super::liveness`] explains the protocol).
impl Shared {
    /// Whether a live process holds this segment's liveness lock. It only
    /// asks, so probing can never get in a reviving writer's way.
    pub fn writer_alive(&self) -> io::Result<bool> {
        os::writer_lock_held(&self.data)
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

/// Takes the liveness lock on a new channel's data, before anyone can reach it.
pub(crate) fn go_live(shared: &Shared) -> Result<()> {
    match os::try_lock_writer(&shared.data) {
        Ok(true) => Ok(()),
        Ok(false) => Err(Error::Os { op: "lock", path: shared.path.clone(), source: io::ErrorKind::WouldBlock.into() }),
        Err(source) => Err(Error::Os { op: "lock", path: shared.path.clone(), source }),
    }
}
