//! Helpers shared by the integration tests (and the stress harness).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use skinware::{ReaderOptions, WriterOptions};

/// A private segment directory under /dev/shm (real tmpfs shared memory),
/// removed with everything in it when dropped.
pub struct SegmentDir {
    pub path: PathBuf,
}

impl SegmentDir {
    pub fn new(test: &str) -> SegmentDir {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let base = if Path::new("/dev/shm").is_dir() { PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
        let path =
            base.join(format!("skinware-test-{}-{}-{test}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)));
        std::fs::create_dir_all(&path).unwrap();
        SegmentDir { path }
    }

    pub fn writer(&self) -> WriterOptions {
        WriterOptions { dir: Some(self.path.clone()), ..WriterOptions::default() }
    }

    pub fn reader(&self) -> ReaderOptions {
        ReaderOptions { dir: Some(self.path.clone()), ..ReaderOptions::default() }
    }

    pub fn segment(&self, skin: &str, channel: &str) -> PathBuf {
        self.path.join(format!("skinware.{skin}.{channel}"))
    }

    /// Names of the files left in the directory.
    pub fn files(&self) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(&self.path)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        names
    }
}

impl Drop for SegmentDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.path);
    }
}

/// The bytes of a live channel's frames memory, as any reader receives it
/// (this is the hand-over a hostile reader would make by hand).
pub fn capture_memory(dir: &SegmentDir, skin: &str, channel: &str) -> Vec<u8> {
    use std::os::unix::fs::FileExt;
    let (data, _bell) = receive_fds(&dir.segment(skin, channel));
    let file = std::fs::File::from(data);
    let mut bytes = vec![0u8; file.metadata().unwrap().len() as usize];
    file.read_exact_at(&mut bytes, 0).unwrap();
    bytes
}

/// Connects to a channel's socket and takes the two descriptors it hands over.
pub fn receive_fds(socket: &Path) -> (std::os::fd::OwnedFd, std::os::fd::OwnedFd) {
    use rustix::net::{RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags};
    let stream = std::os::unix::net::UnixStream::connect(socket).unwrap();
    let mut greeting = [0u8; 16];
    let mut space = [std::mem::MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
    let mut control = RecvAncillaryBuffer::new(&mut space);
    rustix::net::recvmsg(&stream, &mut [std::io::IoSliceMut::new(&mut greeting)], &mut control, RecvFlags::empty())
        .unwrap();
    let mut fds = Vec::new();
    for message in control.drain() {
        if let RecvAncillaryMessage::ScmRights(rights) = message {
            fds.extend(rights);
        }
    }
    assert_eq!(fds.len(), 2, "the writer handed over {} descriptors", fds.len());
    let bell = fds.pop().unwrap();
    (fds.pop().unwrap(), bell)
}

/// What a fake writer answers on a channel's socket.
pub enum Answer {
    /// Memory files holding these frame bytes (and a zeroed doorbell page),
    /// sealed against shrinking or not.
    Memory { data: Vec<u8>, sealed: bool },
    /// These bytes, and no descriptor.
    Bytes(Vec<u8>),
    /// Nothing: connections are accepted by the kernel and never answered.
    Silence,
}

/// A process pretending to be a channel's writer (another program, an older
/// skinware, or a hostile one): it binds the channel's socket and answers
/// every reader the same way, until dropped.
pub struct FakeWriter {
    path: PathBuf,
    _thread: Option<std::thread::JoinHandle<()>>,
    _listener: std::sync::Arc<std::os::unix::net::UnixListener>,
}

impl FakeWriter {
    pub fn serve(dir: &SegmentDir, skin: &str, channel: &str, answer: Answer) -> FakeWriter {
        use rustix::fs::{MemfdFlags, SealFlags};
        use std::os::unix::fs::FileExt;
        let path = dir.segment(skin, channel);
        let listener = std::sync::Arc::new(std::os::unix::net::UnixListener::bind(&path).unwrap());
        let memory_file = |bytes: &[u8], sealed: bool| {
            let fd = rustix::fs::memfd_create("fake", MemfdFlags::ALLOW_SEALING | MemfdFlags::CLOEXEC).unwrap();
            let file = std::fs::File::from(fd);
            file.set_len(bytes.len() as u64).unwrap();
            file.write_all_at(bytes, 0).unwrap();
            if sealed {
                rustix::fs::fcntl_add_seals(&file, SealFlags::SHRINK | SealFlags::GROW | SealFlags::SEAL).unwrap();
            }
            file
        };
        let thread = match answer {
            Answer::Silence => None,
            Answer::Bytes(bytes) => {
                let listener = listener.clone();
                Some(std::thread::spawn(move || {
                    for stream in listener.incoming().flatten() {
                        let _ = std::io::Write::write_all(&mut &stream, &bytes);
                    }
                }))
            }
            Answer::Memory { data, sealed } => {
                let data = memory_file(&data, sealed);
                let bell = memory_file(&[0u8; 4096], sealed);
                Some(serve_memory(listener.clone(), data, bell))
            }
        };
        FakeWriter { path, _thread: thread, _listener: listener }
    }

    /// Serves these memory files (the caller keeps its own descriptor of
    /// the data, e.g. to rewrite it while readers read).
    pub fn serve_files(
        dir: &SegmentDir,
        skin: &str,
        channel: &str,
        data: &std::fs::File,
        bell: std::fs::File,
    ) -> FakeWriter {
        let path = dir.segment(skin, channel);
        let listener = std::sync::Arc::new(std::os::unix::net::UnixListener::bind(&path).unwrap());
        // Readers get their own open file, as from a real writer: an open
        // file's own lock does not count as held when it asks.
        let reopened = std::fs::File::open(format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(data))).unwrap();
        let thread = serve_memory(listener.clone(), reopened, bell);
        FakeWriter { path, _thread: Some(thread), _listener: listener }
    }
}

/// Answers every connection with the two descriptors, as a writer does.
fn serve_memory(
    listener: std::sync::Arc<std::os::unix::net::UnixListener>,
    data: std::fs::File,
    bell: std::fs::File,
) -> std::thread::JoinHandle<()> {
    use rustix::net::{SendAncillaryBuffer, SendAncillaryMessage, SendFlags};
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let fds = [std::os::fd::AsFd::as_fd(&data), std::os::fd::AsFd::as_fd(&bell)];
            let mut space = [std::mem::MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
            let mut control = SendAncillaryBuffer::new(&mut space);
            control.push(SendAncillaryMessage::ScmRights(&fds));
            let _ =
                rustix::net::sendmsg(&stream, &[std::io::IoSlice::new(b"SKINHND1")], &mut control, SendFlags::NOSIGNAL);
        }
    })
}

impl Drop for FakeWriter {
    fn drop(&mut self) {
        // The thread blocks in accept for the rest of the test binary's life;
        // removing the socket keeps it from answering anybody else.
        let _ = std::fs::remove_file(&self.path);
    }
}
