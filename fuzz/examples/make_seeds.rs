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
