//! One browser: the geometry at connect, then updates as the browser grants
//! credit. The browser acknowledges each update it has drawn; the server never
//! has more than [`MAX_CREDIT`] updates unacknowledged, and each update holds
//! the newest frames at the moment it is sent, so a slow browser gets fewer,
//! fresher updates instead of a growing queue.

#![forbid(unsafe_code)]

use std::net::TcpStream;
use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};
use skin::viewer_message::{self, ClientMessage, ReadMode};
use skinware_geometry::SkinGeometry;
use tungstenite::{Message, WebSocket};

use super::overlays::OverlaySource;
use super::protocol::{self, LayerUpdate};
use super::sampler::{LayerToRead, Sampler, Samplers};

/// Updates the server may send ahead of the browser's acknowledgements.
const MAX_CREDIT: u32 = 4;
/// How long to wait for the browser when it has no credit left.
const IDLE_POLL: Duration = Duration::from_millis(20);
/// How long to look at the socket between updates when there is credit.
const BUSY_POLL: Duration = Duration::from_millis(1);
/// The mode a new browser starts in.
const INITIAL_MODE: ReadMode = ReadMode::Asap;

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
        let samplers = Arc::new(Samplers::new(skin, dir.clone()));
        Site { skin: skin.to_owned(), dir, shutdown, samplers }
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
pub fn run(mut socket: WebSocket<TcpStream>, site: &Site) -> Result<()> {
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
        if session.credit == 0 {
            continue;
        }
        if session.send_update()?.is_break() {
            return Ok(());
        }
    }
}

/// Closes the WebSocket, ignoring a browser that is already gone.
fn close(socket: &mut WebSocket<TcpStream>) {
    let _ = socket.close(None);
    let _ = socket.flush();
}

/// Sends the skin's geometry, or the error that the page shows instead of a
/// map; returns the layers to read.
fn send_geometry(socket: &mut WebSocket<TcpStream>, site: &Site) -> Result<Vec<LayerToRead>> {
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

/// The state of one browser's connection after the geometry was sent.
struct Session<'a> {
    socket: WebSocket<TcpStream>,
    site: &'a Site,
    layers: Vec<LayerToRead>,
    mode: ReadMode,
    sampler: Arc<Sampler>,
    overlays: OverlaySource,
    /// Updates the browser will still accept before it acknowledges more.
    credit: u32,
    /// The board version of the last update sent.
    seen_version: u64,
    /// Per layer, the sequence number of the last responses sent.
    sent_seq: Vec<u64>,
    /// Updates sent so far: the number of the next one.
    updates_sent: u32,
    /// The update being encoded, reused between updates.
    message: Vec<u8>,
    /// The read timeout the socket has now, to set it only when it changes.
    poll: Option<Duration>,
}

impl<'a> Session<'a> {
    fn start(socket: WebSocket<TcpStream>, site: &'a Site, layers: Vec<LayerToRead>) -> Result<Session<'a>> {
        let mode = INITIAL_MODE;
        let sampler = site.samplers.subscribe(&layers, mode).context("cannot start the layer readers")?;
        Ok(Session {
            socket,
            site,
            mode,
            sampler,
            overlays: OverlaySource::new(&site.skin),
            credit: 0,
            seen_version: 0,
            sent_seq: vec![0u64; layers.len()],
            updates_sent: 0,
            message: Vec::new(),
            poll: None,
            layers,
        })
    }

    /// Everything the browser said since the last update: waiting for it
    /// only while there is no credit, and not at all once it has spoken.
    /// Breaks when the browser left.
    fn read_browser(&mut self) -> Result<ControlFlow<()>> {
        let mut wanted = if self.credit > 0 { BUSY_POLL } else { IDLE_POLL };
        loop {
            if self.poll != Some(wanted) {
                self.socket.get_mut().set_read_timeout(Some(wanted))?;
                self.poll = Some(wanted);
            }
            wanted = BUSY_POLL;
            match self.socket.read() {
                Ok(Message::Text(text)) => match viewer_message::decode(text.as_str()) {
                    Ok(message) => self.obey(message)?,
                    Err(e) => tracing::warn!("browser message ignored: {e}"),
                },
                Ok(Message::Close(_)) => return Ok(ControlFlow::Break(())),
                Ok(_) => {}
                Err(e) if is_timeout(&e) => return Ok(ControlFlow::Continue(())),
                Err(e) if is_closed(&e) => return Ok(ControlFlow::Break(())),
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Acts on one message of the browser.
    fn obey(&mut self, message: ClientMessage) -> Result<()> {
        match message {
            ClientMessage::Ack(n) => self.credit = self.credit.saturating_add(n).min(MAX_CREDIT),
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
        // Outside the board's lock: it may search the segment directory.
        let newest_overlays = self.overlays.poll();
        let (sent_seq, message, updates_sent, mode) =
            (&mut self.sent_seq, &mut self.message, self.updates_sent, self.mode);
        let taken = self.sampler.take_newer(self.seen_version, IDLE_POLL, |board| {
            let updates: Vec<LayerUpdate<'_>> = board
                .layers
                .iter()
                .zip(sent_seq)
                .map(|(slot, sent)| {
                    let changed = slot.seq != 0 && slot.seq != *sent;
                    *sent = slot.seq;
                    LayerUpdate { slot, with_responses: changed }
                })
                .collect();
            protocol::encode_update(message, updates_sent, mode, &updates, &newest_overlays);
            board.version
        });
        if let Some(version) = taken {
            self.seen_version = version;
            self.updates_sent = self.updates_sent.wrapping_add(1);
            self.credit -= 1;
            match self.socket.send(Message::binary(std::mem::take(&mut self.message))) {
                Ok(()) => {}
                Err(e) if is_closed(&e) => return Ok(ControlFlow::Break(())),
                Err(e) => return Err(e.into()),
            }
        }
        Ok(ControlFlow::Continue(()))
    }
}
