//! The viewer in a real browser: headless Chromium, driven through
//! chromedriver with the W3C WebDriver protocol, looking at two skins:
//!
//! - [`demo`]: `skin demo`, the paper's 30,848-sensor virtual skin with its
//!   contact and motion services;
//! - [`icub`]: `skin view` of `examples/icub-can.toml`, an 8-bit iCub skin
//!   on emulated CAN boards (`skin run` with its `[[emulator]]`s), started
//!   after the viewer and stopped before it.
//!
//! Both save screenshots in `target/browser/`. They need `chromium` and
//! `chromedriver` (Debian: `apt-get install chromium chromium-driver`);
//! without them they are skipped, except under `CI=true`.

#![forbid(unsafe_code)]

mod demo;
mod icub;

use std::path::{Path, PathBuf};
use std::process::Child;
use std::time::{Duration, Instant};

use serde_json::Value;
use skinware_bench::chromium::{self, Programs, STATS_PROBE};

/// chromedriver and Chromium, if both are installed; `None` (the test
/// then skips, saying why) if not, except under `CI=true`, which fails.
fn browser_programs(test: &str) -> Option<Programs> {
    match Programs::find() {
        Ok(programs) => Some(programs),
        Err(reason) => {
            assert!(std::env::var("CI").as_deref() != Ok("true"), "CI must run the browser test, but {reason}");
            println!("SKIPPED: {test}: {reason}");
            None
        }
    }
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
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
fn wait_for<T>(what: &str, within: Duration, probe: impl FnMut() -> Option<T>) -> T {
    chromium::wait_for(what, within, probe).unwrap_or_else(|e| panic!("{e}"))
}

/// The bench's WebDriver client ([`chromium::Browser`]), whose failures
/// fail the test.
struct Browser(chromium::Browser);

impl Browser {
    fn start(programs: &Programs) -> Browser {
        Browser(chromium::Browser::start(programs).unwrap_or_else(|e| panic!("start a Chromium session: {e}")))
    }

    fn open(&self, url: &str) {
        self.0.open(url).unwrap_or_else(|e| panic!("open {url}: {e}"));
    }

    fn run(&self, script: &str) -> Value {
        self.0.run(script).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Runs `script`, which calls `done(value)` (its last argument) when
    /// it has the answer; returns the value.
    fn run_async(&self, script: &str) -> Value {
        self.0.run_async(script).unwrap_or_else(|e| panic!("{e}"))
    }

    fn screenshot(&self, name: &str) -> PathBuf {
        let png = self.0.screenshot_png().unwrap_or_else(|e| panic!("{e}"));
        let path = artifact_dir().join(name);
        std::fs::write(&path, &png).unwrap();
        println!("browser: screenshot {} ({} bytes)", path.display(), png.len());
        path
    }
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

/// The labels the page shows over the map's pieces.
fn piece_labels(browser: &Browser) -> Vec<String> {
    let labels = browser.run(
        "return [...document.querySelectorAll('#labels .piece-label')].filter(e => !e.hidden).map(e => e.textContent);",
    );
    labels.as_array().unwrap().iter().map(|l| l.as_str().unwrap().to_owned()).collect()
}

/// What the page's banner says of the whole skin, if it shows.
fn banner(browser: &Browser) -> Option<String> {
    let text = browser.run("const b = document.getElementById('banner'); return b.hidden ? null : b.textContent;");
    text.as_str().map(str::to_owned)
}

/// The writer rate, read rate and latency cells of `layer`'s row.
fn rate_cells(browser: &Browser, layer: &str) -> Vec<String> {
    let script = format!(
        "const row = document.querySelector('#layers tr[data-layer=\"{layer}\"]');
         return [3, 4, 5].map(i => row.cells[i].textContent);"
    );
    browser.run(&script).as_array().unwrap().iter().map(|c| c.as_str().unwrap().to_owned()).collect()
}

/// The states the page was told of `layer` (by index), each change once, in order.
fn states_seen(browser: &Browser, layer: usize) -> Vec<String> {
    let seen = browser.run(&format!("return (window.skinStats.statesSeen[{layer}] || []).slice();"));
    seen.as_array().unwrap().iter().map(|s| s.as_str().unwrap().to_owned()).collect()
}

/// Types `full_scale` into the colour range control of `sensor_type`, as a
/// user does (the input's change event), or presses its "auto" button.
fn set_full_scale(browser: &Browser, sensor_type: &str, full_scale: Option<u32>) {
    let row = format!("document.querySelector('#ranges tr[data-sensor-type=\"{sensor_type}\"]')");
    match full_scale {
        Some(value) => browser.run(&format!(
            "const input = {row}.querySelector('input');
             input.value = '{value}';
             input.dispatchEvent(new Event('change'));"
        )),
        None => browser.run(&format!("{row}.querySelector('button').click();")),
    };
}

/// Pixels of the canvas brighter than a resting taxel, once the page drew
/// after `change` (which makes it draw: a change of the colour range).
fn lit_after(browser: &Browser, change: impl FnOnce()) -> u64 {
    let draws = browser.run(STATS_PROBE)["draws"].as_u64().unwrap();
    change();
    wait_for("the page to draw again", Duration::from_secs(10), || {
        (browser.run(STATS_PROBE)["draws"].as_u64()? > draws).then_some(())
    });
    browser.run(CANVAS_PROBE)["lit"].as_u64().unwrap()
}

/// What nothing but the colour range may change on the canvas of the
/// on-request mode: every layer's newest frame and every state it was shown in.
fn still(browser: &Browser) -> Value {
    browser.run("return [window.skinStats.seqs, window.skinStats.statesSeen];")
}

/// The lit pixels of the same still frames (on request) at the automatic
/// range, at `full_scale` typed in for `sensor_type`, and at "auto" again.
/// Measured while every layer runs, and again if a frame or a layer's
/// state changed meanwhile (a loaded machine may make a layer late, and the
/// page hatch it faulted).
fn lit_at_scales(browser: &Browser, sensor_type: &str, full_scale: u32) -> [u64; 3] {
    const ALL_RUNNING: &str = "return window.skinStats.statesSeen.every(seen => seen[seen.length - 1] === 'running');";
    for _ in 0..20 {
        if browser.run(ALL_RUNNING) != true {
            println!("browser: a layer is not running (a loaded machine?); the colour range is measured once it is");
            std::thread::sleep(Duration::from_millis(500));
            continue;
        }
        let before = still(browser);
        let lit_auto = browser.run(CANVAS_PROBE)["lit"].as_u64().unwrap();
        let lit_typed = lit_after(browser, || set_full_scale(browser, sensor_type, Some(full_scale)));
        let legend = browser.run("return document.getElementById('scale-max').textContent;");
        assert_eq!(legend.as_str().map(|text| text.replace(',', "")), Some(full_scale.to_string()), "the legend's end");
        let lit_back = lit_after(browser, || set_full_scale(browser, sensor_type, None));
        if still(browser) == before {
            return [lit_auto, lit_typed, lit_back];
        }
        println!("browser: the frames or states changed while the colour range was measured; again");
    }
    panic!("the on-request frames never stayed still long enough to compare colour ranges");
}
