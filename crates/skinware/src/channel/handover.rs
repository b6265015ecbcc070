//! Handing a channel's memory to its readers.
//!
//! A channel's frames live in sealed memory files that have no name (see
//! [`super::segment`]), so nobody can truncate, grow or unlink them. The
//! writer makes them reachable through a unix socket named like the channel,
//! `<dir>/skinware.<skin>.<channel>`: every reader that connects receives two
//! file descriptors (`SCM_RIGHTS`), the data opened read-only and the
//! doorbell, and the connection ends. The kernel checks the socket file's
//! permissions on `connect`, so they are the channel's read permission.
//!
//! A thread of the writer's process answers the socket; it never touches the
//! acquisition thread, and a reader that connects and then stalls costs it
//! nothing (the hand-over is one non-blocking send). If the socket file is
//! unlinked or replaced, the thread binds it again within a second: readers
//! attached meanwhile are not affected, and new ones can attach again.

#![forbid(unsafe_code)]

use std::io::{self, IoSlice, IoSliceMut};
use std::mem::MaybeUninit;
use std::os::fd::{AsFd, OwnedFd};
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use rustix::event::{EventfdFlags, PollFd, PollFlags};
use rustix::net::{
    RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags, SendAncillaryBuffer, SendAncillaryMessage, SendFlags,
};

use super::liveness::{FileIdentity, Kept, NameLock, path_identity};
use crate::error::{Error, Result};
use crate::shm;
use crate::sync::{AtomicU32, Ordering};

/// The bytes that come with the two descriptors: what they are and the
/// version of the hand-over.
const GREETING: &[u8; 8] = b"SKINHND1";

/// How long a reader waits for the writer's hand-over once connected. The
/// writer's thread answers at once; only a stopped or hung writer takes this long.
pub(crate) const ANSWER_TIMEOUT: Duration = Duration::from_secs(1);
/// The same for a look at every channel (`skin ls`, the supervisor's log).
pub(crate) const LISTING_ANSWER_TIMEOUT: Duration = Duration::from_millis(200);

/// How often the writer's thread checks that its socket is still in place.
const RECHECK: Duration = Duration::from_millis(250);

/// The writer's side: a thread answering the channel's socket until stopped.
/// It also keeps the channel's name lock in place, and gives it back when
/// stopped.
pub(crate) struct Server {
    wake: OwnedFd,
    thread: Option<JoinHandle<HeldName>>,
    /// Set by the thread once another writer has taken the channel's name.
    name_lost: Arc<AtomicU32>,
}

/// What the hand-over thread gives back when stopped: the name lock, and
/// the identity of the socket it had bound if the name is still this
/// writer's (`None` once another writer took it: nothing there is ours).
pub(crate) struct HeldName {
    pub lock: NameLock,
    pub socket: Option<FileIdentity>,
}

impl Server {
    /// Binds the channel's socket at `path` with permissions `mode` and starts
    /// handing `data` (read-only) and `bell` to whoever connects.
    pub fn start(
        path: PathBuf,
        mode: u32,
        label: String,
        name: NameLock,
        data: OwnedFd,
        bell: OwnedFd,
    ) -> Result<Server> {
        let os_error = |op, source: io::Error| Error::Os { op, path: path.clone(), source };
        let bound = bind(&path, mode)?;
        let wake = rustix::event::eventfd(0, EventfdFlags::CLOEXEC | EventfdFlags::NONBLOCK)
            .map_err(|e| os_error("eventfd", e.into()))?;
        let stop = wake.try_clone().map_err(|e| os_error("dup", e))?;
        let spawn_error = |e| Error::Os { op: "spawn the hand-over thread", path: path.clone(), source: e };
        let name_lost = Arc::new(AtomicU32::new(0));
        let served = Served { path: path.clone(), mode, label, name, data, bell, name_lost: name_lost.clone() };
        let thread = std::thread::Builder::new()
            .name("skinware-handover".into())
            .spawn(move || served.serve(bound, &stop))
            .map_err(spawn_error)?;
        Ok(Server { wake, thread: Some(thread), name_lost })
    }

    /// Whether another writer took the channel's name from this one (after
    /// someone removed its lock file); new readers then go to the other.
    pub fn name_lost(&self) -> bool {
        // Relaxed: a flag read for its own sake; nothing is published with it.
        self.name_lost.load(Ordering::Relaxed) != 0
    }
}

impl Server {
    /// Stops answering and returns the name lock (`None` only if the thread
    /// panicked, which drops it).
    pub fn stop(mut self) -> Option<HeldName> {
        self.wake_thread();
        self.thread.take().and_then(|thread| thread.join().ok())
    }

    fn wake_thread(&self) {
        // The eventfd wakes the thread's poll; it closes the listener when it
        // returns, after which connecting readers are refused: the writer is gone.
        let _ = rustix::io::write(&self.wake, &1u64.to_ne_bytes());
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.wake_thread();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// What the writer's thread hands over, and where.
struct Served {
    path: PathBuf,
    mode: u32,
    label: String,
    name: NameLock,
    data: OwnedFd,
    bell: OwnedFd,
    name_lost: Arc<AtomicU32>,
}

impl Served {
    fn serve(mut self, mut bound: (UnixListener, FileIdentity), stop: &OwnedFd) -> HeldName {
        let mut name_held = true;
        let held = |lock, name_held: bool, bound: &(UnixListener, FileIdentity)| HeldName {
            lock,
            socket: name_held.then_some(bound.1),
        };
        let timeout = rustix::time::Timespec { tv_sec: 0, tv_nsec: RECHECK.as_nanos() as i64 };
        loop {
            let mut fds = [PollFd::new(&bound.0, PollFlags::IN), PollFd::new(stop, PollFlags::IN)];
            if let Err(e) = rustix::event::poll(&mut fds, Some(&timeout))
                && e != rustix::io::Errno::INTR
            {
                tracing::error!(channel = %self.label, error = %e, "the hand-over thread cannot poll; readers can no longer attach");
                return held(self.name, name_held, &bound);
            }
            if !fds[1].revents().is_empty() {
                return held(self.name, name_held, &bound);
            }
            while let Ok((stream, _)) = bound.0.accept() {
                hand_over(&stream, &self.data, &self.bell);
            }
            if name_held && self.name.keep_in_place() == Kept::Lost {
                // Another writer took the name while its lock file was gone.
                // Binding the socket again would take it back from that
                // writer, and the two would then take turns: new readers
                // go to the other from now on, and this writer says so.
                name_held = false;
                self.name_lost.store(1, Ordering::Relaxed);
                tracing::error!(channel = %self.label, "someone removed the channel's name lock and another writer took the name; this writer keeps publishing to the readers it has, but new readers go to the other writer. Stop one of them");
            }
            if name_held && path_identity(&self.path) != Some(bound.1) {
                match bind(&self.path, self.mode) {
                    Ok(rebound) => {
                        tracing::warn!(channel = %self.label, path = %self.path.display(), "the channel's socket was removed or replaced; bound it again");
                        bound = rebound;
                    }
                    Err(e) => {
                        tracing::warn!(channel = %self.label, error = %e, "cannot bind the channel's socket again")
                    }
                }
            }
        }
    }
}

/// Sends the greeting and the two descriptors. A reader that has gone, or
/// whose socket is full, simply does not get them; the writer never waits.
fn hand_over(stream: &UnixStream, data: &OwnedFd, bell: &OwnedFd) {
    let fds = [data.as_fd(), bell.as_fd()];
    let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
    let mut control = SendAncillaryBuffer::new(&mut space);
    if !control.push(SendAncillaryMessage::ScmRights(&fds)) {
        return;
    }
    let _ = rustix::net::sendmsg(
        stream,
        &[IoSlice::new(GREETING)],
        &mut control,
        SendFlags::DONTWAIT | SendFlags::NOSIGNAL,
    );
}

/// The longest path a Unix socket address holds (`sun_path` less its NUL).
const SOCKET_PATH_MAX: usize = 107;

/// Binds a listening socket under a temporary name, gives it `mode`, and
/// renames it onto `path`, so that the name never shows a socket with the
/// wrong permissions. Returns it with the identity of the file at `path`.
fn bind(path: &Path, mode: u32) -> Result<(UnixListener, FileIdentity)> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("channel");
    let temp = dir.join(format!("{}{name}.{}.{}", shm::TEMP_PREFIX, std::process::id(), crate::os::monotonic_ns()));
    let os_error = |op, source| Error::Os { op, path: path.to_owned(), source };
    if temp.as_os_str().len() > SOCKET_PATH_MAX {
        let reason = format!(
            "its socket, bound first as {} ({} bytes), does not fit a Unix socket address ({SOCKET_PATH_MAX} bytes); \
             use a shorter segment directory (SKINWARE_SHM_DIR) or a shorter skin or channel name",
            temp.display(),
            temp.as_os_str().len()
        );
        return Err(os_error("bind", std::io::Error::new(std::io::ErrorKind::InvalidInput, reason)));
    }
    let listener = UnixListener::bind(&temp).map_err(|e| os_error("bind", e))?;
    let placed = std::fs::set_permissions(&temp, std::fs::Permissions::from_mode(mode))
        .map_err(|e| os_error("chmod", e))
        .and_then(|()| std::fs::rename(&temp, path).map_err(|e| os_error("rename", e)))
        .and_then(|()| listener.set_nonblocking(true).map_err(|e| os_error("fcntl", e)));
    if let Err(e) = placed {
        let _ = std::fs::remove_file(&temp);
        return Err(e);
    }
    let identity = path_identity(path).ok_or_else(|| os_error("stat", io::ErrorKind::NotFound.into()))?;
    Ok((listener, identity))
}

/// What a reader got when it asked for a channel's memory.
pub(crate) enum Fetched {
    /// The data (read-only) and the doorbell.
    Memory { data: OwnedFd, bell: OwnedFd },
    /// The socket is there but nobody listens: the writer is dead or dropped.
    NoWriter,
}

/// The reader's side: connects to the channel's socket at `path` and receives
/// the writer's two descriptors, waiting at most `answer_timeout` for them.
pub(crate) fn fetch(path: &Path, label: &str, answer_timeout: Duration) -> Result<Fetched> {
    let mut fetched = fetch_all(&[(path, label)], answer_timeout);
    fetched.pop().unwrap_or_else(|| Err(Error::NotAnswering { channel: label.to_owned(), path: path.to_owned() }))
}

/// [`fetch`] of many channels at once, in the same order: every connection is
/// made first, then all the answers are awaited together until one deadline,
/// so that writers that do not answer (stopped, hung) cost the whole call at
/// most `answer_timeout`, not that much each.
///
/// Nothing here can block past the deadline: the socket is connected
/// non-blocking (a listener whose queue is full, because its process is
/// stopped and accepts no one, answers `EAGAIN` instead of making `connect`
/// wait for it), and only a socket is connected to (a symbolic link at the
/// channel's name is refused, not followed).
pub(crate) fn fetch_all(channels: &[(&Path, &str)], answer_timeout: Duration) -> Vec<Result<Fetched>> {
    let deadline = crate::os::monotonic_ns().saturating_add(answer_timeout.as_nanos().min(u128::from(u64::MAX)) as u64);
    let mut results: Vec<Option<Result<Fetched>>> = Vec::with_capacity(channels.len());
    let mut pending: Vec<Option<OwnedFd>> = Vec::with_capacity(channels.len());
    for &(path, label) in channels {
        match connect(path, label) {
            Ok(Connection::Pending(socket)) => {
                results.push(None);
                pending.push(Some(socket));
            }
            Ok(Connection::Refused) => {
                results.push(Some(Ok(Fetched::NoWriter)));
                pending.push(None);
            }
            Err(e) => {
                results.push(Some(Err(e)));
                pending.push(None);
            }
        }
    }
    loop {
        let waiting: Vec<usize> = (0..channels.len()).filter(|&i| pending[i].is_some()).collect();
        let now = crate::os::monotonic_ns();
        if waiting.is_empty() || now >= deadline {
            break;
        }
        let left = deadline - now;
        let timeout =
            rustix::time::Timespec { tv_sec: (left / 1_000_000_000) as i64, tv_nsec: (left % 1_000_000_000) as i64 };
        let mut ready = vec![false; waiting.len()];
        {
            let mut fds: Vec<PollFd<'_>> = waiting
                .iter()
                .filter_map(|&i| pending[i].as_ref().map(|socket| PollFd::new(socket, PollFlags::IN)))
                .collect();
            match rustix::event::poll(&mut fds, Some(&timeout)) {
                Ok(_) | Err(rustix::io::Errno::INTR) => {}
                Err(e) => {
                    for &i in &waiting {
                        let (path, _) = channels[i];
                        results[i] = Some(Err(Error::Os { op: "poll", path: path.to_owned(), source: e.into() }));
                        pending[i] = None;
                    }
                    break;
                }
            }
            for (flag, fd) in ready.iter_mut().zip(&fds) {
                *flag = !fd.revents().is_empty();
            }
        }
        for (k, &i) in waiting.iter().enumerate() {
            if ready[k]
                && let Some(socket) = pending[i].take()
            {
                let (path, label) = channels[i];
                match receive(&socket, path, label) {
                    Ok(Some(fetched)) => results[i] = Some(Ok(fetched)),
                    // Woken without a message yet: wait on.
                    Ok(None) => pending[i] = Some(socket),
                    Err(e) => results[i] = Some(Err(e)),
                }
            }
        }
    }
    results
        .into_iter()
        .zip(channels)
        .map(|(result, &(path, label))| {
            result.unwrap_or_else(|| Err(Error::NotAnswering { channel: label.to_owned(), path: path.to_owned() }))
        })
        .collect()
}

/// A connection being made to a channel's socket.
enum Connection {
    /// Connected; the writer's answer is awaited on this socket.
    Pending(OwnedFd),
    /// The socket is there but nobody listens: the writer is dead or dropped.
    Refused,
}

/// Connects, without blocking, to the channel's socket at `path`.
fn connect(path: &Path, label: &str) -> Result<Connection> {
    use rustix::io::Errno;
    use rustix::net::{AddressFamily, SocketAddrUnix, SocketFlags, SocketType};
    let os_error = |op, source: io::Error| Error::Os { op, path: path.to_owned(), source };
    let missing = || Error::Missing { channel: label.to_owned(), path: path.to_owned() };
    match std::fs::symlink_metadata(path) {
        Ok(meta) if meta.file_type().is_socket() => {}
        Ok(meta) => {
            let found = shm::describe_file_type(rustix::fs::FileType::from_raw_mode(
                std::os::unix::fs::MetadataExt::mode(&meta),
            ));
            return Err(Error::NotAChannel { channel: label.to_owned(), path: path.to_owned(), found });
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Err(missing()),
        Err(e) => return Err(os_error("stat", e)),
    }
    let address = SocketAddrUnix::new(path).map_err(|e| os_error("connect", e.into()))?;
    let socket = rustix::net::socket_with(
        AddressFamily::UNIX,
        SocketType::STREAM,
        SocketFlags::NONBLOCK | SocketFlags::CLOEXEC,
        None,
    )
    .map_err(|e| os_error("socket", e.into()))?;
    match rustix::net::connect(&socket, &address) {
        // A Unix socket connects at once, or is queued at once (INPROGRESS
        // is not expected, but waiting for the answer covers it too).
        Ok(()) | Err(Errno::INPROGRESS) => Ok(Connection::Pending(socket)),
        Err(Errno::CONNREFUSED) => Ok(Connection::Refused),
        Err(Errno::NOENT) => Err(missing()),
        Err(Errno::ACCESS) | Err(Errno::PERM) => {
            Err(Error::AccessDenied { channel: label.to_owned(), path: path.to_owned() })
        }
        // The listener's queue is full: its process accepts nobody (stopped).
        Err(Errno::AGAIN) => Err(Error::NotAnswering { channel: label.to_owned(), path: path.to_owned() }),
        Err(e) => Err(os_error("connect", e.into())),
    }
}

/// Receives the writer's answer on a connected socket that poll found
/// readable; `None` if nothing is there yet after all.
fn receive(stream: &OwnedFd, path: &Path, label: &str) -> Result<Option<Fetched>> {
    let os_error = |op, source| Error::Os { op, path: path.to_owned(), source };
    let mut greeting = [0u8; 16];
    let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
    let mut control = RecvAncillaryBuffer::new(&mut space);
    let received = rustix::net::recvmsg(
        stream,
        &mut [IoSliceMut::new(&mut greeting)],
        &mut control,
        RecvFlags::CMSG_CLOEXEC | RecvFlags::DONTWAIT,
    );
    let not_answering = || Error::NotAnswering { channel: label.to_owned(), path: path.to_owned() };
    let received = match received {
        Ok(received) => received,
        Err(rustix::io::Errno::AGAIN) | Err(rustix::io::Errno::INTR) => return Ok(None),
        // The writer closed the connection without answering: it is being dropped.
        Err(rustix::io::Errno::CONNRESET) => return Ok(Some(Fetched::NoWriter)),
        Err(e) => return Err(os_error("receive the channel", e.into())),
    };
    // Whatever descriptors came are taken (and closed on return) before anything is judged.
    let mut fds: Vec<OwnedFd> = Vec::new();
    for message in control.drain() {
        if let RecvAncillaryMessage::ScmRights(rights) = message {
            fds.extend(rights);
        }
    }
    if received.bytes == 0 && fds.is_empty() {
        // The writer closed without answering: it is being dropped.
        return Ok(Some(Fetched::NoWriter));
    }
    if received.bytes != GREETING.len() || &greeting[..GREETING.len()] != GREETING || fds.len() != 2 {
        return Err(Error::Corrupt {
            channel: label.to_owned(),
            reason: format!(
                "its socket answered {} bytes and {} descriptors, not a skinware hand-over (is {} served by another program?)",
                received.bytes,
                fds.len(),
                path.display()
            ),
        });
    }
    let bell = fds.pop().ok_or_else(not_answering)?;
    let data = fds.pop().ok_or_else(not_answering)?;
    Ok(Some(Fetched::Memory { data, bell }))
}
