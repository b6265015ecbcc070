//! `DdsBridge` to rclpy: every standard topic decoded by ROS's own type
//! support, its values compared with the frame of the same stamp, its node,
//! type and QoS read from rclpy's graph.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde_json::Value;
use skinware::{Stop, TopologyBuilder, Writer, WriterOptions};
use skinware_dds::{DdsBridge, DdsOptions, Rates};
use skinware_geometry::{Calibration, SkinGeometry};

use super::{TempDir, domain, rclpy, ros_pythons};

const SKIN: &str = "ddstest";

/// One layer, `arm`, of 4 taxels: 0, 2 and 3 on the forearm, 1 on the hand.
fn geometry() -> (skinware::LayerTopology, SkinGeometry) {
    let mut builder = TopologyBuilder::new("arm", "pressure", 50.0);
    builder.patch(1).module(1, [10, 11, 12, 13]);
    let layer = builder.build().unwrap();
    let calibration = Calibration::parse(
        "skinware-calibration 1\n\
         arm 10 0.125 0.25 0.5 0 0 1 0.002 forearm\n\
         arm 11 -0.5 0.75 1.5 0 1 0 0.002 hand\n\
         arm 12 1 2 3 1 0 0 0.002 forearm\n\
         arm 13 0 0 0.0625 0 0 1 0.002 forearm\n",
        "test",
    )
    .unwrap();
    let geometry = SkinGeometry::build(SKIN, std::slice::from_ref(&layer), &calibration, &[]).unwrap();
    (layer, geometry)
}

/// Frame `n`'s responses: each distinct, so a cloud names its frame.
fn responses(n: u64) -> Vec<u16> {
    (0..4).map(|k| ((n * 7 + k * 1000) % 65536) as u16).collect()
}

/// Writes the layer at 50 Hz until `stop`; every frame's acquisition time
/// (CLOCK_MONOTONIC ns) by its first response.
fn write_layer(mut writer: Writer, stop: Stop, written: Arc<Mutex<BTreeMap<u16, u64>>>) {
    let mut ticker = skinware::Ticker::from_hz(50.0);
    let mut n = 1;
    while ticker.wait(&stop).is_some() {
        let now = skinware::os::monotonic_ns();
        let mut frame = writer.begin();
        frame.write_responses(0, &responses(n)).unwrap();
        frame.set_acquired_ns(now);
        frame.publish();
        written.lock().unwrap().insert(responses(n)[0], now);
        n += 1;
    }
}

#[cfg_attr(
    skip_no_rclpy,
    ignore = "needs rclpy: SKINWARE_ROS2_PYTHONS, a Python per ROS distro with ros-<distro>-rclpy[fastrtps] \
              and the std, sensor and diagnostic messages (pip, no ROS installation; see docs/ros2.md)"
)]
#[test]
fn rclpy_decodes_every_standard_topic_with_the_values_of_its_frame() {
    for (slot, python) in ros_pythons().iter().enumerate() {
        one_distro(python, domain(slot as u32));
    }
}

fn one_distro(python: &str, domain: u16) {
    let dir = TempDir::new(&format!("bridge-{domain}"));
    let (layer, geometry) = geometry();
    geometry.publish(dir.path()).unwrap();
    let options = WriterOptions {
        period: Some(Duration::from_millis(20)),
        dir: Some(dir.path().to_owned()),
        ..WriterOptions::default()
    };
    let writer = Writer::create(SKIN, "arm", layer.frame_bytes(), &layer.encode(), &options).unwrap();
    let stop = Stop::new();
    let written = Arc::new(Mutex::new(BTreeMap::new()));
    let writing = {
        let (stop, written) = (stop.clone(), Arc::clone(&written));
        std::thread::spawn(move || write_layer(writer, stop, written))
    };
    let mut options = DdsOptions::new(SKIN);
    options.domain = domain;
    options.view.dir = Some(dir.path().to_owned());
    options.view.rates = Rates { map_hz: 5.0, ..Rates::default() };
    let bridge = DdsBridge::start(options).unwrap();
    let clouds = ["forearm", "hand"].map(|link| skinware_ros2::cloud_topic(SKIN, "arm", link));
    let map = skinware_ros2::map_topic(SKIN);
    let output = rclpy(python, domain)
        .args(["subscribe", "3"])
        .args(&clouds)
        .args([skinware_ros2::DIAGNOSTICS_TOPIC, skinware_ros2::TF_STATIC_TOPIC, &map])
        .output()
        .unwrap();
    let report = bridge.stop();
    stop.stop();
    writing.join().unwrap();
    assert!(output.status.success(), "{python}: {}", String::from_utf8_lossy(&output.stderr));
    let seen: Value = serde_json::from_slice(&output.stdout).expect("the peer prints JSON");
    eprintln!("{python}: bridge report {report:#?}");

    check_graph(&seen["graph"], &clouds, &map);
    let offset_ns = skinware_ros2::clock_offset_ns();
    let written = written.lock().unwrap();
    for topic in &clouds {
        let messages = seen["received"][topic].as_array().unwrap();
        // 10 Hz for 3 s: discovery, and the bridge's once-a-second look for
        // subscribers, may take the first second.
        assert!(messages.len() >= 12, "{python}: {} clouds on {topic} in 3 s", messages.len());
        for message in messages {
            check_cloud(message, &geometry, &written, offset_ns);
        }
    }
    let diagnostics = seen["received"][skinware_ros2::DIAGNOSTICS_TOPIC].as_array().unwrap();
    assert!(!diagnostics.is_empty(), "{python}: no /diagnostics in 3 s at 1 Hz");
    let last = &diagnostics.last().unwrap()["status"][0];
    assert_eq!(last["name"], format!("skin/{SKIN}/arm"));
    assert_eq!(last["level"], 0, "running at its nominal rate is OK: {last}");
    assert!(last["values"]["frames"].as_str().unwrap().parse::<u64>().unwrap() > 50);
    let images = seen["received"][&map].as_array().unwrap();
    assert!(images.len() >= 4, "{python}: {} map images in 3 s at 5 Hz", images.len());
    assert_eq!(images[0]["encoding"], "rgb8");
    assert_eq!(images[0]["frame_id"], format!("{SKIN}/map"));
}

/// The bridge's node publishes each topic with its type and QoS.
fn check_graph(graph: &Value, clouds: &[String], map: &str) {
    let publisher = |topic: &str| {
        let infos = graph[topic].as_array().unwrap_or_else(|| panic!("no publisher of {topic} in rclpy's graph"));
        assert_eq!(infos.len(), 1, "{topic}: {infos:?}");
        infos[0].clone()
    };
    for topic in clouds.iter().map(String::as_str).chain([map]) {
        let info = publisher(topic);
        assert_eq!(info["qos"]["reliability"], "BEST_EFFORT", "{topic}: {info}");
        assert_eq!(info["qos"]["durability"], "VOLATILE", "{topic}: {info}");
    }
    assert_eq!(publisher(&clouds[0])["type"], "sensor_msgs/msg/PointCloud2");
    assert_eq!(publisher(map)["type"], "sensor_msgs/msg/Image");
    let diagnostics = publisher(skinware_ros2::DIAGNOSTICS_TOPIC);
    assert_eq!(diagnostics["type"], "diagnostic_msgs/msg/DiagnosticArray");
    assert_eq!(diagnostics["qos"]["reliability"], "RELIABLE");
    let tf = publisher(skinware_ros2::TF_STATIC_TOPIC);
    assert_eq!(tf["type"], "tf2_msgs/msg/TFMessage");
    assert_eq!(tf["qos"]["reliability"], "RELIABLE");
    assert_eq!(tf["qos"]["durability"], "TRANSIENT_LOCAL");
    assert_eq!(diagnostics["node"], format!("skin_bridge_{SKIN}"), "the node's name in the graph: {diagnostics}");
}

/// A cloud's positions are its link's taxels', and its responses are
/// those of the frame whose acquisition its stamp gives.
fn check_cloud(message: &Value, geometry: &SkinGeometry, written: &BTreeMap<u16, u64>, offset_ns: i64) {
    let link = message["frame_id"].as_str().unwrap();
    let sensors: Vec<usize> = if link == "forearm" { vec![0, 2, 3] } else { vec![1] };
    let points = message["points"].as_array().unwrap();
    assert_eq!(points.len(), sensors.len());
    let point = |p: &Value| -> Vec<f64> { p.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect() };
    let first = point(&points[0]);
    // Which frame: its first sensor's response is (n * 7 + k * 1000) mod 65536.
    let k = sensors[0] as u64;
    let response0 = ((first[3] as u64 + 65536 - (k * 1000) % 65536) % 65536) as u16;
    let acquired = *written.get(&response0).unwrap_or_else(|| panic!("a cloud of no written frame: {message}"));
    let stamp = message["stamp_ns"].as_i64().unwrap();
    let expected = acquired as i64 + offset_ns;
    assert!((stamp - expected).abs() < 2_000_000, "stamp {stamp} is the frame's acquisition {expected}");
    for (p, &sensor) in points.iter().zip(&sensors) {
        let p = point(p);
        let position = geometry.positions[sensor];
        for axis in 0..3 {
            assert!((p[axis] - f64::from(position[axis])).abs() < 1e-6, "{link} point {p:?} is at {position:?}");
        }
        let n_response = (u64::from(response0) + sensor as u64 * 1000) % 65536;
        assert_eq!(p[3] as u64, n_response, "{link}: sensor {sensor} of the same frame");
    }
}
