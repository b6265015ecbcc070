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
