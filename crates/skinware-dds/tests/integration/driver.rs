//! An rclpy publisher feeds a `ros2` layer: its values are read back from
//! the layer, stopping the publisher faults the layer, and starting it
//! again brings the layer back.

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use skinware::rt::RtOptions;
use skinware::{DriverHandler, FrameStatus, HandlerOptions, Reader, ReaderOptions, TopologyBuilder, WriterState};
use skinware_dds::driver::{Ros2Driver, Ros2Input};

use super::{TempDir, domain, rclpy, ros_pythons};

const SENSORS: usize = 6;

#[cfg_attr(
    skip_no_rclpy,
    ignore = "needs rclpy: SKINWARE_ROS2_PYTHONS, a Python per ROS distro with ros-<distro>-rclpy[fastrtps] \
              and the std, sensor and diagnostic messages (pip, no ROS installation; see docs/ros2.md)"
)]
#[test]
fn an_rclpy_publisher_is_a_layer_that_faults_when_it_stops_and_comes_back() {
    let kinds = ["PointCloud2", "UInt16MultiArray", "Float32MultiArray"];
    for (slot, python) in ros_pythons().iter().enumerate() {
        // Each distro feeds every kind at once, each on its own topic; the
        // domain is the test's own (slots 2 and 3).
        let feeding: Vec<_> = kinds
            .map(|kind| {
                let python = python.clone();
                std::thread::spawn(move || one_kind(&python, kind, domain(2 + slot as u32)))
            })
            .into_iter()
            .collect();
        for feed in feeding {
            feed.join().unwrap();
        }
    }
}

fn one_kind(python: &str, kind: &str, domain: u16) {
    let dir = TempDir::new(&format!("d{domain}{}", &kind[..2]));
    let skin = "ddsd";
    let mut builder = TopologyBuilder::new("fingertip", "pressure", 50.0);
    builder.patch(1).module(1, 0..SENSORS as u32);
    let topology = builder.build().unwrap();
    let topic = &format!("/sensor/{}/pressure", kind.to_lowercase());
    let input = Ros2Input::parse(kind, None).unwrap();
    let driver =
        Ros2Driver::new(topology, RtOptions::default(), topic, input, domain, Duration::from_millis(500)).unwrap();
    let counters = driver.counters();
    let options = HandlerOptions { dir: Some(dir.path().to_owned()), ..HandlerOptions::default() };
    let handler = DriverHandler::start(skin, Box::new(driver), &options).unwrap();
    let reader_options = ReaderOptions { dir: Some(dir.path().to_owned()), ..ReaderOptions::default() };
    let mut reader = Reader::open_with(skin, "fingertip", &reader_options).unwrap();

    // On for 3 s, silent for 2 s, on again for 3 s.
    let mut child = rclpy(python, domain)
        .args(["publish", topic, kind, "50", "3,2,3", &SENSORS.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = BufReader::new(child.stdout.take().unwrap());
    let watching = std::thread::spawn(move || watch(&mut reader));
    let phases: Vec<serde_json::Value> =
        stdout.lines().map(|line| serde_json::from_str(&line.unwrap()).unwrap()).collect();
    assert!(child.wait().unwrap().success(), "{python} publish {kind}");
    std::thread::sleep(Duration::from_millis(300));
    let (states, fresh, first_fresh) = watching.join().unwrap();
    handler.stop();

    let published = phases.last().unwrap()["published"].as_u64().unwrap();
    let (received, superseded, rejected) = (
        counters.received.load(Ordering::Relaxed),
        counters.superseded.load(Ordering::Relaxed),
        counters.rejected.load(Ordering::Relaxed),
    );
    eprintln!(
        "{python} {kind}: published {published}, received {received}, superseded {superseded}, rejected {rejected}; \
         states {states:?}; {} fresh frames read",
        fresh.len()
    );
    assert_eq!(rejected, 0, "{kind}: every message fits");
    // Best effort: the talker waits for the match, and on one machine none
    // is lost (every run so far); a CI machine's stall may drop a few.
    assert!(
        (received + superseded) * 100 >= published * 97,
        "{kind}: {} of {published} messages reached the layer",
        received + superseded
    );
    // Running while it publishes, faulted in the silence (after the first
    // message: not the wait for discovery), running again.
    let after_first: Vec<WriterState> =
        states.iter().filter(|(_, at)| *at > first_fresh.unwrap_or(f64::MAX)).map(|(state, _)| *state).collect();
    assert!(
        after_first.windows(2).any(|w| w == [WriterState::Faulted, WriterState::Running]),
        "{kind}: the layer's states {states:?}, the first message at {first_fresh:?} s"
    );
    // Each fresh frame is one message: responses (n * 7 + k) % 65536, n rising.
    assert!(fresh.len() > 100, "{kind}: {} fresh frames", fresh.len());
    let mut last_n = None;
    for responses in &fresh {
        let n = u64::from(responses[0]) / 7;
        for (k, &response) in responses.iter().enumerate() {
            assert_eq!(u64::from(response), (n * 7 + k as u64) % 65536, "{kind}: frame {responses:?}");
        }
        assert!(last_n.is_none_or(|last| n > last), "{kind}: message {n} after {last_n:?}");
        last_n = Some(n);
    }
}

/// What [`watch`] saw: states with when (s), fresh frames, the first's time.
type Watched = (Vec<(WriterState, f64)>, Vec<Vec<u16>>, Option<f64>);

/// The layer's states as they change (with when), every fresh frame's
/// responses, and when the first came, for 9 s.
fn watch(reader: &mut Reader) -> Watched {
    let start = Instant::now();
    let mut states: Vec<(WriterState, f64)> = Vec::new();
    let mut fresh = Vec::new();
    let mut last_seq = 0;
    let mut first_fresh = None;
    while start.elapsed() < Duration::from_secs(9) {
        let state = reader.writer_state();
        if states.last().is_none_or(|(last, _)| *last != state) {
            states.push((state, start.elapsed().as_secs_f64()));
        }
        if let Ok(frame) = reader.latest()
            && frame.seq() != last_seq
        {
            last_seq = frame.seq();
            if frame.status() == FrameStatus::OK {
                fresh.push(frame.responses().to_vec());
                first_fresh.get_or_insert(start.elapsed().as_secs_f64());
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    (states, fresh, first_fresh)
}

/// A forged writer on the layer's topic, under its type's name: what its
/// bytes claim.
#[derive(Debug, serde::Serialize)]
struct Forged {
    sec: i32,
    nanosec: u32,
    /// The frame id's length: far more than the message holds.
    frame_id_length: u32,
    rest: [u8; 8],
}

#[test]
fn forged_and_malformed_messages_are_counted_and_fault_the_layer_never_a_panic() {
    use ros2_client::{Context, ContextOptions, MessageTypeName, Name, NodeName, NodeOptions};
    use skinware_ros2::standard::{POINT_FIELD_FLOAT32, PointCloud2, PointField};

    let domain = domain(4);
    let dir = TempDir::new(&format!("f{domain}"));
    let mut builder = TopologyBuilder::new("forged", "pressure", 50.0);
    builder.patch(1).module(1, 0..4);
    let topic = "/sensor/forged";
    let input = Ros2Input::parse("PointCloud2", None).unwrap();
    let driver =
        Ros2Driver::new(builder.build().unwrap(), RtOptions::default(), topic, input, domain, Duration::from_secs(5))
            .unwrap();
    let counters = driver.counters();
    let options = HandlerOptions { dir: Some(dir.path().to_owned()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("ddsf", Box::new(driver), &options).unwrap();
    let mut reader = Reader::open_with(
        "ddsf",
        "forged",
        &ReaderOptions { dir: Some(dir.path().to_owned()), ..ReaderOptions::default() },
    )
    .unwrap();

    let context = Context::with_options(ContextOptions::new().domain_id(domain)).unwrap();
    let mut node =
        context.new_node(NodeName::new("/", "forger").unwrap(), NodeOptions::new().enable_rosout(false)).unwrap();
    let qos = ros2_client::QosProfile::subscription_default();
    let ros_topic = node
        .create_topic(&Name::parse(topic).unwrap(), MessageTypeName::new("sensor_msgs", "PointCloud2"), &qos)
        .unwrap();
    let forger = node.create_publisher::<Forged>(&ros_topic, Some(qos.clone())).unwrap();
    let honest = node.create_publisher::<PointCloud2>(&ros_topic, Some(qos)).unwrap();
    let cloud = |width: u32, field: &str, data_len: usize| PointCloud2 {
        header: skinware_ros2::Header { stamp: skinware_ros2::Time::default(), frame_id: "x".into() },
        height: 1,
        width,
        fields: vec![PointField { name: field.into(), offset: 0, datatype: POINT_FIELD_FLOAT32, count: 1 }],
        is_bigendian: false,
        point_step: 4,
        row_step: 4 * width,
        data: (0..data_len).map(|k| if k % 4 == 3 { 0x42 } else { 0 }).collect(),
        is_dense: true,
    };
    // Wait for the match (discovery) with the truth, then forge, lie and
    // finally tell the truth again.
    let deadline = Instant::now() + Duration::from_secs(20);
    while counters.received.load(Ordering::Relaxed) == 0 && Instant::now() < deadline {
        honest.publish(cloud(4, "response", 16)).unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(reader.writer_state(), WriterState::Running, "the first good message runs the layer");
    let received_before = counters.received.load(Ordering::Relaxed);
    let rejected = || counters.rejected.load(Ordering::Relaxed);
    while rejected() == 0 && Instant::now() < deadline {
        forger.publish(Forged { sec: 1, nanosec: 2, frame_id_length: 0xffff_fff0, rest: [0xff; 8] }).unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(rejected() >= 1, "bytes that are no PointCloud2 are counted");
    let forged = rejected();
    for lie in [cloud(1000, "response", 16), cloud(4, "pressure", 16)] {
        let before = rejected();
        while rejected() == before && Instant::now() < deadline {
            honest.publish(lie.clone()).unwrap();
            std::thread::sleep(Duration::from_millis(50));
        }
    }
    assert!(rejected() >= forged + 2, "a cloud of the wrong size, and one without the field, are counted");
    assert_eq!(reader.writer_state(), WriterState::Faulted, "a period of only misfits faults the layer");
    assert_eq!(counters.received.load(Ordering::Relaxed), received_before, "no misfit became a frame");
    while counters.received.load(Ordering::Relaxed) == received_before && Instant::now() < deadline {
        honest.publish(cloud(4, "response", 16)).unwrap();
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(100));
    let frame = reader.latest().unwrap();
    // 0x42000000 as a little-endian f32 is 32.0.
    assert_eq!(frame.responses(), [32, 32, 32, 32]);
    assert_eq!(reader.writer_state(), WriterState::Running);
    handler.stop();
}
