//! The floor under what a browser costs the viewer, for `skin bench
//! kilohertz` (which runs it as the hidden `skin bench-floor`, a process of
//! its own as the viewer is): a bare WebSocket server that does, per
//! browser, only what no viewer of this design can leave out. It waits for
//! the browser's acknowledgement, and for each one sends one message (of an
//! update's size unless told otherwise) through the viewer's own send path
//! (one `sendmsg` from where the bytes are). By default it reads no skin,
//! keeps no board and paces nothing, so the
//! difference between its cost with 10 browsers and with 1 is what the
//! kernel and the wake-ups charge per browser on this machine: what the
//! viewer's per-browser cost is compared with, in the same run.
//!
//! The bytes it sends are in the same cache state as the viewer's: a
//! writer thread (not counted, like the viewer's layer readers are not part
//! of what a browser costs) writes a new update into a spare buffer every
//! millisecond and swaps it in, as the layer readers do with the board, and
//! each send takes the newest. A buffer that nothing rewrote would be sent
//! from a warm cache, cheaper than anything the viewer can do.
//!
//! With `--read-skin`, it reads every layer of the skin instead, with the
//! viewer's own samplers (in the viewer's first mode, asap: every frame as
//! it is published; shared by all browsers and stopped with the last, as the
//! viewer's are), and answers each acknowledgement with the board as it is:
//! a head of the viewer's size and every layer's newest responses, sent
//! from where the readers left them. That is the viewer without what its
//! sessions decide (pacing, credit, the acknowledgement's JSON, overlays,
//! the head's contents), so its whole CPU with 10 browsers over 1 is the
//! ratio of a viewer whose sessions cost only the message.

#![forbid(unsafe_code)]

use std::io::{IoSlice, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{Context, Result};
use tungstenite::Message;

use skinware_viewer::protocol::{KIND_GEOMETRY, KIND_UPDATE, LAYER_RECORD_BYTES, UPDATE_HEADER_BYTES, responses_le};
use skinware_viewer::sampler::{LayerToRead, Sampler, Samplers};
use skinware_viewer::server::BROWSER_READ_BYTES;
use skinware_viewer::session::{BrowserStream, INITIAL_MODE, WebSocketHeader, send_message};

/// How long a connection's read waits before it looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(100);

/// The name of the threads that serve a browser each: what the bench
/// measures of this process.
pub const BROWSER_THREAD: &str = "floor-browser";

/// The largest update it sends: a WebSocket message the viewer could send.
const MAX_UPDATE_BYTES: usize = 16 << 20;

/// Arguments of the hidden `bench-floor` role.
#[derive(Clone, Debug, clap::Args)]
pub struct FloorArgs {
    /// Bytes of each update message.
    #[arg(long, value_parser = parse_update_bytes)]
    pub bytes: usize,
    /// Read every layer of this skin (in `SKINWARE_SHM_DIR`) as the viewer
    /// does and send its newest frames instead (`--bytes` is still
    /// required, and unused).
    #[arg(long)]
    pub read_skin: Option<String>,
}

/// The viewer's readers of a skin, whose board the floor server sends.
struct SkinReaders {
    samplers: Samplers,
    layers: Vec<LayerToRead>,
}

impl SkinReaders {
    /// The readers of `skin`'s layers, as its geometry lists them; none runs yet.
    fn open(skin: &str) -> Result<SkinReaders> {
        let dir = skinware::shm::segment_dir();
        let geometry = skinware_geometry::SkinGeometry::open_in(&dir, skin)
            .with_context(|| format!("the floor server cannot read skin {skin:?}'s geometry in {}", dir.display()))?;
        Ok(SkinReaders { samplers: Samplers::new(skin, Some(dir)), layers: LayerToRead::all_of(&geometry) })
    }

    /// The running readers, shared with every browser that holds them:
    /// started by the first, stopped when the last lets go.
    fn start(&self) -> Result<Arc<Sampler>> {
        self.samplers.subscribe(&self.layers, INITIAL_MODE).context("the floor server cannot start its layer readers")
    }
}

/// An update's size that is no number, or out of range.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum UpdateBytesError {
    /// The text is not a number (or too large for one).
    #[error("{text:?} is not a number of bytes")]
    NotANumber {
        /// What was given.
        text: String,
    },
    /// 0, or more than 16 MiB.
    #[error("{bytes} is not an update's size: give 1 to {most} bytes (16 MiB)")]
    OutOfRange {
        /// What was given.
        bytes: usize,
        /// The most allowed.
        most: usize,
    },
}

/// An update's size in bytes: 1 to 16 MiB, refused here rather than as an
/// allocation that aborts.
pub fn parse_update_bytes(text: &str) -> Result<usize, UpdateBytesError> {
    let bytes: usize = text.trim().parse().map_err(|_| UpdateBytesError::NotANumber { text: text.to_owned() })?;
    if !(1..=MAX_UPDATE_BYTES).contains(&bytes) {
        return Err(UpdateBytesError::OutOfRange { bytes, most: MAX_UPDATE_BYTES });
    }
    Ok(bytes)
}

/// Runs the floor server: prints the address it listens on, then serves
/// until its standard input closes (the bench ended).
pub fn run(args: &FloorArgs) -> Result<()> {
    let readers = args.read_skin.as_deref().map(SkinReaders::open).transpose()?;
    let server = FloorServer::start(args.bytes, readers)?;
    let mut stdout = std::io::stdout();
    writeln!(stdout, "{}", server.address)?;
    stdout.flush()?;
    let mut rest = Vec::new();
    let _ = std::io::stdin().read_to_end(&mut rest);
    Ok(())
}

/// The running floor server; stopped (its threads joined) when dropped.
struct FloorServer {
    address: String,
    shared: Arc<Shared>,
    acceptor: Option<JoinHandle<()>>,
    rewriter: Option<JoinHandle<()>>,
}

/// What the server's threads share.
struct Shared {
    stop: AtomicBool,
    /// The newest update, replaced whole by the rewriter.
    newest: Mutex<Arc<Vec<u8>>>,
    /// Browsers connected: the rewriter works only while there is one, so
    /// that the floor server loads the machine only in its own rounds.
    browsers: Mutex<usize>,
    browsers_changed: Condvar,
    /// With `--read-skin`: the skin's readers, whose board is sent instead.
    readers: Option<SkinReaders>,
}

impl Shared {
    fn newest(&self) -> Arc<Vec<u8>> {
        self.newest.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    fn count_browsers(&self, change: impl FnOnce(&mut usize)) {
        change(&mut self.browsers.lock().unwrap_or_else(|p| p.into_inner()));
        self.browsers_changed.notify_all();
    }

    /// Waits while no browser is connected; false once the server stops.
    fn wait_for_browsers(&self) -> bool {
        let browsers = self.browsers.lock().unwrap_or_else(|p| p.into_inner());
        let idle = |browsers: &mut usize| *browsers == 0 && !self.stop.load(Ordering::Relaxed);
        let _unused = self.browsers_changed.wait_while(browsers, idle).unwrap_or_else(|p| p.into_inner());
        !self.stop.load(Ordering::Relaxed)
    }
}

/// How often the rewriter writes a new update: the skin's rate.
const REWRITE_EVERY: Duration = Duration::from_millis(1);

impl FloorServer {
    /// Listens on a free loopback port and answers each acknowledgement of
    /// a browser with one binary message of `update_bytes` bytes.
    fn start(update_bytes: usize, readers: Option<SkinReaders>) -> Result<FloorServer> {
        let listener = TcpListener::bind("127.0.0.1:0").context("cannot listen on loopback for the floor server")?;
        let address = listener.local_addr()?.to_string();
        let mut update = vec![0u8; update_bytes.max(1)];
        update[0] = KIND_UPDATE;
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            newest: Mutex::new(Arc::new(update)),
            browsers: Mutex::new(0),
            browsers_changed: Condvar::new(),
            readers,
        });
        // What is sent from the skin's board needs no stand-in.
        let rewriter = shared.readers.is_none().then(|| {
            let shared = shared.clone();
            std::thread::spawn(move || rewrite(&shared))
        });
        let acceptor = {
            let shared = shared.clone();
            std::thread::spawn(move || accept_browsers(&listener, &shared))
        };
        Ok(FloorServer { address, shared, acceptor: Some(acceptor), rewriter })
    }
}

impl Drop for FloorServer {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        self.shared.count_browsers(|_| {});
        // The acceptor blocks in accept(): a connection wakes it to see the flag.
        let _ = TcpStream::connect(&self.address);
        for thread in [self.acceptor.take(), self.rewriter.take()].into_iter().flatten() {
            let _ = thread.join();
        }
    }
}

/// While a browser is connected, writes a new update every
/// [`REWRITE_EVERY`] into a buffer no send holds (the one it replaced last
/// time, once the sends let go of it), then swaps it in.
fn rewrite(shared: &Shared) {
    let mut spare = Arc::new(shared.newest().as_ref().clone());
    let mut count = 0u8;
    while shared.wait_for_browsers() {
        std::thread::sleep(REWRITE_EVERY);
        count = count.wrapping_add(1);
        if Arc::get_mut(&mut spare).is_none() {
            // A send still holds it: write a new one.
            spare = Arc::new(shared.newest().as_ref().clone());
        }
        if let Some(bytes) = Arc::get_mut(&mut spare) {
            bytes[1..].fill(count);
            spare = std::mem::replace(&mut *shared.newest.lock().unwrap_or_else(|p| p.into_inner()), spare);
        }
    }
}

fn accept_browsers(listener: &TcpListener, shared: &Arc<Shared>) {
    let mut connections: Vec<JoinHandle<()>> = Vec::new();
    while !shared.stop.load(Ordering::Relaxed) {
        let Ok((stream, _)) = listener.accept() else {
            std::thread::sleep(Duration::from_millis(10));
            continue;
        };
        if shared.stop.load(Ordering::Relaxed) {
            break;
        }
        connections.retain(|connection| !connection.is_finished());
        let shared = shared.clone();
        let spawned = std::thread::Builder::new().name(BROWSER_THREAD.into()).spawn(move || {
            shared.count_browsers(|browsers| *browsers += 1);
            let served = serve_browser(stream, &shared);
            shared.count_browsers(|browsers| *browsers -= 1);
            if let Err(e) = served {
                eprintln!("kilohertz: the floor server lost a browser: {e:#}");
            }
        });
        match spawned {
            Ok(connection) => connections.push(connection),
            Err(e) => eprintln!("kilohertz: the floor server cannot start a thread for a browser: {e}"),
        }
    }
    for connection in connections {
        let _ = connection.join();
    }
}

/// One browser: a token geometry message, then one update per
/// acknowledgement, until it closes or the server stops.
fn serve_browser(stream: TcpStream, shared: &Shared) -> Result<()> {
    stream.set_read_timeout(Some(STOP_POLL))?;
    stream.set_nodelay(true)?;
    // The viewer's read buffer (`skinware_viewer::server`): tungstenite zeroes it before every read.
    let config = tungstenite::protocol::WebSocketConfig::default().read_buffer_size(BROWSER_READ_BYTES);
    let mut socket = tungstenite::accept_with_config(BrowserStream::new(stream), Some(config))
        .map_err(|e| anyhow::anyhow!("WebSocket handshake with a browser failed: {e}"))?;
    socket.send(Message::binary(vec![KIND_GEOMETRY]))?;
    // With the skin's readers: shared with the other browsers, stopped with the last.
    let mut board = match &shared.readers {
        Some(readers) => Some(BoardSender::new(readers.start()?, readers.layers.len())),
        None => None,
    };
    while !shared.stop.load(Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Text(_)) => {
                let sent = match &mut board {
                    Some(board) => board.send(&mut socket),
                    None => {
                        let update = shared.newest();
                        let header = WebSocketHeader::binary(update.len());
                        send_message(&mut socket, &mut [IoSlice::new(header.bytes()), IoSlice::new(&update)])
                    }
                };
                match sent {
                    Ok(()) => {}
                    Err(e) if ended_by_browser(&e) => break,
                    Err(e) => return Err(e.into()),
                }
            }
            Ok(Message::Close(_)) => break,
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) if ended_by_browser(&e) => break,
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

/// Sends the skin's board as the viewer's session sends it: the slots'
/// responses shared under the board's lock, written after it.
struct BoardSender {
    /// The readers whose board is sent.
    sampler: Arc<Sampler>,
    /// A head of the viewer's size for this many layers (its contents are
    /// not the floor's business).
    head: Vec<u8>,
    /// The layers' responses taken for the message being sent; emptied
    /// once it is, so that the readers write in place again.
    responses: Vec<Arc<Vec<u16>>>,
    /// Responses converted to little-endian, on a big-endian machine only.
    scratch: Vec<Vec<u8>>,
}

impl BoardSender {
    /// Sends the board of `sampler`, which reads `layers` layers.
    fn new(sampler: Arc<Sampler>, layers: usize) -> BoardSender {
        let mut head = vec![0u8; UPDATE_HEADER_BYTES + layers * LAYER_RECORD_BYTES];
        head[0] = KIND_UPDATE;
        BoardSender { sampler, head, responses: Vec::with_capacity(layers), scratch: vec![Vec::new(); layers] }
    }

    /// Sends the board as it is now, as one binary message.
    fn send(&mut self, socket: &mut tungstenite::WebSocket<BrowserStream>) -> tungstenite::Result<()> {
        let responses = &mut self.responses;
        // A version no board has: the board as it is, at once.
        self.sampler.take_newer(u64::MAX, Duration::ZERO, |board| {
            responses.clear();
            responses.extend(board.layers.iter().map(|slot| slot.responses.clone()));
        });
        let length = self.head.len() + responses.iter().map(|r| 2 * r.len()).sum::<usize>();
        let header = WebSocketHeader::binary(length);
        let mut parts = Vec::with_capacity(2 + responses.len());
        parts.push(IoSlice::new(header.bytes()));
        parts.push(IoSlice::new(&self.head));
        for (layer, scratch) in responses.iter().zip(&mut self.scratch) {
            parts.push(IoSlice::new(responses_le(layer, scratch)));
        }
        let sent = send_message(socket, &mut parts);
        drop(parts);
        // Let go, so that the readers write in place again.
        responses.clear();
        sent
    }
}

/// How a browser's connection ends at the end of a window: closed, or reset
/// because the browser closed with an update unread.
fn ended_by_browser(error: &tungstenite::Error) -> bool {
    match error {
        tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed => true,
        tungstenite::Error::Io(e) => {
            matches!(e.kind(), std::io::ErrorKind::ConnectionReset | std::io::ErrorKind::BrokenPipe)
        }
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn update_sizes_outside_1_byte_to_16_mib_are_refused_by_name() {
        assert_eq!(parse_update_bytes("1"), Ok(1));
        assert_eq!(parse_update_bytes(" 61832 "), Ok(61_832));
        assert_eq!(parse_update_bytes("16777216"), Ok(MAX_UPDATE_BYTES));
        for refused in ["0", "16777217"] {
            let error = parse_update_bytes(refused).unwrap_err().to_string();
            assert_eq!(error, format!("{refused} is not an update's size: give 1 to 16777216 bytes (16 MiB)"));
        }
        let error = parse_update_bytes("99999999999999999999").unwrap_err().to_string();
        assert!(error.contains("is not a number of bytes"), "{error}");
        assert_eq!(parse_update_bytes("abc").unwrap_err().to_string(), "\"abc\" is not a number of bytes");
        assert_eq!(parse_update_bytes("-5").unwrap_err().to_string(), "\"-5\" is not a number of bytes");
        assert_eq!(parse_update_bytes("0"), Err(UpdateBytesError::OutOfRange { bytes: 0, most: MAX_UPDATE_BYTES }));
    }
}
