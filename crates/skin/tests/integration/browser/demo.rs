//! The viewer in a real browser: `skin demo` (the paper's 30,848-sensor skin)
//! looked at by headless Chromium, driven through chromedriver with the W3C
//! WebDriver protocol. It checks that the heatmap is drawn and moves, that
//! hovering names a taxel, that a pulled cable shows as faulted and then as
//! recovered while the other layers keep updating, that the three reader modes
//! work, that the page keeps up (frame rate, lag behind the writers), and that
//! Ctrl-C leaves nothing behind. It saves screenshots in `target/browser/`.
//!
//! Needs `chromium` and `chromedriver` (Debian: `apt-get install chromium
//! chromium-driver`). Without them it is skipped, except under `CI=true`.

#![forbid(unsafe_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use skinware::{Reader, ReaderOptions};

use crate::util::{interrupt_and_wait, one_skin_at_a_time};

/// The skin of `examples/demo.toml`.
const SKIN: &str = "default";
/// The layer whose cable the test pulls.
const PULLED: &str = "virtual-2";
/// The page must draw at least this many new updates per second.
const MIN_FPS: f64 = 30.0;

fn find_program(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    names.iter().flat_map(|name| std::env::split_paths(&path).map(move |dir| dir.join(name))).find(|p| p.is_file())
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// Where screenshots go: `target/browser/`, wherever the target directory is.
fn artifact_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).parent().unwrap().join("browser");
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn send_signal(pid: u32, signal: rustix::process::Signal) {
    if let Some(pid) = rustix::process::Pid::from_raw(pid as i32) {
        let _ = rustix::process::kill_process(pid, signal);
    }
}

fn wait_for_exit(child: &mut Child, within: Duration) -> Option<std::process::ExitStatus> {
    let started = Instant::now();
    while started.elapsed() < within {
        if let Ok(Some(status)) = child.try_wait() {
            return Some(status);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    None
}

/// Polls `probe` until it returns something, or fails the test naming `what`.
fn wait_for<T>(what: &str, within: Duration, mut probe: impl FnMut() -> Option<T>) -> T {
    let started = Instant::now();
    loop {
        if let Some(value) = probe() {
            return value;
        }
        assert!(started.elapsed() < within, "timed out after {within:?} waiting for {what}");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// `skin demo` in its own segment directory; stopped (and its directory
/// removed) when dropped, even if the test failed.
struct Demo {
    child: Child,
    dir: PathBuf,
    url: String,
}

impl Demo {
    fn start(port: u16) -> Demo {
        let dir = PathBuf::from("/dev/shm").join(format!("skin-browser-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_skin"))
            .args(["demo", "--no-browser-hint", "--listen", &format!("127.0.0.1:{port}")])
            .env("SKINWARE_SHM_DIR", &dir)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .expect("start skin demo");
        let stdout = child.stdout.take().unwrap();
        let (lines, received) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                println!("demo: {line}");
                let _ = lines.send(line);
            }
        });
        let mut demo = Demo { child, dir, url: String::new() };
        let started = Instant::now();
        demo.url = loop {
            match received.recv_timeout(Duration::from_millis(200)) {
                Ok(line) => {
                    if let Some(url) = line.strip_prefix("skin demo: ") {
                        break url.trim().to_owned();
                    }
                }
                Err(_) => {
                    if let Ok(Some(status)) = demo.child.try_wait() {
                        panic!("skin demo exited with {status} before printing its URL");
                    }
                    assert!(started.elapsed() < Duration::from_secs(120), "skin demo printed no URL in 120 s");
                }
            }
        };
        assert_eq!(demo.url, format!("http://127.0.0.1:{port}/"));
        demo
    }

    fn skin_command(&self) -> Command {
        let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
        command.env("SKINWARE_SHM_DIR", &self.dir);
        command
    }

    fn pull(&self, restore: bool) {
        let mut command = self.skin_command();
        command.args(["pull", PULLED, "--skin", SKIN]);
        if restore {
            command.arg("--restore");
        }
        let output = command.output().unwrap();
        assert!(output.status.success(), "skin pull: {}", String::from_utf8_lossy(&output.stderr));
    }

    fn reader(&self, layer: &str) -> Reader {
        let options = ReaderOptions { dir: Some(self.dir.clone()), ..ReaderOptions::default() };
        Reader::open_with(SKIN, layer, &options).unwrap()
    }

    /// Ctrl-C; returns the names left in the segment directory.
    fn interrupt(&mut self) -> Vec<String> {
        let status = interrupt_and_wait(&mut self.child, "skin demo", Duration::from_secs(30));
        assert!(status.success(), "skin demo exited with {status} on SIGINT");
        std::fs::read_dir(&self.dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect()
    }
}

impl Drop for Demo {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            // SIGTERM first, so that the supervisor stops its drivers and removes its channels.
            send_signal(self.child.id(), rustix::process::Signal::TERM);
            if wait_for_exit(&mut self.child, Duration::from_secs(15)).is_none() {
                let _ = self.child.kill();
                let _ = self.child.wait();
            }
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// One HTTP/1.1 exchange with chromedriver, which answers with a
/// Content-Length (and may keep the connection open regardless).
fn http(port: u16, method: &str, path: &str, body: Option<&Value>) -> Result<Value, String> {
    let address = ([127, 0, 0, 1], port).into();
    let mut stream = TcpStream::connect_timeout(&address, Duration::from_secs(5)).map_err(|e| e.to_string())?;
    stream.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let body = body.map(Value::to_string).unwrap_or_default();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\
         Content-Type: application/json; charset=utf-8\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    )
    .map_err(|e| e.to_string())?;
    let mut reply = Vec::new();
    let mut chunk = [0u8; 64 * 1024];
    let (head_end, length) = loop {
        let n = stream.read(&mut chunk).map_err(|e| format!("{method} {path}: {e}"))?;
        if n == 0 {
            return Err(format!("{method} {path}: connection closed after {} bytes", reply.len()));
        }
        reply.extend_from_slice(&chunk[..n]);
        if let Some(at) = reply.windows(4).position(|w| w == b"\r\n\r\n") {
            let head = String::from_utf8_lossy(&reply[..at]).to_ascii_lowercase();
            let length = head
                .lines()
                .find_map(|l| l.strip_prefix("content-length:"))
                .and_then(|v| v.trim().parse::<usize>().ok());
            break (at + 4, length.ok_or_else(|| format!("{method} {path}: no Content-Length in {head:?}"))?);
        }
    };
    while reply.len() < head_end + length {
        let n = stream.read(&mut chunk).map_err(|e| format!("{method} {path}: {e}"))?;
        if n == 0 {
            return Err(format!("{method} {path}: reply cut short"));
        }
        reply.extend_from_slice(&chunk[..n]);
    }
    let head = String::from_utf8_lossy(&reply[..head_end]);
    let status: u16 = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
    let body = &reply[head_end..head_end + length];
    let value: Value = serde_json::from_slice(body)
        .map_err(|e| format!("{method} {path}: not JSON ({e}): {}", String::from_utf8_lossy(body)))?;
    if status != 200 {
        return Err(format!("{method} {path}: HTTP {status}: {}", value["value"]["message"]));
    }
    Ok(value["value"].clone())
}

/// chromedriver and one headless Chromium session; both ended when dropped.
struct Browser {
    driver: Child,
    port: u16,
    session: String,
}

impl Browser {
    fn start(chromedriver: &Path, chromium: &Path) -> Browser {
        let port = free_port();
        let driver = Command::new(chromedriver)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromedriver");
        let mut browser = Browser { driver, port, session: String::new() };
        wait_for("chromedriver to be ready", Duration::from_secs(60), || {
            http(port, "GET", "/status", None).ok().filter(|v| v["ready"] == true)
        });
        let capabilities = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chromium,
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                         "--window-size=1400,900", "--hide-scrollbars"],
            },
        }}});
        let session = http(port, "POST", "/session", Some(&capabilities)).expect("start a Chromium session");
        browser.session = session["sessionId"].as_str().expect("a session id").to_owned();
        browser
    }

    fn command(&self, method: &str, path: &str, body: Option<&Value>) -> Value {
        let path = format!("/session/{}{path}", self.session);
        http(self.port, method, &path, body).unwrap_or_else(|e| panic!("WebDriver: {e}"))
    }

    fn run(&self, script: &str) -> Value {
        self.command("POST", "/execute/sync", Some(&json!({ "script": script, "args": [] })))
    }

    fn screenshot(&self, name: &str) -> PathBuf {
        let encoded = self.command("GET", "/screenshot", None);
        let png = base64_decode(encoded.as_str().expect("base64 screenshot"));
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "the screenshot is not a PNG");
        let path = artifact_dir().join(name);
        std::fs::write(&path, &png).unwrap();
        println!("browser: screenshot {} ({} bytes)", path.display(), png.len());
        path
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

fn base64_decode(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        b'/' => 63,
        _ => panic!("not base64: {c:?}"),
    };
    let digits: Vec<u8> = text.bytes().filter(|c| !c.is_ascii_whitespace() && *c != b'=').map(value).collect();
    let mut out = Vec::with_capacity(digits.len() * 3 / 4);
    for chunk in digits.chunks(4) {
        let bits = chunk.iter().enumerate().fold(0u32, |acc, (i, &d)| acc | u32::from(d) << (18 - 6 * i));
        out.extend_from_slice(&bits.to_be_bytes()[1..chunk.len()]);
    }
    out
}

/// The canvas: how many distinct colours (up to 1000), a hash of its
/// pixels, and how many pixels are brighter than a resting taxel.
const CANVAS_PROBE: &str = r#"
    const c = document.getElementById('map');
    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
    const colours = new Set(); let hash = 0, lit = 0;
    for (let i = 0; i < d.length; i += 4) {
      const v = (d[i] << 16) | (d[i + 1] << 8) | d[i + 2];
      if (colours.size < 1000) colours.add(v);
      hash = (Math.imul(hash, 31) + v) | 0;
      if (d[i] + d[i + 1] + d[i + 2] > 150) lit++;
    }
    return { width: c.width, height: c.height, distinct: colours.size, hash, lit };
"#;

const STATS_PROBE: &str = "return Object.assign({ now: performance.now() }, window.skinStats);";

fn layer_state(browser: &Browser, layer: &str) -> (String, String) {
    let script = format!(
        "const row = document.querySelector('tr[data-layer=\"{layer}\"]');
         return row ? [row.dataset.state, row.querySelector('.badge').textContent] : null;"
    );
    let value = browser.run(&script);
    (value[0].as_str().unwrap_or_default().to_owned(), value[1].as_str().unwrap_or_default().to_owned())
}

fn seqs(browser: &Browser) -> Vec<u64> {
    browser.run(STATS_PROBE)["seqs"].as_array().unwrap().iter().map(|s| s.as_u64().unwrap()).collect()
}

fn choose_mode(browser: &Browser, mode: &str, rate_hz: f64) {
    browser.run(&format!(
        "document.getElementById('rate').value = '{rate_hz}';
         document.querySelector('input[name=mode][value={mode}]').checked = true;
         document.getElementById('mode').dispatchEvent(new Event('change'));"
    ));
    wait_for(&format!("the page to report mode {mode}"), Duration::from_secs(10), || {
        (browser.run(STATS_PROBE)["mode"] == mode).then_some(())
    });
}

#[test]
fn demo_in_headless_chromium() {
    let chromedriver = find_program(&["chromedriver"]);
    let chromium = find_program(&["chromium", "chromium-browser", "google-chrome"]);
    let (Some(chromedriver), Some(chromium)) = (chromedriver, chromium) else {
        let reason = "chromium and chromedriver are not installed (Debian: apt-get install chromium chromium-driver)";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "CI must run the browser test, but {reason}");
        println!("SKIPPED: demo_in_headless_chromium: {reason}");
        return;
    };
    let _alone = one_skin_at_a_time();
    let mut demo = Demo::start(free_port());
    let browser = Browser::start(&chromedriver, &chromium);
    browser.command("POST", "/url", Some(&json!({ "url": demo.url })));

    the_heatmap_is_drawn_and_changes(&browser);
    hovering_names_a_taxel(&browser);
    the_page_keeps_up(&browser, &demo);
    a_pulled_cable_shows_as_faulted_then_recovered(&browser, &demo);
    reader_modes_work(&browser, &demo);

    // 6. Ctrl-C stops everything and leaves nothing behind.
    drop(browser);
    let left = demo.interrupt();
    assert!(left.is_empty(), "left in the segment directory: {left:?}");
}

/// Step 1: The heatmap is drawn, is not uniform, and changes.
fn the_heatmap_is_drawn_and_changes(browser: &Browser) {
    wait_for("the first updates to be drawn", Duration::from_secs(60), || {
        (browser.run(STATS_PROBE)["draws"].as_u64()? >= 5).then_some(())
    });
    let first = browser.run(CANVAS_PROBE);
    println!("browser: canvas {first}");
    assert!(first["width"].as_u64().unwrap() >= 300 && first["height"].as_u64().unwrap() >= 200);
    assert!(first["distinct"].as_u64().unwrap() >= 3, "the canvas is (nearly) uniform: {first}");
    wait_for("the canvas to change", Duration::from_secs(10), || {
        (browser.run(CANVAS_PROBE)["hash"] != first["hash"]).then_some(())
    });
    wait_for("a contact to be drawn", Duration::from_secs(30), || {
        (browser.run(CANVAS_PROBE)["lit"].as_u64()? > 20).then_some(())
    });
    // The services' overlays: contact markers and motion arrows.
    wait_for("contact markers and motion arrows", Duration::from_secs(30), || {
        let stats = browser.run(STATS_PROBE);
        (stats["updatesWithMarkers"].as_u64()? > 0 && stats["updatesWithArrows"].as_u64()? > 0).then_some(())
    });
}

/// Step 2: Hovering names a taxel.
fn hovering_names_a_taxel(browser: &Browser) {
    let tooltip = browser.run(
        "const c = document.getElementById('map'), r = c.getBoundingClientRect();
         const tip = document.getElementById('tooltip');
         for (let y = 4; y < r.height; y += 5) for (let x = 4; x < r.width; x += 5) {
           c.dispatchEvent(new MouseEvent('mousemove', { clientX: r.left + x, clientY: r.top + y, bubbles: true }));
           if (!tip.hidden) return tip.textContent;
         }
         return null;",
    );
    let tooltip = tooltip.as_str().expect("hovering the map never showed a tooltip");
    for part in ["uid ", "module ", "patch ", "layer virtual-", "response "] {
        assert!(tooltip.contains(part), "tooltip {tooltip:?} lacks {part:?}");
    }
}

/// Step 3: The page keeps up: frame rate, bytes per update, and lag behind the writers.
fn the_page_keeps_up(browser: &Browser, demo: &Demo) {
    let before = browser.run(STATS_PROBE);
    std::thread::sleep(Duration::from_secs(5));
    let after = browser.run(STATS_PROBE);
    let delta = |key: &str| after[key].as_f64().unwrap() - before[key].as_f64().unwrap();
    let seconds = delta("now") / 1e3;
    let fps = delta("draws") / seconds;
    let updates_per_second = delta("updates") / seconds;
    let bytes_per_update = delta("updateBytes") / delta("updates").max(1.0);
    println!(
        "browser: {fps:.1} fps (draws of new updates), {updates_per_second:.1} updates/s, {bytes_per_update:.0} bytes/update, \
         geometry {} bytes, render {:.2} ms/draw, over {seconds:.1} s, 30,848 sensors",
        after["geometryBytes"],
        after["renderMs"].as_f64().unwrap()
    );
    assert!(fps >= MIN_FPS, "the page drew {fps:.1} new updates per second; it must keep {MIN_FPS}");
    assert!((100.0..=62_000.0).contains(&bytes_per_update), "{bytes_per_update} bytes per update");
    let mut newest = demo.reader("virtual-0");
    let lags: Vec<u64> = (0..5)
        .map(|_| {
            std::thread::sleep(Duration::from_millis(200));
            let shown = seqs(browser)[0];
            newest.latest().unwrap().seq().saturating_sub(shown)
        })
        .collect();
    println!("browser: virtual-0 frames behind the writer: {lags:?}");
    assert!(lags.iter().min().unwrap() <= &4, "the page lags behind the writer by {lags:?} frames");
    assert!(lags.iter().max().unwrap() <= &25, "the page fell behind the writer by {lags:?} frames");
    browser.screenshot("view.png");
}

/// Step 4: A pulled cable shows as faulted while the other layers keep updating; then recovered.
fn a_pulled_cable_shows_as_faulted_then_recovered(browser: &Browser, demo: &Demo) {
    demo.pull(false);
    let (state, badge) = wait_for("the pulled layer to show as faulted", Duration::from_secs(15), || {
        Some(layer_state(browser, PULLED)).filter(|(state, _)| state == "faulted")
    });
    assert_eq!(badge, "faulted");
    println!("browser: {PULLED} shows {state}");
    let frozen = seqs(browser);
    std::thread::sleep(Duration::from_secs(1));
    let moved = seqs(browser);
    let pulled_index = 2;
    for (index, (old, new)) in frozen.iter().zip(&moved).enumerate() {
        if index != pulled_index {
            assert!(new > old, "layer virtual-{index} stopped updating while {PULLED} was pulled");
            assert_eq!(layer_state(browser, &format!("virtual-{index}")).0, "running");
        }
    }
    browser.screenshot("view-faulted.png");
    demo.pull(true);
    wait_for("the pulled layer to show as running again", Duration::from_secs(15), || {
        (layer_state(browser, PULLED).0 == "running").then_some(())
    });
    let recovered = seqs(browser)[pulled_index];
    wait_for("fresh frames of the recovered layer", Duration::from_secs(10), || {
        (seqs(browser)[pulled_index] > recovered).then_some(())
    });
}

/// In periodic mode a reader keeps getting the last frame of a writer that
/// died, which still says "running": the viewer must show the layer gone
/// (the kernel's word, not the dead writer's last one), then follow the
/// driver the demo restarts and show its frames.
fn a_killed_driver_shows_gone_then_its_successor_in_periodic_mode(browser: &Browser, demo: &Demo) {
    const STATES_SEEN: &str = "return window.skinStats.statesSeen[0].slice();";
    let pid = demo.reader("virtual-0").writer_pid();
    let before = seqs(browser)[0];
    let states_before = browser.run(STATES_SEEN).as_array().map_or(0, Vec::len);
    send_signal(pid, rustix::process::Signal::KILL);
    let started = Instant::now();
    // The page records every state an update reported, so a short gap is not missed between two looks.
    wait_for("virtual-0 to be reported gone after its driver was SIGKILLed", Duration::from_secs(15), || {
        let seen = browser.run(STATES_SEEN);
        seen.as_array()?.iter().skip(states_before).any(|state| state == "gone").then_some(())
    });
    let gone_after = started.elapsed();
    // The successor's sequence numbers start again from 1.
    wait_for("the restarted driver's frames in periodic mode", Duration::from_secs(30), || {
        let options = ReaderOptions { dir: Some(demo.dir.clone()), ..ReaderOptions::default() };
        let successor = Reader::open_with(SKIN, "virtual-0", &options).ok()?.writer_pid();
        (successor != pid && layer_state(browser, "virtual-0").0 == "running" && seqs(browser)[0] < before)
            .then_some(())
    });
    let running = started.elapsed();
    let shown = seqs(browser)[0];
    wait_for("further frames of the restarted driver", Duration::from_secs(10), || {
        (seqs(browser)[0] > shown).then_some(())
    });
    println!(
        "browser: driver {pid} SIGKILLed in periodic mode: gone reported after {:.0} ms, its successor's frames after {:.0} ms",
        gone_after.as_secs_f64() * 1e3,
        running.as_secs_f64() * 1e3
    );
}

/// Step 5: Reader modes: periodic at the chosen rate, on request only when asked.
fn reader_modes_work(browser: &Browser, demo: &Demo) {
    choose_mode(browser, "periodic", 10.0);
    wait_for("virtual-0 to be read at about 10 Hz", Duration::from_secs(15), || {
        let rate: f64 = browser
            .run("return document.querySelector('tr[data-layer=\"virtual-0\"]').cells[4].textContent;")
            .as_str()?
            .parse()
            .ok()?;
        (7.0..=13.0).contains(&rate).then_some(())
    });
    a_killed_driver_shows_gone_then_its_successor_in_periodic_mode(browser, demo);
    choose_mode(browser, "request", 10.0);
    std::thread::sleep(Duration::from_millis(500));
    let idle = seqs(browser);
    std::thread::sleep(Duration::from_secs(1));
    assert_eq!(seqs(browser), idle, "frames arrived in on-request mode without a request");
    browser.run("document.getElementById('request').click();");
    wait_for("every layer to answer the request", Duration::from_secs(10), || {
        seqs(browser).iter().zip(&idle).all(|(new, old)| new > old).then_some(())
    });
    choose_mode(browser, "asap", 10.0);
}
