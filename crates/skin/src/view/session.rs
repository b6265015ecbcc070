//! One browser: the geometry at connect, then updates as the browser grants
//! credit. The browser acknowledges each update it has drawn; the server never
//! has more than [`MAX_CREDIT`] updates unacknowledged, and each update holds
//! the newest frames at the moment it is sent, so a slow browser gets fewer,
//! fresher updates instead of a growing queue.
//!
//! The updates are sent by the dispatcher of the browser's sampler
//! ([`super::browsers`]), not by a thread of the browser's own: a thread per
//! browser woke for every acknowledgement, which was most of what a browser
//! cost. The browser's thread does only what may wait.

#![forbid(unsafe_code)]

use std::io::IoSlice;
use std::net::TcpStream;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, TryLockError};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use skin::viewer_message::{self, ClientMessage, ReadMode};
use skinware_geometry::SkinGeometry;
use tungstenite::{Message, WebSocket};

use super::overlays::{Overlays, SharedOverlays};
use super::protocol::{self, LayerUpdate};
use super::sampler::{LayerSlot, LayerToRead, Sampler, Samplers};

/// Updates the server may send ahead of the browser's acknowledgements.
const MAX_CREDIT: u32 = 4;
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
/// A browser's TCP connection, whose reads and writes each wait (reads up to
/// the socket's read timeout) only when asked to, and otherwise return
/// `WouldBlock` at once: the dispatcher that serves every browser of a
/// sampler must never wait for one of them.
#[derive(Debug)]
pub struct BrowserStream {
    /// The connection.
    pub stream: TcpStream,
    /// Whether the next reads may wait for data.
    pub wait_for_reads: bool,
    /// Whether the next writes may wait for the browser to take data.
    pub wait_for_writes: bool,
}

impl BrowserStream {
    /// A connection whose reads and writes wait.
    pub fn new(stream: TcpStream) -> BrowserStream {
        BrowserStream { stream, wait_for_reads: true, wait_for_writes: true }
    }
}

impl std::io::Read for BrowserStream {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        if self.wait_for_reads {
            return self.stream.read(buffer);
        }
        rustix::net::recv(&self.stream, buffer, rustix::net::RecvFlags::DONTWAIT)
            .map(|(read, _)| read)
            .map_err(std::io::Error::from)
    }
}

impl std::io::Write for BrowserStream {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        if self.wait_for_writes {
            return self.stream.write(bytes);
        }
        rustix::net::send(&self.stream, bytes, rustix::net::SendFlags::DONTWAIT | rustix::net::SendFlags::NOSIGNAL)
            .map_err(std::io::Error::from)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

/// The mode a new browser starts in.
const INITIAL_MODE: ReadMode = ReadMode::Asap;
/// How often a browser's own thread looks at the shutdown flag while the
/// dispatcher serves the browser.
const SHUTDOWN_POLL: Duration = Duration::from_millis(250);

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
}

impl Site {
    /// The site of `skin` (segments in `dir`, or the default directory).
    pub fn new(skin: &str, dir: Option<PathBuf>, shutdown: Arc<AtomicBool>) -> Site {
        let overlays = Arc::new(SharedOverlays::new(skin, dir.clone()));
        let samplers = Arc::new(Samplers::new(skin, dir.clone(), overlays));
        Site { skin: skin.to_owned(), dir, shutdown, samplers }
    }
}

fn is_timeout(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::Io(e)
        if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut))
}

/// Serves one browser until it leaves or the viewer shuts down: sends the
/// geometry, then hands the browser to its sampler's dispatcher, which
/// reads its acknowledgements and sends its updates without this thread.
/// This thread does only what may wait: a mode change (which may start
/// readers), the rest of an update a slow browser did not take at once,
/// and the close.
pub fn run(mut socket: WebSocket<BrowserStream>, site: &Site) -> Result<()> {
    let layers = send_geometry(&mut socket, site)?;
    let mut sampler = site.samplers.subscribe(&layers, INITIAL_MODE).context("cannot start the layer readers")?;
    let browser = Arc::new(Browser::new(socket, layers.len(), INITIAL_MODE));
    sampler.browsers().add(&browser).context("cannot watch the browser's connection")?;
    let served = attend(&browser, &mut sampler, &layers, site);
    sampler.browsers().remove(&browser);
    served
}

/// Waits for what the dispatcher leaves to this thread, and does it.
fn attend(browser: &Arc<Browser>, sampler: &mut Arc<Sampler>, layers: &[LayerToRead], site: &Site) -> Result<()> {
    loop {
        let mut connection = browser.lock();
        while !connection.wants_its_thread() && !site.shutdown.load(Ordering::Relaxed) {
            connection = browser
                .attention
                .wait_timeout(connection, SHUTDOWN_POLL)
                .unwrap_or_else(|poisoned| poisoned.into_inner())
                .0;
        }
        if site.shutdown.load(Ordering::Relaxed) {
            close(&mut connection.socket);
            return Ok(());
        }
        if connection.left {
            return Ok(());
        }
        if connection.unsent.is_some() {
            match connection.finish_update() {
                Ok(()) => {}
                Err(e) if is_closed(&e) => return Ok(()),
                Err(e) => return Err(e.into()),
            }
        }
        if let Some(mode) = connection.new_mode.take() {
            connection.mode = mode;
            connection.seen_version = 0;
            drop(connection);
            let moved = site.samplers.subscribe(layers, mode).context("cannot start the layer readers")?;
            sampler.browsers().remove(browser);
            // The old sampler stops here if this was its last browser.
            *sampler = moved;
            sampler.browsers().add(browser).context("cannot watch the browser's connection")?;
            tracing::debug!(?mode, "reader mode changed");
        }
    }
}

fn is_closed(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed)
        || matches!(error, tungstenite::Error::Io(e) if matches!(e.kind(),
            std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset | std::io::ErrorKind::ConnectionAborted))
}

/// Closes the WebSocket, ignoring a browser that is already gone.
fn close(socket: &mut WebSocket<BrowserStream>) {
    socket.get_mut().wait_for_writes = true;
    let _ = socket.close(None);
    let _ = socket.flush();
}

/// Sends the skin's geometry, or the error that the page shows instead of a
/// map; returns the layers to read.
fn send_geometry(socket: &mut WebSocket<BrowserStream>, site: &Site) -> Result<Vec<LayerToRead>> {
    let dir = site.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
    let geometry = match SkinGeometry::open_in(&dir, &site.skin) {
        Ok(geometry) => geometry,
        Err(e) => {
            // The page shows this text instead of a map.
            let text = serde_json::json!({ "error": e.to_string() }).to_string();
            socket.send(Message::text(text))?;
            close(socket);
            return Err(e.into());
        }
    };
    socket.send(Message::binary(protocol::encode_geometry(&geometry))).context("cannot send the geometry")?;
    let layers =
        geometry.layers.iter().map(|l| LayerToRead { name: l.name.clone(), sensors: l.sensors.len() }).collect();
    Ok(layers)
}

/// One browser, shared by its own thread and the dispatcher of the sampler
/// it reads from: whoever holds the connection serves it, and the
/// dispatcher only ever tries the lock, so that a browser its thread is
/// busy with never holds up the others.
#[derive(Debug)]
pub struct Browser {
    connection: Mutex<Connection>,
    /// Signalled when the browser needs its own thread ([`Connection::wants_its_thread`]).
    attention: Condvar,
    /// The browser's key in its dispatcher's epoll set.
    pub key: u64,
}

static NEXT_BROWSER_KEY: AtomicU64 = AtomicU64::new(1);

impl Browser {
    /// The browser at the other end of `socket`, which has been sent the
    /// geometry of `layers` layers, reading in `mode`.
    pub fn new(socket: WebSocket<BrowserStream>, layers: usize, mode: ReadMode) -> Browser {
        Browser {
            connection: Mutex::new(Connection::new(socket, layers, mode)),
            attention: Condvar::new(),
            key: NEXT_BROWSER_KEY.fetch_add(1, Ordering::Relaxed),
        }
    }

    /// The connection, waiting for whoever serves it now.
    pub fn lock(&self) -> MutexGuard<'_, Connection> {
        // A thread that panicked serving the browser left whole values.
        self.connection.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }

    /// The connection if nobody serves it now.
    pub fn try_lock(&self) -> Option<MutexGuard<'_, Connection>> {
        match self.connection.try_lock() {
            Ok(connection) => Some(connection),
            Err(TryLockError::Poisoned(poisoned)) => Some(poisoned.into_inner()),
            Err(TryLockError::WouldBlock) => None,
        }
    }

    /// Wakes the browser's own thread (after [`Connection::wants_its_thread`] became true).
    pub fn call_its_thread(&self) {
        self.attention.notify_one();
    }
}

/// What one browser's connection holds between updates.
#[derive(Debug)]
pub struct Connection {
    socket: WebSocket<BrowserStream>,
    mode: ReadMode,
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
    /// emptied once sent, so that the layers' readers write in place again.
    update: Vec<LayerUpdate>,
    /// The head of the update being sent, reused between updates.
    head: Vec<u8>,
    /// Responses converted to little-endian, on a big-endian machine only.
    scratch: Vec<Vec<u8>>,
    /// When its next update is due.
    pacing: Pacing,
    /// Bytes written of an update the browser did not take all of at once
    /// (WebSocket header included); its own thread writes the rest, and no
    /// other update goes before.
    unsent: Option<usize>,
    /// The mode the browser asked for, which its own thread switches to.
    new_mode: Option<ReadMode>,
    /// The browser closed the connection, or it failed.
    pub left: bool,
}

/// What a browser said, as far as its dispatcher must act on it.
#[derive(Debug, Default)]
pub struct Heard {
    /// It asked for one frame of every layer (on-request mode).
    pub request: bool,
}

impl Connection {
    fn new(mut socket: WebSocket<BrowserStream>, layers: usize, mode: ReadMode) -> Connection {
        let stream = socket.get_mut();
        stream.wait_for_reads = false;
        stream.wait_for_writes = false;
        Connection {
            socket,
            mode,
            credit: 0,
            seen_version: 0,
            sent_seq: vec![0u64; layers],
            updates_sent: 0,
            update: Vec::with_capacity(layers),
            head: Vec::new(),
            scratch: vec![Vec::new(); layers],
            pacing: Pacing::default(),
            unsent: None,
            new_mode: None,
            left: false,
        }
    }

    /// The TCP connection, to watch it.
    pub fn stream(&self) -> &TcpStream {
        &self.socket.get_ref().stream
    }

    /// Whether something waits for the browser's own thread: the rest of
    /// an update, a mode change, or the end.
    pub fn wants_its_thread(&self) -> bool {
        self.unsent.is_some() || self.new_mode.is_some() || self.left
    }

    /// Reads everything the browser said, without waiting: acknowledgements
    /// grant credit; the rest is for the dispatcher or the browser's thread.
    pub fn read_messages(&mut self) -> Heard {
        let mut heard = Heard::default();
        while !self.left {
            match self.socket.read() {
                Ok(Message::Text(text)) => match viewer_message::decode(text.as_str()) {
                    Ok(ClientMessage::Ack(n)) => {
                        self.credit = self.credit.saturating_add(n).min(MAX_CREDIT);
                        self.pacing.acknowledged(Instant::now());
                    }
                    Ok(ClientMessage::Mode(mode)) => {
                        self.new_mode = (mode != self.mode).then_some(mode);
                    }
                    Ok(ClientMessage::Request) => heard.request = true,
                    Err(e) => tracing::warn!("browser message ignored: {e}"),
                },
                Ok(Message::Close(_)) => self.left = true,
                Ok(_) => {}
                Err(e) if is_timeout(&e) => break,
                Err(e) => {
                    if !is_closed(&e) {
                        tracing::debug!("browser connection failed: {e}");
                    }
                    self.left = true;
                }
            }
        }
        heard
    }

    /// The mode the browser asked for, which its own thread is to switch to.
    #[cfg(test)]
    pub fn mode_asked(&self) -> Option<ReadMode> {
        self.new_mode
    }

    /// Whether an update may go now, if the board has something new.
    pub fn ready_for_update(&self, now: Instant) -> bool {
        !self.wants_its_thread() && self.credit > 0 && self.pacing.until_due(now).is_none()
    }

    /// Whether the board at `version` has anything this browser was not sent.
    pub fn has_seen(&self, version: u64) -> bool {
        self.seen_version == version
    }

    /// Sends the board's `layers` at `version` with `overlays`, without
    /// waiting: what the browser does not take at once is left for its
    /// own thread ([`Connection::wants_its_thread`]).
    pub fn send_update(&mut self, version: u64, layers: &[LayerSlot], overlays: &Overlays) {
        self.update.clear();
        self.update.extend(layers.iter().zip(&mut self.sent_seq).map(|(slot, sent)| {
            let with_responses = slot.seq != 0 && slot.seq != *sent;
            *sent = slot.seq;
            LayerUpdate { slot: slot.clone(), with_responses }
        }));
        self.pacing.sent(Instant::now());
        self.seen_version = version;
        protocol::encode_update_head(&mut self.head, self.updates_sent, self.mode, &self.update, overlays);
        self.updates_sent = self.updates_sent.wrapping_add(1);
        self.credit -= 1;
        self.write_update(0, false);
    }

    /// Writes the rest of an update the browser did not take at once,
    /// waiting for it (a slow browser holds up only its own thread).
    pub fn finish_update(&mut self) -> tungstenite::Result<()> {
        let Some(written) = self.unsent.take() else { return Ok(()) };
        self.write_update(written, true);
        match self.left {
            true => Err(tungstenite::Error::ConnectionClosed),
            false => Ok(()),
        }
    }

    /// Writes `self.update` from byte `written` on, waiting for the browser
    /// or not; records what is left, or that the browser left.
    fn write_update(&mut self, written: usize, wait: bool) {
        let length = protocol::update_bytes(self.head.len(), &self.update);
        let header = WebSocketHeader::binary(length);
        let mut parts = Vec::with_capacity(2 + self.update.len());
        parts.push(IoSlice::new(header.bytes()));
        parts.push(IoSlice::new(&self.head));
        for (layer, scratch) in self.update.iter().zip(&mut self.scratch) {
            if let Some(responses) = layer.responses() {
                parts.push(IoSlice::new(protocol::responses_le(responses, scratch)));
            }
        }
        let message = header.bytes().len() + length;
        let mut parts = &mut parts[..];
        IoSlice::advance_slices(&mut parts, written);
        self.socket.get_mut().wait_for_writes = wait;
        let sent = send_message(&mut self.socket, parts, wait);
        self.socket.get_mut().wait_for_writes = false;
        match sent {
            Ok(now) if written + now == message => {
                self.unsent = None;
                self.update.clear();
            }
            Ok(now) => self.unsent = Some(written + now),
            Err(e) => {
                if !is_closed(&e) {
                    tracing::debug!("cannot send an update: {e}");
                }
                self.left = true;
                self.update.clear();
            }
        }
    }
}

/// The header of one unmasked, unfragmented WebSocket message (RFC 6455,
/// 5.2), as a server sends it.
struct WebSocketHeader {
    bytes: [u8; 10],
    len: usize,
}

impl WebSocketHeader {
    /// The header of a binary message of `payload` bytes.
    fn binary(payload: usize) -> WebSocketHeader {
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

    fn bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Writes one WebSocket message, its header first, from where its parts
/// are: tungstenite's `send` would copy a 62 KB update into its own buffer
/// first, for every browser. What tungstenite has queued (a pong, a close)
/// goes before it. Without `wait`, stops where the browser takes no more
/// for now; returns the bytes of `parts` written.
fn send_message(
    socket: &mut WebSocket<BrowserStream>,
    mut parts: &mut [IoSlice<'_>],
    wait: bool,
) -> tungstenite::Result<usize> {
    if !socket.can_write() {
        return Err(tungstenite::Error::AlreadyClosed);
    }
    match socket.flush() {
        Ok(()) => {}
        Err(e) if !wait && is_timeout(&e) => return Ok(0),
        Err(e) => return Err(e),
    }
    let stream = &socket.get_mut().stream;
    // NOSIGNAL: a browser that left is an error here, not a SIGPIPE.
    let flags = match wait {
        true => rustix::net::SendFlags::NOSIGNAL,
        false => rustix::net::SendFlags::NOSIGNAL | rustix::net::SendFlags::DONTWAIT,
    };
    let mut total = 0;
    while !parts.is_empty() {
        match rustix::net::sendmsg(stream, parts, &mut rustix::net::SendAncillaryBuffer::default(), flags) {
            Ok(0) => return Err(tungstenite::Error::Io(std::io::ErrorKind::WriteZero.into())),
            Ok(written) => {
                total += written;
                IoSlice::advance_slices(&mut parts, written);
            }
            Err(rustix::io::Errno::INTR) => {}
            Err(rustix::io::Errno::AGAIN) if !wait => break,
            Err(e) => return Err(tungstenite::Error::Io(e.into())),
        }
    }
    Ok(total)
}

#[cfg(test)]
mod tests {
    use super::*;

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
            assert_eq!(send_message(&mut server, &mut parts, true).unwrap(), header.bytes().len() + length);
        }
        assert!(matches!(client.read().unwrap(), Message::Pong(data) if data.as_ref() == [7]));
        for length in [3, 125, 126, 200, 65_535, 65_536, 70_000] {
            match client.read().unwrap() {
                Message::Binary(data) => assert_eq!(data.as_ref(), &payload[..length], "{length} bytes"),
                other => panic!("expected a binary message of {length} bytes, got {other:?}"),
            }
        }
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
