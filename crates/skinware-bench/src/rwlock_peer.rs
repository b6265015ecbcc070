//! The lock-based baseline of `skin bench peers`: the original Skinware's
//! approach, K shared buffers each behind a process-shared `pthread_rwlock`,
//! plus a process-shared mutex and condition variable to wake waiting
//! readers. A reader holding a buffer's read lock makes the writer wait.
//!
//! This is a peer for comparison only, so it lives here and not in the
//! library; it is the bench crate's one module with `unsafe` (raw pthread
//! objects in shared memory have no safe wrapper).

#![allow(unsafe_code)]

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result, bail};

const SLOTS: usize = 3;

#[repr(C)]
struct Header {
    seq: AtomicU64,
    latest: AtomicU64,
    mutex: libc::pthread_mutex_t,
    cond: libc::pthread_cond_t,
}

#[repr(C)]
struct SlotHeader {
    lock: libc::pthread_rwlock_t,
    seq: u64,
    published_ns: u64,
}

const HEADER_BYTES: usize = 4096;
const SLOT_HEADER_BYTES: usize = 128;

const _: () = assert!(size_of::<Header>() <= HEADER_BYTES && size_of::<SlotHeader>() <= SLOT_HEADER_BYTES);

/// A mapped baseline channel.
pub struct RwLockChannel {
    base: *mut u8,
    len: usize,
    frame_bytes: usize,
    path: PathBuf,
    owner: bool,
}

// SAFETY: all shared state is behind process-shared pthread objects or atomics.
unsafe impl Send for RwLockChannel {}

fn check(rc: libc::c_int, what: &str) -> Result<()> {
    if rc != 0 {
        bail!("{what} failed: {}", std::io::Error::from_raw_os_error(rc));
    }
    Ok(())
}

impl RwLockChannel {
    fn slot_stride(frame_bytes: usize) -> usize {
        (SLOT_HEADER_BYTES + frame_bytes).div_ceil(64) * 64
    }

    fn map(path: &Path, frame_bytes: usize, create: bool) -> Result<RwLockChannel> {
        let len = HEADER_BYTES + SLOTS * Self::slot_stride(frame_bytes);
        let file = if create {
            let file = File::options().read(true).write(true).create_new(true).open(path)?;
            file.set_len(len as u64)?;
            file
        } else {
            File::options().read(true).write(true).open(path)?
        };
        use rustix::mm::{MapFlags, ProtFlags, mmap};
        // SAFETY: a fresh mapping chosen by the kernel, of a file at least `len` long.
        let base =
            unsafe { mmap(std::ptr::null_mut(), len, ProtFlags::READ | ProtFlags::WRITE, MapFlags::SHARED, &file, 0) }
                .with_context(|| format!("mmap {}", path.display()))?;
        Ok(RwLockChannel { base: base.cast(), len, frame_bytes, path: path.to_owned(), owner: create })
    }

    fn header(&self) -> *mut Header {
        self.base.cast()
    }

    fn slot(&self, index: usize) -> *mut SlotHeader {
        // SAFETY: index < SLOTS keeps the offset inside the mapping.
        unsafe { self.base.add(HEADER_BYTES + index * Self::slot_stride(self.frame_bytes)).cast() }
    }

    fn data(&self, index: usize) -> *mut u8 {
        // SAFETY: as in `slot`; the data follows the slot header within the stride.
        unsafe { self.slot(index).cast::<u8>().add(SLOT_HEADER_BYTES) }
    }

    /// Creates and initialises a channel (the writer's side).
    pub fn create(path: &Path, frame_bytes: usize) -> Result<RwLockChannel> {
        let channel = Self::map(path, frame_bytes, true)?;
        // SAFETY: the memory is freshly mapped, zeroed and ours alone until the
        // readers start; each pthread object is initialised once with
        // PTHREAD_PROCESS_SHARED attributes before any use.
        unsafe {
            let mut mutex_attr: libc::pthread_mutexattr_t = std::mem::zeroed();
            check(libc::pthread_mutexattr_init(&mut mutex_attr), "mutexattr_init")?;
            check(libc::pthread_mutexattr_setpshared(&mut mutex_attr, libc::PTHREAD_PROCESS_SHARED), "setpshared")?;
            check(libc::pthread_mutex_init(&mut (*channel.header()).mutex, &mutex_attr), "mutex_init")?;
            let mut cond_attr: libc::pthread_condattr_t = std::mem::zeroed();
            check(libc::pthread_condattr_init(&mut cond_attr), "condattr_init")?;
            check(libc::pthread_condattr_setpshared(&mut cond_attr, libc::PTHREAD_PROCESS_SHARED), "setpshared")?;
            check(libc::pthread_condattr_setclock(&mut cond_attr, libc::CLOCK_MONOTONIC), "setclock")?;
            check(libc::pthread_cond_init(&mut (*channel.header()).cond, &cond_attr), "cond_init")?;
            let mut rw_attr: libc::pthread_rwlockattr_t = std::mem::zeroed();
            check(libc::pthread_rwlockattr_init(&mut rw_attr), "rwlockattr_init")?;
            check(libc::pthread_rwlockattr_setpshared(&mut rw_attr, libc::PTHREAD_PROCESS_SHARED), "setpshared")?;
            for index in 0..SLOTS {
                check(libc::pthread_rwlock_init(&mut (*channel.slot(index)).lock, &rw_attr), "rwlock_init")?;
            }
        }
        Ok(channel)
    }

    /// Opens a channel a writer created.
    pub fn open(path: &Path, frame_bytes: usize) -> Result<RwLockChannel> {
        Self::map(path, frame_bytes, false)
    }

    /// Writer: copies `frame` into the next buffer under its write lock (waiting
    /// for readers holding it), then announces it and wakes waiting readers.
    pub fn publish(&self, frame: &[u8]) -> Result<u64> {
        let frame = &frame[..self.frame_bytes.min(frame.len())];
        // SAFETY: the header and slots are initialised process-shared pthread
        // objects; the data region is only written under the slot's write lock.
        unsafe {
            let header = self.header();
            let seq = (*header).seq.load(Ordering::Relaxed) + 1;
            let index = (seq as usize) % SLOTS;
            let slot = self.slot(index);
            check(libc::pthread_rwlock_wrlock(&mut (*slot).lock), "wrlock")?;
            std::ptr::copy_nonoverlapping(frame.as_ptr(), self.data(index), frame.len());
            (*slot).seq = seq;
            (*slot).published_ns = skinware::os::monotonic_ns();
            check(libc::pthread_rwlock_unlock(&mut (*slot).lock), "unlock")?;
            check(libc::pthread_mutex_lock(&mut (*header).mutex), "mutex_lock")?;
            (*header).latest.store(index as u64, Ordering::Relaxed);
            (*header).seq.store(seq, Ordering::Relaxed);
            check(libc::pthread_cond_broadcast(&mut (*header).cond), "broadcast")?;
            check(libc::pthread_mutex_unlock(&mut (*header).mutex), "mutex_unlock")?;
            Ok(seq)
        }
    }

    /// Reader: waits (until `deadline_ns`) for a frame newer than `after`,
    /// copies it out under its buffer's read lock and returns (seq,
    /// published_ns, ns spent locking, copying and unlocking).
    pub fn wait_newer(&self, after: u64, out: &mut [u8], deadline_ns: u64) -> Result<Option<(u64, u64, u64)>> {
        // SAFETY: as in `publish`; the data region is only read under the read lock.
        unsafe {
            let header = self.header();
            check(libc::pthread_mutex_lock(&mut (*header).mutex), "mutex_lock")?;
            while (*header).seq.load(Ordering::Relaxed) <= after {
                let deadline = libc::timespec {
                    tv_sec: (deadline_ns / 1_000_000_000) as _,
                    tv_nsec: (deadline_ns % 1_000_000_000) as _,
                };
                let rc = libc::pthread_cond_timedwait(&mut (*header).cond, &mut (*header).mutex, &deadline);
                if rc == libc::ETIMEDOUT {
                    libc::pthread_mutex_unlock(&mut (*header).mutex);
                    return Ok(None);
                }
            }
            let index = (*header).latest.load(Ordering::Relaxed) as usize % SLOTS;
            check(libc::pthread_mutex_unlock(&mut (*header).mutex), "mutex_unlock")?;
            let slot = self.slot(index);
            let started = skinware::os::monotonic_ns();
            check(libc::pthread_rwlock_rdlock(&mut (*slot).lock), "rdlock")?;
            let n = out.len().min(self.frame_bytes);
            std::ptr::copy_nonoverlapping(self.data(index), out.as_mut_ptr(), n);
            std::hint::black_box(&mut *out);
            let (seq, published_ns) = ((*slot).seq, (*slot).published_ns);
            check(libc::pthread_rwlock_unlock(&mut (*slot).lock), "unlock")?;
            Ok(Some((seq, published_ns, skinware::os::monotonic_ns() - started)))
        }
    }
}

impl RwLockChannel {
    /// Reader on request: copies the newest buffer out under its read lock,
    /// without waiting. Returns its sequence number.
    pub fn read_latest(&self, out: &mut [u8]) -> Result<u64> {
        // SAFETY: as in `publish`; the data region is only read under the read lock.
        unsafe {
            let index = (*self.header()).latest.load(Ordering::Acquire) as usize % SLOTS;
            let slot = self.slot(index);
            check(libc::pthread_rwlock_rdlock(&mut (*slot).lock), "rdlock")?;
            let n = out.len().min(self.frame_bytes);
            std::ptr::copy_nonoverlapping(self.data(index), out.as_mut_ptr(), n);
            std::hint::black_box(&mut *out);
            let seq = (*slot).seq;
            check(libc::pthread_rwlock_unlock(&mut (*slot).lock), "unlock")?;
            Ok(seq)
        }
    }
}

impl Drop for RwLockChannel {
    fn drop(&mut self) {
        // SAFETY: base/len come from a successful mmap and nothing borrows them.
        let _ = unsafe { rustix::mm::munmap(self.base.cast(), self.len) };
        if self.owner {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}
