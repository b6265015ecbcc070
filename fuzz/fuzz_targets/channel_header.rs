//! Opening a channel whose memory holds arbitrary bytes (what a foreign,
//! damaged or hostile process serving a channel's socket can hand over), then
//! using every read the reader offers: a typed error or a value, never a
//! panic or a fault. The first input byte chooses whether the memory is
//! sealed (a reader must refuse unsealed memory before mapping it) and
//! whether this input goes through the channel's socket (one in 64, since the
//! round trip costs most of an execution) or straight to the validation.
#![no_main]

use std::fs::File;
use std::io::IoSlice;
use std::mem::MaybeUninit;
use std::os::fd::AsFd;
use std::os::unix::fs::FileExt;
use std::os::unix::net::UnixListener;
use std::path::PathBuf;
use std::sync::{Mutex, OnceLock};
use std::time::Duration;

use libfuzzer_sys::fuzz_target;
use rustix::fs::{MemfdFlags, SealFlags};
use rustix::net::{SendAncillaryBuffer, SendAncillaryMessage, SendFlags};
use skinware::{Reader, ReaderOptions};

/// The memory the fake writer hands over now: frames and doorbell.
static MEMORY: Mutex<Option<(File, File)>> = Mutex::new(None);

fn dir() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = if std::path::Path::new("/dev/shm").is_dir() { "/dev/shm".into() } else { std::env::temp_dir() };
        let dir = base.join(format!("skinware-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("fuzz segment directory");
        let listener = UnixListener::bind(dir.join("skinware.fuzz.layer")).expect("bind the channel's socket");
        std::thread::spawn(move || serve(listener));
        dir
    })
}

/// A fake writer: hands whatever memory is current to every reader.
fn serve(listener: UnixListener) {
    for stream in listener.incoming().flatten() {
        let memory = MEMORY.lock().unwrap_or_else(|p| p.into_inner());
        let Some((data, bell)) = memory.as_ref() else { continue };
        let fds = [data.as_fd(), bell.as_fd()];
        let mut space = [MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
        let mut control = SendAncillaryBuffer::new(&mut space);
        control.push(SendAncillaryMessage::ScmRights(&fds));
        let _ = rustix::net::sendmsg(&stream, &[IoSlice::new(b"SKINHND1")], &mut control, SendFlags::NOSIGNAL);
    }
}

fn memory_file(bytes: &[u8], sealed: bool) -> File {
    let fd = rustix::fs::memfd_create("fuzz", MemfdFlags::ALLOW_SEALING | MemfdFlags::CLOEXEC).expect("memfd");
    let file = File::from(fd);
    file.set_len(bytes.len() as u64).expect("size the memory");
    file.write_all_at(bytes, 0).expect("fill the memory");
    if sealed {
        rustix::fs::fcntl_add_seals(&file, SealFlags::SHRINK | SealFlags::GROW | SealFlags::SEAL).expect("seal");
    }
    file
}

fuzz_target!(|input: &[u8]| {
    let Some((&choice, bytes)) = input.split_first() else { return };
    let dir = dir();
    let sealed = choice & 1 == 0;
    let data = memory_file(bytes, sealed);
    let bell = memory_file(&[choice; 4096], sealed);
    let opened = if choice >> 2 == 0 {
        *MEMORY.lock().unwrap_or_else(|p| p.into_inner()) = Some((data, bell));
        let options = ReaderOptions { dir: Some(dir.clone()), allow_gone: true, ..ReaderOptions::default() };
        Reader::open_with("fuzz", "layer", &options)
    } else {
        // Bit 1: an anticipating reader, whose grid arithmetic takes the
        // header's period and the frames' times (issue #36).
        Reader::from_memory(data.into(), bell.into(), choice & 2 != 0)
    };
    if let Ok(mut reader) = opened {
        let _ = reader.topology();
        let _ = reader.schema();
        let _ = reader.writer_state();
        // The statistics' quantiles add up the writer's counts.
        let _ = reader.writer_stats().write_ns_quantile(0.99);
        let _ = skinware::histogram_quantile(&reader.writer_stats().lateness_histogram, 0.5);
        let _ = reader.latest().map(|frame| frame.responses().len());
        let _ = reader.wait_newer(Duration::ZERO).map(|frame| frame.seq());
        // A second look at the same memory: what the anticipation predicts
        // from the first frame's time and the forged period.
        let _ = reader.latest().map(|frame| frame.published_ns());
        let _ = reader.wait_newer(Duration::from_micros(50)).map(|frame| frame.seq());
    }
    if choice >> 2 == 0 {
        let _ = skinware::list_channels(dir);
    }
});
