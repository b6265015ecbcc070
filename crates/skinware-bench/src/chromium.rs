//! The viewer's page in a real browser: headless Chromium, driven through
//! chromedriver with the W3C WebDriver protocol (JSON over HTTP/1.1 on
//! localhost), and the page's own counters (`window.skinStats`) read back.
//!
//! One client for two users: `skin bench kilohertz --chromium`, which
//! measures how fast the page draws beside the loaded skin, and the `skin`
//! crate's browser tests, which check what the page shows. It is small on
//! purpose (no async runtime, no WebDriver crate): a few commands over
//! one short HTTP exchange each are all either needs.
//!
//! Both programs come from the system: `chromium` and `chromedriver`
//! (Debian: `apt-get install chromium chromium-driver`); [`Programs::find`]
//! says so when they are missing.

#![forbid(unsafe_code)]

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde::Serialize;
use serde_json::{Value, json};

/// What went wrong driving the browser.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A program is not on `PATH`.
    #[error(
        "{missing} is not installed (not on PATH): the viewer's page needs chromium and chromedriver \
         (Debian: apt-get install chromium chromium-driver)"
    )]
    NotInstalled {
        /// The program looked for.
        missing: &'static str,
    },
    /// chromedriver did not start, or no port was free for it.
    #[error("cannot start {program}: {source}")]
    Start {
        /// The program, or what was being set up.
        program: String,
        /// Why.
        source: std::io::Error,
    },
    /// A WebDriver command failed: no connection, an HTTP error, or a reply
    /// that is not WebDriver's JSON.
    #[error("WebDriver {method} {path}: {detail}")]
    Request {
        /// The HTTP method.
        method: String,
        /// The command's path (under the session's, for a session's command).
        path: String,
        /// What went wrong, with chromedriver's message if it sent one.
        detail: String,
    },
    /// Something awaited did not happen in time.
    #[error("timed out after {within:?} waiting for {what}")]
    Timeout {
        /// What was awaited.
        what: String,
        /// How long.
        within: Duration,
    },
}

/// chromedriver and the Chromium it drives.
#[derive(Clone, Debug)]
pub struct Programs {
    /// The `chromedriver` executable.
    pub chromedriver: PathBuf,
    /// The browser: `chromium`, `chromium-browser` or `google-chrome`.
    pub chromium: PathBuf,
}

impl Programs {
    /// Both programs from `PATH`, or [`Error::NotInstalled`] naming the
    /// first one missing and the packages to install.
    pub fn find() -> Result<Programs, Error> {
        let chromium = find_program(&["chromium", "chromium-browser", "google-chrome"])
            .ok_or(Error::NotInstalled { missing: "chromium" })?;
        let chromedriver = find_program(&["chromedriver"]).ok_or(Error::NotInstalled { missing: "chromedriver" })?;
        Ok(Programs { chromedriver, chromium })
    }
}

/// The first of `names` that is a file in a directory of `PATH`.
fn find_program(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    names.iter().flat_map(|name| std::env::split_paths(&path).map(move |dir| dir.join(name))).find(|p| p.is_file())
}

/// Polls `probe` every 100 ms until it returns something, or returns
/// [`Error::Timeout`] naming `what` after `within`.
pub fn wait_for<T>(what: &str, within: Duration, mut probe: impl FnMut() -> Option<T>) -> Result<T, Error> {
    let started = Instant::now();
    loop {
        if let Some(value) = probe() {
            return Ok(value);
        }
        if started.elapsed() >= within {
            return Err(Error::Timeout { what: what.to_owned(), within });
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// chromedriver and one headless Chromium session; both ended when dropped.
pub struct Browser {
    driver: Child,
    port: u16,
    session: String,
}

impl Browser {
    /// Starts chromedriver on a free port of localhost and a headless
    /// Chromium session of 1400 × 900 pixels (without GPU or sandbox: it
    /// runs as root in containers, and on machines without a GPU).
    pub fn start(programs: &Programs) -> Result<Browser, Error> {
        // WebDriver's JSON holds text: a path that is not UTF-8 cannot go in it.
        let binary = programs.chromium.to_str().ok_or_else(|| Error::Start {
            program: programs.chromium.display().to_string(),
            source: std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "its path is not UTF-8, which WebDriver needs: install it or link it under a UTF-8 path",
            ),
        })?;
        let port = TcpListener::bind("127.0.0.1:0")
            .and_then(|listener| listener.local_addr())
            .map_err(|source| Error::Start { program: "a port for chromedriver".into(), source })?
            .port();
        let driver = Command::new(&programs.chromedriver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|source| Error::Start { program: programs.chromedriver.display().to_string(), source })?;
        // From here on, dropping the browser stops chromedriver.
        let mut browser = Browser { driver, port, session: String::new() };
        wait_for("chromedriver to be ready", Duration::from_secs(60), || {
            http(port, "GET", "/status", None).ok().filter(|v| v["ready"] == true)
        })?;
        let capabilities = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": binary,
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                         "--window-size=1400,900", "--hide-scrollbars"],
            },
        }}});
        let session = http(port, "POST", "/session", Some(&capabilities))?;
        browser.session = session["sessionId"]
            .as_str()
            .ok_or_else(|| Error::Request {
                method: "POST".into(),
                path: "/session".into(),
                detail: format!("no session id in {session}"),
            })?
            .to_owned();
        Ok(browser)
    }

    /// Sends a command of the session (`path` under `/session/ID`); returns
    /// its reply's `value`.
    pub fn command(&self, method: &str, path: &str, body: Option<&Value>) -> Result<Value, Error> {
        http(self.port, method, &format!("/session/{}{path}", self.session), body)
    }

    /// Opens `url` and waits for it to load.
    pub fn open(&self, url: &str) -> Result<(), Error> {
        self.command("POST", "/url", Some(&json!({ "url": url }))).map(drop)
    }

    /// Runs `script` in the page (a function body: `return` gives the value).
    pub fn run(&self, script: &str) -> Result<Value, Error> {
        self.command("POST", "/execute/sync", Some(&json!({ "script": script, "args": [] })))
    }

    /// Runs `script`, which calls `done(value)` (its last argument) when
    /// it has the answer; returns the value.
    pub fn run_async(&self, script: &str) -> Result<Value, Error> {
        let script = format!("const done = arguments[arguments.length - 1];\n{script}");
        self.command("POST", "/execute/async", Some(&json!({ "script": script, "args": [] })))
    }

    /// The page as a PNG.
    pub fn screenshot_png(&self) -> Result<Vec<u8>, Error> {
        let encoded = self.command("GET", "/screenshot", None)?;
        let not_png = |detail: String| Error::Request { method: "GET".into(), path: "/screenshot".into(), detail };
        let png = base64_decode(encoded.as_str().ok_or_else(|| not_png(format!("not a string: {encoded}")))?)
            .ok_or_else(|| not_png("not base64".into()))?;
        if !png.starts_with(b"\x89PNG\r\n\x1a\n") {
            return Err(not_png("not a PNG".into()));
        }
        Ok(png)
    }

    /// chromedriver's process id.
    pub fn driver_pid(&self) -> u32 {
        self.driver.id()
    }

    /// chromedriver and every process it started, and they theirs (the
    /// browser, its renderer, GPU and utility processes): whose CPU is the
    /// browser's. Read from `/proc` now; a process started later is not in it.
    pub fn process_ids(&self) -> Vec<u32> {
        let parents: Vec<(u32, u32)> = std::fs::read_dir("/proc")
            .map(|entries| {
                entries
                    .flatten()
                    .filter_map(|entry| entry.file_name().to_str()?.parse::<u32>().ok())
                    .filter_map(|pid| Some((pid, crate::procs::parent_of(pid)?)))
                    .collect()
            })
            .unwrap_or_default();
        let mut found = vec![self.driver_pid()];
        let mut next = 0;
        while let Some(&parent) = found.get(next) {
            found.extend(parents.iter().filter(|(_, of)| *of == parent).map(|(pid, _)| *pid));
            next += 1;
        }
        found
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let _ = http(self.port, "DELETE", &format!("/session/{}", self.session), None);
        }
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

/// One HTTP/1.1 exchange with chromedriver on `port`, which answers with a
/// Content-Length (and may keep the connection open regardless); returns
/// the reply's `value`.
fn http(port: u16, method: &str, path: &str, body: Option<&Value>) -> Result<Value, Error> {
    let failed = |detail: String| Error::Request { method: method.into(), path: path.into(), detail };
    let address = ([127, 0, 0, 1], port).into();
    let mut stream = TcpStream::connect_timeout(&address, Duration::from_secs(5)).map_err(|e| failed(e.to_string()))?;
    // Loading a page of a large skin can take a while on a loaded machine.
    stream.set_read_timeout(Some(Duration::from_secs(120))).map_err(|e| failed(e.to_string()))?;
    let body = body.map(Value::to_string).unwrap_or_default();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\
         Content-Type: application/json; charset=utf-8\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .map_err(|e| failed(e.to_string()))?;
    let (status, reply) = read_reply(&mut stream).map_err(failed)?;
    let value: Value = serde_json::from_slice(&reply)
        .map_err(|e| failed(format!("not JSON ({e}): {}", String::from_utf8_lossy(&reply))))?;
    if status != 200 {
        return Err(failed(format!("HTTP {status}: {}", value["value"]["message"])));
    }
    Ok(value["value"].clone())
}

/// An HTTP reply's status and body, read to its Content-Length.
fn read_reply(stream: &mut TcpStream) -> Result<(u16, Vec<u8>), String> {
    let mut reply = Vec::new();
    let mut chunk = [0u8; 64 * 1024];
    let (head_end, length) = loop {
        let n = stream.read(&mut chunk).map_err(|e| e.to_string())?;
        if n == 0 {
            return Err(format!("connection closed after {} bytes", reply.len()));
        }
        reply.extend_from_slice(&chunk[..n]);
        if let Some(at) = reply.windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&reply[..at]).to_ascii_lowercase();
            let length = head
                .lines()
                .find_map(|l| l.strip_prefix("content-length:"))
                .and_then(|v| v.trim().parse::<usize>().ok());
            break (at + 4, length.ok_or_else(|| format!("no Content-Length in {head:?}"))?);
        }
    };
    // A reply is never near that size; a length that is cannot be read.
    let end = head_end.checked_add(length).filter(|&end| end <= 1 << 30).ok_or("a reply longer than 1 GiB")?;
    while reply.len() < end {
        let n = stream.read(&mut chunk).map_err(|e| e.to_string())?;
        if n == 0 {
            return Err("reply cut short".into());
        }
        reply.extend_from_slice(&chunk[..n]);
    }
    let head = String::from_utf8_lossy(&reply[..head_end]);
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
    Ok((status, reply[head_end..end].to_vec()))
}

/// Standard base64 (what WebDriver's screenshots are), or `None` if `text`
/// holds anything else.
fn base64_decode(text: &str) -> Option<Vec<u8>> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let digits: Vec<u8> =
        text.bytes().filter(|c| !c.is_ascii_whitespace() && *c != b'=').map(value).collect::<Option<_>>()?;
    let mut out = Vec::with_capacity(digits.len() * 3 / 4);
    for chunk in digits.chunks(4) {
        let bits = chunk.iter().enumerate().fold(0u32, |acc, (i, &d)| acc | u32::from(d) << (18 - 6 * i));
        out.extend_from_slice(&bits.to_be_bytes()[1..chunk.len()]);
    }
    Some(out)
}

/// The page's counters (`window.skinStats`: updates, draws, bytes...) with
/// its clock (`now`, ms), for [`PageRates::between`].
pub const STATS_PROBE: &str = "return Object.assign({ now: performance.now() }, window.skinStats);";

/// How the page kept up between two readings of [`STATS_PROBE`].
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct PageRates {
    /// Between the readings, by the page's clock.
    pub seconds: f64,
    /// Draws of new updates per second (the page draws only when an update
    /// came since its last draw, at most once per animation frame).
    pub fps: f64,
    /// Updates received per second.
    pub updates_per_s: f64,
    /// Bytes per update received (the viewer's compact encoding).
    pub bytes_per_update: f64,
    /// What the same updates would have been with raw responses (protocol 2).
    pub raw_bytes_per_update: f64,
    /// The page's moving average of a draw's cost, ms, at the second reading.
    pub render_ms: f64,
    /// The page's decoding cost per update, ms, at the second reading.
    pub decode_ms: f64,
}

impl PageRates {
    /// The rates between readings `before` and `after` of [`STATS_PROBE`]
    /// (a counter the page lacks counts as 0).
    pub fn between(before: &Value, after: &Value) -> PageRates {
        let delta = |key: &str| after[key].as_f64().unwrap_or(0.0) - before[key].as_f64().unwrap_or(0.0);
        let seconds = delta("now") / 1e3;
        let per_second = |key: &str| if seconds > 0.0 { delta(key) / seconds } else { 0.0 };
        let updates = delta("updates").max(1.0);
        PageRates {
            seconds,
            fps: per_second("draws"),
            updates_per_s: per_second("updates"),
            bytes_per_update: delta("updateBytes") / updates,
            raw_bytes_per_update: delta("rawUpdateBytes") / updates,
            render_ms: after["renderMs"].as_f64().unwrap_or(0.0),
            decode_ms: after["decodeMs"].as_f64().unwrap_or(0.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_decodes_what_it_should_and_refuses_the_rest() {
        assert_eq!(base64_decode("aGVsbG8=").as_deref(), Some(&b"hello"[..]));
        assert_eq!(base64_decode("aGVs\nbG8h").as_deref(), Some(&b"hello!"[..]));
        assert_eq!(base64_decode("aGV*"), None);
    }

    #[test]
    fn rates_come_from_the_counters_and_the_page_clock() {
        let before = json!({ "now": 1000.0, "draws": 10, "updates": 20, "updateBytes": 2000, "rawUpdateBytes": 6000 });
        let after = json!({ "now": 3000.0, "draws": 130, "updates": 140, "updateBytes": 14000,
                            "rawUpdateBytes": 42000, "renderMs": 2.5 });
        let rates = PageRates::between(&before, &after);
        assert_eq!(rates.seconds, 2.0);
        assert_eq!(rates.fps, 60.0);
        assert_eq!(rates.updates_per_s, 60.0);
        assert_eq!(rates.bytes_per_update, 100.0);
        assert_eq!(rates.raw_bytes_per_update, 300.0);
        assert_eq!(rates.render_ms, 2.5);
    }

    #[test]
    fn a_missing_program_is_named_with_the_packages_to_install() {
        let said = Error::NotInstalled { missing: "chromedriver" }.to_string();
        assert!(said.starts_with("chromedriver is not installed"), "{said}");
        assert!(said.contains("apt-get install chromium chromium-driver"), "{said}");
    }

    #[test]
    fn a_page_without_counters_gives_zeros_not_a_panic() {
        let rates = PageRates::between(&Value::Null, &json!({}));
        assert_eq!((rates.fps, rates.updates_per_s, rates.bytes_per_update), (0.0, 0.0, 0.0));
    }
}
