//! The HTTP side: one thread per connection, serving the embedded page and
//! upgrading `/ws` to the WebSocket of a [`session`].

#![forbid(unsafe_code)]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, ToSocketAddrs};
use std::sync::atomic::Ordering;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tungstenite::WebSocket;
use tungstenite::protocol::{Role, WebSocketConfig};

use crate::session::{self, Site};

const PAGE_HTML: &str = include_str!("page.html");
const PAGE_JS: &str = include_str!("page.js");
const PAGE_CSS: &str = include_str!("page.css");

/// A request head larger than this is refused: the page's requests are tiny.
const MAX_HEAD_BYTES: usize = 16 * 1024;
/// A WebSocket message or frame from the browser larger than this ends the
/// connection before it is buffered (tungstenite's default is 64 MiB): the
/// page's messages are under [`crate::message::MAX_MESSAGE_BYTES`].
const MAX_INCOMING_BYTES: usize = 64 * 1024;
/// The start of the name of a connection's thread (then the browser's port,
/// within Linux's 15 characters): what `top -H` shows, and what `skin bench
/// kilohertz` measures as the browsers' own cost.
pub const BROWSER_THREAD_PREFIX: &str = "browser-";
/// Bytes read from a browser at a time; its messages are a few dozen bytes.
pub const BROWSER_READ_BYTES: usize = 4 * 1024;

/// Binds the viewer's address, with an error that says what to do when it fails.
pub fn bind(listen: &str) -> Result<TcpListener> {
    let address: SocketAddr =
        listen.to_socket_addrs().ok().and_then(|mut addresses| addresses.next()).with_context(|| {
            format!("--listen {listen:?} is not an address; write it as HOST:PORT, e.g. 127.0.0.1:8080")
        })?;
    let listener = TcpListener::bind(address).map_err(|e| match e.kind() {
        std::io::ErrorKind::AddrInUse => anyhow::anyhow!(
            "cannot listen on {address}: the port is in use (another `skin view` or `skin demo`?); \
             stop it or choose another port with --listen {}:PORT",
            address.ip()
        ),
        std::io::ErrorKind::PermissionDenied => anyhow::anyhow!(
            "cannot listen on {address}: permission denied (ports below 1024 need privileges); choose a port above 1023"
        ),
        _ => anyhow::Error::new(e).context(format!("cannot listen on {address}")),
    })?;
    if !address.ip().is_loopback() {
        tracing::warn!(%address, "listening beyond loopback: anyone who can reach this address can watch the skin");
    }
    Ok(listener)
}

/// How often the accept loop looks at the shutdown flag when neither a
/// browser nor a signal woke it: for a flag set by something other than
/// SIGINT or SIGTERM. (It looked every 25 ms, which cost an idle viewer
/// 0.2 % of a core in wake-ups on this project's 2-vCPU machine.)
const SHUTDOWN_CHECK: rustix::time::Timespec = rustix::time::Timespec { tv_sec: 1, tv_nsec: 0 };

/// Serves the page and its WebSocket until `site.shutdown` is set.
///
/// The accept loop sleeps until a browser connects or SIGINT or SIGTERM
/// arrives (the callers set `site.shutdown` on those signals), so an idle
/// viewer costs nothing between connections.
pub fn serve(listener: TcpListener, site: &Site) -> Result<()> {
    // Non-blocking accept: a wake-up with nobody to accept is not a hang.
    listener.set_nonblocking(true).context("cannot make the listening socket non-blocking")?;
    let (signalled, signal_end) =
        std::os::unix::net::UnixStream::pair().context("cannot create the viewer's shutdown socket pair")?;
    // Drained after each wake-up, without waiting.
    signalled.set_nonblocking(true).context("cannot make the viewer's shutdown socket non-blocking")?;
    // Each handler owns a clone of `signal_end`; `unregister` closes it
    // once no handler is running any more.
    let handlers = [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM]
        .into_iter()
        .map(|signal| {
            let end = signal_end.try_clone()?;
            signal_hook::low_level::pipe::register(signal, end)
        })
        .collect::<std::io::Result<Vec<_>>>()
        .context("cannot install the viewer's signal handlers")?;
    drop(signal_end);
    let served = accept_until_shutdown(&listener, &signalled, site);
    for handler in handlers {
        signal_hook::low_level::unregister(handler);
    }
    served
}

fn accept_until_shutdown(
    listener: &TcpListener,
    signalled: &std::os::unix::net::UnixStream,
    site: &Site,
) -> Result<()> {
    use rustix::event::{PollFd, PollFlags};
    while !site.shutdown.load(Ordering::Relaxed) {
        let mut waiting = [PollFd::new(listener, PollFlags::IN), PollFd::new(signalled, PollFlags::IN)];
        match rustix::event::poll(&mut waiting, Some(&SHUTDOWN_CHECK)) {
            Ok(_) | Err(rustix::io::Errno::INTR) => {}
            Err(e) => return Err(std::io::Error::from(e)).context("cannot wait for browsers (poll)"),
        }
        if waiting[1].revents().contains(PollFlags::IN) {
            // The signal's byte: read, so that a flag not set by that signal does not make poll spin.
            let mut bytes = [0u8; 16];
            while matches!(rustix::net::recv(signalled, &mut bytes, rustix::net::RecvFlags::DONTWAIT), Ok((1.., _))) {}
        }
        if !waiting[0].revents().contains(PollFlags::IN) {
            continue;
        }
        match listener.accept() {
            Ok((stream, peer)) => {
                let site = site.clone();
                let spawned = std::thread::Builder::new()
                    .name(format!("{BROWSER_THREAD_PREFIX}{}", peer.port()))
                    .spawn(move || {
                        if let Err(e) = handle_connection(stream, &site) {
                            tracing::debug!(%peer, "connection ended: {e:#}");
                        }
                    });
                if let Err(e) = spawned {
                    tracing::warn!(%peer, "cannot start a thread for a connection: {e}");
                }
            }
            // Another wake-up than a browser's, or one that left already.
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
            Err(e) => {
                tracing::warn!("accept failed: {e}");
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    }
    Ok(())
}

/// A parsed request head.
struct Request {
    method: String,
    path: String,
    headers: Vec<(String, String)>,
}

impl Request {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(key, _)| key.eq_ignore_ascii_case(name)).map(|(_, value)| value.as_str())
    }

    fn header_has_token(&self, name: &str, token: &str) -> bool {
        self.header(name).is_some_and(|value| value.split(',').any(|t| t.trim().eq_ignore_ascii_case(token)))
    }
}

/// Reads up to the end of the head; returns it and whatever came after.
fn read_head(stream: &mut TcpStream) -> Result<(Request, Vec<u8>)> {
    let mut buffer = Vec::with_capacity(1024);
    let mut chunk = [0u8; 2048];
    let end = loop {
        if let Some(at) = buffer.windows(4).position(|w| w == b"\r\n\r\n") {
            break at;
        }
        if buffer.len() > MAX_HEAD_BYTES {
            bail!("request head larger than {MAX_HEAD_BYTES} bytes");
        }
        let n = stream.read(&mut chunk)?;
        if n == 0 {
            bail!("connection closed before the end of the request head");
        }
        buffer.extend_from_slice(&chunk[..n]);
    };
    let head = std::str::from_utf8(&buffer[..end]).context("request head is not UTF-8")?;
    let mut lines = head.split("\r\n");
    let mut request_line = lines.next().unwrap_or_default().split_whitespace();
    let (Some(method), Some(path)) = (request_line.next(), request_line.next()) else {
        bail!("malformed request line {head:?}");
    };
    let headers = lines
        .filter_map(|line| line.split_once(':'))
        .map(|(key, value)| (key.trim().to_owned(), value.trim().to_owned()))
        .collect();
    let request = Request { method: method.to_owned(), path: path.to_owned(), headers };
    Ok((request, buffer[end + 4..].to_vec()))
}

fn respond(stream: &mut TcpStream, status: &str, content_type: &str, body: &[u8]) -> Result<()> {
    write!(
        stream,
        "HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-store\r\n\
         X-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    stream.write_all(body)?;
    stream.flush()?;
    Ok(())
}

/// A page from another site must not open our WebSocket (browsers send
/// `Origin` on WebSocket requests, and do not apply the same-origin policy to them).
fn same_origin(request: &Request) -> bool {
    match (request.header("origin"), request.header("host")) {
        (None, _) => true,
        (Some(origin), Some(host)) => origin.split_once("://").is_some_and(|(_, rest)| rest == host),
        (Some(_), None) => false,
    }
}

/// Why a WebSocket asked for with `query` cannot be served, if it cannot:
/// the page speaks another protocol version than this server (a page
/// loaded before an upgrade, which asks for none or for its own in
/// `?protocol=N`). The text is what the page shows; every version of the
/// page shows an `{"error": ...}` text message.
fn refusal_of_version(query: &str) -> Option<String> {
    let asked = query.split('&').find_map(|pair| pair.strip_prefix("protocol="));
    let version = crate::protocol::PROTOCOL_VERSION;
    match asked {
        Some(asked) if asked == version.to_string() => None,
        Some(asked) => Some(format!(
            "this page speaks the viewer's protocol {asked}, the server speaks {version}: reload the page (Ctrl-R) to get its new version"
        )),
        None => Some(format!(
            "this page is from an older viewer (protocol 1), the server speaks protocol {version}: reload the page (Ctrl-R) to get its new version"
        )),
    }
}

fn handle_connection(mut stream: TcpStream, site: &Site) -> Result<()> {
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    stream.set_write_timeout(Some(Duration::from_secs(10)))?;
    stream.set_nodelay(true)?;
    let (request, leftover) = read_head(&mut stream)?;
    if request.method != "GET" {
        return respond(&mut stream, "405 Method Not Allowed", "text/plain", b"only GET\n");
    }
    let (path, query) = request.path.split_once('?').unwrap_or((request.path.as_str(), ""));
    match path {
        "/" | "/index.html" => respond(&mut stream, "200 OK", "text/html; charset=utf-8", PAGE_HTML.as_bytes()),
        "/view.js" => respond(&mut stream, "200 OK", "text/javascript; charset=utf-8", PAGE_JS.as_bytes()),
        "/view.css" => respond(&mut stream, "200 OK", "text/css; charset=utf-8", PAGE_CSS.as_bytes()),
        "/favicon.ico" => respond(&mut stream, "204 No Content", "text/plain", b""),
        "/ws" => {
            let key = request.header("sec-websocket-key").map(str::to_owned);
            let upgrade =
                request.header_has_token("connection", "upgrade") && request.header_has_token("upgrade", "websocket");
            let Some(key) = key.filter(|_| upgrade) else {
                return respond(
                    &mut stream,
                    "400 Bad Request",
                    "text/plain",
                    b"a WebSocket upgrade is expected here\n",
                );
            };
            if !same_origin(&request) {
                return respond(&mut stream, "403 Forbidden", "text/plain", b"cross-origin WebSocket refused\n");
            }
            let accept = tungstenite::handshake::derive_accept_key(key.as_bytes());
            write!(
                stream,
                "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
                 Sec-WebSocket-Accept: {accept}\r\n\r\n"
            )?;
            stream.flush()?;
            // A small read buffer: tungstenite zeroes the whole buffer before
            // every read, and its 128 KiB default made each poll for a
            // browser's acknowledgement cost a 128 KiB memset.
            let config = WebSocketConfig::default()
                .max_message_size(Some(MAX_INCOMING_BYTES))
                .max_frame_size(Some(MAX_INCOMING_BYTES))
                .read_buffer_size(BROWSER_READ_BYTES);
            let mut socket = WebSocket::from_partially_read(
                session::BrowserStream::new(stream),
                leftover,
                Role::Server,
                Some(config),
            );
            match refusal_of_version(query) {
                None => session::run(socket, site),
                Some(text) => {
                    // What a page of another version shows in place of the map.
                    socket.send(tungstenite::Message::text(serde_json::json!({ "error": text }).to_string()))?;
                    let _ = socket.close(None);
                    let _ = socket.flush();
                    Ok(())
                }
            }
        }
        _ => respond(&mut stream, "404 Not Found", "text/plain", b"not found\n"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pages_of_another_protocol_version_are_told_to_reload() {
        assert_eq!(refusal_of_version("protocol=3"), None);
        assert_eq!(crate::protocol::WEBSOCKET_PATH.split_once('?').map(|(_, q)| refusal_of_version(q)), Some(None));
        let old_page = refusal_of_version("").unwrap();
        assert!(old_page.contains("older viewer") && old_page.contains("reload the page"), "{old_page}");
        // A page of protocol 2 (raw responses), open from before the compact encoding.
        let protocol_2 = refusal_of_version("protocol=2").unwrap();
        assert_eq!(
            protocol_2,
            "this page speaks the viewer's protocol 2, the server speaks 3: reload the page (Ctrl-R) to get its new version"
        );
        let other = refusal_of_version("x=1&protocol=4").unwrap();
        assert!(other.contains("protocol 4, the server speaks 3") && other.contains("reload"), "{other}");
    }
}
