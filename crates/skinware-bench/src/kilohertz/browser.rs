//! The bench's browsers: WebSocket clients that speak the page's protocol
//! (`docs/viewer.md`) and acknowledge what they received at a display's
//! rate, and the clock that dates what they receive.

use std::collections::BTreeMap;
use std::net::TcpStream;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use skinware::{Reader, ReaderOptions};
use skinware_viewer::protocol::{KIND_GEOMETRY, KIND_UPDATE, LAYER_SEQ_OFFSET, UPDATE_HEADER_BYTES};
use skinware_viewer::session::{BrowserStream, Reads};
use tungstenite::{Message, WebSocket};

use super::report::BrowserFigures;
use crate::measure::Percentiles;

/// Acquisition times of layer 0's frames by sequence number, for the
/// browsers to date what they receive. Its reader stops with `stop`, or
/// when the last clone is dropped.
#[derive(Clone)]
pub(super) struct SeqClock {
    /// Acquisition time (CLOCK_MONOTONIC ns) by sequence number, the newest 20,000.
    table: Arc<Mutex<BTreeMap<u64, u64>>>,
    /// Stops the reader with the last clone.
    _stop: Arc<StopOnDrop>,
}

/// Sets its flag when dropped.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

impl SeqClock {
    /// Starts reading layer 0 of the skin in segment directory `dir`, until `stop`.
    pub(super) fn start(dir: &Path, stop: Arc<AtomicBool>) -> SeqClock {
        let table = Arc::new(Mutex::new(BTreeMap::new()));
        let clock = SeqClock { table: table.clone(), _stop: Arc::new(StopOnDrop(stop.clone())) };
        let options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
        std::thread::spawn(move || {
            let Ok(mut reader) = Reader::open_with("default", "virtual-0", &options) else { return };
            while !stop.load(Ordering::Relaxed) {
                if let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) {
                    let (seq, acquired) = (frame.seq(), frame.acquired_ns());
                    let mut table = table.lock().unwrap_or_else(|p| p.into_inner());
                    table.insert(seq, acquired);
                    while table.len() > 20_000 {
                        table.pop_first();
                    }
                }
            }
        });
        clock
    }

    /// When the frame `seq` of layer 0 was acquired, if it was seen.
    fn acquired(&self, seq: u64) -> Option<u64> {
        self.table.lock().unwrap_or_else(|p| p.into_inner()).get(&seq).copied()
    }
}

/// Updates per second count only what a browser received inside the
/// measured window, which its caller marks here.
#[derive(Debug, Default)]
pub(super) struct WindowMarks {
    /// When the window opened.
    pub(super) start: OnceLock<Instant>,
    /// When it closed.
    pub(super) end: OnceLock<Instant>,
}

impl WindowMarks {
    /// Whether `at` is inside the window (an open one has no end yet).
    fn contains(&self, at: Instant) -> bool {
        self.start.get().is_some_and(|start| at >= *start) && self.end.get().is_none_or(|end| at < *end)
    }

    /// The window's length, once it closed.
    fn seconds(&self) -> Option<f64> {
        Some(self.end.get()?.duration_since(*self.start.get()?).as_secs_f64())
    }
}

/// One browser: takes the geometry, then acknowledges the updates it
/// received `ack_hz` times a second, as a page does after each animation
/// frame that drew something.
pub(super) fn browse(
    address: &str,
    ack_hz: f64,
    (stop, marks): (&AtomicBool, &WindowMarks),
    clock: &SeqClock,
) -> Result<BrowserFigures> {
    let stream = BrowserStream::new(TcpStream::connect(address)?);
    let (mut socket, _) =
        tungstenite::client(format!("ws://{address}{}", skinware_viewer::protocol::WEBSOCKET_PATH), stream)
            .map_err(|e| anyhow::anyhow!("WebSocket handshake with the viewer failed: {e}"))?;
    // Reads that find nothing return at once (writes still block); the
    // waiting is done by `poll`, whose timeout is a high-resolution timer. A
    // socket's read timeout counts in the kernel's ticks, which are in step
    // with the writers' periods: every acknowledgement of a run then came at
    // the same point of the skin's millisecond.
    socket.get_mut().reads = Reads::DontWait;
    let period = Duration::from_secs_f64(1.0 / ack_hz);
    let mut geometry = false;
    let mut tally = Tally::default();
    let started = Instant::now();
    let mut next_ack = started + period;
    while !stop.load(Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Binary(data)) if data.first() == Some(&KIND_GEOMETRY) && !geometry => {
                geometry = true;
                socket.send(Message::text(r#"{"ack":2}"#))?;
            }
            Ok(Message::Binary(data)) if data.first() == Some(&KIND_UPDATE) => tally.update(&data, marks, clock),
            Ok(Message::Text(text)) => bail!("the viewer refused the browser: {text}"),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e)) if e.kind() == std::io::ErrorKind::WouldBlock => {
                sleep_until_readable(&socket, next_ack)?;
            }
            Err(e) => return Err(e.into()),
        }
        let now = Instant::now();
        if now >= next_ack {
            if tally.unacked > 0 {
                socket.send(Message::text(format!(r#"{{"ack":{}}}"#, tally.unacked)))?;
                tally.unacked = 0;
            }
            while next_ack <= now {
                next_ack += period;
            }
        }
    }
    let seconds = started.elapsed().as_secs_f64();
    let _ = socket.close(None);
    Ok(BrowserFigures {
        ack_hz,
        updates_per_s: marks.seconds().map_or(tally.updates as f64 / seconds, |window| tally.in_window as f64 / window),
        kb_per_update: tally.bytes as f64 / 1e3 / tally.updates.max(1) as f64,
        latency_us: Percentiles::of(&mut tally.latency),
    })
}

/// What a browser counted of the updates it received.
#[derive(Debug, Default)]
struct Tally {
    /// Updates received.
    updates: u64,
    /// Of them, those received inside the measured window.
    in_window: u64,
    /// Their bytes.
    bytes: u64,
    /// Received since the last acknowledgement.
    unacked: u32,
    /// From the acquisition of layer 0's newest frame to the update holding it, µs.
    latency: Vec<u64>,
    /// Layer 0's sequence number in the last update.
    last_seq: u64,
}

impl Tally {
    /// Counts the update `data` (the whole message), received now.
    fn update(&mut self, data: &[u8], marks: &WindowMarks, clock: &SeqClock) {
        self.updates += 1;
        if marks.contains(Instant::now()) {
            self.in_window += 1;
        }
        self.bytes += data.len() as u64;
        self.unacked += 1;
        // Layer 0's sequence number, in its record after the header (the
        // same offset in protocols 2 and 3: only the responses, after the
        // records, changed). The responses are not decoded: the page's
        // work, not the viewer's, which is what the bench measures.
        let seq_at = UPDATE_HEADER_BYTES + LAYER_SEQ_OFFSET;
        if let Some(seq) = data.get(seq_at..seq_at + 8).map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
            && seq != self.last_seq
        {
            self.last_seq = seq;
            if let Some(acquired) = clock.acquired(seq) {
                self.latency.push(skinware::os::monotonic_ns().saturating_sub(acquired) / 1_000);
            }
        }
    }
}

/// Asleep until an update comes or the next acknowledgement is due, at
/// `next_ack`, as a page is between its animation frames (a client that
/// polled every 2 ms, before, loaded the machine with wake-ups that grew
/// with the browsers).
fn sleep_until_readable(socket: &WebSocket<BrowserStream>, next_ack: Instant) -> Result<()> {
    let until_ack = next_ack.saturating_duration_since(Instant::now());
    let timeout = rustix::time::Timespec::try_from(until_ack)?;
    let mut readable = [rustix::event::PollFd::new(&socket.get_ref().stream, rustix::event::PollFlags::IN)];
    match rustix::event::poll(&mut readable, Some(&timeout)) {
        Ok(_) | Err(rustix::io::Errno::INTR) => Ok(()),
        Err(e) => Err(std::io::Error::from(e).into()),
    }
}
