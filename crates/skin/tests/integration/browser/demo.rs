//! `skin demo` (the paper's 30,848-sensor skin) in headless Chromium. It
//! checks that the heatmap is drawn and moves, that its pieces are labelled
//! with their body parts, that hovering names a taxel and its place, that a
//! pulled cable shows as faulted and then as recovered while the other
//! layers keep updating, that the three reader modes work (and the overlays
//! follow them), that no layer shows a false "gone" when the mode changes,
//! that the page keeps up (frame rate, lag behind the writers), and that
//! Ctrl-C leaves nothing behind, with the page saying its server is gone.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use skinware::{Reader, ReaderOptions};
use skinware_bench::chromium::PageRates;

use super::*;
use crate::util::{interrupt_and_wait, one_skin_at_a_time};

/// The skin of `examples/demo.toml`.
const SKIN: &str = "default";
/// The layer whose cable the test pulls.
const PULLED: &str = "virtual-2";
/// The page must draw at least this many new updates per second.
const MIN_FPS: f64 = 30.0;

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
            .env("RUST_LOG", "info")
            .stdout(Stdio::piped())
            .stderr(crate::util::log_file(&dir, "skin-demo"))
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
        crate::util::show_logs_if_failing(&self.dir);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
#[cfg_attr(
    skip_no_chromium,
    ignore = "needs chromium and chromedriver (Debian: apt-get install chromium chromium-driver)"
)]
fn demo_in_headless_chromium() {
    let Some(programs) = browser_programs("demo_in_headless_chromium") else {
        return;
    };
    let _alone = one_skin_at_a_time();
    let mut demo = Demo::start(free_port());
    let browser = Browser::start(&programs);
    browser.open(&demo.url);

    the_heatmap_is_drawn_and_changes(&browser);
    the_pieces_are_labelled_with_their_body_parts(&browser);
    a_page_of_the_old_protocol_is_told_to_reload(&browser);
    hovering_names_a_taxel(&browser);
    the_page_decodes_what_the_server_sent(&browser);
    the_page_keeps_up(&browser, &demo);
    a_pulled_cable_shows_as_faulted_then_recovered(&browser, &demo);
    reader_modes_work(&browser, &demo);

    // 7. Ctrl-C stops everything and leaves nothing behind; the page says its server is gone.
    let left = demo.interrupt();
    assert!(left.is_empty(), "left in the segment directory: {left:?}");
    the_page_says_its_server_is_gone(&browser);
}

/// A page of protocol 1 (open in a tab from before an upgrade) opened
/// `/ws` without a version, one of protocol 2 (raw responses) `/ws?protocol=2`:
/// each gets the text message every page shows, saying to reload, not
/// bytes it cannot read.
fn a_page_of_the_old_protocol_is_told_to_reload(browser: &Browser) {
    for (path, expected) in [("/ws", "older viewer"), ("/ws?protocol=2", "protocol 2, the server speaks 3")] {
        let answer = browser.run_async(&format!(
            "const ws = new WebSocket(`ws://${{location.host}}{path}`);
             ws.binaryType = 'arraybuffer';
             ws.onmessage = e => {{ done(typeof e.data === 'string' ? JSON.parse(e.data).error : 'binary'); ws.close(); }};
             ws.onerror = () => done('error');"
        ));
        let text = answer.as_str().unwrap_or_default();
        assert!(text.contains(expected) && text.contains("reload the page"), "a page opening {path} got {answer}");
        println!("browser: a page opening {path} is told: {text}");
    }
}

/// The page's decoder against the server's: the bytes of the update the
/// page decoded last, decoded again here with
/// `skinware_viewer::protocol::decode_update_responses` (which the
/// viewer's round-trip tests check against its encoder), give exactly the
/// responses the page holds for the layers that update carried. Taken in
/// one script, between two of the page's messages. Several updates, so
/// that contacts (wide blocks) and resting skin (narrow ones) both pass.
fn the_page_decodes_what_the_server_sent(browser: &Browser) {
    const LAST_UPDATE: &str = "
        const bytes = new Uint8Array(window.skinLastUpdate);
        const view = new DataView(window.skinLastUpdate);
        const layers = skin.layers.map((layer, l) => ({
          count: layer.count,
          shown: view.getUint8(16 + 32 * l + 1) & 1 ? Array.from(responses.subarray(layer.first, layer.first + layer.count)) : null,
        }));
        return { bytes: Array.from(bytes), layers, number: stats.lastUpdateNumber };";
    let mut layers_checked = 0;
    let mut numbers = Vec::new();
    for _ in 0..6 {
        let last = browser.run(LAST_UPDATE);
        let bytes: Vec<u8> = last["bytes"].as_array().unwrap().iter().map(|b| b.as_u64().unwrap() as u8).collect();
        let layers = last["layers"].as_array().unwrap();
        let counts: Vec<usize> = layers.iter().map(|l| l["count"].as_u64().unwrap() as usize).collect();
        let sent = skinware_viewer::protocol::decode_update_responses(&bytes, &counts)
            .unwrap_or_else(|e| panic!("the update the page decoded does not decode here: {e}"));
        for (index, (sent, layer)) in sent.iter().zip(layers).enumerate() {
            let shown: Option<Vec<u16>> =
                layer["shown"].as_array().map(|v| v.iter().map(|r| r.as_u64().unwrap() as u16).collect());
            assert_eq!(sent.is_some(), shown.is_some(), "virtual-{index}: carried by the update or not");
            if let (Some(sent), Some(shown)) = (sent, shown) {
                let differing = sent.iter().zip(&shown).filter(|(a, b)| a != b).count();
                assert_eq!(differing, 0, "virtual-{index}: {differing} taxels the page decoded differ from those sent");
                layers_checked += 1;
            }
        }
        numbers.push(last["number"].as_u64().unwrap());
        std::thread::sleep(Duration::from_millis(150));
    }
    println!("browser: the page decoded exactly what the server sent: {layers_checked} layers of updates {numbers:?}");
    assert!(layers_checked >= 3, "only {layers_checked} layers' responses were compared");
}

/// Step 2: Each map piece is labelled with its body part (the virtual
/// body's links) and the regions of `examples/demo.toml` that hold it whole.
fn the_pieces_are_labelled_with_their_body_parts(browser: &Browser) {
    let mut labels = piece_labels(browser);
    labels.sort_unstable();
    let mut expected = vec!["torso".to_owned()];
    for side in ["left", "right"] {
        for (part, region) in [("upper_arm", "arm"), ("forearm", "arm"), ("thigh", "leg"), ("shin", "leg")] {
            expected.push(format!("{side}_{part} · {side}_{region}"));
        }
    }
    expected.sort_unstable();
    assert_eq!(labels, expected, "the labels over the map's pieces");
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
    for part in
        ["uid ", "module ", "patch ", "link ", "region", "layer virtual-", "pressure", "response ", "full colour at "]
    {
        assert!(tooltip.contains(part), "tooltip {tooltip:?} lacks {part:?}");
    }
}

/// Step 3: The page keeps up: frame rate, bytes per update (compact, and
/// what protocol 2's raw responses would have been), the viewer's CPU,
/// and lag behind the writers. The CPU is printed, not asserted (it is the
/// machine's load as much as the viewer's); the bytes are asserted.
fn the_page_keeps_up(browser: &Browser, demo: &Demo) {
    let demo_pid = demo.child.id();
    let (process_before, sessions_before) = (process_cpu_ns(demo_pid), session_cpu_ns(demo_pid));
    let before = browser.run(STATS_PROBE);
    std::thread::sleep(Duration::from_secs(5));
    let after = browser.run(STATS_PROBE);
    let (process_after, sessions_after) = (process_cpu_ns(demo_pid), session_cpu_ns(demo_pid));
    let PageRates { seconds, fps, updates_per_s, bytes_per_update, raw_bytes_per_update: raw_per_update, .. } =
        PageRates::between(&before, &after);
    let percent = |ns: u64| ns as f64 / 1e9 / seconds * 100.0;
    println!(
        "browser: {fps:.1} fps (draws of new updates), {updates_per_s:.1} updates/s, {bytes_per_update:.0} bytes/update \
         ({raw_per_update:.0} with raw responses: {:.1} %), decoding {:.3} ms/update, \
         geometry {} bytes, render {:.2} ms/draw, over {seconds:.1} s, 30,848 sensors",
        100.0 * bytes_per_update / raw_per_update,
        after["decodeMs"].as_f64().unwrap(),
        after["geometryBytes"],
        after["renderMs"].as_f64().unwrap()
    );
    println!(
        "browser: viewer CPU: its browser session {:.2} % of a core, the whole skin demo process {:.1} % (supervisor, drivers, services, viewer)",
        percent(sessions_after.saturating_sub(sessions_before)),
        percent(process_after.saturating_sub(process_before)),
    );
    assert!(fps >= MIN_FPS, "the page drew {fps:.1} new updates per second; it must keep {MIN_FPS}");
    assert!((100.0..=62_000.0).contains(&bytes_per_update), "{bytes_per_update} bytes per update");
    assert!(
        2.0 * bytes_per_update <= raw_per_update,
        "the compact encoding must halve the bytes: {bytes_per_update:.0} against {raw_per_update:.0} raw"
    );
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
    browser.screenshot("viewer-paper.png");
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

/// Step 5: Reader modes: periodic at the chosen rate, on request only when
/// asked, with the overlays following the requested frames and the colour
/// range control changing the scale of frames that stay still; and no
/// layer shown gone by a change of mode (only connecting, at most).
fn reader_modes_work(browser: &Browser, demo: &Demo) {
    let before = (0..5).map(|layer| states_seen(browser, layer).len()).collect::<Vec<_>>();
    choose_mode(browser, "periodic", 10.0);
    wait_for("virtual-0 to be read at about 10 Hz", Duration::from_secs(15), || {
        let rate: f64 = browser
            .run("return document.querySelector('tr[data-layer=\"virtual-0\"]').cells[4].textContent;")
            .as_str()?
            .parse()
            .ok()?;
        (7.0..=13.0).contains(&rate).then_some(())
    });
    no_layer_was_shown_gone_since(browser, &before);
    a_killed_driver_shows_gone_then_its_successor_in_periodic_mode(browser, demo);
    let before = (0..5).map(|layer| states_seen(browser, layer).len()).collect::<Vec<_>>();
    choose_mode(browser, "request", 10.0);
    std::thread::sleep(Duration::from_millis(500));
    let idle = seqs(browser);
    std::thread::sleep(Duration::from_secs(1));
    assert_eq!(seqs(browser), idle, "frames arrived in on-request mode without a request");
    browser.run("document.getElementById('request').click();");
    wait_for("every layer to answer the request", Duration::from_secs(10), || {
        seqs(browser).iter().zip(&idle).all(|(new, old)| new > old).then_some(())
    });
    the_overlays_stay_with_the_requested_frames(browser);
    the_colour_range_control_changes_the_scale(browser);
    choose_mode(browser, "asap", 10.0);
    wait_for("every layer running again in asap mode", Duration::from_secs(10), || {
        (0..5).all(|l| layer_state(browser, &format!("virtual-{l}")).0 == "running").then_some(())
    });
    no_layer_was_shown_gone_since(browser, &before);
}

/// The states the page was told of since `before` (each layer's count of
/// states seen then) hold no "gone": a layer a new reader has not read yet
/// is connecting.
fn no_layer_was_shown_gone_since(browser: &Browser, before: &[usize]) {
    for (layer, &from) in before.iter().enumerate() {
        let seen = states_seen(browser, layer);
        let since = &seen[from.min(seen.len())..];
        println!("browser: virtual-{layer} states shown across the change of mode: {since:?}");
        assert!(
            !since.iter().any(|state| state == "gone"),
            "virtual-{layer} was shown gone by a change of mode: {since:?}"
        );
    }
}

/// On request, the updates between requests (new rates) keep the contacts
/// of the frames requested: the heatmap stands still, and so do its circles.
fn the_overlays_stay_with_the_requested_frames(browser: &Browser) {
    wait_for("requested frames with contacts on them", Duration::from_secs(30), || {
        browser.run("document.getElementById('request').click();");
        std::thread::sleep(Duration::from_millis(400));
        (browser.run(STATS_PROBE)["markers"].as_u64()? > 0).then_some(())
    });
    let held = browser.run(STATS_PROBE);
    let updates = held["updates"].as_u64().unwrap();
    wait_for("updates between requests (new rates)", Duration::from_secs(10), || {
        (browser.run(STATS_PROBE)["updates"].as_u64()? >= updates + 3).then_some(())
    });
    let later = browser.run(STATS_PROBE);
    println!(
        "browser: on request, {} updates without a request carried the same {} contact(s)",
        later["updates"].as_u64().unwrap() - updates,
        later["markers"]
    );
    assert_eq!(later["overlayChanges"], held["overlayChanges"], "the contacts moved without a request");
    assert_eq!(later["markers"], held["markers"]);
}

/// The colour range typed in for the sensor type changes the colours of
/// the same (requested, still) frames; "auto" brings back the learnt one.
fn the_colour_range_control_changes_the_scale(browser: &Browser) {
    let stats = browser.run(STATS_PROBE);
    let auto = stats["autoScales"][0].as_u64().unwrap();
    assert!(auto > 1_000, "the virtual skin's learnt full scale is {auto}");
    // Full colour at 20 above baseline: the resting skin's noise (±8) lights up.
    let [lit_auto, lit_narrow, lit_back] = lit_at_scales(browser, "pressure", 20);
    println!(
        "browser: lit pixels of the same frames: {lit_auto} at auto ({auto}), {lit_narrow} at 20, {lit_back} back at auto"
    );
    assert!(lit_narrow > 3 * lit_auto.max(1_000), "a narrow range must light the noise: {lit_narrow} vs {lit_auto}");
    assert!(lit_back.abs_diff(lit_auto) * 20 <= lit_auto.max(100), "auto again: {lit_back} vs {lit_auto}");
    assert_eq!(browser.run(STATS_PROBE)["fullScales"][0], browser.run(STATS_PROBE)["autoScales"][0]);
}

/// Step 7: Once the demo stopped, the page says its server is gone, shows
/// no rates and draws no contacts.
fn the_page_says_its_server_is_gone(browser: &Browser) {
    let said = wait_for("the page to say its server is gone", Duration::from_secs(10), || {
        banner(browser).filter(|text| text.contains("server is gone"))
    });
    println!("browser: after Ctrl-C the page says: {said}");
    wait_for("the rates to be cleared", Duration::from_secs(5), || {
        rate_cells(browser, "virtual-0").iter().all(|cell| cell == "\u{2014}").then_some(())
    });
    let stats = browser.run(STATS_PROBE);
    assert_eq!((stats["markers"].as_u64(), stats["arrows"].as_u64()), (Some(0), Some(0)), "stale contacts");
    assert_eq!(stats["skinState"], "server gone");
    assert_eq!(layer_state(browser, "virtual-0").1, "unknown");
}

/// The CPU time of process `pid` so far, ns (utime + stime, in clock ticks).
fn process_cpu_ns(pid: u32) -> u64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // The fields after the command name, which may hold spaces, in parentheses.
    let fields: Vec<&str> = stat.rsplit_once(')').map_or(vec![], |(_, rest)| rest.split_whitespace().collect());
    let ticks: u64 = [11, 12].iter().map(|&n| fields.get(n).and_then(|f| f.parse::<u64>().ok()).unwrap_or(0)).sum();
    ticks * 1_000_000_000 / rustix::param::clock_ticks_per_second()
}

/// The run time so far of process `pid`'s browser sessions (the threads
/// the viewer names `browser-PORT`, which encode and send the updates), ns,
/// from each thread's schedstat.
fn session_cpu_ns(pid: u32) -> u64 {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return 0 };
    tasks
        .flatten()
        .filter(|task| {
            std::fs::read_to_string(task.path().join("comm"))
                .is_ok_and(|comm| comm.starts_with(skinware_viewer::server::BROWSER_THREAD_PREFIX))
        })
        .filter_map(|task| std::fs::read_to_string(task.path().join("schedstat")).ok())
        .filter_map(|stat| stat.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}
