//! Following a successor at once: how readers learn, within a millisecond,
//! that a new writer has taken their dead writer's channel name.
//!
//! A dead writer's memory is never revived ([`super::liveness`]): its
//! successor creates new memory and binds the channel's socket again, and
//! attached readers must switch to it. Nothing in the old memory can tell
//! them (only the dead writer could write it), and the successor cannot reach
//! the old memory either. What every reader *can* see is the segment
//! directory: the successor's socket appears in it under the channel's name
//! (renamed into place, [`super::handover`]).
//!
//! So each process that reads channels has one watcher thread, started with
//! its first reader, asleep on an `inotify` descriptor watching the segment
//! directories its readers use. When a socket appears under the name of a
//! channel some reader of this process follows, the thread asks the new
//! writer for its memory (once for all those readers), checks that the
//! reader's writer is really dead, leaves the memory with each reader and
//! raises its flag, and wakes the readers asleep on the old channel's
//! doorbell (a futex word in memory the readers may write). A successor
//! that does not answer at once (stopped, or not scheduled yet), or a
//! reader's writer that is not dead yet, is tried again, 20 ms later and
//! then less often, up to a second apart, for about ten minutes. A process
//! forked from one with a watcher starts its own (threads do not survive a
//! fork).
//!
//! What it costs, and whom:
//! * the writer: nothing. Its publish is unchanged; the successor's only
//!   extra is the directory event the kernel makes for its rename anyway;
//! * a reader reading an unchanged channel: one relaxed load of its flag per
//!   read, no system call;
//! * a hostile process that may write the directory can make events, but
//!   only by creating names, and one under a live channel's name needs that
//!   name removed first (the directory is sticky): the writer's user only.
//!   Every event leads to a hand-over that is checked like any other: a
//!   reader switches only to memory that validates, of the same shape, once
//!   its own writer is dead;
//! * if the process cannot watch (inotify's limit of 128 instances per user
//!   reached, say), readers fall back to re-checking every 100 ms in their
//!   blocking reads, as before, and the first reader says so in the log.

#![forbid(unsafe_code)]

use std::collections::HashMap;
use std::mem::MaybeUninit;
use std::os::fd::OwnedFd;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, Weak};
use std::time::Duration;

use rustix::fs::inotify;

use super::doorbell;
use super::segment::{self, Opened, Shared};
use crate::lock;
use crate::os::{self, SHARED_FUTEX};
use crate::shm;
use crate::sync::{AtomicU32, Ordering};

/// How long the watcher waits, after a successor appeared, for the old
/// writer's death to be visible: a dying process lets go of the name lock
/// and of its memory's liveness lock one after the other.
const DEATH_GRACE: Duration = Duration::from_millis(20);

/// One reader's link to the watcher.
pub(crate) struct Follower {
    /// Raised (Release) once `successor` holds a new writer's memory.
    flagged: AtomicU32,
    /// The successor's memory, validated, left by the watcher.
    successor: Mutex<Option<Arc<Shared>>>,
    /// The channel the reader reads now: whose death is checked, and whose
    /// doorbell wakes the reader.
    current: Mutex<Weak<Shared>>,
}

impl Follower {
    fn new() -> Follower {
        Follower { flagged: AtomicU32::new(0), successor: Mutex::new(None), current: Mutex::new(Weak::new()) }
    }

    /// Whether the watcher has left a successor: a relaxed load, the whole
    /// cost of this design on a read of an unchanged channel.
    pub(crate) fn flagged(&self) -> bool {
        self.flagged.load(Ordering::Relaxed) != 0
    }

    /// Takes the successor the watcher left, if any.
    pub(crate) fn take(&self) -> Option<Arc<Shared>> {
        // Acquire: pairs with the Release in `leave`, after the memory was put.
        if self.flagged.swap(0, Ordering::Acquire) == 0 {
            return None;
        }
        lock(&self.successor).take()
    }

    /// The reader now reads `shared`.
    pub(crate) fn set_current(&self, shared: &Arc<Shared>) {
        *lock(&self.current) = Arc::downgrade(shared);
    }

    /// Leaves `successor` with the reader and wakes it if it sleeps on its
    /// current channel's doorbell.
    fn leave(&self, successor: Arc<Shared>) {
        *lock(&self.successor) = Some(successor);
        self.flagged.store(1, Ordering::Release);
        if let Some(current) = lock(&self.current).upgrade() {
            doorbell::nudge(&current.doorbell().notify, &SHARED_FUTEX);
        }
    }
}

/// Registers a reader of `skin`/`channel` in `dir`, now reading `current`,
/// with the process's watcher. `None` if this process cannot watch `dir`:
/// the reader then finds a successor only by its periodic re-check.
pub(crate) fn follow(dir: &Path, skin: &str, channel: &str, current: &Arc<Shared>) -> Option<Arc<Follower>> {
    let watcher = watcher()?;
    let watch = watcher.watch(dir)?;
    let follower = Arc::new(Follower::new());
    follower.set_current(current);
    let name = shm::segment_path(Path::new(""), skin, channel).into_os_string().into_string().ok()?;
    let mut followed = lock(&watcher.followed);
    let readers = followed.readers.entry((watch, name)).or_default();
    readers.retain(|reader| reader.strong_count() > 0);
    readers.push(Arc::downgrade(&follower));
    Some(follower)
}

/// The process's watcher: one inotify descriptor and the thread reading it.
struct Watcher {
    inotify: OwnedFd,
    followed: Mutex<Followed>,
}

#[derive(Default)]
struct Followed {
    /// Watched directories, by watch descriptor, and the other way round.
    dirs: HashMap<i32, PathBuf>,
    watches: HashMap<PathBuf, i32>,
    /// The readers following each channel: (watch, socket file name).
    readers: HashMap<(i32, String), Vec<Weak<Follower>>>,
}

/// A channel whose successor could not be handed over yet, and when to try
/// again: (attempts so far, next try, CLOCK_MONOTONIC ns).
type Pending = HashMap<(i32, String), (u32, u64)>;

/// How long the watcher waits for a successor's hand-over: short, since the
/// thread serves every channel of the process, and it tries again.
const ANSWER_TIMEOUT: Duration = Duration::from_millis(100);
/// Tries at handing over a successor, 20 ms apart and doubling to a second:
/// about ten minutes in all (a successor stopped, a writer not dead yet).
const MAX_ATTEMPTS: u32 = 600;

/// The process's watcher, and the process it belongs to: a child forked
/// from a process that had one inherits the value but not the thread, and
/// starts its own.
static WATCHER: Mutex<Option<(u32, &'static Watcher)>> = Mutex::new(None);

/// Whether the warning that the process cannot watch was given.
static WARNED: AtomicU32 = AtomicU32::new(0);

/// The process's watcher, started the first time a reader asks (and again
/// in a forked child). Failing to start it is not remembered: the next
/// reader tries again.
fn watcher() -> Option<&'static Watcher> {
    let pid = std::process::id();
    let mut current = lock(&WATCHER);
    if let Some((owner, watcher)) = *current
        && owner == pid
    {
        return Some(watcher);
    }
    let started = inotify::init(inotify::CreateFlags::CLOEXEC | inotify::CreateFlags::NONBLOCK)
        .map_err(std::io::Error::from)
        .and_then(|inotify| {
            // One per process (per fork): it lives as long as the process.
            let watcher: &'static Watcher =
                Box::leak(Box::new(Watcher { inotify, followed: Mutex::new(Followed::default()) }));
            std::thread::Builder::new()
                .name("skinware-successions".into())
                .spawn(move || watcher.run())
                .map(|_| watcher)
        });
    match started {
        Ok(watcher) => {
            *current = Some((pid, watcher));
            Some(watcher)
        }
        Err(e) => {
            if WARNED.swap(1, Ordering::Relaxed) == 0 {
                tracing::warn!(error = %e, "cannot watch the segment directory (inotify); readers follow a restarted writer within 100 ms instead of at once");
            }
            None
        }
    }
}

impl Watcher {
    /// The watch of `dir`, added if new.
    fn watch(&self, dir: &Path) -> Option<i32> {
        let mut followed = lock(&self.followed);
        if let Some(&watch) = followed.watches.get(dir) {
            return Some(watch);
        }
        let flags = inotify::WatchFlags::CREATE | inotify::WatchFlags::MOVED_TO | inotify::WatchFlags::ONLYDIR;
        match inotify::add_watch(&self.inotify, dir, flags) {
            Ok(watch) => {
                followed.watches.insert(dir.to_owned(), watch);
                followed.dirs.insert(watch, dir.to_owned());
                Some(watch)
            }
            Err(e) => {
                tracing::warn!(dir = %dir.display(), error = %e, "cannot watch the segment directory; readers there follow a restarted writer within 100 ms instead of at once");
                None
            }
        }
    }

    /// The thread: waits for events, or for the next try at a successor that
    /// could not be handed over yet, for ever.
    fn run(&self) {
        let mut buffer = [MaybeUninit::<u8>::uninit(); 4096];
        let mut pending = Pending::new();
        loop {
            let now = os::monotonic_ns();
            let next = pending.values().map(|&(_, at)| at).min();
            let timeout = next.map(|at| {
                let left = at.saturating_sub(now);
                rustix::time::Timespec { tv_sec: (left / 1_000_000_000) as i64, tv_nsec: (left % 1_000_000_000) as i64 }
            });
            let mut fds = [rustix::event::PollFd::new(&self.inotify, rustix::event::PollFlags::IN)];
            match rustix::event::poll(&mut fds, timeout.as_ref()) {
                Ok(_) | Err(rustix::io::Errno::INTR) => {}
                Err(e) => {
                    tracing::error!(error = %e, "the successor watcher cannot wait for events; readers follow a restarted writer within 100 ms instead of at once");
                    return;
                }
            }
            if !self.take_events(&mut buffer, &mut pending) {
                return;
            }
            let now = os::monotonic_ns();
            let due: Vec<(i32, String)> =
                pending.iter().filter(|(_, (_, at))| *at <= now).map(|(key, _)| key.clone()).collect();
            for key in due {
                if self.hand_successor(key.0, &key.1) {
                    pending.remove(&key);
                } else if let Some((attempts, at)) = pending.get_mut(&key) {
                    *attempts += 1;
                    if *attempts >= MAX_ATTEMPTS {
                        pending.remove(&key);
                    } else {
                        let delay_ms = 20u64.saturating_mul(1 << (*attempts).min(6)).min(1000);
                        *at = os::monotonic_ns() + delay_ms * 1_000_000;
                    }
                }
            }
        }
    }

    /// Reads every event there is; a socket appearing under a followed
    /// channel's name makes that channel due now. `false` if the descriptor
    /// cannot be read any more.
    fn take_events(&self, buffer: &mut [MaybeUninit<u8>], pending: &mut Pending) -> bool {
        let mut events = inotify::Reader::new(&self.inotify, buffer);
        let now = os::monotonic_ns();
        loop {
            match events.next() {
                Ok(event) => {
                    if event.events().contains(inotify::ReadFlags::QUEUE_OVERFLOW) {
                        // Events were lost: look at every followed channel.
                        for key in lock(&self.followed).readers.keys() {
                            pending.insert(key.clone(), (0, now));
                        }
                    } else if let Some(name) = event.file_name().and_then(|name| name.to_str().ok())
                        && shm::parse_segment_name(name).is_some()
                    {
                        let key = (event.wd(), name.to_owned());
                        if lock(&self.followed).readers.contains_key(&key) {
                            pending.insert(key, (0, now));
                        }
                    }
                }
                Err(rustix::io::Errno::AGAIN) => return true,
                Err(rustix::io::Errno::INTR) => {}
                Err(e) => {
                    tracing::error!(error = %e, "the successor watcher cannot read its events; readers follow a restarted writer within 100 ms instead of at once");
                    return false;
                }
            }
        }
    }

    /// A socket appeared as `name` in the directory of `watch`: if readers
    /// follow that channel, opens the new writer's memory once and leaves it
    /// with each of them whose writer is dead. `true` when done (handed, or
    /// nothing to hand); `false` to try again later (the successor did not
    /// answer, or a reader's writer is not dead yet).
    fn hand_successor(&self, watch: i32, name: &str) -> bool {
        let Some((skin, channel)) = shm::parse_segment_name(name) else { return true };
        let (dir, readers) = {
            let mut followed = lock(&self.followed);
            let Some(dir) = followed.dirs.get(&watch).cloned() else { return true };
            let key = (watch, name.to_owned());
            let Some(readers) = followed.readers.get_mut(&key) else { return true };
            readers.retain(|reader| reader.strong_count() > 0);
            let live: Vec<Arc<Follower>> = readers.iter().filter_map(Weak::upgrade).collect();
            if live.is_empty() {
                followed.readers.remove(&key);
                return true;
            }
            (dir, live)
        };
        let successor = match segment::open_segment(&dir, skin, channel, ANSWER_TIMEOUT) {
            Ok(Opened::Live(successor)) => Arc::new(successor),
            // Nobody behind the socket, or no socket: nothing to follow.
            Ok(Opened::NoWriter) | Err(crate::Error::Missing { .. }) => return true,
            // Not answering (stopped, busy), or nothing valid: try again.
            Err(_) => return false,
        };
        let identity = successor.identity();
        let mut done = true;
        // Whether each current memory's writer is dead, asked once per memory.
        let mut dead: HashMap<Option<(u64, u64)>, bool> = HashMap::new();
        for reader in readers {
            let Some(current) = lock(&reader.current).upgrade() else { continue };
            let current_identity = current.identity();
            if current_identity == identity {
                // The same memory bound again (after someone unlinked the socket).
                continue;
            }
            if !*dead.entry(current_identity).or_insert_with(|| dies_soon(&current)) {
                // A second live writer under the name: wait for this one's end.
                done = false;
                continue;
            }
            reader.leave(successor.clone());
        }
        done
    }
}

/// Whether `current`'s writer is dead, or dies within [`DEATH_GRACE`].
fn dies_soon(current: &Shared) -> bool {
    let until = os::monotonic_ns().saturating_add(DEATH_GRACE.as_nanos() as u64);
    loop {
        if !current.writer_alive().unwrap_or(true) {
            return true;
        }
        if os::monotonic_ns() >= until {
            return false;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
