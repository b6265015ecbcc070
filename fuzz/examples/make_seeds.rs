//! Writes a seed corpus of valid inputs for each fuzz target (run once:
//! `cargo +nightly run --manifest-path fuzz/Cargo.toml --example make_seeds`).

use std::path::Path;

use skinware::{TopologyBuilder, Writer, WriterOptions};
use skinware_geometry::{Calibration, RegionSpec, Selector, SensorCalibration, SkinGeometry};
use skinware_services::{ServiceInfo, framework::ServiceMode};

fn write(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus").join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), bytes).unwrap();
}

fn main() {
    let mut builder = TopologyBuilder::new("palm", "pressure", 50.0);
    builder.patch(1).module(10, 1..=6).module(11, 7..=12);
    builder.patch(2).module(20, [100, 101]);
    let topology = builder.build().unwrap();
    write("topology", "palm", &topology.encode());

    let info = ServiceInfo {
        schema: ("skinware.contact".into(), 1),
        record_bytes: 96,
        rate_hz: Some(50.0),
        inputs: vec!["pressure".into()],
        labels: vec!["palm".into(), "finger".into()],
    };
    write("service_description", "contact", &info.encode());
    let _ = ServiceMode::Sporadic;

    let mut calibration = Calibration::new();
    let mut text = String::from("skinware-calibration 1\n");
    for uid in 1..=12u32 {
        let (row, column) = ((uid - 1) / 6, (uid - 1) % 6);
        let (x, y) = (f64::from(column) * 0.005, f64::from(row) * 0.005);
        let link = if column < 3 { "palm" } else { "finger" };
        text.push_str(&format!("pressure {uid} {x} {y} 0 0 0 1 0.002 {link}\n"));
        let sensor =
            SensorCalibration { position: [x, y, 0.0], normal: [0.0, 0.0, 1.0], radius: 0.002, link: link.into() };
        calibration.insert("pressure", uid, sensor).unwrap();
    }
    write("calibration", "native", text.as_bytes());
    write(
        "calibration",
        "skin-calib",
        b"2\npressure 1 5000000 0 0 0 0 1000000 2000000 palm\npressure 2 0 5000000 0 0 0 1000000 2000000 finger\n",
    );

    let mut strip = TopologyBuilder::new("strip", "pressure", 50.0);
    strip.patch(1).module(10, 1..=6).module(11, 7..=12);
    let regions = [RegionSpec { name: "palm".into(), selectors: vec![Selector::Link("palm".into())] }];
    let geometry = SkinGeometry::build("s", &[strip.build().unwrap()], &calibration, &regions).unwrap();
    let file = geometry.encode();
    // The target appends the checksum itself.
    write("geometry", "strip", &file[..file.len() - 8]);

    let dir = std::env::temp_dir().join(format!("skinware-seeds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let options = WriterOptions { dir: Some(dir.clone()), ..WriterOptions::default() };
    let mut writer = Writer::create("fuzz", "layer", topology.frame_bytes(), &topology.encode(), &options).unwrap();
    writer.publish_bytes(&vec![7; topology.frame_bytes()], skinware::FrameStatus::OK).unwrap();
    // The target's input: a byte choosing sealed memory (even), then the frames memory.
    let mut seed = vec![0u8];
    seed.extend(frames_memory(&dir.join("skinware.fuzz.layer")));
    write("channel_header", "layer", &seed);
    drop(writer);
    let _ = std::fs::remove_dir_all(&dir);

    config_seeds();
    for (name, message) in [
        ("ack", r#"{"ack":2}"#),
        ("asap", r#"{"mode":"asap"}"#),
        ("periodic", r#"{"mode":"periodic","rate_hz":12.5}"#),
        ("request-mode", r#"{"mode":"request"}"#),
        ("request", r#"{"request":true}"#),
    ] {
        write("viewer_message", name, message.as_bytes());
    }
}

/// The frames memory a live writer hands over on its socket, as a reader gets it.
fn frames_memory(socket: &std::path::Path) -> Vec<u8> {
    use rustix::net::{RecvAncillaryBuffer, RecvAncillaryMessage, RecvFlags};
    use std::os::unix::fs::FileExt;
    let stream = std::os::unix::net::UnixStream::connect(socket).unwrap();
    let mut greeting = [0u8; 16];
    let mut space = [std::mem::MaybeUninit::uninit(); rustix::cmsg_space!(ScmRights(2))];
    let mut control = RecvAncillaryBuffer::new(&mut space);
    rustix::net::recvmsg(&stream, &mut [std::io::IoSliceMut::new(&mut greeting)], &mut control, RecvFlags::empty())
        .unwrap();
    let data = control
        .drain()
        .find_map(|message| match message {
            RecvAncillaryMessage::ScmRights(mut rights) => rights.next(),
            _ => None,
        })
        .expect("the writer handed over its memory");
    let file = std::fs::File::from(data);
    let mut bytes = vec![0u8; file.metadata().unwrap().len() as usize];
    file.read_exact_at(&mut bytes, 0).unwrap();
    bytes
}

/// The example configs, and a small one with every key.
fn config_seeds() {
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
    for entry in std::fs::read_dir(&examples).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let name = path.file_stem().unwrap().to_str().unwrap().to_owned();
            write("config", &name, &std::fs::read(&path).unwrap());
        }
    }
    write("config", "every-key", EVERY_KEY.as_bytes());
}

/// Every key of the format (examples/README.md), on a small skin.
const EVERY_KEY: &str = r#"skin = "s"
group_access = true

[[driver]]
name = "g"
kind = "virtual"
sensors = 96
layers = 2
sensors_per_module = 4
modules_per_patch = [1, 3]
rate_hz = { random = [30, 50] }
seed = 7
slots = 4
random_contacts = false
dead_taxels = [1, 2]
stuck_taxels = [3]
rt = { fifo_priority = 10, lock_memory = false, cpus = [0, 1] }
restart = { min_backoff_s = 0.1, max_backoff_s = 2 }
[[driver.cable_pull]]
layer = "g-1"
at_s = 1
duration_s = 0.5
every_s = 3
[[driver.contact]]
part = "left_forearm"
at_s = 0.5
angle_deg = 90
height = 0.1
velocity = [0.05, 0]
press_s = 0.2
slide_s = 1
release_s = 0.2
peak = 20000
sigma = 0.01

[[driver]]
name = "x"
kind = "virtual"
rate_hz = 100
calibration = "hand.calib"
[[driver.layer]]
name = "palm"
sensor_type = "pressure"
rate_hz = 200
sensors = 8
rt = { cpus = [0] }
[[driver.layer.patch]]
id = 1
[[driver.layer.patch.module]]
id = 1
uid_range = [1, 4]
[[driver.layer.patch.module]]
id = 2
uids = [5, 6, 7, 8]

[[region]]
name = "r"
uids = [1]
uid_range = [2, 3]
modules = [1]
patches = [1]
links = ["torso"]
near = { point = [0, 0, 1], radius = 0.1 }
[[region.in_layer]]
layer = "palm"
uids = [5]
uid_range = [6, 7]
modules = [2]
patches = [1]

[[service]]
name = "contact"
kind = "contact"
rate_hz = 50
threshold_sigma = 4
min_threshold = 20
baseline_tau_s = 10
restart = { min_backoff_s = 0.2, max_backoff_s = 5 }

[[service]]
name = "motion"
kind = "motion"
input = "contact"
min_speed = 0.01
window_s = 0.2
"#;
