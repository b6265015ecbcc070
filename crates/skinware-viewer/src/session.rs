//! One browser: the geometry at connect, then updates as the browser grants
//! credit. The browser acknowledges each update it has drawn; the server never
//! has more than `MAX_CREDIT` updates unacknowledged, and each update holds
//! the newest frames at the moment it is sent, so a slow browser gets fewer,
//! fresher updates instead of a growing queue.

#![forbid(unsafe_code)]

use std::io::IoSlice;
use std::net::TcpStream;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use skinware_geometry::SkinGeometry;
use tungstenite::{Message, WebSocket};

use crate::message::{self, ClientMessage, ReadMode};
use crate::overlays::{HeldOverlays, SharedOverlays};
use crate::protocol::{self, LayerUpdate};
use crate::range::{self, ResponseRange};
use crate::sampler::{LayerToRead, Sampler, Samplers};

/// Updates the server may send ahead of the browser's acknowledgements.
const MAX_CREDIT: u32 = 4;
/// How long to wait for the browser when it has no credit left.
const IDLE_POLL: Duration = Duration::from_millis(20);
/// A browser's frame interval until its acknowledgements tell (60 Hz).
const DISPLAY_INTERVAL: Duration = Duration::from_micros(16_667);
/// Acknowledgement intervals the frame interval is the median of.
const INTERVALS_KEPT: usize = 16;

/// When a browser's next update is due. A browser draws at most one update
/// per frame of its display, and acknowledges after each frame it drew: so
/// one update goes as soon as it acknowledges, and it is drawn at its next
/// frame; more before the next acknowledgement would be encoded and sent for
/// nothing (at 1 kHz, most of them). If no acknowledgement comes for 1.5
/// frame intervals (the median recent acknowledgement interval; a long
/// round trip, or a busy page), another goes, within the browser's credit. (Timing
/// the update to arrive just before the browser's next frame would make what
/// it draws a few milliseconds fresher, but where in its frame a page
/// acknowledges is unknown: headless Chromium then missed a frame in two.)
#[derive(Debug, Default)]
struct Pacing {
    last_ack: Option<Instant>,
    intervals: std::collections::VecDeque<Duration>,
    /// The median of `intervals`, computed when one arrives (the loop asks
    /// for it several times per update); `None` before the first.
    median_interval: Option<Duration>,
    sent_since_ack: u32,
    last_sent: Option<Instant>,
}

impl Pacing {
    /// The median recent acknowledgement interval: two acknowledgements
    /// read together (this thread was busy) must not make it look short.
    fn frame_interval(&self) -> Duration {
        self.median_interval.unwrap_or(DISPLAY_INTERVAL)
    }

    fn acknowledged(&mut self, now: Instant) {
        if let Some(previous) = self.last_ack.replace(now) {
            if self.intervals.len() == INTERVALS_KEPT {
                self.intervals.pop_front();
            }
            self.intervals
                .push_back(now.duration_since(previous).clamp(Duration::from_millis(2), Duration::from_secs(2)));
            let mut sorted = [Duration::ZERO; INTERVALS_KEPT];
            let sorted = &mut sorted[..self.intervals.len()];
            for (into, interval) in sorted.iter_mut().zip(&self.intervals) {
                *into = *interval;
            }
            sorted.sort_unstable();
            self.median_interval = Some(sorted[sorted.len() / 2]);
        }
        self.sent_since_ack = 0;
    }

    fn sent(&mut self, now: Instant) {
        self.sent_since_ack += 1;
        self.last_sent = Some(now);
    }

    /// How long until the next update is due; `None` if it is due now.
    fn until_due(&self, now: Instant) -> Option<Duration> {
        let due = match self.last_sent {
            // Half a frame of slack: an acknowledgement a little late is not
            // a missing one.
            Some(sent) if self.sent_since_ack > 0 => sent + self.frame_interval().mul_f32(1.5),
            _ => return None,
        };
        // Less than a millisecond is not worth a sleep.
        due.checked_duration_since(now).filter(|left| *left >= Duration::from_millis(1))
    }
}
/// A browser's TCP connection, whose reads wait (up to the socket's read
/// timeout) only when asked to and otherwise return `WouldBlock` at once,
/// while its writes always block: a slow browser slows only its own thread.
#[derive(Debug)]
pub struct BrowserStream {
    /// The connection.
    pub stream: TcpStream,
    /// How the next reads behave.
    pub reads: Reads,
}

/// How a [`BrowserStream`]'s next reads behave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reads {
    /// Wait for data, up to the socket's read timeout.
    Wait,
    /// Take what the socket holds, or `WouldBlock` at once.
    DontWait,
    /// `WouldBlock` without asking the socket: tungstenite then returns only
    /// the messages it already holds in its buffer, for no system call.
    BufferedOnly,
}

impl BrowserStream {
    /// A connection whose reads wait.
    pub fn new(stream: TcpStream) -> BrowserStream {
        BrowserStream { stream, reads: Reads::Wait }
    }
}

impl std::io::Read for BrowserStream {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        match self.reads {
            Reads::Wait => self.stream.read(buffer),
            Reads::DontWait => rustix::net::recv(&self.stream, buffer, rustix::net::RecvFlags::DONTWAIT)
                .map(|(read, _)| read)
                .map_err(std::io::Error::from),
            Reads::BufferedOnly => Err(std::io::ErrorKind::WouldBlock.into()),
        }
    }
}

impl std::io::Write for BrowserStream {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.stream.write(bytes)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

/// How long a browser's connection waits for a geometry that is not
/// published yet (a skin just started with `skin run`, `skin replay` or
/// `skin demo`, which publish it a moment later) before it shows the error.
pub const GEOMETRY_WAIT: Duration = Duration::from_secs(10);

/// The mode a new browser starts in.
pub const INITIAL_MODE: ReadMode = ReadMode::Asap;

/// What every connection needs to know. It lives here, with the session that
/// reads it, so that the server depends on the session and not both ways.
#[derive(Clone, Debug)]
pub struct Site {
    /// The skin to show.
    pub skin: String,
    /// Segment directory; `None` for the default.
    pub dir: Option<PathBuf>,
    /// Set on SIGINT/SIGTERM: connections close and the server's `serve` returns.
    pub shutdown: Arc<AtomicBool>,
    /// The layer readers, shared by the browsers reading in the same mode.
    pub samplers: Arc<Samplers>,
    /// The services' overlays, shared by every browser.
    pub overlays: Arc<SharedOverlays>,
    /// The geometry message last encoded, shared by the browsers that
    /// connect while the published geometry stays the same file.
    pub geometry: Arc<GeometryCache>,
}

/// The geometry message, decoded, checked and encoded once per published
/// geometry instead of once per browser (a 30,848-taxel skin's took about
/// 13 ms of CPU at every connect). A published geometry is renamed into
/// place whole, so the file's identity (device, inode, length, modification
/// time) says whether it is still the one encoded.
#[derive(Debug, Default)]
pub struct GeometryCache {
    /// The last geometry encoded, and the file it came from.
    encoded: std::sync::Mutex<Option<(FileIdentity, Arc<EncodedGeometry>)>>,
}

/// One published geometry, as the browsers get it.
#[derive(Debug)]
pub struct EncodedGeometry {
    /// The geometry message ([`protocol::encode_geometry`]).
    pub message: Vec<u8>,
    /// The layers to read.
    pub layers: Vec<LayerToRead>,
}

/// What tells two versions of a published file apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct FileIdentity {
    device: u64,
    inode: u64,
    bytes: u64,
    modified: Option<std::time::SystemTime>,
}

impl FileIdentity {
    fn of(path: &std::path::Path) -> Option<FileIdentity> {
        use std::os::unix::fs::MetadataExt;
        let metadata = std::fs::metadata(path).ok()?;
        Some(FileIdentity {
            device: metadata.dev(),
            inode: metadata.ino(),
            bytes: metadata.len(),
            modified: metadata.modified().ok(),
        })
    }
}

impl GeometryCache {
    /// The geometry published for `skin` in `dir`: the one encoded last if
    /// the file is still the same, else read, checked and encoded now. The
    /// error is the one [`SkinGeometry::open_in`] gives (missing, corrupt).
    pub fn get(
        &self,
        dir: &std::path::Path,
        skin: &str,
    ) -> Result<Arc<EncodedGeometry>, skinware_geometry::GeometryError> {
        // Looked at before the read: a geometry replaced in between is then
        // encoded under the old identity, which the next browser's look
        // finds different, and encodes again.
        let identity = FileIdentity::of(&SkinGeometry::published_path(dir, skin));
        let mut encoded = self.encoded.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if let (Some((cached_identity, cached)), Some(identity)) = (encoded.as_ref(), identity)
            && *cached_identity == identity
        {
            return Ok(cached.clone());
        }
        let geometry = SkinGeometry::open_in(dir, skin)?;
        let fresh = Arc::new(EncodedGeometry {
            message: protocol::encode_geometry(&geometry),
            layers: LayerToRead::all_of(&geometry),
        });
        // A file that could not be looked at is not remembered.
        *encoded = identity.map(|identity| (identity, fresh.clone()));
        Ok(fresh)
    }
}

impl GeometryCache {
    /// [`get`](Self::get), waiting up to `within` (or until `shutdown`)
    /// for a geometry that is missing to be published; `waiting` is called
    /// once, when it is found missing and the wait begins. Other errors (a
    /// corrupt file) are returned at once.
    pub fn get_waiting(
        &self,
        dir: &std::path::Path,
        skin: &str,
        within: Duration,
        shutdown: &AtomicBool,
        waiting: impl FnOnce(),
    ) -> Result<Arc<EncodedGeometry>, skinware_geometry::GeometryError> {
        let deadline = Instant::now() + within;
        let mut waiting = Some(waiting);
        loop {
            match self.get(dir, skin) {
                Err(skinware_geometry::GeometryError::Missing { .. })
                    if Instant::now() < deadline && !shutdown.load(Ordering::Relaxed) =>
                {
                    if let Some(waiting) = waiting.take() {
                        waiting();
                    }
                    std::thread::sleep(Duration::from_millis(50));
                }
                result => return result,
            }
        }
    }
}

impl Site {
    /// The site of `skin` (segments in `dir`, or the default directory).
    pub fn new(skin: &str, dir: Option<PathBuf>, shutdown: Arc<AtomicBool>) -> Site {
        let samplers = Arc::new(Samplers::new(skin, dir.clone()));
        let overlays = Arc::new(SharedOverlays::new(skin, dir.clone()));
        Site { skin: skin.to_owned(), dir, shutdown, samplers, overlays, geometry: Arc::default() }
    }
}

fn is_timeout(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::Io(e)
        if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut))
}

fn is_closed(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed)
}

/// Serves one browser until it leaves or the viewer shuts down.
pub fn run(mut socket: WebSocket<BrowserStream>, site: &Site) -> Result<()> {
    let layers = send_geometry(&mut socket, site)?;
    let mut session = Session::start(socket, site, layers)?;
    loop {
        if site.shutdown.load(Ordering::Relaxed) {
            close(&mut session.socket);
            return Ok(());
        }
        if session.read_browser()?.is_break() {
            return Ok(());
        }
        if session.credit == 0 || session.pacing.until_due(Instant::now()).is_some() {
            continue;
        }
        if session.send_update()?.is_break() {
            return Ok(());
        }
    }
}

/// Closes the WebSocket, ignoring a browser that is already gone.
fn close(socket: &mut WebSocket<BrowserStream>) {
    let _ = socket.close(None);
    let _ = socket.flush();
}

/// Sends the skin's geometry, or the error that the page shows instead of a
/// map; returns the layers to read.
fn send_geometry(socket: &mut WebSocket<BrowserStream>, site: &Site) -> Result<Vec<LayerToRead>> {
    let dir = site.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
    // The page shows the wait where it shows errors, until the geometry comes.
    let waiting = format!("waiting up to {} s for skin {}'s geometry", GEOMETRY_WAIT.as_secs(), site.skin);
    let found = site.geometry.get_waiting(&dir, &site.skin, GEOMETRY_WAIT, &site.shutdown, || {
        let _ = socket.send(Message::text(serde_json::json!({ "error": waiting }).to_string()));
    });
    let geometry = match found {
        Ok(geometry) => geometry,
        Err(e) => {
            // The page shows this text instead of a map.
            let text = serde_json::json!({ "error": e.to_string() }).to_string();
            socket.send(Message::text(text))?;
            close(socket);
            return Err(e.into());
        }
    };
    // From the shared message, without a copy for each browser.
    let header = WebSocketHeader::binary(geometry.message.len());
    send_message(socket, &mut [IoSlice::new(header.bytes()), IoSlice::new(&geometry.message)])
        .context("cannot send the geometry")?;
    Ok(geometry.layers.clone())
}

/// The state of one browser's connection after the geometry was sent.
struct Session<'a> {
    socket: WebSocket<BrowserStream>,
    site: &'a Site,
    layers: Vec<LayerToRead>,
    mode: ReadMode,
    sampler: Arc<Sampler>,
    /// Updates the browser will still accept before it acknowledges more.
    credit: u32,
    /// The board version of the last update sent.
    seen_version: u64,
    /// Per layer, the sequence number of the last responses sent.
    sent_seq: Vec<u64>,
    /// Updates sent so far: the number of the next one.
    updates_sent: u32,
    /// The update being sent: per layer, the slot taken from the board
    /// (whose responses it shares) and whether its responses go along;
    /// emptied once encoded, so that the layers' readers write in place again.
    update: Vec<LayerUpdate>,
    /// The update being sent, encoded: reused between updates, so that
    /// encoding one allocates nothing once it has grown to an update's size.
    message: Vec<u8>,
    /// The read timeout the socket has now, to set it only when it changes.
    poll: Option<Duration>,
    /// The overlays its updates carry, polled with new frames only.
    overlays: HeldOverlays,
    /// Each layer's sensor type, as an index: layers of one type share a colour range.
    type_of: Vec<usize>,
    /// The layers' colour ranges in the update being sent, shared by type,
    /// and the types' ranges (kept between updates).
    ranges: (Vec<Option<ResponseRange>>, Vec<Option<ResponseRange>>),
    /// When its next update is due.
    pacing: Pacing,
    /// A wait for the browser just ended with a message: the update it
    /// made due goes without a read that would find nothing first.
    just_spoke: bool,
}

impl<'a> Session<'a> {
    fn start(socket: WebSocket<BrowserStream>, site: &'a Site, layers: Vec<LayerToRead>) -> Result<Session<'a>> {
        let mode = INITIAL_MODE;
        let sampler = site.samplers.subscribe(&layers, mode).context("cannot start the layer readers")?;
        Ok(Session {
            socket,
            site,
            mode,
            sampler,
            credit: 0,
            seen_version: 0,
            sent_seq: vec![0u64; layers.len()],
            updates_sent: 0,
            update: Vec::with_capacity(layers.len()),
            message: Vec::new(),
            poll: None,
            overlays: HeldOverlays::default(),
            type_of: types_of(&layers),
            ranges: (Vec::with_capacity(layers.len()), Vec::new()),
            pacing: Pacing::default(),
            just_spoke: false,
            layers,
        })
    }

    /// What the browser said since the last update: waiting for it (at most
    /// [`IDLE_POLL`]) only while there is no credit or no update is due yet,
    /// and never once it has spoken. With credit the board, not the
    /// browser, is what we wait for: a read that slept would cost a wake-up
    /// per update, which at 1 kHz is most of what a browser costs. A wait
    /// ends with the first message, and the call right after it takes only
    /// what tungstenite already holds (a request sent along with the
    /// acknowledgement, say), without asking the socket: what arrived later
    /// is read by the next wait, right after the update, so that an
    /// acknowledgement costs no read that finds nothing (one system call
    /// per update). Breaks when the browser left.
    fn read_browser(&mut self) -> Result<ControlFlow<()>> {
        // One timeout for every wait, so that it is set once: an update due
        // without an acknowledgement may go up to IDLE_POLL late.
        let wait = self.credit == 0 || self.pacing.until_due(Instant::now()).is_some();
        if wait && self.poll != Some(IDLE_POLL) {
            self.socket.get_mut().stream.set_read_timeout(Some(IDLE_POLL))?;
            self.poll = Some(IDLE_POLL);
        }
        let just_spoke = std::mem::take(&mut self.just_spoke);
        self.socket.get_mut().reads = match (wait, just_spoke) {
            (true, _) => Reads::Wait,
            (false, true) => Reads::BufferedOnly,
            (false, false) => Reads::DontWait,
        };
        loop {
            match self.socket.read() {
                Ok(Message::Text(text)) => match message::decode(text.as_str()) {
                    Ok(message) => self.obey(message)?,
                    Err(e) => tracing::warn!("browser message ignored: {e}"),
                },
                Ok(Message::Close(_)) => return Ok(ControlFlow::Break(())),
                Ok(_) => {}
                Err(e) if is_timeout(&e) => return Ok(ControlFlow::Continue(())),
                Err(e) if is_closed(&e) => return Ok(ControlFlow::Break(())),
                Err(e) => return Err(e.into()),
            }
            if wait {
                self.just_spoke = true;
                return Ok(ControlFlow::Continue(()));
            }
        }
    }

    /// Acts on one message of the browser.
    fn obey(&mut self, message: ClientMessage) -> Result<()> {
        match message {
            ClientMessage::Ack(n) => {
                self.credit = self.credit.saturating_add(n).min(MAX_CREDIT);
                self.pacing.acknowledged(Instant::now());
            }
            ClientMessage::Mode(new_mode) => {
                if new_mode != self.mode {
                    self.mode = new_mode;
                    // The old sampler stops when its last browser leaves it.
                    self.sampler = self
                        .site
                        .samplers
                        .subscribe(&self.layers, self.mode)
                        .context("cannot start the layer readers")?;
                    self.seen_version = 0;
                    tracing::debug!(mode = ?self.mode, "reader mode changed");
                }
            }
            ClientMessage::Request => self.sampler.request(),
        }
        Ok(())
    }

    /// Sends the newest frames, if anything changed since the last update
    /// (waiting up to [`IDLE_POLL`] for a change). Breaks when the browser left.
    fn send_update(&mut self) -> Result<ControlFlow<()>> {
        let (update, sent_seq) = (&mut self.update, &mut self.sent_seq);
        // Under the board's lock only long enough to share each layer's
        // responses: the encoding and the write happen after.
        let taken = self.sampler.take_newer(self.seen_version, IDLE_POLL, |board| {
            update.clear();
            update.extend(board.layers.iter().zip(sent_seq).map(|(slot, sent)| {
                let with_responses = slot.seq != 0 && slot.seq != *sent;
                *sent = slot.seq;
                LayerUpdate { slot: slot.clone(), with_responses }
            }));
            board.version
        });
        let Some(version) = taken else {
            return Ok(ControlFlow::Continue(()));
        };
        self.share_ranges_by_type();
        self.pacing.sent(Instant::now());
        self.seen_version = version;
        // After the board's lock: a poll may search the segment directory.
        let fresh_frames = self.update.iter().any(|layer| layer.with_responses);
        let any_running = self.update.iter().any(|layer| layer.slot.state == Some(skinware::WriterState::Running));
        let shared = &self.site.overlays;
        let overlays = self.overlays.for_update(fresh_frames, any_running, || shared.poll());
        // The responses in the compact encoding, less than half their raw
        // bytes: 6-10 µs per board of the paper's skin in a release build,
        // paid once per frame by the first session that sends it; the
        // others copy its bytes (docs/viewer.md).
        protocol::encode_update(&mut self.message, self.updates_sent, self.mode, &self.update, overlays);
        // Let go of the board's buffers before the write, which may block
        // on a slow browser: the layers' readers then write in place again.
        self.update.clear();
        self.updates_sent = self.updates_sent.wrapping_add(1);
        self.credit -= 1;
        let header = WebSocketHeader::binary(self.message.len());
        let mut parts = [IoSlice::new(header.bytes()), IoSlice::new(&self.message)];
        let sent = send_message(&mut self.socket, &mut parts);
        match sent {
            Ok(()) => Ok(ControlFlow::Continue(())),
            Err(e) if is_closed(&e) => Ok(ControlFlow::Break(())),
            Err(e) => Err(e.into()),
        }
    }
}

/// Each layer's sensor type as an index (the first layer's type is 0, the
/// next other type 1, ...).
fn types_of(layers: &[LayerToRead]) -> Vec<usize> {
    let mut types: Vec<&str> = Vec::new();
    layers
        .iter()
        .map(|layer| {
            types.iter().position(|&t| t == layer.sensor_type).unwrap_or_else(|| {
                types.push(&layer.sensor_type);
                types.len() - 1
            })
        })
        .collect()
}

impl Session<'_> {
    /// Gives each layer of the update being sent the colour range of its
    /// sensor type ([`range::share_by_type`]).
    fn share_ranges_by_type(&mut self) {
        let (ranges, scratch) = &mut self.ranges;
        ranges.clear();
        ranges.extend(self.update.iter().map(|layer| layer.slot.range));
        range::share_by_type(ranges, &self.type_of, scratch);
        for (layer, range) in self.update.iter_mut().zip(ranges.iter()) {
            layer.slot.range = *range;
        }
    }
}

/// The header of one unmasked, unfragmented WebSocket message (RFC 6455,
/// 5.2), as a server sends it.
pub struct WebSocketHeader {
    bytes: [u8; 10],
    len: usize,
}

impl WebSocketHeader {
    /// The header of a binary message of `payload` bytes.
    pub fn binary(payload: usize) -> WebSocketHeader {
        const FIN_BINARY: u8 = 0x82;
        let mut bytes = [0; 10];
        bytes[0] = FIN_BINARY;
        let len = match payload {
            0..=125 => {
                bytes[1] = payload as u8;
                2
            }
            126..=0xFFFF => {
                bytes[1] = 126;
                bytes[2..4].copy_from_slice(&(payload as u16).to_be_bytes());
                4
            }
            _ => {
                bytes[1] = 127;
                bytes[2..10].copy_from_slice(&(payload as u64).to_be_bytes());
                10
            }
        };
        WebSocketHeader { bytes, len }
    }

    /// The header's bytes, to go before the payload.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Writes one WebSocket message, its header first, from where its parts
/// are: tungstenite's `send` would copy a 62 KB update into its own buffer
/// first, for every browser. What tungstenite has queued (a pong, a close)
/// goes before it.
pub fn send_message(socket: &mut WebSocket<BrowserStream>, parts: &mut [IoSlice<'_>]) -> tungstenite::Result<()> {
    if !socket.can_write() {
        return Err(tungstenite::Error::AlreadyClosed);
    }
    socket.flush()?;
    let stream = &socket.get_mut().stream;
    let mut parts = parts;
    while !parts.is_empty() {
        // NOSIGNAL: a browser that left is an error here, not a SIGPIPE.
        match rustix::net::sendmsg(
            stream,
            parts,
            &mut rustix::net::SendAncillaryBuffer::default(),
            rustix::net::SendFlags::NOSIGNAL,
        ) {
            Ok(0) => return Err(tungstenite::Error::Io(std::io::ErrorKind::WriteZero.into())),
            Ok(written) => IoSlice::advance_slices(&mut parts, written),
            Err(rustix::io::Errno::INTR) => {}
            Err(e) => return Err(tungstenite::Error::Io(e.into())),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// After the acknowledgement that made an update due, the session reads
    /// only what tungstenite already holds: a message that came in the same
    /// segment is handled at once, and a later one stays in the socket
    /// (no system call) until a read that asks the socket.
    #[test]
    fn buffered_only_reads_return_what_tungstenite_holds_and_leave_the_socket_alone() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let client = TcpStream::connect(listener.local_addr().unwrap()).unwrap();
        let (server, _) = listener.accept().unwrap();
        server.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut server =
            WebSocket::from_raw_socket(BrowserStream::new(server), tungstenite::protocol::Role::Server, None);
        let mut client = WebSocket::from_raw_socket(client, tungstenite::protocol::Role::Client, None);
        // Two messages in one segment, as a page sends an acknowledgement and a request together.
        client.write(Message::text(r#"{"ack":1}"#)).unwrap();
        client.write(Message::text(r#"{"request":true}"#)).unwrap();
        client.flush().unwrap();
        let mut peeked = [0u8; 64];
        let both = loop {
            let (bytes, _) =
                rustix::net::recv(&server.get_ref().stream, &mut peeked, rustix::net::RecvFlags::PEEK).unwrap();
            if bytes >= 2 * 6 + 9 + 16 {
                break bytes;
            }
        };
        assert_eq!(both, 2 * 6 + 9 + 16, "two masked text frames");
        assert!(matches!(server.read().unwrap(), Message::Text(t) if t.as_str() == r#"{"ack":1}"#));
        server.get_mut().reads = Reads::BufferedOnly;
        assert!(matches!(server.read().unwrap(), Message::Text(t) if t.as_str() == r#"{"request":true}"#));
        assert!(matches!(server.read(), Err(e) if is_timeout(&e)), "nothing more is buffered");
        client.send(Message::text(r#"{"ack":2}"#)).unwrap();
        std::thread::sleep(Duration::from_millis(50));
        assert!(matches!(server.read(), Err(e) if is_timeout(&e)), "the socket is not asked");
        server.get_mut().reads = Reads::DontWait;
        assert!(matches!(server.read().unwrap(), Message::Text(t) if t.as_str() == r#"{"ack":2}"#));
        assert!(matches!(server.read(), Err(e) if is_timeout(&e)), "the socket is empty");
    }

    /// A message written in parts, with a header of each of the three
    /// lengths, is what a WebSocket client reads, after a pong that
    /// tungstenite queued.
    #[test]
    fn messages_written_in_parts_are_what_a_client_reads() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let client = TcpStream::connect(listener.local_addr().unwrap()).unwrap();
        let (server, _) = listener.accept().unwrap();
        let mut server =
            WebSocket::from_raw_socket(BrowserStream::new(server), tungstenite::protocol::Role::Server, None);
        let mut client = WebSocket::from_raw_socket(client, tungstenite::protocol::Role::Client, None);
        client.send(Message::Ping(vec![7u8].into())).unwrap();
        assert!(matches!(server.read().unwrap(), Message::Ping(_)));
        let payload: Vec<u8> = (0..70_000u32).map(|i| (i * 31 % 251) as u8).collect();
        for length in [3, 125, 126, 200, 65_535, 65_536, 70_000] {
            let message = &payload[..length];
            let (first, rest) = message.split_at(length / 3);
            let (second, third) = rest.split_at(rest.len() / 2);
            let header = WebSocketHeader::binary(length);
            let mut parts = [header.bytes(), first, second, third].map(IoSlice::new);
            send_message(&mut server, &mut parts).unwrap();
        }
        assert!(matches!(client.read().unwrap(), Message::Pong(data) if data.as_ref() == [7]));
        for length in [3, 125, 126, 200, 65_535, 65_536, 70_000] {
            match client.read().unwrap() {
                Message::Binary(data) => assert_eq!(data.as_ref(), &payload[..length], "{length} bytes"),
                other => panic!("expected a binary message of {length} bytes, got {other:?}"),
            }
        }
    }

    /// Browsers get the geometry encoded once while its file stays the
    /// same, the new one as soon as it is published again, and the
    /// library's error when it is missing.
    #[test]
    fn the_geometry_is_encoded_once_per_published_file() {
        let dir = std::env::temp_dir().join(format!("skin-geometry-cache-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cache = GeometryCache::default();
        let missing = cache.get(&dir, "cached").unwrap_err();
        assert!(matches!(missing, skinware_geometry::GeometryError::Missing { .. }), "{missing}");

        let first = crate::virtual_geometry("cached", 240);
        first.publish(&dir).unwrap();
        let encoded = cache.get(&dir, "cached").unwrap();
        assert_eq!(encoded.message, protocol::encode_geometry(&first));
        assert_eq!(encoded.layers.iter().map(|l| l.sensors).collect::<Vec<_>>(), [120, 120]);
        assert!(Arc::ptr_eq(&encoded, &cache.get(&dir, "cached").unwrap()), "the same file is not read again");

        let second = crate::virtual_geometry("cached", 480);
        second.publish(&dir).unwrap();
        let again = cache.get(&dir, "cached").unwrap();
        assert_eq!(again.message, protocol::encode_geometry(&second), "a geometry published again is read again");
        assert_eq!(again.layers.iter().map(|l| l.sensors).collect::<Vec<_>>(), [240, 240]);
        // A restarted `skin run` publishes a file of the same length: a new
        // one all the same (renamed into place), so it is read again.
        second.publish(&dir).unwrap();
        assert!(!Arc::ptr_eq(&again, &cache.get(&dir, "cached").unwrap()), "the same bytes in a new file");

        std::fs::write(SkinGeometry::published_path(&dir, "cached"), b"not a geometry").unwrap();
        let corrupt = cache.get(&dir, "cached").unwrap_err();
        assert!(matches!(corrupt, skinware_geometry::GeometryError::Corrupt { .. }), "{corrupt}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A geometry published while a connection waits is the one it gets; a
    /// wait says so once, ends at its bound or at shutdown with the
    /// library's error, and does not hold up a corrupt file's.
    #[test]
    fn a_missing_geometry_is_waited_for_a_bounded_time() {
        let dir = std::env::temp_dir().join(format!("skin-geometry-wait-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (cache, running) = (GeometryCache::default(), AtomicBool::new(false));
        let mut said = 0;
        let publisher = {
            let dir = dir.clone();
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(200));
                crate::virtual_geometry("late", 240).publish(&dir).unwrap();
            })
        };
        let found = cache.get_waiting(&dir, "late", Duration::from_secs(60), &running, || said += 1).unwrap();
        publisher.join().unwrap();
        assert_eq!(found.layers.len(), 2);
        assert_eq!(said, 1, "the wait is said once");

        let mut said = 0;
        let never = cache.get_waiting(&dir, "never", Duration::from_millis(100), &running, || said += 1);
        assert!(matches!(never, Err(skinware_geometry::GeometryError::Missing { .. })));
        assert_eq!(said, 1);
        let stopping = AtomicBool::new(true);
        let stopped = cache.get_waiting(&dir, "never", Duration::from_secs(3600), &stopping, || {});
        assert!(matches!(stopped, Err(skinware_geometry::GeometryError::Missing { .. })), "shutdown ends the wait");

        std::fs::write(SkinGeometry::published_path(&dir, "bad"), b"not a geometry").unwrap();
        let mut said = 0;
        let corrupt = cache.get_waiting(&dir, "bad", Duration::from_secs(3600), &running, || said += 1);
        assert!(matches!(corrupt, Err(skinware_geometry::GeometryError::Corrupt { .. })));
        assert_eq!(said, 0, "only a missing geometry is waited for");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A browser receives the cached geometry, sent in parts from the shared
    /// message, as the one WebSocket message the page decodes, and the
    /// session reads the layers it lists.
    #[test]
    fn a_browser_receives_the_geometry_whole() {
        let dir = std::env::temp_dir().join(format!("skin-geometry-send-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let geometry = crate::virtual_geometry("sent", 4_000);
        geometry.publish(&dir).unwrap();
        let site = Site::new("sent", Some(dir.clone()), Arc::new(AtomicBool::new(false)));
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let client = TcpStream::connect(listener.local_addr().unwrap()).unwrap();
        let (server, _) = listener.accept().unwrap();
        let reader = std::thread::spawn(move || {
            let mut client = WebSocket::from_raw_socket(client, tungstenite::protocol::Role::Client, None);
            client.read().unwrap()
        });
        let mut server =
            WebSocket::from_raw_socket(BrowserStream::new(server), tungstenite::protocol::Role::Server, None);
        let layers = send_geometry(&mut server, &site).unwrap();
        assert_eq!(
            layers.iter().map(|l| (l.name.as_str(), l.sensors)).collect::<Vec<_>>(),
            [("v-0", 2_000), ("v-1", 2_000)]
        );
        match reader.join().unwrap() {
            Message::Binary(bytes) => assert!(bytes.as_ref() == protocol::encode_geometry(&geometry).as_slice()),
            other => panic!("expected the geometry, got {other:?}"),
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// One update per acknowledgement, at once; without acknowledgements,
    /// one per frame interval, which the acknowledgements teach.
    #[test]
    fn updates_go_once_per_acknowledged_frame() {
        let start = Instant::now();
        let at = |ms: f64| start + Duration::from_secs_f64(ms / 1e3);
        let mut pacing = Pacing::default();
        assert_eq!(pacing.until_due(at(0.0)), None, "the first update goes at once");
        pacing.sent(at(0.0));
        let wait = pacing.until_due(at(1.0)).expect("a second waits");
        assert!((wait.as_secs_f64() * 1e3 - 24.0).abs() < 0.01, "{wait:?}");
        for frame in 1..=4 {
            pacing.acknowledged(at(16.667 * f64::from(frame)));
            assert_eq!(pacing.until_due(at(16.667 * f64::from(frame))), None, "at once after an acknowledgement");
            pacing.sent(at(16.667 * f64::from(frame) + 0.1));
        }
        assert!(pacing.until_due(at(70.0)).is_some(), "one update per frame");
        assert_eq!(pacing.until_due(at(66.768 + 25.001)), None, "a frame without acknowledgement: the next");

        let mut slow = Pacing::default();
        for tick in 1..=5 {
            slow.acknowledged(at(200.0 * f64::from(tick)));
        }
        slow.sent(at(1000.0));
        let wait = slow.until_due(at(1000.0)).unwrap();
        assert!((wait.as_secs_f64() * 1e3 - 300.0).abs() < 0.01, "{wait:?}");
    }
}
