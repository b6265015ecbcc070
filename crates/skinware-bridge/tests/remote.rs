//! The remote reader against a fake bridge on zenoh, in one process: good
//! frames are read in all three modes; malformed or hostile messages on the
//! frame and state keys give errors and are counted, never a panic; a bridge
//! that goes away makes the channel unreachable. And the attachment's bytes
//! are what zenoh-ext's own serializer writes.

#![cfg(feature = "zenoh")]

use std::time::{Duration, Instant};

use skinware::{ChannelKind, WriterState};
use skinware_bridge::BridgeError;
use skinware_bridge::link::LinkOptions;
use skinware_bridge::protocol::{self, ChannelList, ChannelState, RemoteChannel};
use skinware_bridge::remote::{RemoteSkin, RemoteState};
use skinware_bridge::rmw_zenoh::Attachment;
use skinware_ros2::{SkinFrameRef, Time};
use zenoh::Wait;

fn port() -> u16 {
    (30_000 + std::process::id() % 20_000) as u16
}

fn frame(seq: u64, responses: &[u16]) -> Vec<u8> {
    skinware_ros2::encode(
        &SkinFrameRef {
            stamp: Time { sec: 1, nanosec: 0 },
            published: Time { sec: 1, nanosec: 5 },
            seq,
            status: 0,
            skipped: 0,
            responses,
            payload: &[],
        },
        0,
    )
    .unwrap()
}

/// A fake bridge of skin `fake` with one layer, `palm`: it lists the
/// channel, answers requests with frame 77, and publishes what the test puts.
struct FakeBridge {
    _session: zenoh::Session,
    _channels: zenoh::query::Queryable<()>,
    _request: zenoh::query::Queryable<()>,
    token: zenoh::liveliness::LivelinessToken,
    frames: zenoh::pubsub::Publisher<'static>,
    states: zenoh::pubsub::Publisher<'static>,
}

fn fake_bridge(endpoint: &str) -> FakeBridge {
    let bridge_link = LinkOptions { listen: vec![endpoint.to_owned()], ..LinkOptions::default() };
    let bridge = bridge_link.open().expect("the fake bridge's session");
    let channel = RemoteChannel {
        name: "palm".into(),
        kind: ChannelKind::Layer,
        payload_bytes: 6,
        slots: 3,
        period: Some(Duration::from_millis(10)),
        schema: ("skinware.layer".into(), 1),
        description: Vec::new(),
    };
    let list = ChannelList { skin: "fake".into(), channels: vec![channel] }.encode();
    let channels = bridge
        .declare_queryable(protocol::channels_key("fake"))
        .callback(move |query| {
            let _ = query.reply(query.key_expr().clone(), list.clone()).wait();
        })
        .wait()
        .unwrap();
    let request = bridge
        .declare_queryable(protocol::request_key("fake", "palm"))
        .callback(|query| {
            let _ = query.reply(query.key_expr().clone(), frame(77, &[7, 7, 7])).wait();
        })
        .wait()
        .unwrap();
    let token = bridge.liveliness().declare_token(protocol::bridge_token_key("fake")).wait().unwrap();
    // Blocking, so that no message of the test is dropped by a busy queue.
    let block = zenoh::qos::CongestionControl::Block;
    let frames =
        bridge.declare_publisher(protocol::frame_key("fake", "palm")).congestion_control(block).wait().unwrap();
    let states =
        bridge.declare_publisher(protocol::state_key("fake", "palm")).congestion_control(block).wait().unwrap();
    FakeBridge { _session: bridge, _channels: channels, _request: request, token, frames, states }
}

/// Waits until a subscriber of `publisher` (the reader's) has reached the fake bridge.
fn wait_for_subscriber(publisher: &zenoh::pubsub::Publisher<'_>, what: &str) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while !publisher.matching_status().wait().unwrap().matching() {
        assert!(Instant::now() < deadline, "the reader's {what} subscription never reached the bridge");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Hostile frames: garbage, a wrong size, a service payload on a layer, a
/// length field claiming gigabytes. Each is an error, counted.
fn hostile_frames_are_refused(frames: &zenoh::pubsub::Publisher<'_>, reader: &mut skinware_bridge::remote::Reader) {
    let mut huge = frame(5, &[1, 2, 3]);
    // The responses' length: after the 4-byte header, two stamps and three u64s.
    huge[44..48].copy_from_slice(&u32::MAX.to_le_bytes());
    for (index, hostile) in
        [vec![0xff; 3], vec![0, 1, 0, 0, 9], frame(5, &[1, 2]), huge, Vec::new()].into_iter().enumerate()
    {
        frames.put(hostile).wait().unwrap();
        match reader.wait_newer(Duration::from_secs(5)) {
            Err(BridgeError::Malformed { .. }) => {}
            other => panic!("hostile frame {index} gave {other:?}"),
        }
    }
    assert_eq!(reader.stats().malformed, 5);
}

#[test]
fn a_fake_bridge_is_read_and_its_garbage_refused() {
    let endpoint = format!("tcp/127.0.0.1:{}", port());
    let bridge = fake_bridge(&endpoint);
    let (frames, states) = (&bridge.frames, &bridge.states);
    let link = LinkOptions { connect: vec![endpoint], ..LinkOptions::default() };
    let remote = RemoteSkin::connect(&link, "fake", Duration::from_secs(10)).expect("connect");
    assert!(remote.reader("elbow").unwrap_err().to_string().contains("has no channel \"elbow\""));
    let mut reader = remote.reader("palm").unwrap();
    wait_for_subscriber(frames, "frame");
    wait_for_subscriber(states, "state");

    // As soon as available; then a gap of two frames is counted.
    frames.put(frame(1, &[1, 2, 3])).wait().unwrap();
    let got = reader.wait_newer(Duration::from_secs(5)).unwrap();
    assert_eq!((got.seq, got.responses()), (1, vec![1, 2, 3]));
    frames.put(frame(4, &[4, 5, 6])).wait().unwrap();
    assert_eq!(reader.wait_newer(Duration::from_secs(5)).unwrap().skipped, 2);
    assert_eq!(reader.stats().skipped, 2);

    hostile_frames_are_refused(frames, &mut reader);
    // And the reader goes on.
    frames.put(frame(9, &[9, 9, 9])).wait().unwrap();
    assert_eq!(reader.wait_newer(Duration::from_secs(5)).unwrap().seq, 9);

    // States: a good one is read; garbage is counted and changes nothing.
    let faulted = ChannelState {
        state: WriterState::Faulted,
        published_seq: 9,
        sent: 3,
        dropped: 0,
        latency_ns: 1,
        period_ns: 0,
    };
    states.put(faulted.encode()).wait().unwrap();
    states.put(b"SKBSTA01 but not really".to_vec()).wait().unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    while (reader.bridge_state().is_none() || reader.stats().malformed < 6) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(reader.state(), RemoteState::Writer(WriterState::Faulted));
    assert_eq!(reader.stats().malformed, 6);

    // On request: the bridge's answer.
    assert_eq!(reader.request(Duration::from_secs(2)).unwrap().seq, 77);

    // Periodic: the newest at each tick.
    let mut ticker = skinware::Ticker::from_hz(50.0);
    let stop = skinware::Stop::new();
    assert_eq!(reader.next_periodic(&mut ticker, &stop).unwrap().seq, 77);

    // The bridge goes away: its token goes with it.
    drop(bridge.token);
    let deadline = Instant::now() + Duration::from_secs(5);
    while reader.state() != RemoteState::Unreachable && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(reader.state(), RemoteState::Unreachable);
    assert_eq!(reader.stats().unreachable, 1);
}

#[test]
fn the_attachment_is_what_zenoh_ext_serializes() {
    let attachment =
        Attachment { sequence_number: 42, source_timestamp: 1_700_000_000_123_456_789, source_gid: [7; 16] };
    let mut serializer = zenoh_ext::ZSerializer::new();
    serializer.serialize(attachment.sequence_number);
    serializer.serialize(attachment.source_timestamp);
    serializer.serialize(attachment.source_gid);
    let theirs = serializer.finish().to_bytes().into_owned();
    assert_eq!(theirs, attachment.encode());
    let bytes = zenoh::bytes::ZBytes::from(attachment.encode().to_vec());
    let mut deserializer = zenoh_ext::ZDeserializer::new(&bytes);
    assert_eq!(deserializer.deserialize::<i64>().unwrap(), 42);
}

#[test]
fn the_example_zenoh_configurations_are_valid() {
    let examples = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/zenoh");
    for name in ["robot-tls.json5", "robot-acl.json5"] {
        let link = LinkOptions { config_file: Some(examples.join(name)), ..LinkOptions::default() };
        let config = link.config().unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(config.get_json("listen/endpoints").unwrap().contains("tls/0.0.0.0:7447"), "{name}");
    }
    let missing = LinkOptions { config_file: Some(examples.join("missing.json5")), ..LinkOptions::default() };
    assert!(missing.config().unwrap_err().to_string().contains("missing.json5"));
}
