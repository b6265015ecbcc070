//! Thin wrappers over the operating-system primitives the exchange relies on:
//! the monotonic clock, futexes, open-file-description locks and real-time
//! scheduling. The protocols that use them live in `channel/` (the doorbell,
//! liveness); this module only makes the calls. The only `unsafe` here is the
//! libc calls that `rustix` does not wrap (`fcntl` locks and the scheduler's
//! policy) or that Valgrind cannot follow through it (the clock).

use std::io;
use std::num::NonZeroU32;
use std::os::fd::{AsFd, AsRawFd};
use std::time::Duration;

use rustix::thread::futex;
use rustix::time::Timespec;

use crate::channel::doorbell::{Futex, Wake};
use crate::sync::AtomicU32;

/// Nanoseconds on CLOCK_MONOTONIC: the clock of every timestamp in a frame.
///
/// Through libc (the vDSO, as fast as rustix's) rather than rustix: rustix
/// finds the vDSO by parsing the ELF image the auxiliary vector points at,
/// which Valgrind does not map, so every program using skinware crashed
/// under Valgrind (rustix issue #1559), and the C API's users run Valgrind.
pub fn monotonic_ns() -> u64 {
    let mut now = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `now` is a valid, writable timespec for the call's duration;
    // CLOCK_MONOTONIC always exists on Linux, so the call cannot fail (and
    // if it did, `now` would stay zero rather than be uninitialised).
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut now) };
    now.tv_sec as u64 * 1_000_000_000 + now.tv_nsec as u64
}

fn timespec_from_ns(ns: u64) -> Timespec {
    Timespec { tv_sec: (ns / 1_000_000_000) as i64, tv_nsec: (ns % 1_000_000_000) as i64 }
}

fn wake_from(result: rustix::io::Result<()>) -> io::Result<Wake> {
    use rustix::io::Errno;
    match result {
        Ok(()) | Err(Errno::AGAIN) | Err(Errno::INTR) => Ok(Wake::Recheck),
        Err(Errno::TIMEDOUT) => Ok(Wake::TimedOut),
        Err(e) => Err(e.into()),
    }
}

/// Futexes through the kernel, with the flags of one kind of word.
#[derive(Clone, Copy, Debug)]
pub(crate) struct KernelFutex {
    flags: futex::Flags,
}

/// Process-shared futexes on words in shared memory: what the doorbell
/// protocol ([`crate::channel::doorbell`]) sleeps and wakes with.
pub(crate) const SHARED_FUTEX: KernelFutex = KernelFutex { flags: futex::Flags::empty() };

/// Process-private futexes, on words in this process's own memory: the
/// writer's handoff to its ringer ([`crate::channel::ringer`]) and the stop
/// signal ([`crate::rt::Stop`]). The kernel finds their waiters without
/// looking up a shared mapping.
pub(crate) const PRIVATE_FUTEX: KernelFutex = KernelFutex { flags: futex::Flags::PRIVATE };

impl Futex for KernelFutex {
    fn now_ns(&self) -> u64 {
        monotonic_ns()
    }

    fn wait(&self, word: &AtomicU32, expected: u32, timeout: Duration) -> io::Result<Wake> {
        let timeout = timespec_from_ns(timeout.as_nanos().min(u64::MAX as u128) as u64);
        wake_from(futex::wait(word.as_std(), self.flags, expected, Some(&timeout)))
    }

    fn wake_all(&self, word: &AtomicU32) {
        // A failed wake can only be EFAULT on a bad address, which a mapped word is not.
        let _ = futex::wake(word.as_std(), self.flags, i32::MAX as u32);
    }
}

impl KernelFutex {
    /// Sleeps while `word` holds `expected`, until the absolute
    /// CLOCK_MONOTONIC `deadline_ns`.
    pub(crate) fn wait_until(&self, word: &AtomicU32, expected: u32, deadline_ns: u64) -> io::Result<Wake> {
        let deadline = timespec_from_ns(deadline_ns);
        let any = NonZeroU32::new(u32::MAX).unwrap_or(NonZeroU32::MIN);
        wake_from(futex::wait_bitset(word.as_std(), self.flags, expected, Some(&deadline), any))
    }
}

/// The CPU the calling thread runs on (rustix answers from the vDSO where
/// the kernel offers one, x86-64 among them, without a system call).
pub(crate) fn current_cpu() -> Option<u32> {
    u32::try_from(rustix::thread::sched_getcpu()).ok()
}

/// The calling thread's SCHED_FIFO or SCHED_RR priority, or `None` if it is
/// in another scheduler (or the system cannot say).
pub(crate) fn current_realtime_priority() -> Option<u8> {
    // SAFETY: sched_getscheduler only reads the calling thread's policy.
    let policy = unsafe { libc::sched_getscheduler(0) } & !libc::SCHED_RESET_ON_FORK;
    if policy != libc::SCHED_FIFO && policy != libc::SCHED_RR {
        return None;
    }
    let mut param = libc::sched_param { sched_priority: 0 };
    // SAFETY: `param` is a valid, writable `sched_param`; pid 0 names the
    // calling thread.
    let rc = unsafe { libc::sched_getparam(0, &mut param) };
    if rc != 0 {
        return None;
    }
    u8::try_from(param.sched_priority).ok()
}

fn ofd_lock_request(kind: libc::c_short, byte: libc::off_t) -> libc::flock {
    libc::flock { l_type: kind, l_whence: libc::SEEK_SET as libc::c_short, l_start: byte, l_len: 1, l_pid: 0 }
}

/// The byte whose lock says the writer is alive (or owns a name).
const LIVENESS_BYTE: libc::off_t = 0;

/// Takes the writer's lock: an exclusive open-file-description lock on byte 0.
/// The kernel drops it when the last descriptor of that open file closes, in
/// particular when the process dies, however it dies. Returns `false` if
/// another open file description holds it.
pub(crate) fn try_lock_writer(fd: impl AsFd) -> io::Result<bool> {
    try_lock_byte(fd, LIVENESS_BYTE)
}

fn try_lock_byte(fd: impl AsFd, byte: libc::off_t) -> io::Result<bool> {
    let mut request = ofd_lock_request(libc::F_WRLCK as libc::c_short, byte);
    // SAFETY: `fd` is a valid open descriptor for the duration of the call, and
    // `request` is a valid, initialised `struct flock` that F_OFD_SETLK only reads.
    let rc = unsafe { libc::fcntl(fd.as_fd().as_raw_fd(), libc::F_OFD_SETLK, &mut request) };
    if rc == 0 {
        return Ok(true);
    }
    let err = io::Error::last_os_error();
    match err.raw_os_error() {
        Some(libc::EAGAIN) | Some(libc::EACCES) => Ok(false),
        _ => Err(err),
    }
}

/// Whether some open file description holds the writer's liveness lock. It only
/// asks (F_OFD_GETLK), so probing can never get in a reviving writer's way.
pub(crate) fn writer_lock_held(fd: impl AsFd) -> io::Result<bool> {
    let mut request = ofd_lock_request(libc::F_RDLCK as libc::c_short, LIVENESS_BYTE);
    // SAFETY: `fd` is a valid open descriptor for the duration of the call, and
    // `request` is a valid `struct flock` that F_OFD_GETLK reads and overwrites.
    let rc = unsafe { libc::fcntl(fd.as_fd().as_raw_fd(), libc::F_OFD_GETLK, &mut request) };
    if rc != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(request.l_type != libc::F_UNLCK as libc::c_short)
}

/// Puts the calling thread in SCHED_FIFO at `priority` (1..=99), with
/// SCHED_RESET_ON_FORK: threads and processes it starts begin in the normal
/// scheduler, so that nothing inherits a real-time priority it did not ask
/// for (a runaway child at SCHED_FIFO could starve the writers).
pub fn set_fifo_priority(priority: u8) -> io::Result<()> {
    let param = libc::sched_param { sched_priority: i32::from(priority) };
    // SAFETY: `param` is a valid `sched_param`; pid 0 names the calling thread.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO | libc::SCHED_RESET_ON_FORK, &param) };
    if rc == 0 { Ok(()) } else { Err(io::Error::last_os_error()) }
}

/// Sets the calling thread's nice value (-20 to 19): its weight among the
/// threads of the normal scheduler. Going below 0 needs root, CAP_SYS_NICE
/// or an RLIMIT_NICE that allows it.
pub fn set_thread_nice(nice: i32) -> io::Result<()> {
    rustix::process::setpriority_process(Some(rustix::thread::gettid()), nice).map_err(Into::into)
}

/// Whether thread or process `pid` (0: the calling thread) is in a real-time
/// scheduling class (SCHED_FIFO or SCHED_RR).
pub fn is_realtime(pid: u32) -> io::Result<bool> {
    let pid = libc::pid_t::try_from(pid).map_err(|_| io::Error::from(io::ErrorKind::InvalidInput))?;
    // SAFETY: sched_getscheduler only reads the scheduling policy of `pid`.
    let policy = unsafe { libc::sched_getscheduler(pid) };
    if policy < 0 {
        return Err(io::Error::last_os_error());
    }
    let policy = policy & !libc::SCHED_RESET_ON_FORK;
    Ok(policy == libc::SCHED_FIFO || policy == libc::SCHED_RR)
}

/// Puts the calling thread back in the normal (SCHED_OTHER) scheduler, e.g. in
/// a process started by a real-time thread, which inherits its policy.
pub fn set_normal_scheduling() -> io::Result<()> {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: `param` is a valid `sched_param`; pid 0 names the calling thread.
    let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_OTHER, &param) };
    if rc == 0 { Ok(()) } else { Err(io::Error::last_os_error()) }
}

/// Limits how long any real-time thread of this process may run without a
/// blocking system call (`RLIMIT_RTTIME`, the soft limit): past `limit` the
/// kernel sends SIGXCPU, which ends the process unless handled. A guard for
/// code that must never spin in SCHED_FIFO, such as a test of it: a thread
/// that spins is ended rather than holding its CPU for good. The hard limit
/// is left as it is; a soft limit above it is cut to it.
pub fn limit_realtime_run(limit: Duration) -> io::Result<()> {
    use rustix::process::{Resource, getrlimit, setrlimit};
    let mut rlimit = getrlimit(Resource::Rttime);
    let micros = u64::try_from(limit.as_micros()).unwrap_or(u64::MAX);
    rlimit.current = Some(rlimit.maximum.map_or(micros, |maximum| maximum.min(micros)));
    setrlimit(Resource::Rttime, rlimit).map_err(Into::into)
}

/// Locks all current and future pages of the process in RAM.
pub fn lock_memory() -> io::Result<()> {
    use rustix::mm::{MlockAllFlags, mlockall};
    mlockall(MlockAllFlags::CURRENT | MlockAllFlags::FUTURE).map_err(Into::into)
}

/// Locks the pages the process has mapped now in RAM (not those it maps
/// later). A supervisor that starts processes from its own executable keeps
/// that file's pages in memory this way, so that a process started later
/// does not wait for the disk to load them again.
pub fn lock_current_memory() -> io::Result<()> {
    use rustix::mm::{MlockAllFlags, mlockall};
    mlockall(MlockAllFlags::CURRENT).map_err(Into::into)
}

/// The size of an x86-64 (and most arm64) transparent huge page.
const HUGE_PAGE_BYTES: usize = 2 << 20;

/// Zeroed memory of the process's own, in a private anonymous mapping whose
/// every 2 MiB the kernel is asked to back with one transparent huge page
/// (`madvise(MADV_HUGEPAGE)`).
///
/// For state that a thread walks through once a period, long after its
/// lines and its page-table entries have left the caches: with 4 KiB pages
/// each page of it costs a page walk too (on a virtual machine, a walk of
/// two tables), and the hardware's prefetchers stop at each page's end.
/// Whether huge pages are given is the kernel's choice
/// (`/sys/kernel/mm/transparent_hugepage/enabled`: `always` or `madvise`
/// give them, `never` does not); without them this is plain memory.
pub struct HugePageMemory {
    /// The start of the mapping, 2 MiB-aligned.
    start: std::ptr::NonNull<u64>,
    /// The aligned stretch's length, bytes: a whole number of huge pages.
    mapped: usize,
    /// The words asked for.
    words: usize,
    /// What to unmap when dropped, start and length: the aligned stretch,
    /// or more of the reservation where giving back its head or tail failed.
    owned: (std::ptr::NonNull<u8>, usize),
}

// SAFETY: the mapping is owned by this value alone (nothing else holds its
// address) and is plain memory, so it may move to and be shared with other
// threads like a `Vec<u64>`; `&mut` access goes through `&mut self`.
unsafe impl Send for HugePageMemory {}
// SAFETY: as above; shared access gives `&[u64]` only.
unsafe impl Sync for HugePageMemory {}

impl HugePageMemory {
    /// `words` zeroed words. Fails only if the kernel refuses the mapping
    /// (address space or a memory limit); a refused huge-page advice is not
    /// an error.
    pub fn zeroed(words: usize) -> io::Result<HugePageMemory> {
        let too_large = || io::Error::new(io::ErrorKind::OutOfMemory, format!("{words} words do not fit in memory"));
        let bytes = words.max(1).checked_mul(8).ok_or_else(too_large)?;
        let mapped = bytes.checked_next_multiple_of(HUGE_PAGE_BYTES).ok_or_else(too_large)?;
        // One huge page more than needed, so that a 2 MiB-aligned stretch of
        // `mapped` bytes lies inside; the rest is given back at once.
        let reserved = mapped.checked_add(HUGE_PAGE_BYTES).ok_or_else(too_large)?;
        if cfg!(miri) {
            return Err(io::Error::new(io::ErrorKind::Unsupported, "no mappings under Miri"));
        }
        use rustix::mm::{Advice, MapFlags, ProtFlags, madvise, mmap_anonymous, munmap};
        // SAFETY: a new private anonymous mapping at an address the kernel
        // chooses: it cannot overlap memory anything else uses.
        let base = unsafe {
            mmap_anonymous(std::ptr::null_mut(), reserved, ProtFlags::READ | ProtFlags::WRITE, MapFlags::PRIVATE)
        }?;
        let head = (base as usize).next_multiple_of(HUGE_PAGE_BYTES) - base as usize;
        let tail = reserved - head - mapped;
        // Only a mapping with MAP_FIXED is placed at address 0, which this is not.
        let base = std::ptr::NonNull::new(base.cast::<u8>())
            .ok_or_else(|| io::Error::other("the kernel mapped memory at address 0"))?;
        // SAFETY: `base..base + head` and the `tail` bytes after the aligned
        // stretch are parts of the mapping just made, used by nothing; both
        // lengths are multiples of the page size (the mapping and the huge
        // page are), as munmap requires; `head` is below one huge page and
        // `head + mapped + tail` is `reserved`, so both `add`s stay inside the
        // mapping. A part that could not be given back
        // (at the kernel's limit of mappings) stays in `owned`, to be
        // unmapped with the rest: larger than asked, never leaked.
        let (start, owned) = unsafe {
            let start = base.add(head);
            let mut owned = (base, reserved);
            if head == 0 || munmap(base.as_ptr().cast(), head).is_ok() {
                owned = (start, mapped + tail);
                if tail == 0 || munmap(start.add(mapped).as_ptr().cast(), tail).is_ok() {
                    owned = (start, mapped);
                }
            }
            // Advice only: where the kernel gives no huge pages, the memory
            // is as good, and nothing is lost but the speed.
            let _ = madvise(start.as_ptr().cast(), mapped, Advice::LinuxHugepage);
            (start.cast::<u64>(), owned)
        };
        Ok(HugePageMemory { start, mapped, words, owned })
    }

    /// The words.
    pub fn words(&self) -> &[u64] {
        // SAFETY: `start` is the 2 MiB-aligned start of a readable, writable
        // mapping of `mapped` >= 8 * `words` bytes that this value owns and
        // keeps until it drops; anonymous memory starts zeroed, so every word
        // is initialised, and `&self` rules out a `&mut` alive at once.
        unsafe { std::slice::from_raw_parts(self.start.as_ptr(), self.words) }
    }

    /// The words, to write.
    pub fn words_mut(&mut self) -> &mut [u64] {
        // SAFETY: as in `words`; `&mut self` makes this the only reference.
        unsafe { std::slice::from_raw_parts_mut(self.start.as_ptr(), self.words) }
    }
}

impl Drop for HugePageMemory {
    fn drop(&mut self) {
        // SAFETY: the mapping this value made and owns; no reference into it
        // outlives `self`. A failed munmap leaks the memory, nothing worse.
        let _ = unsafe { rustix::mm::munmap(self.owned.0.as_ptr().cast(), self.owned.1) };
    }
}

impl std::fmt::Debug for HugePageMemory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("HugePageMemory").field("words", &self.words).field("mapped", &self.mapped).finish()
    }
}

/// The CPUs the calling thread may run on.
pub fn allowed_cpus() -> io::Result<Vec<usize>> {
    let set = rustix::thread::sched_getaffinity(None)?;
    Ok((0..rustix::thread::CpuSet::MAX_CPU).filter(|&cpu| set.is_set(cpu)).collect())
}

/// Pins the calling thread to the given CPUs.
pub fn pin_to_cpus(cpus: &[usize]) -> io::Result<()> {
    let mut set = rustix::thread::CpuSet::new();
    for &cpu in cpus {
        if cpu >= rustix::thread::CpuSet::MAX_CPU {
            return Err(io::Error::new(io::ErrorKind::InvalidInput, format!("CPU {cpu} does not exist")));
        }
        set.set(cpu);
    }
    rustix::thread::sched_setaffinity(None, &set).map_err(Into::into)
}

#[cfg(all(test, not(miri)))]
mod tests {
    use super::*;

    /// The kernel's count of page faults that wanted a huge page and got
    /// small ones (none had been free), if it keeps one.
    fn huge_page_fallbacks() -> Option<u64> {
        let vmstat = std::fs::read_to_string("/proc/vmstat").ok()?;
        vmstat.lines().find_map(|line| line.strip_prefix("thp_fault_fallback ")?.trim().parse().ok())
    }

    /// The memory is zeroed, whole, writable and aligned for huge pages;
    /// where the kernel gives transparent huge pages for it (its policy is
    /// not `never`, and it had a free one: no fault fell back to small
    /// pages meanwhile), `smaps` shows them.
    #[test]
    fn huge_page_memory_is_zeroed_aligned_and_backed_by_huge_pages_where_the_kernel_gives_them() {
        let fallbacks_before = huge_page_fallbacks();
        let words = 300_000; // 2.3 MiB: two huge pages
        let mut memory = HugePageMemory::zeroed(words).expect("map 2.3 MiB");
        assert_eq!(memory.words().len(), words);
        assert!(memory.words().iter().all(|&w| w == 0));
        assert_eq!(memory.words().as_ptr() as usize % HUGE_PAGE_BYTES, 0);
        for (k, word) in memory.words_mut().iter_mut().enumerate() {
            *word = k as u64;
        }
        assert_eq!(memory.words()[words - 1], words as u64 - 1);
        let start = memory.words().as_ptr() as usize;
        let policy = std::fs::read_to_string("/sys/kernel/mm/transparent_hugepage/enabled").unwrap_or_default();
        let smaps = std::fs::read_to_string("/proc/self/smaps").unwrap_or_default();
        let huge_kb = smaps
            .split_inclusive('\n')
            .skip_while(|line| !line.starts_with(&format!("{start:x}-")))
            .find_map(|line| line.strip_prefix("AnonHugePages:"))
            .and_then(|kb| kb.trim().trim_end_matches("kB").trim().parse::<u64>().ok());
        let fell_back = fallbacks_before.zip(huge_page_fallbacks()).is_none_or(|(before, after)| after > before);
        match huge_kb {
            Some(kb) if !policy.contains("[never]") && !fell_back => {
                assert!(kb >= 2048, "no huge page backs the memory: {kb} kB (policy {policy})")
            }
            _ => println!(
                "SKIPPED the huge-page check: policy `{}`, smaps {huge_kb:?} kB, a fault fell back to small pages: {fell_back}",
                policy.trim()
            ),
        }
    }

    /// Threads and processes started by a SCHED_FIFO thread run in the normal
    /// scheduler. Needs CAP_SYS_NICE (root here); skipped, saying so, without.
    #[test]
    fn real_time_priority_is_not_inherited() {
        let outcome = std::thread::spawn(|| {
            if let Err(e) = set_fifo_priority(1) {
                return Err(format!("SCHED_FIFO refused ({e})"));
            }
            assert!(is_realtime(0).unwrap(), "the thread did not enter SCHED_FIFO");
            let thread_rt = std::thread::spawn(|| is_realtime(0).unwrap()).join().unwrap();
            let mut child = std::process::Command::new("sleep").arg("5").spawn().expect("start sleep(1)");
            let child_rt = is_realtime(child.id());
            let _ = child.kill();
            let _ = child.wait();
            Ok((thread_rt, child_rt.unwrap()))
        })
        .join()
        .unwrap();
        match outcome {
            Ok((thread_rt, child_rt)) => {
                assert!(!thread_rt, "a thread started by a SCHED_FIFO thread inherited its priority");
                assert!(!child_rt, "a process started by a SCHED_FIFO thread inherited its priority");
            }
            Err(reason) => println!("SKIPPED: real_time_priority_is_not_inherited: {reason}"),
        }
    }
}
