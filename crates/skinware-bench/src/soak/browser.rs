//! The viewer's browser for the soak (the hidden `bench-soak-browser`
//! role): a WebSocket client that speaks the page's protocol
//! (`docs/viewer.md`), so that the soak can see the viewer stall or fail
//! through every fault without a real browser's rendering on the machine.

use std::net::TcpStream;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

/// Arguments of the hidden `bench-soak-browser` role.
#[derive(Clone, Debug, clap::Args)]
pub struct BrowserArgs {
    /// The viewer's address (`host:port`).
    #[arg(long)]
    pub address: String,
    /// Where to write what it received (JSON).
    #[arg(long)]
    pub report: PathBuf,
}

/// What the browser-like client reports.
#[derive(Debug, Default, serde::Serialize)]
struct BrowserReport {
    /// Updates received.
    updates: u64,
    /// Geometries received (one per connection).
    geometries: u64,
    /// Connections made (the first and every reconnection).
    connections: u64,
    /// Errors that ended a connection.
    errors: u64,
    /// The longest time without an update once connected, ms.
    longest_gap_ms: f64,
    /// When that gap ended (CLOCK_MONOTONIC ns), to find what caused it.
    longest_gap_ended_ns: u64,
    /// Every wait for an update longer than [`STALL_MS`]: when it ended
    /// (CLOCK_MONOTONIC ns) and how long it was (ms), for the soak to match
    /// with its faults (the first 10,000).
    stalls: Vec<(u64, f64)>,
    /// The last error, if any.
    last_error: Option<String>,
}

/// The shortest wait for an update that the browser lists as a stall: ten
/// times the viewer's period at 30-50 Hz layers.
const STALL_MS: f64 = 300.0;

/// The viewer's browser for the soak: takes the geometry, acknowledges
/// the updates at 60 Hz as a page does, reconnects if the connection ends,
/// and writes what it received to `--report` twice a second, until its
/// standard input closes.
pub fn run(args: &BrowserArgs) -> Result<()> {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stopper = stop.clone();
    std::thread::spawn(move || {
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
        stopper.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let mut report = BrowserReport::default();
    let mut last_written = Instant::now();
    let write = |report: &BrowserReport| -> Result<()> {
        let temp = args.report.with_extension("tmp");
        std::fs::write(&temp, serde_json::to_vec(report)?)?;
        std::fs::rename(&temp, &args.report)?;
        Ok(())
    };
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        report.connections += 1;
        if let Err(e) = browse(
            &args.address,
            &stop,
            &mut report,
            &mut || {
                if last_written.elapsed() > Duration::from_millis(500) {
                    last_written = Instant::now();
                    true
                } else {
                    false
                }
            },
            &write,
        ) {
            report.errors += 1;
            report.last_error = Some(format!("{e:#}"));
            std::thread::sleep(Duration::from_millis(200));
        }
        write(&report)?;
    }
    write(&report)
}

/// One connection of [`run`].
fn browse(
    address: &str,
    stop: &std::sync::atomic::AtomicBool,
    report: &mut BrowserReport,
    due: &mut dyn FnMut() -> bool,
    write: &dyn Fn(&BrowserReport) -> Result<()>,
) -> Result<()> {
    use tungstenite::Message;
    let stream = TcpStream::connect(address).with_context(|| format!("cannot connect to the viewer at {address}"))?;
    stream.set_read_timeout(Some(Duration::from_millis(16)))?;
    let (mut socket, _) =
        tungstenite::client(format!("ws://{address}{}", skinware_viewer::protocol::WEBSOCKET_PATH), stream)
            .map_err(|e| anyhow::anyhow!("WebSocket handshake with the viewer failed: {e}"))?;
    let mut unacked = 0u32;
    let mut last_update: Option<Instant> = None;
    let mut next_ack = Instant::now();
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Binary(data)) if data.first() == Some(&1) => {
                report.geometries += 1;
                socket.send(Message::text(r#"{"ack":2}"#))?;
            }
            Ok(Message::Binary(data)) if data.first() == Some(&2) => {
                report.updates += 1;
                unacked += 1;
                if let Some(last) = last_update {
                    let gap_ms = last.elapsed().as_secs_f64() * 1e3;
                    let now_ns = skinware::os::monotonic_ns();
                    if gap_ms > report.longest_gap_ms {
                        report.longest_gap_ms = gap_ms;
                        report.longest_gap_ended_ns = now_ns;
                    }
                    if gap_ms > STALL_MS && report.stalls.len() < 10_000 {
                        report.stalls.push((now_ns, gap_ms));
                    }
                }
                last_update = Some(Instant::now());
            }
            Ok(Message::Close(_)) => bail!("the viewer closed the connection"),
            Ok(Message::Text(text)) => bail!("the viewer refused the browser: {text}"),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => return Err(e.into()),
        }
        if Instant::now() >= next_ack {
            next_ack = Instant::now() + Duration::from_secs_f64(1.0 / 60.0);
            if unacked > 0 {
                socket.send(Message::text(format!(r#"{{"ack":{unacked}}}"#)))?;
                unacked = 0;
            }
        }
        if due() {
            write(report)?;
        }
    }
    let _ = socket.close(None);
    Ok(())
}
