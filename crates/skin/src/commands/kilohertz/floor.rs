//! The floor under what a browser costs the viewer, for `skin bench
//! kilohertz` (which runs it as the hidden `skin bench-floor`, a process of
//! its own as the viewer is): a bare WebSocket server that does, per
//! browser, only what no viewer of this design can leave out. It waits for the browser's
//! acknowledgement, and for each one sends one message of an update's size
//! through the viewer's own send path (one `sendmsg` from where the bytes
//! are). It reads no skin, keeps no board and paces nothing, so the
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

#![forbid(unsafe_code)]

use std::io::{IoSlice, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{Context, Result};
use tungstenite::Message;

use crate::view::protocol::{KIND_GEOMETRY, KIND_UPDATE};
use crate::view::server::BROWSER_READ_BYTES;
use crate::view::session::{BrowserStream, WebSocketHeader, send_message};

/// How long a connection's read waits before it looks at the stop flag.
const STOP_POLL: Duration = Duration::from_millis(100);

/// The name of the threads that serve a browser each: what the bench
/// measures of this process.
pub const BROWSER_THREAD: &str = "floor-browser";

/// Arguments of the hidden `bench-floor` role.
#[derive(clap::Args)]
pub struct FloorArgs {
    /// Bytes of each update message.
    #[arg(long)]
    bytes: usize,
}

/// Runs the floor server: prints the address it listens on, then serves
/// until its standard input closes (the bench ended).
pub fn run(args: &FloorArgs) -> Result<()> {
    let server = FloorServer::start(args.bytes)?;
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
    stop: Arc<AtomicBool>,
    acceptor: Option<JoinHandle<()>>,
    rewriter: Option<JoinHandle<()>>,
}

/// The newest update, replaced whole by the rewriter.
type Newest = Arc<Mutex<Arc<Vec<u8>>>>;

/// How often the rewriter writes a new update: the skin's rate.
const REWRITE_EVERY: Duration = Duration::from_millis(1);

impl FloorServer {
    /// Listens on a free loopback port and answers each acknowledgement of
    /// a browser with one binary message of `update_bytes` bytes.
    fn start(update_bytes: usize) -> Result<FloorServer> {
        let listener = TcpListener::bind("127.0.0.1:0").context("cannot listen on loopback for the floor server")?;
        let address = listener.local_addr()?.to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let mut update = vec![0u8; update_bytes.max(1)];
        update[0] = KIND_UPDATE;
        let newest: Newest = Arc::new(Mutex::new(Arc::new(update)));
        let rewriter = {
            let (stop, newest) = (stop.clone(), newest.clone());
            std::thread::spawn(move || rewrite(&newest, &stop))
        };
        let acceptor = {
            let stop = stop.clone();
            std::thread::spawn(move || accept_browsers(&listener, &stop, &newest))
        };
        Ok(FloorServer { address, stop, acceptor: Some(acceptor), rewriter: Some(rewriter) })
    }
}

impl Drop for FloorServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // The acceptor blocks in accept(): a connection wakes it to see the flag.
        let _ = TcpStream::connect(&self.address);
        for thread in [self.acceptor.take(), self.rewriter.take()].into_iter().flatten() {
            let _ = thread.join();
        }
    }
}

/// Writes a new update every [`REWRITE_EVERY`] into a buffer no send holds
/// (the one it replaced last time, once the sends let go of it), then swaps
/// it in.
fn rewrite(newest: &Newest, stop: &AtomicBool) {
    let mut spare = Arc::new(lock(newest).as_ref().clone());
    let mut count = 0u8;
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(REWRITE_EVERY);
        count = count.wrapping_add(1);
        if Arc::get_mut(&mut spare).is_none() {
            // A send still holds it: write a new one.
            spare = Arc::new(lock(newest).as_ref().clone());
        }
        if let Some(bytes) = Arc::get_mut(&mut spare) {
            bytes[1..].fill(count);
            spare = std::mem::replace(&mut *lock(newest), spare);
        }
    }
}

fn lock(newest: &Newest) -> std::sync::MutexGuard<'_, Arc<Vec<u8>>> {
    newest.lock().unwrap_or_else(|p| p.into_inner())
}

fn accept_browsers(listener: &TcpListener, stop: &Arc<AtomicBool>, newest: &Newest) {
    let mut connections = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let Ok((stream, _)) = listener.accept() else {
            std::thread::sleep(Duration::from_millis(10));
            continue;
        };
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let (stop, newest) = (stop.clone(), newest.clone());
        let spawned = std::thread::Builder::new().name(BROWSER_THREAD.into()).spawn(move || {
            if let Err(e) = serve_browser(stream, &stop, &newest) {
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
fn serve_browser(stream: TcpStream, stop: &AtomicBool, newest: &Newest) -> Result<()> {
    stream.set_read_timeout(Some(STOP_POLL))?;
    stream.set_nodelay(true)?;
    // The viewer's read buffer (`view::server`): tungstenite zeroes it before every read.
    let config = tungstenite::protocol::WebSocketConfig::default().read_buffer_size(BROWSER_READ_BYTES);
    let mut socket = tungstenite::accept_with_config(BrowserStream::new(stream), Some(config))
        .map_err(|e| anyhow::anyhow!("WebSocket handshake with a browser failed: {e}"))?;
    socket.send(Message::binary(vec![KIND_GEOMETRY]))?;
    while !stop.load(Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Text(_)) => {
                let update = lock(newest).clone();
                let header = WebSocketHeader::binary(update.len());
                let mut parts = [IoSlice::new(header.bytes()), IoSlice::new(&update)];
                send_message(&mut socket, &mut parts)?;
            }
            Ok(Message::Close(_)) => break,
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed) => break,
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}
