//! ROS 2 over DDS end to end (feature `dds`), across two hosts made of
//! network namespaces and a veth pair:
//!
//! - on the sensor's host, a stock rclpy node (Fast DDS, default settings)
//!   publishes a fingertip's pressures as `std_msgs/UInt16MultiArray`;
//! - on the robot's host, `skin run examples/ros2-sensor.toml` reads that
//!   topic as a layer (driver kind `ros2`) with a contact service on it,
//!   and `skin bridge --ros2 dds` publishes the skin's standard topics;
//! - back on the sensor's host, an rclpy subscriber finds the bridge's node
//!   in its graph and decodes the skin's cloud, markers and `/diagnostics`.
//!
//! Every cloud's responses are one published message's (the pattern
//! `(n * 7 + k) % 65536` of message `n`, taxel `k`), and so are the layer's
//! frames, read here from the robot host's shared memory.
//!
//! Needs root (namespaces) and `SKINWARE_ROS2_PYTHONS` (rclpy); without
//! them the test says so and is skipped, except under `CI=true`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use skinware::{Reader, ReaderOptions, WriterState};

use crate::util::{Running, one_skin_at_a_time};

fn skip(reason: &str) {
    assert!(std::env::var("CI").map_or(true, |v| v != "true"), "under CI=true this test must run: {reason}");
    println!("SKIPPED: {reason}");
}

fn peer() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../skinware-dds/tests/integration/rclpy_peer.py")
}

/// Two network namespaces joined by a veth pair, with multicast routed
/// over it (DDS discovery), deleted when dropped.
struct Hosts(Vec<String>);

impl Hosts {
    fn link(a: &str, b: &str) -> Option<Hosts> {
        let ip = |args: &[&str]| Command::new("ip").args(args).output().is_ok_and(|o| o.status.success());
        let mut hosts = Hosts(Vec::new());
        for ns in [a, b] {
            if !ip(&["netns", "add", ns]) {
                return None;
            }
            hosts.0.push(ns.to_owned());
        }
        let (veth_a, veth_b) = (format!("{a}v"), format!("{b}v"));
        assert!(ip(&["link", "add", &veth_a, "netns", a, "type", "veth", "peer", "name", &veth_b, "netns", b]));
        for (ns, dev, address) in [(a, &veth_a, "10.231.12.1/24"), (b, &veth_b, "10.231.12.2/24")] {
            assert!(ip(&["-n", ns, "addr", "add", address, "dev", dev]));
            assert!(ip(&["-n", ns, "link", "set", dev, "up", "multicast", "on"]));
            assert!(ip(&["-n", ns, "link", "set", "lo", "up"]));
            assert!(ip(&["-n", ns, "route", "add", "224.0.0.0/4", "dev", dev]));
        }
        Some(hosts)
    }

    /// `program` in namespace `ns`.
    fn exec(ns: &str, program: &str) -> Command {
        let mut command = Command::new("ip");
        command.args(["netns", "exec", ns, program]);
        command
    }
}

impl Drop for Hosts {
    fn drop(&mut self) {
        for ns in &self.0 {
            let _ = Command::new("ip").args(["netns", "del", ns]).output();
        }
    }
}

#[test]
fn a_ros2_sensor_on_one_host_is_a_skin_layer_on_another_and_its_cloud_comes_back() {
    let Some(python) = std::env::var("SKINWARE_ROS2_PYTHONS").ok().and_then(|l| l.split(':').next().map(str::to_owned))
    else {
        return skip(
            "no SKINWARE_ROS2_PYTHONS: a Python with rclpy (pip ros-kilted-rclpy[fastrtps], see docs/ros2.md)",
        );
    };
    if python.is_empty() {
        return skip("SKINWARE_ROS2_PYTHONS is empty");
    }
    let _alone = one_skin_at_a_time();
    let id = std::process::id() % 10_000;
    let (robot, sensor) = (format!("skr{id}"), format!("sks{id}"));
    let Some(_hosts) = Hosts::link(&robot, &sensor) else {
        return skip("cannot create network namespaces here (needs root and iproute2)");
    };
    let dir = std::env::temp_dir().join(format!("skin-ros2-e2e-{id}"));
    std::fs::create_dir_all(&dir).unwrap();
    let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/ros2-sensor.toml");
    let skin_in = |ns: &str| {
        let mut command = Hosts::exec(ns, env!("CARGO_BIN_EXE_skin"));
        command.env("SKINWARE_SHM_DIR", &dir).env("RUST_LOG", "warn").env("ROS_DOMAIN_ID", "7");
        command
    };
    let rclpy_in = |ns: &str| {
        let mut command = Hosts::exec(ns, &python);
        command.arg(peer()).env("ROS_DOMAIN_ID", "7").env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp");
        command
    };
    let skin = Running(skin_in(&robot).arg("run").arg(&config).spawn().unwrap());
    let talker = Running(
        rclpy_in(&sensor)
            .args(["publish", "/fingertip/pressure", "UInt16MultiArray", "100", "30", "64"])
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut layer = wait_for_running_layer(&dir, Duration::from_secs(30));
    let bridge = Running(skin_in(&robot).args(["bridge", "--skin", "fingertip", "--ros2", "dds"]).spawn().unwrap());
    let cloud_topic = "/skin/fingertip/fingertip/cloud/fingertip";
    let output = rclpy_in(&sensor)
        .args(["subscribe", "4", cloud_topic, "/diagnostics", "/skin/fingertip/contact/markers"])
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let seen: serde_json::Value = serde_json::from_slice(&output.stdout).expect("the subscriber prints JSON");
    // The layer's newest frame, before anything stops.
    let frame = layer.latest().unwrap().responses().to_vec();
    // Stopped before their directory goes.
    drop((bridge, talker, skin));

    // The layer's own frames are the talker's messages.
    check_pattern(&frame.iter().map(|r| f64::from(*r)).collect::<Vec<_>>(), "the layer's frame");

    assert_eq!(seen["graph"][cloud_topic][0]["node"], "skin_bridge_fingertip", "{}", seen["graph"]);
    let clouds = seen["received"][cloud_topic].as_array().unwrap();
    // 10 Hz for 4 s, less discovery and the bridge's once-a-second look for subscribers.
    assert!(clouds.len() >= 12, "{} clouds across the link in 4 s at 10 Hz", clouds.len());
    for cloud in clouds {
        assert_eq!(cloud["frame_id"], "fingertip");
        let responses: Vec<f64> = cloud["points"].as_array().unwrap().iter().map(|p| p[3].as_f64().unwrap()).collect();
        check_pattern(&responses, "a cloud");
    }
    let diagnostics = seen["received"]["/diagnostics"].as_array().unwrap();
    let last = diagnostics.last().expect("/diagnostics across the link");
    let layer_status = last["status"].as_array().unwrap().iter().find(|s| s["name"] == "skin/fingertip/fingertip");
    assert_eq!(layer_status.expect("the layer's status")["level"], 0, "{last}");
    assert!(!seen["received"]["/skin/fingertip/contact/markers"].as_array().unwrap().is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

/// Responses `(n * 7 + k) % 65536` of one message `n`: 64 of them.
fn check_pattern(responses: &[f64], what: &str) {
    assert_eq!(responses.len(), 64, "{what}");
    let first = responses[0] as u64;
    for (k, response) in responses.iter().enumerate() {
        assert_eq!(*response as u64, (first + k as u64) % 65536, "{what}: {responses:?}");
    }
}

/// The `fingertip` layer, once its driver is running (the talker found).
fn wait_for_running_layer(dir: &Path, within: Duration) -> Reader {
    let deadline = Instant::now() + within;
    let options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
    loop {
        if let Ok(reader) = Reader::open_with("fingertip", "fingertip", &options)
            && reader.writer_state() == WriterState::Running
        {
            return reader;
        }
        assert!(Instant::now() < deadline, "the ros2 layer never ran: no message from the other host?");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The topics `skin demo`'s skin has on DDS, as `skin bridge --ros2 dds --json` lists them.
fn demo_topics() -> Vec<String> {
    let id = std::process::id() % 10_000;
    let dir = std::env::temp_dir().join(format!("skin-ros2-demo-{id}"));
    std::fs::create_dir_all(&dir).unwrap();
    let skin = |args: &[&str]| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
        command.args(args).env("SKINWARE_SHM_DIR", &dir).env("RUST_LOG", "warn");
        command
    };
    let port = format!("127.0.0.1:{}", 19_000 + id % 1_000);
    let demo = Running(skin(&["demo", "--listen", &port, "--no-browser-hint"]).stdout(Stdio::null()).spawn().unwrap());
    let deadline = Instant::now() + Duration::from_secs(180);
    loop {
        let running = skinware::list_channels(&dir)
            .unwrap_or_default()
            .iter()
            .filter(|c| c.state == WriterState::Running && c.stats.frames > 2)
            .count();
        // 5 layers and the contact service's channels.
        if running >= 6 {
            break;
        }
        assert!(Instant::now() < deadline, "skin demo's skin did not come up");
        std::thread::sleep(Duration::from_millis(200));
    }
    let domain = (60 + id % 100).to_string();
    let output = skin(&["bridge", "--ros2", "dds", "--domain", &domain, "--seconds", "1", "--json"]).output().unwrap();
    drop(demo);
    let _ = std::fs::remove_dir_all(&dir);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).expect("--json");
    report["dds_topics"].as_array().unwrap().iter().map(|t| t["topic"].as_str().unwrap().to_owned()).collect()
}

#[test]
fn the_rviz_config_and_the_foxglove_layout_name_what_skin_demo_publishes() {
    let _alone = one_skin_at_a_time();
    let topics = demo_topics();
    let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/ros2");
    let rviz = std::fs::read_to_string(docs.join("skin.rviz")).unwrap();
    let named: Vec<&str> =
        rviz.lines().filter_map(|line| line.trim().strip_prefix("Value: ")).filter(|v| v.starts_with('/')).collect();
    let clouds: Vec<&String> = topics.iter().filter(|t| t.contains("/cloud/")).collect();
    assert_eq!(clouds.len(), 13, "the paper's skin: 13 layer-and-link clouds: {topics:?}");
    for topic in &named {
        assert!(topics.iter().any(|t| t == topic), "skin.rviz names {topic}, which skin demo does not publish");
    }
    for cloud in &clouds {
        assert!(named.contains(&cloud.as_str()), "skin.rviz does not show {cloud}");
    }
    assert!(rviz.contains("Fixed Frame: base_link") && rviz.contains("Channel Name: response"));
    let layout: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(docs.join("foxglove-layout.json")).unwrap()).unwrap();
    let three_d = layout["configById"]["3D!skin"]["topics"].as_object().unwrap();
    for topic in three_d.keys() {
        assert!(topics.contains(topic), "the Foxglove layout names {topic}, which skin demo does not publish");
    }
    for cloud in &clouds {
        assert_eq!(three_d[cloud.as_str()]["colorField"], "response", "{cloud}");
    }
    let image = layout["configById"]["Image!map"]["imageMode"]["imageTopic"].as_str().unwrap();
    assert!(topics.iter().any(|t| t == image), "{image}");
    assert_eq!(layout["configById"]["DiagnosticSummary!skin"]["topicToRender"], "/diagnostics");
}
