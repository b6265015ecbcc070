//! The standard messages, decoded by rclpy (each ROS distro's Python in
//! `SKINWARE_ROS2_PYTHONS`, colon-separated: CI installs Jazzy's and
//! Kilted's), compared value by value with what was encoded; and every type
//! hash compared with the one the ROS packages publish.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;
use skinware::{TopologyBuilder, WriterState, WriterStats};
use skinware_geometry::{Calibration, SkinGeometry};
use skinware_ros2::cloud::LayerClouds;
use skinware_ros2::diagnostics::{ChannelHealth, diagnostics};
use skinware_ros2::markers::ContactMarkers;
use skinware_ros2::standard::{DIAGNOSTIC_ARRAY, MARKER_ARRAY, POINT_CLOUD2};
use skinware_ros2::type_hash::MESSAGE_TYPES;
use skinware_ros2::{Time, type_hash};
use skinware_services::contact::{Contact, RegionContacts};

/// The packages the ROS wheels CI installs ship (tactile_msgs and tf2_msgs
/// are not among them).
const PACKAGES: [&str; 6] =
    ["builtin_interfaces", "std_msgs", "sensor_msgs", "geometry_msgs", "visualization_msgs", "diagnostic_msgs"];

fn ros_pythons() -> Vec<String> {
    let list = std::env::var("SKINWARE_ROS2_PYTHONS").unwrap_or_default();
    list.split(':').filter(|p| !p.is_empty()).map(str::to_owned).collect()
}

fn geometry() -> SkinGeometry {
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
    SkinGeometry::build("oracle", &[layer], &calibration, &[]).unwrap()
}

/// Writes the three standard messages into `dir` as the oracle reads them.
fn write_messages(dir: &Path, geometry: &SkinGeometry) {
    let stamp = Time { sec: 1_700_000_000, nanosec: 123_456_789 };
    let clouds = LayerClouds::new(geometry, 0).unwrap();
    let forearm = clouds.clouds.iter().find(|c| c.link == "forearm").unwrap();
    std::fs::write(dir.join("sensor_msgs__PointCloud2.cdr"), forearm.encode(&[7, 8, 65535, 0], stamp).unwrap())
        .unwrap();

    let mut record = RegionContacts { count: 1, ..RegionContacts::default() };
    record.contacts[0] = Contact {
        centroid: [0.5, 0.25, 0.125],
        normal: [0.0, 1.0, 0.0],
        total: 10_000.0,
        peak_sensor: 1,
        ..Contact::default()
    };
    let drawing =
        ContactMarkers { geometry: Some(geometry), root: "base_link", lifetime: std::time::Duration::from_millis(300) };
    std::fs::write(dir.join("visualization_msgs__MarkerArray.cdr"), drawing.encode(&[record], stamp).unwrap()).unwrap();

    let health = |channel: &str, state, rate_hz| ChannelHealth {
        channel: channel.into(),
        writer: "virtual".into(),
        state,
        rate_hz,
        nominal_hz: 50.0,
        stats: WriterStats { frames: 1234, faults: 5, missed_periods: 2, ..WriterStats::default() },
        restarts: Some(3),
    };
    let channels = [health("virtual-0", WriterState::Running, 49.5), health("virtual-1", WriterState::Faulted, 0.0)];
    std::fs::write(dir.join("diagnostic_msgs__DiagnosticArray.cdr"), diagnostics("default", &channels, stamp).unwrap())
        .unwrap();
}

fn run_oracle(python: &str, dir: &Path) -> Value {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/integration/rclpy_oracle.py");
    let names: Vec<&str> = MESSAGE_TYPES
        .iter()
        .map(|t| t.name)
        .filter(|name| PACKAGES.iter().any(|p| name.starts_with(&format!("{p}/"))))
        .collect();
    let output = Command::new(python)
        .arg(&script)
        .arg(dir)
        .args(&names)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}"));
    assert!(output.status.success(), "{python} {script:?}: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("the oracle prints JSON")
}

fn check_cloud(cloud: &Value) {
    assert_eq!(cloud["header"]["frame_id"], "forearm");
    assert_eq!(cloud["header"]["stamp"]["sec"], 1_700_000_000);
    assert_eq!(cloud["header"]["stamp"]["nanosec"], 123_456_789);
    assert_eq!((cloud["height"].as_u64(), cloud["width"].as_u64()), (Some(1), Some(3)));
    let fields: Vec<(String, u64, u64)> = cloud["fields"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (f["name"].as_str().unwrap().to_owned(), f["offset"].as_u64().unwrap(), f["datatype"].as_u64().unwrap())
        })
        .collect();
    let expected = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7), ("response", 12, 7)];
    assert_eq!(fields, expected.map(|(n, o, d)| (n.to_owned(), o, d)));
    let bytes: Vec<u8> = cloud["data"].as_array().unwrap().iter().map(|b| b.as_u64().unwrap() as u8).collect();
    let floats: Vec<f32> = bytes.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    // Sensors 0, 2 and 3 of the layer are on the forearm: their positions, and responses 7, 65535 and 0.
    assert_eq!(floats, [0.125, 0.25, 0.5, 7.0, 1.0, 2.0, 3.0, 65535.0, 0.0, 0.0, 0.0625, 0.0]);
    assert_eq!(cloud["is_dense"], true);
    assert_eq!(cloud["is_bigendian"], false);
}

fn check_markers(array: &Value) {
    let markers = array["markers"].as_array().unwrap();
    assert_eq!(markers.len(), 2);
    assert_eq!(markers[0]["action"], 3, "DELETEALL first");
    let arrow = &markers[1];
    assert_eq!((arrow["type"].as_i64(), arrow["action"].as_i64()), (Some(0), Some(0)));
    assert_eq!(arrow["header"]["frame_id"], "hand", "the link of the contact's most pressed taxel");
    assert_eq!(arrow["lifetime"]["nanosec"], 300_000_000);
    let point = |p: &Value| [p["x"].as_f64().unwrap(), p["y"].as_f64().unwrap(), p["z"].as_f64().unwrap()];
    let points: Vec<[f64; 3]> = arrow["points"].as_array().unwrap().iter().map(point).collect();
    assert_eq!(
        points,
        [[0.5, 0.25 + 0.03, 0.125], [0.5, 0.25, 0.125]],
        "0.02 m + 10,000 × 1e-6 m above, to the centroid"
    );
    assert_eq!(arrow["pose"]["orientation"]["w"], 1.0);
}

fn check_diagnostics(array: &Value) {
    let status = array["status"].as_array().unwrap();
    assert_eq!(status.len(), 2);
    assert_eq!(status[0]["name"], "skin/default/virtual-0");
    assert_eq!(status[0]["hardware_id"], "virtual");
    // `byte` arrives in Python as a one-byte `bytes`.
    let level = |s: &Value| s["level"].as_u64().or_else(|| s["level"][0].as_u64());
    assert_eq!(level(&status[0]), Some(0));
    assert_eq!(level(&status[1]), Some(2));
    let values = status[1]["values"].as_array().unwrap();
    let value = |key: &str| values.iter().find(|v| v["key"] == key).map(|v| v["value"].clone());
    assert_eq!(value("faults"), Some("5".into()));
    assert_eq!(value("restarts"), Some("3".into()));
    assert_eq!(value("state"), Some("faulted".into()));
}

#[cfg_attr(
    skip_no_rclpy,
    ignore = "needs rclpy: SKINWARE_ROS2_PYTHONS, a Python per ROS distro with \
              ros-<distro>-rclpy[fastrtps] and the sensor, std, visualization and diagnostic messages \
              (pip, no ROS installation; see docs/ros2.md)"
)]
#[test]
fn rclpy_decodes_every_standard_message_and_publishes_our_hashes() {
    let pythons = ros_pythons();
    assert!(!pythons.is_empty(), "SKINWARE_ROS2_PYTHONS names no Python");
    let geometry = geometry();
    let dir = std::env::temp_dir().join(format!("skinware-rclpy-oracle-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    write_messages(&dir, &geometry);
    for python in &pythons {
        let report = run_oracle(python, &dir);
        let distro = report["distro"].as_str().unwrap_or("?").to_owned();
        println!(
            "{python} ({distro}): decoded {:?}",
            report["messages"].as_object().map(|m| m.keys().collect::<Vec<_>>())
        );
        check_cloud(&report["messages"][POINT_CLOUD2]);
        check_markers(&report["messages"][MARKER_ARRAY]);
        check_diagnostics(&report["messages"][DIAGNOSTIC_ARRAY]);
        let hashes = report["hashes"].as_object().unwrap();
        let mut compared = 0;
        for (name, published) in hashes {
            let Some(published) = published.as_str() else { panic!("{distro} ships no type description of {name}") };
            assert_eq!(type_hash(name).as_deref(), Some(published), "{distro}: {name}");
            compared += 1;
        }
        println!("{distro}: {compared} type hashes equal to the published ones");
        assert!(compared >= 20, "{compared} hashes compared");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
