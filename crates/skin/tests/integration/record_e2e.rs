//! End to end through the CLI, on the paper's skin (5 layers, 30,848 taxels,
//! contact and motion services): `skin record` for 10 s, `skin replay` of it
//! recorded again (frames bit for bit, timing printed), a recorder killed
//! with SIGKILL (`skin info` says so, `--recover` finishes the file), and
//! Python's `mcap` + `mcap-ros2-support` as the independent reader of what
//! was written.
//!
//! The oracle needs a Python with `mcap` and `mcap-ros2-support`:
//! `$SKINWARE_PYTHON` (`.ci/run` makes a venv), else `python3`. Without it
//! that part says so and is skipped, except under `CI=true`, where it fails.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use sha2::Digest;
use skinware_record::file::{RecordStream, RecordingHeader, read_header};
use skinware_record::mcap::records::{MessageHeader, Record};
use skinware_ros2::{self as msgs, Gap, Image, LayerStats, SkinFrame, standard};

use crate::util::{interrupt_and_wait, one_skin_at_a_time};

struct Dir(PathBuf);

impl Drop for Dir {
    fn drop(&mut self) {
        crate::util::show_logs_if_failing(&self.0);
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn skin_command(dir: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
    command.env("SKINWARE_SHM_DIR", dir.join("shm")).env("RUST_LOG", "warn");
    command
}

fn skin(dir: &Path, args: &[&str]) -> Output {
    let output = skin_command(dir).args(args).output().expect("run skin");
    assert!(output.status.success(), "skin {args:?} failed: {}", String::from_utf8_lossy(&output.stderr));
    output
}

fn json(dir: &Path, args: &[&str]) -> serde_json::Value {
    let output = skin(dir, args);
    serde_json::from_slice(&output.stdout)
        .unwrap_or_else(|e| panic!("skin {args:?}: {e}: {}", String::from_utf8_lossy(&output.stdout)))
}

fn interrupt(child: &mut Child) {
    interrupt_and_wait(child, "the recorder", Duration::from_secs(20));
}

fn python() -> Option<String> {
    let python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
    let found = Command::new(&python).args(["-c", "import mcap, mcap_ros2.decoder"]).output().ok()?;
    found.status.success().then_some(python)
}

#[test]
fn the_paper_skin_is_recorded_replayed_and_read_by_an_independent_reader() {
    let _alone = one_skin_at_a_time();
    let dir = Dir(PathBuf::from("/dev/shm").join(format!("skin-record-e2e-{}", std::process::id())));
    let d = dir.0.as_path();
    std::fs::create_dir_all(d.join("shm")).unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/paper-virtual-skin.toml");
    let mut supervisor = Running(
        skin_command(d)
            .arg("run")
            .arg(&config)
            .stdout(Stdio::null())
            .stderr(crate::util::log_file(d, "skin-run"))
            .spawn()
            .unwrap(),
    );

    // 10 s of every layer and service.
    let a = d.join("a.mcap");
    let summary = json(d, &["record", a.to_str().unwrap(), "--services", "--seconds", "10", "--wait", "180", "--json"]);
    assert_eq!(
        summary["channels"].as_object().unwrap().len(),
        8,
        "5 layers, contact, contact-taxels, motion: {summary}"
    );
    // Frames missed (a debug build of the skin at SCHED_FIFO can starve the
    // recorder; `skin bench record` measures the release build: none) are
    // counted, and the file says the same as the summary, channel by channel.
    let info = json(d, &["info", a.to_str().unwrap(), "--json"]);
    for (channel, recorded) in summary["channels"].as_object().unwrap() {
        let file = &info["channels"][channel];
        assert_eq!(
            (&file["frames"], &file["lost"], &file["gaps"]),
            (&recorded["frames"], &recorded["lost"], &recorded["gaps"]),
            "{channel}"
        );
    }
    println!("recorded {} frames, {} lost (counted)", summary["frames"], summary["lost"]);
    assert!(summary["frames"].as_u64().unwrap() > 1500, "{summary}");
    assert!(summary["images"].as_u64().unwrap() >= 30, "{summary}");

    the_recording_holds_what_ros_tools_draw(&a);
    let parts = a_split_recording_is_whole_files(d);
    killed_recorder_leaves_a_readable_file(d);
    a_stopped_recorder_writes_its_gaps(d);
    interrupt(&mut supervisor.0);

    replay_is_recorded_bit_for_bit(d, &a);
    a_split_recording_replays_whole(d, &parts);
    the_demo_shows_a_recording(d, &a);
    the_python_oracle_reads_what_was_written(&a);
    rosbags_reads_the_offered_qos(&a);
    the_python_oracle_reads_what_was_written(&d.join("recovered.mcap"));
    for part in &parts {
        the_python_oracle_reads_what_was_written(part);
    }
}

/// `skin record --split-seconds 1` for 3.5 s: at least three files, each
/// finished and whole (`skin info` reads its channels and geometry), which
/// hold every recorded frame once, in order. Returns them for the Python
/// oracle.
fn a_split_recording_is_whole_files(d: &Path) -> Vec<PathBuf> {
    let split = d.join("split.mcap");
    let summary = json(
        d,
        &["record", split.to_str().unwrap(), "--services", "--seconds", "3.5", "--split-seconds", "1", "--json"],
    );
    let parts: Vec<PathBuf> =
        summary["parts"].as_array().unwrap().iter().map(|p| PathBuf::from(p.as_str().unwrap())).collect();
    assert!(parts.len() >= 3, "{summary}");
    assert!(!split.exists(), "the parts are named split_000.mcap, ...: {summary}");
    let mut seqs: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    for (index, part) in parts.iter().enumerate() {
        assert_eq!(part, &d.join(format!("split_{index:03}.mcap")));
        let info = json(d, &["info", part.to_str().unwrap(), "--json"]);
        assert_eq!(info["ending"], "finished", "{info}");
        assert!(info["has_geometry"].as_bool().unwrap(), "{info}");
        assert_eq!(info["channels"].as_object().unwrap().len(), 8, "{info}");
        for (channel, frames) in frames(part) {
            seqs.entry(channel).or_default().extend(frames.iter().map(|f| f.2));
        }
    }
    let total: usize = seqs.values().map(Vec::len).sum();
    assert_eq!(total as u64, summary["frames"].as_u64().unwrap(), "{summary}");
    for (channel, seq) in &seqs {
        assert!(seq.windows(2).all(|w| w[0] < w[1]), "{channel}: each frame once, in order, over the parts");
    }
    // `skin info` of the name it was recorded under describes every part.
    let described = json(d, &["info", split.to_str().unwrap(), "--json"]);
    assert_eq!(described.as_array().map(Vec::len), Some(parts.len()), "{described}");
    let text = String::from_utf8(skin(d, &["info", split.to_str().unwrap()]).stdout).unwrap();
    assert!(text.contains(&format!("recorded in {} parts", parts.len())), "{text}");
    parts
}

/// `skin replay split.mcap`, the name the split recording was made under,
/// plays every part in turn: as many frames as the parts hold together.
fn a_split_recording_replays_whole(d: &Path, parts: &[PathBuf]) {
    let split = d.join("split.mcap");
    let report = json(d, &["replay", split.to_str().unwrap(), "--skin", "splitback", "--speed", "4", "--json"]);
    let recorded: usize = parts.iter().map(|part| frames(part).values().map(Vec::len).sum::<usize>()).sum();
    assert_eq!(report["frames"].as_u64().unwrap() as usize, recorded, "{report}");
}

fn killed_recorder_leaves_a_readable_file(d: &Path) {
    let c = d.join("killed.mcap");
    let mut recorder = Running(
        skin_command(d).args(["record", c.to_str().unwrap(), "--services"]).stderr(Stdio::null()).spawn().unwrap(),
    );
    std::thread::sleep(Duration::from_millis(3500));
    recorder.0.kill().unwrap();
    let _ = recorder.0.wait();
    let info = json(d, &["info", c.to_str().unwrap(), "--json"]);
    assert_eq!(info["ending"], "truncated", "{info}");
    // A chunk is finished every second: at least two seconds of frames are readable.
    assert!(info["duration_s"].as_f64().unwrap() >= 2.0, "{info}");
    let frames = info["frames"].as_u64().unwrap();
    let text = String::from_utf8(skin(d, &["info", c.to_str().unwrap()]).stdout).unwrap();
    assert!(text.contains("UNFINISHED") && text.contains("skin record --recover"), "{text}");

    let recovered = d.join("recovered.mcap");
    let report = json(d, &["record", "--recover", c.to_str().unwrap(), recovered.to_str().unwrap(), "--json"]);
    assert_eq!(report["input_ending"], "truncated", "{report}");
    let info = json(d, &["info", recovered.to_str().unwrap(), "--json"]);
    assert_eq!(info["ending"], "finished", "{info}");
    assert_eq!(info["frames"].as_u64().unwrap(), frames);
    assert!(info["has_geometry"].as_bool().unwrap());
}

/// A recorder that cannot read (stopped with SIGSTOP for 0.6 s while the skin
/// runs on; the layers keep 3 frames at 30–50 Hz) misses frames. Each is
/// counted, a Gap message says which, and the next frame says how many it follows.
fn a_stopped_recorder_writes_its_gaps(d: &Path) {
    let g = d.join("gaps.mcap");
    let mut recorder = Running(
        skin_command(d)
            .args(["record", g.to_str().unwrap(), "--services", "--seconds", "4", "--json"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // Stopped only once it is reading: a chunk of frames is in the file.
    let started = Instant::now();
    loop {
        let info = skin_command(d).args(["info", g.to_str().unwrap(), "--json"]).output().unwrap();
        let frames = serde_json::from_slice::<serde_json::Value>(&info.stdout).ok().and_then(|i| i["frames"].as_u64());
        if frames.is_some_and(|n| n > 0) {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "the recorder wrote no frames in 60 s");
        std::thread::sleep(Duration::from_millis(100));
    }
    let pid = recorder.0.id().to_string();
    assert!(Command::new("kill").args(["-STOP", &pid]).status().unwrap().success());
    std::thread::sleep(Duration::from_millis(600));
    assert!(Command::new("kill").args(["-CONT", &pid]).status().unwrap().success());
    let mut stdout = String::new();
    std::io::Read::read_to_string(recorder.0.stdout.as_mut().unwrap(), &mut stdout).unwrap();
    assert!(recorder.0.wait().unwrap().success());
    let summary: serde_json::Value = serde_json::from_str(&stdout).unwrap();

    let recorded = frames(&g);
    let gaps = gap_messages(&g);
    for (channel, counts) in summary["channels"].as_object().unwrap() {
        let lost = counts["lost"].as_u64().unwrap();
        if channel.starts_with("virtual-") {
            assert!(lost > 0, "{channel}: a layer at 30-50 Hz with 3 slots loses frames in 0.6 s: {summary}");
        }
        let mine: Vec<&Gap> = gaps.iter().filter(|gap| &gap.channel == channel).collect();
        assert_eq!(mine.len() as u64, counts["gaps"].as_u64().unwrap(), "{channel}: gap messages");
        assert_eq!(mine.iter().map(|gap| gap.count).sum::<u64>(), lost, "{channel}: frames the gaps name");
        let frames = &recorded[channel];
        for gap in mine {
            // The frame after the gap says how many it follows, and the frame
            // before it is the one just before the first missing.
            let after = frames.iter().position(|f| f.2 == gap.first_seq + gap.count).expect("the frame after a gap");
            assert_eq!(frames[after].4, gap.count, "{channel}: {gap:?}");
            if after > 0 {
                assert_eq!(frames[after - 1].2, gap.first_seq - 1, "{channel}: {gap:?}");
            }
        }
        // No frame is missing without saying so: each frame's skipped count is
        // the hole in the sequence numbers before it.
        for pair in frames.windows(2) {
            assert_eq!(pair[1].2 - pair[0].2 - 1, pair[1].4, "{channel}: frames {} and {}", pair[0].2, pair[1].2);
        }
    }
    println!("a recorder stopped for 0.6 s: {} frames lost, in {} gaps, each written", summary["lost"], gaps.len());
    the_python_oracle_reads_what_was_written(&g);
}

/// Calls `f` with each message of the recording at `path`, in file order.
fn each_message(path: &Path, mut f: impl FnMut(&RecordingHeader, MessageHeader, &[u8])) {
    let mut stream = RecordStream::open(path).unwrap();
    let (header, first) = read_header(&mut stream).unwrap();
    if let Some((message, data)) = first {
        f(&header, message, &data);
    }
    while let Some(record) = stream.next_record().unwrap() {
        if let Record::Message { header: message, data } = record {
            f(&header, message, &data);
        }
    }
}

/// Every Gap message of a recording.
fn gap_messages(path: &Path) -> Vec<Gap> {
    let mut out = Vec::new();
    each_message(path, |header, message, data| {
        if header.topics.get(&message.channel_id).is_some_and(|t| t.ends_with("/gaps")) {
            out.push(msgs::decode::<Gap>(data, msgs::GAP).unwrap());
        }
    });
    out
}

/// One recorded frame: payload, status, sequence number, publication time, frames missed before it.
type Frame = (Vec<u8>, u64, u64, u64, u64);

fn frames(path: &Path) -> BTreeMap<String, Vec<Frame>> {
    let mut out: BTreeMap<String, Vec<Frame>> = BTreeMap::new();
    each_message(path, |header, message, data| {
        if let Some(channel) = header.channels.get(&message.channel_id) {
            let f: SkinFrame = msgs::decode(data, msgs::SKIN_FRAME).unwrap();
            out.entry(channel.channel.clone()).or_default().push((
                f.channel_bytes(),
                f.status,
                f.seq,
                message.publish_time,
                f.skipped,
            ));
        }
    });
    out
}

fn replay_is_recorded_bit_for_bit(d: &Path, a: &Path) {
    let b = d.join("b.mcap");
    let mut replay = Running(
        skin_command(d)
            // As a replay meant to keep time runs (refused settings are only warned about).
            .args([
                "replay",
                a.to_str().unwrap(),
                "--start-delay",
                "2",
                "--fifo-priority",
                "70",
                "--cpu-wake-latency-us",
                "0",
                "--json",
            ])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let again = json(
        d,
        &["record", b.to_str().unwrap(), "--services", "--wait", "30", "--until-gone", "--map-hz", "0", "--json"],
    );
    let mut stdout = String::new();
    std::io::Read::read_to_string(replay.0.stdout.as_mut().unwrap(), &mut stdout).unwrap();
    assert!(replay.0.wait().unwrap().success());
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let (first, second) = (frames(a), frames(&b));
    let total: usize = first.values().map(Vec::len).sum();
    assert_eq!(report["frames"].as_u64().unwrap() as usize, total, "the replay published every recorded frame");
    // Each replayed frame's publication time minus its recorded one: ideally
    // one constant (when the replay started); the error is how far each
    // strays from the first frame's.
    let mut deltas: Vec<(u64, i64)> = Vec::new();
    for (channel, recorded) in &first {
        let replayed = &second[channel];
        // The replay's sequence numbers start at 1: its frame k is the recording's k-th.
        // Every frame is accounted for: published before the recorder
        // started, missed (counted), recorded.
        let before_start = replayed[0].2 - 1 - replayed[0].4;
        let lost = again["channels"][channel]["lost"].as_u64().unwrap();
        assert_eq!(recorded.len() as u64, before_start + lost + replayed.len() as u64, "{channel}: {again}");
        for f in replayed {
            let at = f.2 as usize - 1;
            assert_eq!((&recorded[at].0, recorded[at].1), (&f.0, f.1), "{channel}: frame {at} differs");
            deltas.push((f.3, f.3 as i64 - recorded[at].3 as i64));
        }
    }
    let reference = deltas.iter().min().unwrap().1;
    let mut errors_us: Vec<u64> = deltas.iter().map(|d| (d.1 - reference).unsigned_abs() / 1000).collect();
    errors_us.sort_unstable();
    let q = |p: f64| errors_us[((errors_us.len() - 1) as f64 * p) as usize];
    // Timing is measured, not asserted (see docs/benchmarks.md and `skin bench record`).
    println!(
        "replay timing error over {} frames: p50 {} µs, p99 {} µs, max {} µs; lost by the second recorder: {}",
        errors_us.len(),
        q(0.5),
        q(0.99),
        q(1.0),
        again["lost"]
    );
}

/// `skin demo --replay`: the recording's layers under the supervisor, the
/// demo's services live on them, and the viewer serving its page.
fn the_demo_shows_a_recording(d: &Path, a: &Path) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    drop(listener);
    let mut demo = Running(
        skin_command(d)
            .args([
                "demo",
                "--no-browser-hint",
                "--listen",
                &format!("127.0.0.1:{port}"),
                "--replay",
                a.to_str().unwrap(),
            ])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(demo.0.stdout.take().unwrap()));
    let url = lines.find_map(|line| line.ok()?.strip_prefix("skin demo: ").map(str::to_owned)).expect("the demo's URL");
    let layers = json(d, &["ls", "--json"]);
    let running: Vec<&str> = layers["layers"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|l| l["state"] == "running")
        .map(|l| l["name"].as_str().unwrap())
        .collect();
    assert_eq!(running, ["virtual-0", "virtual-1", "virtual-2", "virtual-3", "virtual-4"], "{layers}");
    let started = Instant::now();
    loop {
        let services = json(d, &["services", "--json"]);
        let live = services["services"].as_array().unwrap().iter().filter(|s| s["state"] == "running").count();
        if live == 3 {
            break;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "the demo's services on the replay: {services}");
        std::thread::sleep(Duration::from_millis(200));
    }
    let mut stream = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    std::io::Write::write_all(&mut stream, b"GET / HTTP/1.0\r\nHost: localhost\r\n\r\n").unwrap();
    let mut page = String::new();
    std::io::Read::read_to_string(&mut stream, &mut page).unwrap();
    assert!(
        page.starts_with("HTTP/1.1 200") || page.starts_with("HTTP/1.0 200"),
        "{url}: {}",
        &page[..page.len().min(200)]
    );
    interrupt(&mut demo.0);
}

/// The bytes the oracle digests for a message (`canonical` in
/// `read_recording.py`): integers as 8 bytes little endian, floats as their
/// bits, strings and arrays after their length.
#[derive(Default)]
struct Canonical(Vec<u8>);

impl Canonical {
    fn int(&mut self, value: impl Into<i128>) -> &mut Self {
        let value: i128 = value.into();
        self.0.extend_from_slice(&(value as u64).to_le_bytes());
        self
    }

    fn float(&mut self, value: f64) -> &mut Self {
        self.0.extend_from_slice(&value.to_le_bytes());
        self
    }

    fn time(&mut self, t: msgs::Time) -> &mut Self {
        self.int(t.sec).int(t.nanosec)
    }

    fn text(&mut self, value: &str) -> &mut Self {
        self.int(value.len() as u64);
        self.0.extend_from_slice(value.as_bytes());
        self
    }

    fn u16s(&mut self, values: &[u16]) -> &mut Self {
        self.int(values.len() as u64);
        self.0.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        self
    }

    fn u8s(&mut self, values: &[u8]) -> &mut Self {
        self.int(values.len() as u64);
        self.0.extend_from_slice(values);
        self
    }

    fn digest(&self) -> String {
        let hash = sha2::Sha256::digest(&self.0);
        hash[..8].iter().map(|b| format!("{b:02x}")).collect()
    }
}

/// What our reader finds in a file, in the oracle's terms: per topic, its
/// message count and each message's digest.
fn our_view(path: &Path) -> BTreeMap<String, Vec<String>> {
    let mut topics: BTreeMap<String, Vec<String>> = BTreeMap::new();
    each_message(path, |header, message, data| {
        let topic = header.topics[&message.channel_id].clone();
        let mut c = Canonical::default();
        if header.channels.contains_key(&message.channel_id) {
            let f: SkinFrame = msgs::decode(data, msgs::SKIN_FRAME).unwrap();
            c.time(f.stamp).time(f.published).int(f.seq).int(f.status).int(f.skipped);
            c.u16s(&f.responses).u8s(&f.payload);
        } else if topic.ends_with("/map") {
            let m: Image = msgs::decode(data, msgs::IMAGE).unwrap();
            c.time(m.header.stamp).text(&m.header.frame_id).int(m.height).int(m.width).text(&m.encoding);
            c.int(m.is_bigendian).int(m.step).u8s(&m.data);
        } else if topic.ends_with("/gaps") {
            let m: Gap = msgs::decode(data, msgs::GAP).unwrap();
            c.time(m.stamp).text(&m.channel).int(m.first_seq).int(m.count);
        } else if let Some(view) = ros_view_canonical(&topic, data) {
            c = view;
        } else {
            let m: LayerStats = msgs::decode(data, msgs::LAYER_STATS).unwrap();
            c.time(m.stamp).text(&m.channel).text(&m.state).int(m.frames).int(m.lost).int(m.faulted);
            c.float(m.rate_hz).float(m.latency_ms).int(m.min_response).int(m.max_response).float(m.mean_response);
        }
        topics.entry(topic).or_default().push(c.digest());
    });
    topics
}

/// Ten seconds of the paper's skin at the default 10 clouds a second: a
/// cloud topic per layer and link, the contact service's markers, the
/// health of all 8 channels on /diagnostics, and /tf_static once.
fn the_recording_holds_what_ros_tools_draw(path: &Path) {
    let topics = our_view(path);
    let count = |topic: &str| topics.get(topic).map_or(0, Vec::len);
    let clouds: Vec<(&String, usize)> =
        topics.iter().filter(|(t, _)| t.contains("/cloud/")).map(|(t, m)| (t, m.len())).collect();
    println!(
        "ROS view: {} cloud topics {clouds:?}; markers {}, diagnostics {}, tf_static {}",
        clouds.len(),
        count("/skin/default/contact/markers"),
        count("/diagnostics"),
        count("/tf_static")
    );
    assert!(clouds.len() >= 5, "a cloud per layer and link: {clouds:?}");
    assert!(clouds.iter().all(|(_, n)| *n >= 10), "clouds at up to 10 Hz for 10 s: {clouds:?}");
    assert!(count("/skin/default/contact/markers") >= 10);
    assert!(count("/diagnostics") >= 5);
    assert_eq!(count("/tf_static"), 1);
    each_message(path, |header, message, data| {
        if header.topics[&message.channel_id] == "/diagnostics" {
            let m: standard::DiagnosticArray = msgs::decode(data, standard::DIAGNOSTIC_ARRAY).unwrap();
            assert_eq!(m.status.len(), 8, "every recorded channel: {m:?}");
        }
    });
}

/// The canonical bytes of a message for ROS tools (clouds, markers,
/// diagnostics, `/tf_static`), or `None` for a topic of another kind.
fn ros_view_canonical(topic: &str, data: &[u8]) -> Option<Canonical> {
    let mut c = Canonical::default();
    if topic.contains("/cloud/") {
        let m: standard::PointCloud2 = msgs::decode(data, standard::POINT_CLOUD2).unwrap();
        c.time(m.header.stamp).text(&m.header.frame_id).int(m.height).int(m.width).int(m.fields.len() as u64);
        for f in &m.fields {
            c.text(&f.name).int(f.offset).int(f.datatype).int(f.count);
        }
        c.int(u8::from(m.is_bigendian)).int(m.point_step).int(m.row_step).u8s(&m.data).int(u8::from(m.is_dense));
    } else if topic.ends_with("/markers") {
        let m: standard::MarkerArray = msgs::decode(data, standard::MARKER_ARRAY).unwrap();
        c.int(m.markers.len() as u64);
        for k in &m.markers {
            c.time(k.header.stamp).text(&k.header.frame_id).text(&k.ns).int(k.id).int(k.kind).int(k.action);
            c.int(k.lifetime.sec).int(k.lifetime.nanosec).int(k.points.len() as u64);
            for p in &k.points {
                c.float(p.x).float(p.y).float(p.z);
            }
        }
    } else if topic == msgs::DIAGNOSTICS_TOPIC {
        let m: standard::DiagnosticArray = msgs::decode(data, standard::DIAGNOSTIC_ARRAY).unwrap();
        c.time(m.header.stamp).text(&m.header.frame_id).int(m.status.len() as u64);
        for s in &m.status {
            c.int(s.level).text(&s.name).text(&s.message).text(&s.hardware_id).int(s.values.len() as u64);
            for kv in &s.values {
                c.text(&kv.key).text(&kv.value);
            }
        }
    } else if topic == msgs::TF_STATIC_TOPIC {
        let m: standard::TfMessage = msgs::decode(data, standard::TF_MESSAGE).unwrap();
        c.int(m.transforms.len() as u64);
        for t in &m.transforms {
            c.time(t.header.stamp).text(&t.header.frame_id).text(&t.child_frame_id);
            let (v, q) = (t.transform.translation, t.transform.rotation);
            c.float(v.x).float(v.y).float(v.z).float(q.x).float(q.y).float(q.z).float(q.w);
        }
    } else {
        return None;
    }
    Some(c)
}

/// `rosbags` (an independent reader of rosbag2 storage) finds each ROS view
/// channel's `offered_qos_profiles`: what `ros2 bag play` offers again.
fn rosbags_reads_the_offered_qos(path: &Path) {
    let python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = Command::new(&python).args(["-c", "import rosbags.rosbag2"]).output();
    if !probe.is_ok_and(|o| o.status.success()) {
        let reason = "no Python with rosbags (set SKINWARE_PYTHON, or pip install rosbags)";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "{reason}: CI must run this oracle");
        println!("SKIPPED: {reason}");
        return;
    }
    let script = r#"
import json, sys
from rosbags.rosbag2 import Reader
with Reader(sys.argv[1]) as reader:
    print(json.dumps({c.topic: [[q.reliability.name, q.durability.name, q.history.name, q.depth]
                                for q in c.ext.offered_qos_profiles] for c in reader.connections}))
"#;
    let output = Command::new(&python).args(["-c", script]).arg(path).output().unwrap();
    assert!(output.status.success(), "rosbags on {}: {}", path.display(), String::from_utf8_lossy(&output.stderr));
    let qos: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let offered = |topic: &str| qos[topic].as_array().and_then(|profiles| profiles.first()).cloned();
    assert_eq!(
        offered("/tf_static"),
        Some(serde_json::json!(["RELIABLE", "TRANSIENT_LOCAL", "KEEP_LAST", 1])),
        "{qos}"
    );
    assert_eq!(offered("/diagnostics"), Some(serde_json::json!(["RELIABLE", "VOLATILE", "KEEP_LAST", 10])), "{qos}");
    let clouds: Vec<&String> = qos.as_object().unwrap().keys().filter(|t| t.contains("/cloud/")).collect();
    assert!(!clouds.is_empty(), "{qos}");
    for cloud in clouds {
        assert_eq!(offered(cloud), Some(serde_json::json!(["BEST_EFFORT", "VOLATILE", "KEEP_LAST", 5])), "{cloud}");
    }
    println!("rosbags reads the offered QoS of {}: {qos}", path.display());
}

fn the_python_oracle_reads_what_was_written(path: &Path) {
    let Some(python) = python() else {
        let reason =
            "no Python with mcap and mcap-ros2-support (set SKINWARE_PYTHON, or pip install mcap mcap-ros2-support)";
        assert!(std::env::var("CI").as_deref() != Ok("true"), "{reason}: CI must run this oracle");
        println!("SKIPPED: {reason}");
        return;
    };
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../skinware-record/tests/python/read_recording.py");
    let output = Command::new(python).arg(script).arg(path).output().unwrap();
    assert!(
        output.status.success(),
        "the Python oracle failed on {}: {}",
        path.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    let theirs: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(theirs["profile"], "ros2");
    assert!(theirs["has_summary"].as_bool().unwrap(), "a finished file has its summary section");
    assert!(theirs["attachments"]["skinware/geometry"].as_u64().unwrap() > 0);
    let ours = our_view(path);
    let theirs_topics = theirs["topics"].as_object().unwrap();
    assert_eq!(
        theirs_topics.keys().collect::<Vec<_>>(),
        ours.keys().collect::<Vec<_>>(),
        "the topics Python found in {}",
        path.display()
    );
    let (mut frames, mut messages) = (0, 0);
    for (topic, mine) in &ours {
        let other = &theirs_topics[topic];
        let digests: Vec<&str> = other["digests"].as_array().unwrap().iter().map(|d| d.as_str().unwrap()).collect();
        assert_eq!(digests.len(), mine.len(), "{topic}: messages decoded by Python");
        // Every field of every message, as Python decoded it against ours.
        if let Some(at) = (0..mine.len()).find(|&i| digests[i] != mine[i]) {
            panic!("{topic}: message {at} decodes differently in Python's mcap-ros2-support than in ours");
        }
        messages += mine.len();
        if other["schema"] == "skinware_msgs/msg/SkinFrame" {
            assert_eq!(other["seq_increasing"], true, "{topic}");
            frames += mine.len();
        }
    }
    let lost: u64 = gap_messages(path).iter().map(|gap| gap.count).sum();
    assert_eq!(
        theirs["topics"]["/skin/default/gaps"]["missing"].as_u64().unwrap_or(0),
        lost,
        "frames missing, by Python"
    );
    let map = &theirs["topics"]["/skin/default/map"];
    assert!(map["messages"].as_u64().unwrap() > 0 && map["lit_pixels"].as_u64().unwrap() > 0, "{map}");
    println!(
        "Python mcap-ros2-support decoded {messages} messages of {}, each field of each the same as ours: \
         {frames} SkinFrame messages (every taxel), {} images (every pixel, {} lit)",
        path.display(),
        map["messages"],
        map["lit_pixels"]
    );
}
