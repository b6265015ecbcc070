//! One browser: the geometry at connect, then updates as the browser grants
//! credit. The browser acknowledges each update it has drawn; the server never
//! has more than [`MAX_CREDIT`] updates unacknowledged, and each update holds
//! the newest frames at the moment it is sent, so a slow browser gets fewer,
//! fresher updates instead of a growing queue.

#![forbid(unsafe_code)]

use std::net::TcpStream;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result};
use skinware_geometry::SkinGeometry;
use tungstenite::{Message, WebSocket};

use super::overlays::OverlaySource;
use super::protocol::{self, ClientMessage, LayerUpdate};
use super::sampler::{LayerToRead, ReadMode, Sampler};

/// Updates the server may send ahead of the browser's acknowledgements.
const MAX_CREDIT: u32 = 4;
/// How long to wait for the browser when it has no credit left.
const IDLE_POLL: Duration = Duration::from_millis(20);
/// How long to look at the socket between updates when there is credit.
const BUSY_POLL: Duration = Duration::from_millis(1);
/// The mode a new browser starts in.
const INITIAL_MODE: ReadMode = ReadMode::Asap;

fn is_timeout(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::Io(e)
        if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut))
}

fn is_closed(error: &tungstenite::Error) -> bool {
    matches!(error, tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed)
}

/// What every connection needs to know.
#[derive(Clone, Debug)]
pub struct Site {
    /// The skin to show.
    pub skin: String,
    /// Segment directory; `None` for the default.
    pub dir: Option<PathBuf>,
    /// Set on SIGINT/SIGTERM: connections close and [`serve`] returns.
    pub shutdown: Arc<AtomicBool>,
}

/// Serves one browser until it leaves or the viewer shuts down.
pub fn run(mut socket: WebSocket<TcpStream>, site: &Site) -> Result<()> {
    let dir = site.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
    let geometry = match SkinGeometry::open_in(&dir, &site.skin) {
        Ok(geometry) => geometry,
        Err(e) => {
            // The page shows this text instead of a map.
            let text = serde_json::json!({ "error": e.to_string() }).to_string();
            socket.send(Message::text(text))?;
            let _ = socket.close(None);
            let _ = socket.flush();
            return Err(e.into());
        }
    };
    socket.send(Message::binary(protocol::encode_geometry(&geometry))).context("cannot send the geometry")?;
    let layers: Vec<LayerToRead> =
        geometry.layers.iter().map(|l| LayerToRead { name: l.name.clone(), sensors: l.sensors.len() }).collect();
    drop(geometry);

    let mut mode = INITIAL_MODE;
    let mut sampler =
        Sampler::start(&site.skin, site.dir.clone(), &layers, mode).context("cannot start the layer readers")?;
    let mut overlays = OverlaySource::new(&site.skin);
    let mut credit = 0u32;
    let mut seen_version = 0u64;
    let mut sent_seq = vec![0u64; layers.len()];
    let mut updates_sent = 0u32;
    let mut message = Vec::new();
    let mut poll = None;
    loop {
        if site.shutdown.load(Ordering::Relaxed) {
            let _ = socket.close(None);
            let _ = socket.flush();
            return Ok(());
        }
        // Everything the browser said since the last update: waiting for it
        // only while there is no credit, and not at all once it has spoken.
        let mut wanted = if credit > 0 { BUSY_POLL } else { IDLE_POLL };
        loop {
            if poll != Some(wanted) {
                socket.get_mut().set_read_timeout(Some(wanted))?;
                poll = Some(wanted);
            }
            wanted = BUSY_POLL;
            match socket.read() {
                Ok(Message::Text(text)) => match protocol::decode_client_message(text.as_str()) {
                    Ok(ClientMessage::Ack(n)) => credit = credit.saturating_add(n).min(MAX_CREDIT),
                    Ok(ClientMessage::Mode(new_mode)) => {
                        if new_mode != mode {
                            mode = new_mode;
                            drop(sampler);
                            sampler = Sampler::start(&site.skin, site.dir.clone(), &layers, mode)
                                .context("cannot start the layer readers")?;
                            seen_version = 0;
                            tracing::debug!(?mode, "reader mode changed");
                        }
                    }
                    Ok(ClientMessage::Request) => sampler.request(),
                    Err(e) => tracing::warn!("browser message ignored: {e}"),
                },
                Ok(Message::Close(_)) => return Ok(()),
                Ok(_) => {}
                Err(e) if is_timeout(&e) => break,
                Err(e) if is_closed(&e) => return Ok(()),
                Err(e) => return Err(e.into()),
            }
        }
        if credit == 0 {
            continue;
        }
        // Outside the board's lock: it may search the segment directory.
        let newest_overlays = overlays.poll();
        let taken = sampler.take_newer(seen_version, IDLE_POLL, |board| {
            let updates: Vec<LayerUpdate<'_>> = board
                .layers
                .iter()
                .zip(&mut sent_seq)
                .map(|(slot, sent)| {
                    let changed = slot.seq != 0 && slot.seq != *sent;
                    *sent = slot.seq;
                    LayerUpdate { slot, with_responses: changed }
                })
                .collect();
            protocol::encode_update(&mut message, updates_sent, mode, &updates, &newest_overlays);
            board.version
        });
        if let Some(version) = taken {
            seen_version = version;
            updates_sent = updates_sent.wrapping_add(1);
            credit -= 1;
            match socket.send(Message::binary(std::mem::take(&mut message))) {
                Ok(()) => {}
                Err(e) if is_closed(&e) => return Ok(()),
                Err(e) => return Err(e.into()),
            }
        }
    }
}
