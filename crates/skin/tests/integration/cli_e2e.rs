//! The command line refuses what it should and says what there is (issue
//! #38): `skin pull` of a layer that is not there or has no simulated cable,
//! `--skin` naming a skin that is not there; `skin ls`'s default listing and
//! its rates; `skin view` started before the skin it shows.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use skinware::{Reader, ReaderOptions};

use crate::util::{interrupt_and_wait, one_skin_at_a_time};

/// A segment directory of one test, removed at the end with whatever runs in it.
struct Place {
    dir: PathBuf,
    children: Vec<Child>,
}

impl Place {
    fn new(test: &str) -> Place {
        let dir = PathBuf::from("/dev/shm").join(format!("skin-cli-{}-{test}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Place { dir, children: Vec::new() }
    }

    fn skin(&self) -> Command {
        let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
        command.env("SKINWARE_SHM_DIR", &self.dir).env("RUST_LOG", "warn");
        command
    }

    /// Runs `skin ARGS` to completion.
    fn run(&self, args: &[&str]) -> Output {
        self.skin().args(args).output().unwrap()
    }

    /// Starts `skin run` of `config` (written into the directory); returns its index.
    fn start_skin(&mut self, config: &str) -> usize {
        let path = self.dir.join("config.toml");
        std::fs::write(&path, config).unwrap();
        let log = || crate::util::log_file(&self.dir, "skin-run");
        self.children
            .push(self.skin().arg("run").arg(&path).stdout(log()).stderr(log()).spawn().expect("start skin run"));
        self.children.len() - 1
    }

    /// A reader of `skin`/`channel` once it has published a frame.
    fn reader(&self, skin: &str, channel: &str) -> Reader {
        let options = ReaderOptions { dir: Some(self.dir.clone()), ..ReaderOptions::default() };
        let started = Instant::now();
        loop {
            if let Ok(mut reader) = Reader::open_with(skin, channel, &options)
                && reader.wait_newer(Duration::from_secs(5)).is_ok()
            {
                return reader;
            }
            assert!(started.elapsed() < Duration::from_secs(120), "{skin}/{channel} never published");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Waits for `skin`/`channel` to exist (a CAN layer may fault before its first frame).
    fn channel(&self, skin: &str, channel: &str) {
        let options = ReaderOptions { dir: Some(self.dir.clone()), allow_gone: true, ..ReaderOptions::default() };
        let started = Instant::now();
        while Reader::open_with(skin, channel, &options).is_err() {
            assert!(started.elapsed() < Duration::from_secs(60), "{skin}/{channel} never appeared");
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// The control files of `skin pull` in the directory.
    fn pull_files(&self) -> Vec<String> {
        std::fs::read_dir(&self.dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|name| name.starts_with("skinware-ctl."))
            .collect()
    }
}

impl Drop for Place {
    fn drop(&mut self) {
        for child in &mut self.children {
            let _ = child.kill();
            let _ = child.wait();
        }
        crate::util::show_logs_if_failing(&self.dir);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

/// The lines a child writes to a pipe, as they come.
fn lines_of(pipe: impl std::io::Read + Send + 'static) -> Receiver<String> {
    let (send, receive) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(pipe).lines().map_while(Result::ok) {
            if send.send(line).is_err() {
                return;
            }
        }
    });
    receive
}

/// The first line of `lines` that contains `text`, within `within`.
fn line_with(lines: &Receiver<String>, text: &str, within: Duration) -> String {
    let deadline = Instant::now() + within;
    loop {
        match lines.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
            Ok(line) if line.contains(text) => return line,
            Ok(_) => {}
            Err(RecvTimeoutError::Timeout) => panic!("no line with {text:?} within {within:?}"),
            Err(RecvTimeoutError::Disconnected) => panic!("the output ended without a line with {text:?}"),
        }
    }
}

/// Skin `cli`: a virtual driver's two layers (`v-0`, `v-1`) and a CAN
/// layer (`bus`) fed by an emulated MTB board.
fn virtual_and_can(dir: &Path) -> String {
    format!(
        r#"skin = "cli"

[[emulator]]
name = "board"
kind = "icub-mtb"
boards = 1
triangles = 2
rate_hz = 50
link = "{link}"

[[driver]]
name = "v"
kind = "virtual"
sensors = 240
layers = 2
rate_hz = 50

[[driver]]
name = "bus"
kind = "can"
interface = "slcan://{link}?bitrate=1000000"
protocol = "icub-mtb"
period_ms = 20
no_load = 240

[[driver.board]]
address = 1
triangles = 2
"#,
        link = dir.join("board").display()
    )
}

/// Issue #38: `skin pull virtual-9` (no such layer) and `skin pull torso` (a
/// CAN layer) both said "cable pulled", and the first left a control file.
#[test]
fn pull_refuses_what_it_cannot_pull_and_leaves_no_file() {
    let _alone = one_skin_at_a_time();
    let mut place = Place::new("pull");
    place.start_skin(&virtual_and_can(&place.dir));
    let mut pulled = place.reader("cli", "v-1");
    place.reader("cli", "v-0");
    place.channel("cli", "bus");

    let unknown = place.run(&["pull", "virtual-9", "--skin", "cli"]);
    assert!(!unknown.status.success());
    let err = stderr(&unknown);
    assert!(err.contains("skin cli has no layer virtual-9; its layers: bus, v-0, v-1"), "{err}");
    assert!(!err.contains("did you mean"), "nothing is close to virtual-9: {err}");
    let close = place.run(&["pull", "vv-1", "--skin", "cli"]);
    assert!(!close.status.success());
    assert!(stderr(&close).contains("did you mean v-1?"), "{}", stderr(&close));

    let can = place.run(&["pull", "bus", "--skin", "cli"]);
    assert!(!can.status.success());
    let err = stderr(&can);
    assert!(
        err.contains("its driver bus is of kind = \"can\", which has no simulated cable")
            && err.contains("only the layers of kind = \"virtual\" drivers can be pulled"),
        "{err}"
    );
    let other_skin = place.run(&["pull", "v-1"]);
    assert!(!other_skin.status.success());
    let err = stderr(&other_skin);
    assert!(
        err.contains("skin default is not running here") && err.contains("skin cli has a v-1: add --skin cli"),
        "{err}"
    );
    assert!(place.pull_files().is_empty(), "a refused pull left {:?}", place.pull_files());

    // What can be pulled still is, and comes back.
    let pull = place.run(&["pull", "v-1", "--skin", "cli"]);
    assert!(pull.status.success(), "{}", stderr(&pull));
    assert_eq!(place.pull_files(), ["skinware-ctl.cli.v-1.pulled"]);
    crate::util::wait_for(&mut pulled, skinware::WriterState::Faulted, Duration::from_secs(10));
    let restore = place.run(&["pull", "v-1", "--skin", "cli", "--restore"]);
    assert!(restore.status.success(), "{}", stderr(&restore));
    assert!(place.pull_files().is_empty());
    crate::util::wait_for(&mut pulled, skinware::WriterState::Running, Duration::from_secs(10));

    skin_that_is_not_there(&place);
    let status = interrupt_and_wait(&mut place.children[0], "skin run", Duration::from_secs(20));
    assert!(status.success(), "skin run exited with {status}");
}

/// Issue #38: `skin top --once --skin nosuch` printed only a header. Every
/// verb given a skin that is not there says so, names the skins that are,
/// and fails.
fn skin_that_is_not_there(place: &Place) {
    let commands: [&[&str]; 8] = [
        &["top", "--once", "--skin", "nosuch"],
        &["ls", "--skin", "nosuch"],
        &["echo", "v-0", "--skin", "nosuch", "--count", "1"],
        &["services", "--skin", "nosuch"],
        &["geometry", "--skin", "nosuch"],
        &["record", "unused.mcap", "--skin", "nosuch", "--seconds", "1"],
        &["view", "--skin", "nosuch", "--wait", "0", "--listen", "127.0.0.1:0"],
        &["ls", "--regions", "--skin", "nosuch"],
    ];
    for args in commands {
        let output = place.run(args);
        let err = stderr(&output);
        assert!(!output.status.success(), "skin {args:?} succeeded: {err}");
        assert!(output.stdout.is_empty(), "skin {args:?} printed {}", String::from_utf8_lossy(&output.stdout));
        assert!(err.contains("skin nosuch") && err.contains("the skins here: cli (3 layers)"), "skin {args:?}: {err}");
    }
    let typo = place.run(&["top", "--once", "--skin", "clj"]);
    assert!(stderr(&typo).contains("did you mean --skin cli?"), "{}", stderr(&typo));
    let layer = place.run(&["echo", "v-2", "--skin", "cli", "--count", "1"]);
    assert!(!layer.status.success());
    assert!(stderr(&layer).contains("skin cli has no layer v-2; its layers: bus, v-0, v-1"), "{}", stderr(&layer));
}

/// Files the user names that are not files: `skin info` and `skin replay`
/// of a FIFO waited forever for a writer at its other end. Each command
/// that reads a named file now refuses a FIFO (and a directory) at once,
/// naming what it found.
#[test]
fn a_fifo_or_a_directory_named_as_a_file_is_refused_at_once() {
    let place = Place::new("fifo");
    let fifo = place.dir.join("pipe.mcap");
    rustix::fs::mknodat(rustix::fs::CWD, &fifo, rustix::fs::FileType::Fifo, rustix::fs::Mode::from(0o600), 0).unwrap();
    let fifo = fifo.to_str().unwrap();
    let folder = place.dir.to_str().unwrap();
    let unused = place.dir.join("unused.mcap");
    let unused = unused.to_str().unwrap();
    let commands: [(&[&str], &str); 6] = [
        (&["info", fifo], "FIFO (named pipe)"),
        (&["replay", fifo, "--skin", "replayed"], "FIFO (named pipe)"),
        (&["run", fifo], "FIFO (named pipe)"),
        (&["record", "--recover", fifo, unused], "FIFO (named pipe)"),
        (&["info", folder], "directory"),
        (&["run", folder], "directory"),
    ];
    for (args, found) in commands {
        let mut child = place.skin().args(args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
        let status = crate::util::exit_within(&mut child, &format!("skin {args:?}"), Duration::from_secs(30));
        let mut err = String::new();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut err).unwrap();
        assert!(!status.success(), "skin {args:?} succeeded: {err}");
        assert!(err.contains(&format!("is a {found}, not a regular file")), "skin {args:?}: {err}");
    }
}

/// With no skin at all, the error says so and how to start one.
#[test]
fn no_skin_at_all_says_how_to_start_one() {
    let place = Place::new("none");
    for args in [
        &["top", "--once", "--skin", "nosuch"][..],
        &["pull", "v-0"],
        &["view", "--wait", "0", "--listen", "127.0.0.1:0"],
    ] {
        let output = place.run(args);
        let err = stderr(&output);
        assert!(!output.status.success(), "skin {args:?}: {err}");
        assert!(err.contains("`skin run CONFIG`") && err.contains("`skin demo`"), "skin {args:?}: {err}");
    }
    let listing = place.run(&["ls"]);
    assert!(listing.status.success());
    let text = String::from_utf8_lossy(&listing.stdout);
    assert!(text.starts_with("no skin runs here") && text.contains("`skin demo`"), "{text}");
    assert!(place.pull_files().is_empty());
}

/// Issue #38: `skin ls` printed a line per patch, 263 for the paper's skin.
/// By default it is one line per layer and per service; `--patches` adds a
/// line per patch.
#[test]
fn ls_is_a_line_per_layer_and_service_of_the_demo() {
    let _alone = one_skin_at_a_time();
    let mut place = Place::new("ls");
    let config =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/demo.toml")).unwrap();
    place.start_skin(&config);
    let channels =
        ["virtual-0", "virtual-1", "virtual-2", "virtual-3", "virtual-4", "contact", "contact-taxels", "motion"];
    for channel in channels {
        place.reader("default", channel);
    }
    let listing = place.run(&["ls", "--skin", "default"]);
    assert!(listing.status.success(), "{}", stderr(&listing));
    let text = String::from_utf8_lossy(&listing.stdout);
    let lines: Vec<&str> = text.lines().collect();
    println!("cli: skin ls of the demo:\n{text}");
    assert_eq!(lines.len(), channels.len(), "{text}");
    for (line, channel) in lines.iter().zip(channels) {
        assert!(line.starts_with(&format!("default/{channel}  [running]")), "{line}");
    }
    for line in &lines[..5] {
        assert!(
            line.contains(" sensors (pressure), ") && line.contains(" modules, ") && line.contains(" patches, "),
            "{line}"
        );
    }
    let json: serde_json::Value =
        serde_json::from_slice(&place.run(&["ls", "--skin", "default", "--json"]).stdout).unwrap();
    let patches: u64 = json["layers"].as_array().unwrap().iter().map(|l| l["patches"].as_u64().unwrap()).sum();
    assert_eq!(json["services"].as_array().unwrap().len(), 3);
    let detailed = place.run(&["ls", "--skin", "default", "--patches"]);
    let detailed = String::from_utf8_lossy(&detailed.stdout);
    assert_eq!(detailed.lines().count() as u64, channels.len() as u64 + patches, "{detailed}");
    assert_eq!(detailed.lines().filter(|l| l.starts_with("  patch ")).count() as u64, patches);
    let status = interrupt_and_wait(&mut place.children[0], "skin run", Duration::from_secs(30));
    assert!(status.success(), "skin run exited with {status}");
}

/// Issue #38: `skin ls` counted frames over 0.3 s, so every rate was a
/// multiple of 3.33 Hz (a 35 Hz writer showed 33.3 or 36.7). Timed by the
/// writer's own clock, it is within a fraction of a hertz.
#[test]
fn ls_times_a_writer_of_known_period() {
    let _alone = one_skin_at_a_time();
    let place = Place::new("rate");
    const HZ: f64 = 35.0;
    let topology = skinware::TopologyBuilder::new("paced", "pressure", HZ).patch(1).module(1, 0..12).build().unwrap();
    let options = skinware::WriterOptions {
        dir: Some(place.dir.clone()),
        period: Some(Duration::from_secs_f64(1.0 / HZ)),
        ..skinware::WriterOptions::default()
    };
    let mut writer =
        skinware::Writer::create("rate", "paced", topology.frame_bytes(), &topology.encode(), &options).unwrap();
    let stop = writer.stop_signal().clone();
    let paced = std::thread::spawn(move || {
        writer.run_periodic(skinware::Ticker::from_hz(HZ), |frame| frame.write_responses(0, &[7; 12])).unwrap();
    });
    let reader = place.reader("rate", "paced");
    let mut rates = Vec::new();
    for _ in 0..3 {
        let listing = place.run(&["ls", "--skin", "rate", "--json"]);
        let json: serde_json::Value = serde_json::from_slice(&listing.stdout).unwrap();
        rates.push(json["layers"][0]["rate_hz"].as_f64().unwrap());
    }
    // `skin ls` times about 10 frames (0.3 s): a frame the writer published
    // late, on a loaded machine, moves the rate by up to HZ × lateness / 0.3 s.
    // The writer's own worst lateness says how far that can be.
    let lateness_s = reader.writer_stats().lateness_ns_max as f64 / 1e9;
    let tolerance = 0.5 + HZ * lateness_s / 0.3;
    stop.stop();
    paced.join().unwrap();
    println!("cli: a {HZ} Hz writer measured by skin ls at {rates:?} Hz (worst lateness {lateness_s:.4} s)");
    for rate in rates {
        assert!((rate - HZ).abs() < tolerance, "measured {rate} Hz for a {HZ} Hz writer, late by up to {lateness_s} s");
    }
}

/// Issue #38: `skin view` started before the skin gave up on its geometry,
/// published a moment later. It waits, says so, and serves the geometry; a
/// browser that connects while the skin restarts waits for it too.
#[test]
fn view_started_before_the_skin_gets_its_geometry() {
    let _alone = one_skin_at_a_time();
    let mut place = Place::new("view");
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let mut view = place
        .skin()
        .args(["view", "--skin", "late", "--wait", "120", "--listen", &format!("127.0.0.1:{port}")])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let (stdout, stderr) = (lines_of(view.stdout.take().unwrap()), lines_of(view.stderr.take().unwrap()));
    place.children.push(view);
    let waiting = line_with(&stderr, "has no geometry yet", Duration::from_secs(30));
    assert!(waiting.contains("`skin run`, `skin replay` or `skin demo`"), "{waiting}");

    let config =
        "skin = \"late\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 240\nlayers = 2\nrate_hz = 50\n";
    let run = place.start_skin(config);
    line_with(&stdout, &format!("skin late on http://127.0.0.1:{port}/"), Duration::from_secs(120));
    let mut browser = connect(port);
    assert_eq!(geometry_counts(&mut browser), (2, 240));

    // The skin stops (its geometry goes with it); a browser that connects
    // now is told it waits, and gets the geometry of the skin started again.
    let status = interrupt_and_wait(&mut place.children[run], "skin run", Duration::from_secs(20));
    assert!(status.success(), "skin run exited with {status}");
    let late_browser = std::thread::spawn(move || {
        let mut browser = connect(port);
        let said = match browser.read().unwrap() {
            tungstenite::Message::Text(text) => text.to_string(),
            other => panic!("expected the wait to be said first, got {other:?}"),
        };
        (said, geometry_counts(&mut browser))
    });
    std::thread::sleep(Duration::from_millis(500));
    place.start_skin(config);
    let (said, layers) = late_browser.join().unwrap();
    assert!(said.contains("waiting up to 10 s for skin late's geometry"), "{said}");
    assert_eq!(layers, (2, 240));
}

/// A WebSocket client on the viewer's endpoint, as the page opens it.
fn connect(port: u16) -> tungstenite::WebSocket<std::net::TcpStream> {
    let stream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    tungstenite::client::client(format!("ws://127.0.0.1:{port}{}", skinware_viewer::protocol::WEBSOCKET_PATH), stream)
        .expect("the WebSocket handshake")
        .0
}

/// The layers and sensors of the geometry message the viewer sends first:
/// its kind byte, the protocol's version, then the counts (docs/viewer.md).
fn geometry_counts(browser: &mut tungstenite::WebSocket<std::net::TcpStream>) -> (u16, u32) {
    match browser.read().unwrap() {
        tungstenite::Message::Binary(bytes) => {
            assert_eq!(bytes[0], skinware_viewer::protocol::KIND_GEOMETRY);
            let layers = u16::from_le_bytes([bytes[2], bytes[3]]);
            (layers, u32::from_le_bytes(bytes[4..8].try_into().unwrap()))
        }
        other => panic!("expected the geometry, got {other:?}"),
    }
}
