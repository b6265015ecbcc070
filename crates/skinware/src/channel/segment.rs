//! A channel's segment: opening and validating one (nothing in it is trusted
//! before it has been checked), creating one complete under a temporary name,
//! and the typed views of its parts ([`Shared`]).

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

use super::ChannelKind;
use super::layout::{ABI_VERSION, Doorbell, Header, Layout, MAGIC, PAGE};
use super::ring::{self, Ring};
use crate::error::{Error, Result};
use crate::shm::{self, Mapping};
use crate::sync::{AtomicU64, Ordering};

/// A mapped, validated channel segment. Shared (through `Arc`) by a reader or
/// writer and the stop handles that can wake it.
pub(crate) struct Shared {
    /// `skin/channel`, for messages.
    pub label: String,
    /// The segment file.
    pub path: PathBuf,
    /// The open segment; a writer's also carries its liveness lock.
    pub file: File,
    pub layout: Layout,
    pub kind: ChannelKind,
    /// The whole segment: read-only for readers, read-write for the writer.
    map: Mapping,
    /// The doorbell page, read-write for everybody.
    doorbell: Mapping,
}

impl Shared {
    pub fn header(&self) -> &Header {
        // SAFETY: the mapping is at least 2 pages (checked when mapping) and
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

    /// Maps a validated layout of `file`.
    fn map(
        label: String,
        path: PathBuf,
        file: File,
        layout: Layout,
        kind: ChannelKind,
        writable: bool,
    ) -> Result<Shared> {
        let map = Mapping::map(&file, &path, 0, layout.file_bytes as usize, writable)?;
        let doorbell = Mapping::map(&file, &path, PAGE, PAGE as usize, true)?;
        debug_assert!(map.len() as u64 >= 2 * PAGE);
        Ok(Shared { label, path, file, layout, kind, map, doorbell })
    }
}

/// `skin/channel`, the way channels are named in messages.
pub(crate) fn label(skin: &str, channel: &str) -> String {
    format!("{skin}/{channel}")
}

fn os_error<'p>(op: &'static str, path: &'p Path) -> impl FnOnce(io::Error) -> Error + 'p {
    move |source| Error::Os { op, path: path.to_owned(), source }
}

/// Opens and validates an existing segment. Nothing in it is trusted before it
/// has been checked: magic, ABI version, self-consistent sizes, file length.
pub(crate) fn open_segment(dir: &Path, skin: &str, channel: &str, writable: bool) -> Result<Shared> {
    shm::validate_name("skin", skin)?;
    shm::validate_name("channel", channel)?;
    let path = shm::segment_path(dir, skin, channel);
    let label = label(skin, channel);
    let file = match File::options().read(true).write(true).open(&path) {
        Ok(file) => file,
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(Error::Missing { channel: label, path });
        }
        Err(e) => {
            return Err(Error::Os { op: "open", path, source: e });
        }
    };
    map_validated(label, path, file, writable)
}

/// Validates an open segment file and maps it.
pub(crate) fn map_validated(label: String, path: PathBuf, file: File, writable: bool) -> Result<Shared> {
    let (layout, kind) = validate(&file, &path, &label)?;
    Shared::map(label, path, file, layout, kind, writable)
}

/// Validates the header of an open segment file and returns its layout.
pub(crate) fn validate(file: &File, path: &Path, label: &str) -> Result<(Layout, ChannelKind)> {
    let size = file.metadata().map_err(os_error("stat", path))?.len();
    let truncated =
        |needed| Error::Truncated { channel: label.to_owned(), path: path.to_owned(), actual: size, needed };
    if size < 8 {
        return Err(truncated(2 * PAGE));
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
    if size < 2 * PAGE {
        return Err(truncated(2 * PAGE));
    }
    // Acquire: pairs with the creator's Release store of the version, which it
    // makes after every other header field.
    match header.abi_version.load(Ordering::Acquire) {
        0 => {
            return Err(Error::Unfinished { channel: label.to_owned() });
        }
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

/// Creates a complete segment under a temporary name and returns it mapped
/// read-write and locked by the caller (the new writer). The caller renames it
/// into place.
pub(crate) fn create_segment(
    temp_path: &Path,
    label: String,
    layout: Layout,
    init: &SegmentInit<'_>,
) -> Result<Shared> {
    use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
    let file = File::options()
        .read(true)
        .write(true)
        .create_new(true)
        .mode(init.mode)
        .open(temp_path)
        .map_err(os_error("create", temp_path))?;
    // The process umask may have removed group bits; the mode was asked for explicitly.
    file.set_permissions(std::fs::Permissions::from_mode(init.mode)).map_err(os_error("chmod", temp_path))?;
    if !crate::os::try_lock_writer(&file).map_err(os_error("lock", temp_path))? {
        return Err(Error::Os { op: "lock", path: temp_path.to_owned(), source: io::ErrorKind::WouldBlock.into() });
    }
    // Allocate every page now: on a tmpfs a sparse file would make the first
    // write to a page beyond free space a SIGBUS instead of this error.
    rustix::fs::fallocate(&file, rustix::fs::FallocateFlags::empty(), 0, layout.file_bytes).map_err(|e| Error::Os {
        op: "allocate (is /dev/shm full?)",
        path: temp_path.to_owned(),
        source: e.into(),
    })?;
    let shared = Shared::map(label, temp_path.to_owned(), file, layout, init.kind, true)?;
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
    pub mode: u32,
}
