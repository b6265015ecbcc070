//! Channel names, where they live, and mapping channel memory.
//!
//! A channel `pressure` of skin `default` is reached through the socket
//! `/dev/shm/skinware.default.pressure`, and its name is owned through the
//! lock file `/dev/shm/.skinware-lock.default.pressure` (the directory can be
//! changed with the `SKINWARE_SHM_DIR` environment variable, which tests use
//! to stay apart). The memory itself has no name ([`crate::channel`]).

use std::fs::File;
use std::os::fd::AsFd;
use std::path::{Path, PathBuf};
use std::ptr::NonNull;

use crate::error::{Error, Result};

/// Longest skin or channel name.
pub const MAX_NAME_LEN: usize = 64;

/// Prefix of every segment file.
pub(crate) const PREFIX: &str = "skinware.";
/// Prefix of sockets still being bound (renamed into place when ready).
pub(crate) const TEMP_PREFIX: &str = ".skinware-tmp.";
/// Prefix of the channel names' lock files.
pub(crate) const LOCK_PREFIX: &str = ".skinware-lock.";

/// The directory holding the segments: `$SKINWARE_SHM_DIR`, or `/dev/shm`.
pub fn segment_dir() -> PathBuf {
    std::env::var_os("SKINWARE_SHM_DIR").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("/dev/shm"))
}

/// Checks a skin or channel name: 1 to [`MAX_NAME_LEN`] of `A-Z a-z 0-9 _ -`.
/// This rules out `/`, `..`, dots (the separator in segment names) and NULs.
pub fn validate_name(what: &'static str, name: &str) -> Result<()> {
    let reason = if name.is_empty() {
        Some("it is empty")
    } else if name.len() > MAX_NAME_LEN {
        Some("it is too long")
    } else if name.contains('/') {
        Some("it contains '/'")
    } else if name.contains("..") {
        Some("it contains '..'")
    } else if !name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-') {
        Some("it contains a character other than A-Z a-z 0-9 _ -")
    } else {
        None
    };
    match reason {
        Some(reason) => Err(Error::InvalidName { what, name: name.to_owned(), reason, max_len: MAX_NAME_LEN }),
        None => Ok(()),
    }
}

/// The segment path of `skin`/`channel` (names must already be valid).
pub(crate) fn segment_path(dir: &Path, skin: &str, channel: &str) -> PathBuf {
    dir.join(format!("{PREFIX}{skin}.{channel}"))
}

/// Splits a segment file name into (skin, channel).
pub(crate) fn parse_segment_name(file_name: &str) -> Option<(&str, &str)> {
    let rest = file_name.strip_prefix(PREFIX)?;
    let (skin, channel) = rest.split_once('.')?;
    (validate_name("skin", skin).is_ok() && validate_name("channel", channel).is_ok()).then_some((skin, channel))
}

/// A memory mapping of (part of) a segment, unmapped on drop.
pub(crate) struct Mapping {
    ptr: NonNull<u8>,
    len: usize,
}

// SAFETY: the mapping is plain shared memory; everything placed in it is accessed
// through atomics (see `SharedMemorySafe`), so it can be shared across threads.
unsafe impl Send for Mapping {}
// SAFETY: as above.
unsafe impl Sync for Mapping {}

impl Mapping {
    /// Maps `len` bytes of `file` from `offset` (page-aligned), shared.
    pub fn map(file: &File, path: &Path, offset: u64, len: usize, writable: bool) -> Result<Mapping> {
        use rustix::mm::{MapFlags, ProtFlags, mmap};
        let prot = if writable { ProtFlags::READ | ProtFlags::WRITE } else { ProtFlags::READ };
        // SAFETY: a null hint lets the kernel choose a fresh address range, so no
        // existing Rust object is aliased; the fd is valid for the call; the
        // resulting memory is only ever accessed through atomics.
        let ptr = unsafe { mmap(std::ptr::null_mut(), len, prot, MapFlags::SHARED, file.as_fd(), offset) }
            .map_err(|e| Error::Os { op: "mmap", path: path.to_owned(), source: e.into() })?;
        let ptr = NonNull::new(ptr.cast::<u8>()).ok_or_else(|| Error::Os {
            op: "mmap",
            path: path.to_owned(),
            source: std::io::ErrorKind::Other.into(),
        })?;
        Ok(Mapping { ptr, len })
    }

    /// A reference to a `T` at byte `offset`.
    ///
    /// # Safety
    /// `offset + size_of::<T>() <= len`, `offset` is aligned for `T`, and `T`
    /// is [`SharedMemorySafe`](crate::channel::layout::SharedMemorySafe) (or an
    /// atomic), so that every bit pattern is a valid `T` and all access is atomic.
    pub unsafe fn get<T>(&self, offset: usize) -> &T {
        debug_assert!(offset + size_of::<T>() <= self.len);
        debug_assert_eq!((self.ptr.as_ptr() as usize + offset) % align_of::<T>(), 0);
        // SAFETY: in bounds and aligned (caller); the memory stays mapped as long
        // as `self` lives, which bounds the returned lifetime.
        unsafe { &*self.ptr.as_ptr().add(offset).cast::<T>() }
    }

    /// `count` 64-bit atomic words from byte `offset`.
    ///
    /// # Safety
    /// `offset + 8 * count <= len` and `offset` is a multiple of 8.
    pub unsafe fn words(&self, offset: usize, count: usize) -> &[crate::sync::AtomicU64] {
        debug_assert!(offset + 8 * count <= self.len);
        debug_assert_eq!(offset % 8, 0);
        // SAFETY: in bounds and aligned (caller; mmap returns page-aligned memory);
        // AtomicU64 accepts any bit pattern; the mapping outlives the slice.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr().add(offset).cast(), count) }
    }
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: `ptr`/`len` came from a successful mmap and every reference into
        // the mapping borrows `self`, so none outlives this call.
        let _ = unsafe { rustix::mm::munmap(self.ptr.as_ptr().cast(), self.len) };
    }
}

/// What a file is, in words, for messages.
pub fn describe_file_type(file_type: rustix::fs::FileType) -> &'static str {
    use rustix::fs::FileType;
    match file_type {
        FileType::RegularFile => "regular file",
        FileType::Directory => "directory",
        FileType::Symlink => "symbolic link",
        FileType::Fifo => "FIFO (named pipe)",
        FileType::Socket => "socket",
        FileType::CharacterDevice => "character device",
        FileType::BlockDevice => "block device",
        _ => "file of an unknown type",
    }
}

/// The error for a file at `path` that is not a regular file.
fn not_regular(path: &Path, file_type: rustix::fs::FileType) -> std::io::Error {
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!(
            "{} is a {}, not a regular file; skinware opens only regular files there (remove it, \
             or use a directory only trusted users can write: SKINWARE_SHM_DIR)",
            path.display(),
            describe_file_type(file_type)
        ),
    )
}

/// Opens for reading a file that the user named (a recording, a
/// configuration, a calibration), following symbolic links (the user's
/// own), but refusing at once anything there that is not a regular file:
/// opening a FIFO waits until some writer opens its other end (forever, if
/// none does), a device may do anything, and a directory cannot be read.
/// As in [`open_regular`], the path is looked at through an `O_PATH` handle
/// first, and the file checked is the file opened, without waiting.
pub fn open_named_file(path: &Path) -> std::io::Result<File> {
    use rustix::fs::{FileType, Mode, OFlags};
    let handle = rustix::fs::open(path, OFlags::PATH | OFlags::CLOEXEC, Mode::empty())?;
    let file_type = FileType::from_raw_mode(rustix::fs::fstat(&handle)?.st_mode);
    if file_type != FileType::RegularFile {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "{} is a {}, not a regular file: give the path of a file",
                path.display(),
                describe_file_type(file_type)
            ),
        ));
    }
    let file = open_through_handle(path, &handle, false)?;
    // Non-blocking was for the open (a lease refuses rather than waits); the
    // reads of a file the user named go as usual (a FUSE file system sees
    // the flag too).
    rustix::fs::fcntl_setfl(&file, OFlags::empty())?;
    Ok(file)
}

/// [`open_named_file`], read whole, refusing a file longer than `max_bytes`.
pub fn read_named_file(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    read_bounded(path, open_named_file(path)?, max_bytes)
}

/// [`read_named_file`] as UTF-8 text.
pub fn read_named_text(path: &Path, max_bytes: u64) -> std::io::Result<String> {
    String::from_utf8(read_named_file(path, max_bytes)?).map_err(|_| {
        std::io::Error::new(std::io::ErrorKind::InvalidData, format!("{} is not UTF-8 text", path.display()))
    })
}

/// Opens the regular file at `path`, read-only or read-write, without ever
/// opening anything else there, and without waiting.
///
/// The segment directory is world-writable: a local user can put a symbolic
/// link there (which a plain open follows, to a file of their choosing), a
/// FIFO (whose open blocks until someone opens the other end), or a device.
/// So the path is first opened with `O_PATH | O_NOFOLLOW`, which opens
/// nothing but a handle to whatever is there (a link itself, not its target);
/// only if that is a regular file is it opened for real, through the handle
/// (`/proc/self/fd`), so that the file checked is the file opened. That open
/// is non-blocking too: a file its owner holds a lease on would otherwise
/// make it wait for the lease's break time (45 s), and refuses instead.
pub fn open_regular(path: &Path, writable: bool) -> std::io::Result<File> {
    open_regular_as(path, writable, None)
}

/// What a file must be besides regular, for [`open_regular_as`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Expected {
    /// The user who must own it.
    pub owner: u32,
    /// The most bytes it may hold.
    pub max_bytes: u64,
}

/// [`open_regular`], refusing also, with `expected`, a file of another
/// owner, one with more than one name (a hard link to some other file of
/// that owner's: a root writer would write into it), or a longer one; all
/// checked on the handle, before the file is opened.
pub(crate) fn open_regular_as(path: &Path, writable: bool, expected: Option<Expected>) -> std::io::Result<File> {
    use rustix::fs::{FileType, Mode, OFlags};
    let handle = rustix::fs::open(path, OFlags::PATH | OFlags::NOFOLLOW | OFlags::CLOEXEC, Mode::empty())?;
    let stat = rustix::fs::fstat(&handle)?;
    let file_type = FileType::from_raw_mode(stat.st_mode);
    if file_type != FileType::RegularFile {
        return Err(not_regular(path, file_type));
    }
    if let Some(expected) = expected {
        let refuse =
            |why: String| std::io::Error::new(std::io::ErrorKind::InvalidData, format!("{} {why}", path.display()));
        if stat.st_uid != expected.owner {
            return Err(refuse(format!("belongs to user {}, not to user {}", stat.st_uid, expected.owner)));
        }
        if stat.st_nlink == 0 {
            // Unlinked between the look and the handle (a cleaner): gone.
            return Err(std::io::ErrorKind::NotFound.into());
        }
        if stat.st_nlink != 1 {
            return Err(refuse(format!(
                "has {} names (hard links): it may be another file linked here",
                stat.st_nlink
            )));
        }
        if stat.st_size as u64 > expected.max_bytes {
            return Err(refuse(format!("holds {} bytes, more than the {} expected", stat.st_size, expected.max_bytes)));
        }
    }
    open_through_handle(path, &handle, writable)
}

/// Opens the file that the `O_PATH` `handle` (of `path`, for messages)
/// holds, without waiting: a file its owner holds a lease on refuses.
fn open_through_handle(path: &Path, handle: &std::os::fd::OwnedFd, writable: bool) -> std::io::Result<File> {
    use rustix::fs::{Mode, OFlags};
    let access = if writable { OFlags::RDWR } else { OFlags::RDONLY };
    let through_handle = format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(handle));
    let flags = access | OFlags::CLOEXEC | OFlags::NOCTTY | OFlags::NONBLOCK;
    let file = match rustix::fs::open(through_handle.as_str(), flags, Mode::empty()) {
        Ok(file) => file,
        Err(rustix::io::Errno::AGAIN) => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("{} is leased by another process: opening it would wait for the lease", path.display()),
            ));
        }
        // The handle is open, so a missing /proc/self/fd/N means no /proc.
        Err(rustix::io::Errno::NOENT) if !Path::new("/proc/self/fd").exists() => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::Unsupported,
                format!(
                    "cannot open {}: skinware opens files through /proc/self/fd, and /proc is not mounted here",
                    path.display()
                ),
            ));
        }
        Err(e) => return Err(e.into()),
    };
    Ok(File::from(file))
}

/// Reads the regular file at `path` whole, refusing anything else there
/// (see [`open_regular`]) and any file longer than `max_bytes`: its size is
/// somebody else's number.
pub fn read_regular(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    read_bounded(path, open_regular(path, false)?, max_bytes)
}

/// `file` (at `path`, for messages) read whole, if it holds at most `max_bytes`.
fn read_bounded(path: &Path, file: File, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let size = file.metadata()?.len();
    if size > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{} holds {size} bytes, more than the {max_bytes} such a file can have", path.display()),
        ));
    }
    // The size is a claim until read: reserve no more than a megabyte for it.
    let mut bytes = Vec::with_capacity(size.min(1 << 20) as usize);
    file.take(max_bytes.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!("{} grew past the {max_bytes} bytes such a file can have while it was read", path.display()),
        ));
    }
    Ok(bytes)
}

/// Creates a new regular file at `path` with permissions `mode`, failing if
/// anything (a symbolic link included) is already there: `O_CREAT | O_EXCL`
/// never follows a link.
pub fn create_new_regular(path: &Path, mode: u32) -> std::io::Result<File> {
    use rustix::fs::{Mode, OFlags};
    let flags = OFlags::WRONLY | OFlags::CREATE | OFlags::EXCL | OFlags::NOFOLLOW | OFlags::CLOEXEC;
    let file = rustix::fs::open(path, flags, Mode::from_raw_mode(mode))?;
    Ok(File::from(file))
}

/// Replaces the file at `path` with `bytes`, whole: written to a new
/// temporary file beside it (named as skinware's temporary files are, so
/// that `skin clean` removes one left by a process killed before the
/// rename) and renamed over it. Readers see the old file or the new one.
/// A symbolic link at `path` is replaced, never followed.
pub fn replace_file(path: &Path, bytes: &[u8], mode: u32) -> std::io::Result<()> {
    use std::io::Write;
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("file");
    let temporary = dir.join(format!("{TEMP_PREFIX}{name}.{}.{}", std::process::id(), crate::os::monotonic_ns()));
    let written = create_new_regular(&temporary, mode).and_then(|mut file| file.write_all(bytes));
    let placed = written.and_then(|()| std::fs::rename(&temporary, path));
    if placed.is_err() {
        let _ = std::fs::remove_file(&temporary);
    }
    placed
}
