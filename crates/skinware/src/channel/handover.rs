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
use std::thread::JoinHandle;
use std::time::Duration;

use rustix::event::{EventfdFlags, PollFd, PollFlags};
use rustix::net::{
    RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags, SendAncillaryBuffer, SendAncillaryMessage, SendFlags,
};

use super::liveness::{FileIdentity, NameLock, path_identity};
use crate::error::{Error, Result};
use crate::shm;

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
    thread: Option<JoinHandle<NameLock>>,
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
        let served = Served { path: path.clone(), mode, label, name, data, bell };
        let thread = std::thread::Builder::new()
            .name("skinware-handover".into())
            .spawn(move || served.serve(bound, &stop))
            .map_err(spawn_error)?;
        Ok(Server { wake, thread: Some(thread) })
    }
}

impl Server {
    /// Stops answering and returns the name lock (`None` only if the thread
    /// panicked, which drops it).
    pub fn stop(mut self) -> Option<NameLock> {
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
}

impl Served {
    fn serve(mut self, mut bound: (UnixListener, FileIdentity), stop: &OwnedFd) -> NameLock {
        let timeout = rustix::time::Timespec { tv_sec: 0, tv_nsec: RECHECK.as_nanos() as i64 };
        loop {
            let mut fds = [PollFd::new(&bound.0, PollFlags::IN), PollFd::new(stop, PollFlags::IN)];
            if let Err(e) = rustix::event::poll(&mut fds, Some(&timeout))
                && e != rustix::io::Errno::INTR
            {
                tracing::error!(channel = %self.label, error = %e, "the hand-over thread cannot poll; readers can no longer attach");
                return self.name;
            }
            if !fds[1].revents().is_empty() {
                return self.name;
            }
            while let Ok((stream, _)) = bound.0.accept() {
                hand_over(&stream, &self.data, &self.bell);
            }
            if !self.name.keep_in_place() {
                tracing::error!(channel = %self.label, "the channel's name lock was removed and another writer took the name; this writer's readers stay with it, new readers go to the other");
            }
            if path_identity(&self.path) != Some(bound.1) {
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
/// the writer's two descriptors.
pub(crate) fn fetch(path: &Path, label: &str, answer_timeout: Duration) -> Result<Fetched> {
    let os_error = |op, source| Error::Os { op, path: path.to_owned(), source };
    match std::fs::metadata(path) {
        Ok(meta) if meta.file_type().is_socket() => {}
        Ok(meta) => {
            let found = if meta.is_file() { "regular file" } else { "file that is not a socket" };
            return Err(Error::NotAChannel { channel: label.to_owned(), path: path.to_owned(), found });
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(Error::Missing { channel: label.to_owned(), path: path.to_owned() });
        }
        Err(e) => return Err(os_error("stat", e)),
    }
    let stream = match UnixStream::connect(path) {
        Ok(stream) => stream,
        Err(e) if e.kind() == io::ErrorKind::ConnectionRefused => return Ok(Fetched::NoWriter),
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            return Err(Error::Missing { channel: label.to_owned(), path: path.to_owned() });
        }
        Err(e) if e.kind() == io::ErrorKind::PermissionDenied => {
            return Err(Error::AccessDenied { channel: label.to_owned(), path: path.to_owned() });
        }
        Err(e) => return Err(os_error("connect", e)),
    };
    stream.set_read_timeout(Some(answer_timeout)).map_err(|e| os_error("setsockopt", e))?;
    let mut greeting = [0u8; 16];
    let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
    let mut control = RecvAncillaryBuffer::new(&mut space);
    let received =
        rustix::net::recvmsg(&stream, &mut [IoSliceMut::new(&mut greeting)], &mut control, RecvFlags::CMSG_CLOEXEC);
    let not_answering = || Error::NotAnswering { channel: label.to_owned(), path: path.to_owned() };
    let received = match received {
        Ok(received) => received,
        Err(rustix::io::Errno::AGAIN) => return Err(not_answering()),
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
        return Ok(Fetched::NoWriter);
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
    Ok(Fetched::Memory { data, bell })
}
