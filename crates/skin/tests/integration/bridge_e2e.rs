//! `skin bridge` end to end (feature `zenoh`):
//!
//! - two hosts made of network namespaces and a veth pair (`skin bench
//!   bridge --quick`): the paper's skin and the bridge on one, remote readers
//!   on the other; every remote frame checked against the local exchange's
//!   frame of the same sequence number, the link shaped to 100/10/1 Mbit/s,
//!   then cut and restored; and `skin view --remote` on the far side, whose
//!   mirror the viewer reads;
//! - ROS 2 without ROS: Python's `eclipse-zenoh` subscribes to the exact
//!   rmw_zenoh keys and `rosbags` decodes the messages
//!   (`bridge_ros2_oracle.py`).
//!
//! Namespaces need root; the oracle needs a Python with `eclipse-zenoh`,
//! `rosbags` and `xxhash` (`$SKINWARE_PYTHON`). Without them a test says so
//! and is skipped, except under `CI=true`, where it fails.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use crate::util::{Running, one_skin_at_a_time};

fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| v == "true")
}

fn skip(reason: &str) {
    assert!(!in_ci(), "under CI=true this test must run: {reason}");
    println!("SKIPPED: {reason}");
}

struct Dir(PathBuf);

impl Drop for Dir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn skin(dir: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
    command.env("SKINWARE_SHM_DIR", dir).env("RUST_LOG", "warn");
    command
}

fn namespaces_work() -> bool {
    let name = format!("skbr-probe-{}", std::process::id());
    let made = Command::new("ip").args(["netns", "add", &name]).output().is_ok_and(|o| o.status.success());
    if made {
        let _ = Command::new("ip").args(["netns", "del", &name]).output();
    }
    made
}

fn checked(output: Output, what: &str) -> Output {
    assert!(
        output.status.success(),
        "{what} failed: {}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    output
}

#[test]
#[cfg_attr(not(feature = "bench"), ignore = "runs `skin bench bridge`: needs skin built with --features bench,zenoh")]
#[cfg_attr(skip_not_root, ignore = "needs root: makes network namespaces and a veth pair")]
fn two_hosts_read_the_skin_through_the_bridge_across_shaping_and_a_cut_link() {
    if !namespaces_work() {
        return skip("cannot create network namespaces here (needs root and iproute2)");
    }
    let _alone = one_skin_at_a_time();
    let out = Dir(std::env::temp_dir().join(format!("skin-bridge-e2e-{}", std::process::id())));
    let output = checked(
        skin(&out.0).args(["bench", "bridge", "--quick", "--out"]).arg(&out.0).output().expect("run skin bench bridge"),
        "skin bench bridge --quick",
    );
    println!("{}", String::from_utf8_lossy(&output.stdout));
    let results: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.0.join("bridge.json")).expect("bridge.json")).expect("JSON");

    // Across the unshaped link: every layer, and every frame that could be
    // checked (still in the writer's ring) equal, bit for bit, to the local one.
    let unshaped = &results["unshaped"];
    let layers = unshaped["layers"].as_object().expect("layers");
    assert_eq!(layers.len(), 5, "{unshaped}");
    let (mut verified, mut mismatched) = (0, 0);
    for (layer, figures) in layers {
        assert!(figures["received"].as_u64().unwrap() > 10, "{layer}: {figures}");
        verified += figures["verified"].as_u64().unwrap();
        mismatched += figures["mismatched"].as_u64().unwrap();
    }
    assert_eq!(mismatched, 0, "remote frames differ from the local ones: {unshaped}");
    assert!(verified > 100, "too few remote frames checked against local ones: {unshaped}");
    let local = results["local"]["frames_per_s"].as_f64().unwrap();
    assert!(local > 50.0, "the skin publishes ~190 frames/s: {}", results["local"]);

    // A link slower than the skin delivers fewer frames and says how many
    // it did not deliver; it never stops delivering.
    let one = &results["1mbit"];
    assert!(one["received"].as_u64().unwrap() > 0, "nothing across 1 Mbit/s: {one}");
    assert!(one["skipped"].as_u64().unwrap() > 0, "2.3 MB/s through 1 Mbit/s must skip frames, and count them: {one}");
    assert!(one["mb_per_s"].as_f64().unwrap() < 0.2, "more than 1 Mbit/s through a 1 Mbit/s link? {one}");
    // And the bridge knows: its remote readers report what they lost
    // (frames the bridge handed to zenoh that never came), cumulatively,
    // once a second and once more with their final figures.
    let channels = one["bridge"]["channels"].as_array().expect("the bridge's --json figures");
    let reported: u64 = channels.iter().filter_map(|c| c["remote_lost"].as_u64()).sum();
    let readers: u64 = channels.iter().filter_map(|c| c["remote_readers"].as_u64()).sum();
    let counted = one["lost"].as_u64().expect("the remote reader's lost frames");
    println!("1 Mbit/s: the readers lost {counted} frames on the link, the bridge was told of {reported}");
    assert!(readers >= 5, "the bridge heard no report from the remote readers: {}", one["bridge"]);
    assert!(reported <= counted, "the bridge shows {reported} lost, the readers counted {counted}: {}", one["bridge"]);
    assert!(
        counted == 0 || reported > 0,
        "the readers lost {counted} frames and the bridge saw none: {}",
        one["bridge"]
    );
    // What a reader skipped and did not count lost, the bridge left out
    // itself and counted as dropped (since it started, so at least this
    // phase's): a reader that counted no loss at all fails this.
    for (layer, figures) in one["layers"].as_object().expect("layers") {
        let not_lost = figures["skipped"].as_u64().unwrap() - figures["lost"].as_u64().unwrap();
        let channel =
            channels.iter().find(|c| c["channel"] == layer.as_str()).expect("the layer in the bridge's figures");
        let dropped = channel["dropped"].as_u64().unwrap();
        assert!(
            not_lost <= dropped,
            "{layer}: {not_lost} frames skipped and not lost, the bridge dropped {dropped}: {one}"
        );
    }

    // A cut link is noticed, and reading resumes by itself when it returns.
    let cut = &results["cut"];
    assert!(cut["detected_ms"].is_number(), "the cut was never noticed: {cut}");
    assert!(cut["recovered_ms"].is_number(), "no frame after the link returned: {cut}");
}

#[test]
fn skin_view_remote_mirrors_the_remote_skin_for_the_viewer() {
    if !namespaces_work() {
        return skip("cannot create network namespaces here (needs root and iproute2)");
    }
    let _alone = one_skin_at_a_time();
    let id = std::process::id();
    let (a, b, veth_a, veth_b) = (
        format!("skbv-a-{id}"),
        format!("skbv-b-{id}"),
        format!("skbva{}", id % 100_000),
        format!("skbvb{}", id % 100_000),
    );
    let _namespaces = Namespaces::linked(&a, &b, &veth_a, &veth_b);
    let robot = Dir(PathBuf::from("/dev/shm").join(format!("sbv-a-{id}")));
    let station = Dir(PathBuf::from("/dev/shm").join(format!("sbv-b-{id}")));
    std::fs::create_dir_all(&robot.0).unwrap();
    std::fs::create_dir_all(&station.0).unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/paper-virtual-skin.toml");
    let in_ns = |ns: &str, dir: &Path| {
        let mut command = Command::new("ip");
        command
            .args(["netns", "exec", ns, env!("CARGO_BIN_EXE_skin")])
            .env("SKINWARE_SHM_DIR", dir)
            .env("RUST_LOG", "warn");
        command
    };
    let _skin = Running(in_ns(&a, &robot.0).arg("run").arg(&config).stdout(Stdio::null()).spawn().unwrap());
    let deadline = Instant::now() + Duration::from_secs(120);
    while skinware::list_channels(&robot.0).map(|c| c.len()).unwrap_or(0) < 5 {
        assert!(Instant::now() < deadline, "`skin run` did not create its 5 layers within 120 s");
        std::thread::sleep(Duration::from_millis(200));
    }
    let _bridge = Running(
        in_ns(&a, &robot.0).args(["bridge", "--listen", "tcp/10.231.9.1:7447"]).stdout(Stdio::null()).spawn().unwrap(),
    );
    let _view = Running(
        in_ns(&b, &station.0)
            .args(["view", "--remote", "10.231.9.1:7447", "--listen", "127.0.0.1:18080"])
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    // The viewer's mirror: every remote layer, live, in the far side's own
    // channels, with the geometry the page draws.
    let mirror = live_mirror_in(&station.0, Duration::from_secs(60));
    let channels = skinware::list_channels(&mirror).unwrap();
    assert_eq!(channels.iter().filter(|c| c.kind == Some(skinware::ChannelKind::Layer)).count(), 5, "{channels:?}");
    let geometry = skinware_geometry::SkinGeometry::open_in(&mirror, "default").expect("the mirrored geometry");
    assert_eq!(geometry.sensor_count(), 30_848);
    // The page is served on the far side.
    let page = checked(
        Command::new("ip")
            .args(["netns", "exec", &b, "python3", "-c"])
            .arg(
                "import urllib.request; print(urllib.request.urlopen('http://127.0.0.1:18080/').read().decode()[:200])",
            )
            .output()
            .unwrap(),
        "fetching the remote view's page",
    );
    assert!(String::from_utf8_lossy(&page.stdout).to_lowercase().contains("<!doctype html"), "{page:?}");
}

/// Two network namespaces joined by a veth pair (10.231.9.1 and .2),
/// deleted when dropped.
struct Namespaces(Vec<String>);

impl Namespaces {
    fn linked(a: &str, b: &str, veth_a: &str, veth_b: &str) -> Namespaces {
        let ip = |args: &[&str]| checked(Command::new("ip").args(args).output().unwrap(), &format!("ip {args:?}"));
        // Each deleted at the end, also if a later step fails.
        let mut namespaces = Namespaces(Vec::new());
        for ns in [a, b] {
            ip(&["netns", "add", ns]);
            namespaces.0.push(ns.to_owned());
        }
        ip(&["link", "add", veth_a, "netns", a, "type", "veth", "peer", "name", veth_b, "netns", b]);
        for (ns, dev, address) in [(a, veth_a, "10.231.9.1/24"), (b, veth_b, "10.231.9.2/24")] {
            ip(&["-n", ns, "addr", "add", address, "dev", dev]);
            ip(&["-n", ns, "link", "set", dev, "up"]);
            ip(&["-n", ns, "link", "set", "lo", "up"]);
        }
        namespaces
    }
}

impl Drop for Namespaces {
    fn drop(&mut self) {
        for ns in &self.0 {
            let _ = Command::new("ip").args(["netns", "del", ns]).output();
        }
    }
}

/// The viewer's mirror in `station`: a directory of channels holding every
/// remote layer, each live (over 20 frames), within `within`.
fn live_mirror_in(station: &Path, within: Duration) -> PathBuf {
    let deadline = Instant::now() + within;
    loop {
        let mirrors: Vec<PathBuf> = std::fs::read_dir(station)
            .map(|d| d.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.is_dir()).collect())
            .unwrap_or_default();
        let ready = mirrors
            .iter()
            .find(|d| skinware::list_channels(d).is_ok_and(|c| c.iter().filter(|c| c.stats.frames > 20).count() >= 5));
        if let Some(ready) = ready {
            return ready.clone();
        }
        assert!(Instant::now() < deadline, "no live mirror of the remote skin in {}", station.display());
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn python() -> Option<String> {
    let python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
    let found = Command::new(&python).args(["-c", "import zenoh, rosbags, xxhash"]).output().ok()?;
    found.status.success().then_some(python)
}

#[test]
fn a_ros2_subscriber_decodes_what_the_bridge_publishes() {
    let Some(python) = python() else {
        return skip(
            "no Python with eclipse-zenoh, rosbags and xxhash (pip install eclipse-zenoh rosbags xxhash, or set SKINWARE_PYTHON)",
        );
    };
    let _alone = one_skin_at_a_time();
    let dir = Dir(PathBuf::from("/dev/shm").join(format!("skin-bridge-ros-{}", std::process::id())));
    std::fs::create_dir_all(&dir.0).unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/demo.toml");
    let _skin = Running(skin(&dir.0).arg("run").arg(&config).stdout(Stdio::null()).spawn().unwrap());
    let deadline = Instant::now() + Duration::from_secs(120);
    while skinware::list_channels(&dir.0).map(|c| c.len()).unwrap_or(0) < 8 {
        assert!(Instant::now() < deadline, "`skin run` did not create its 8 channels within 120 s");
        std::thread::sleep(Duration::from_millis(200));
    }
    let port = 20_000 + std::process::id() % 20_000;
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let _bridge = Running(skin(&dir.0).args(["bridge", "--listen", &endpoint]).stdout(Stdio::null()).spawn().unwrap());
    let sensors = skinware::Reader::open_with(
        "default",
        "virtual-0",
        &skinware::ReaderOptions { dir: Some(dir.0.clone()), ..Default::default() },
    )
    .unwrap()
    .topology()
    .unwrap()
    .sensors
    .len();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/integration/bridge_ros2_oracle.py");
    let output = checked(
        Command::new(&python)
            .arg(&script)
            .args([endpoint.as_str(), "default", "virtual-0", &sensors.to_string(), "contact", "torso"])
            .output()
            .unwrap(),
        "the rmw_zenoh oracle",
    );
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).expect("the oracle prints JSON");
    println!("{report}");
    assert_eq!(report["ok"], true);
    assert_eq!(report["state"]["values"], sensors);
    // The hashes rosbags computed are the ones the bridge put in its keys.
    assert_eq!(report["cloud"]["points"], sensors, "virtual-0 is all on the torso: {report}");
    for type_name in [
        "tactile_msgs/msg/TactileState",
        "sensor_msgs/msg/Image",
        "tactile_msgs/msg/TactileContacts",
        "sensor_msgs/msg/PointCloud2",
        "visualization_msgs/msg/MarkerArray",
        "diagnostic_msgs/msg/DiagnosticArray",
    ] {
        assert_eq!(report["hashes"][type_name].as_str(), skinware_ros2::type_hash(type_name).as_deref(), "{type_name}");
    }
}
