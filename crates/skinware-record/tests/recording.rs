//! Recording and replaying a small skin in this process: frames round-trip
//! bit for bit, gaps are counted, and bad files get clear errors, never
//! panics. (The paper's skin, the CLI, SIGKILL and the Python oracle are in
//! `skin`'s integration tests.)

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use skinware::{ChannelKind, FrameStatus, Reader, ReaderOptions, TopologyBuilder, Writer, WriterOptions};
use skinware_record::file::{Ending, RecordStream, read_header};
use skinware_record::{
    AtEnd, Compression, RecordError, RecordOptions, Recorder, Replay, ReplayOptions, ServiceChoice, scan,
};
use skinware_ros2::SkinFrame;

struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir = PathBuf::from("/dev/shm").join(format!("skinware-record-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(self.0.join("full")).output();
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A layer of `sensors` taxels and a service channel, under skin `skin` in `dir`.
fn channels(dir: &Path, skin: &str, sensors: u32) -> (Writer, Writer) {
    channels_with_slots(dir, skin, sensors, WriterOptions::default().slots)
}

/// [`channels`], with a layer of `slots` buffers.
fn channels_with_slots(dir: &Path, skin: &str, sensors: u32, slots: usize) -> (Writer, Writer) {
    let mut builder = TopologyBuilder::new("touch", "pressure", 200.0);
    builder.patch(1).module(1, 0..sensors);
    let topology = builder.build().unwrap();
    let layer_options = WriterOptions {
        period: Some(Duration::from_millis(5)),
        dir: Some(dir.to_owned()),
        slots,
        ..WriterOptions::default()
    };
    let layer = Writer::create(skin, "touch", topology.frame_bytes(), &topology.encode(), &layer_options).unwrap();
    let service_options = WriterOptions {
        kind: ChannelKind::Service,
        schema_name: "test.records".into(),
        schema_version: 3,
        dir: Some(dir.to_owned()),
        ..WriterOptions::default()
    };
    let service = Writer::create(skin, "events", 13, b"odd-sized records", &service_options).unwrap();
    (layer, service)
}

fn layer_frame(k: u64, sensors: usize) -> Vec<u16> {
    (0..sensors).map(|i| (k.wrapping_mul(7919) as usize ^ i.wrapping_mul(31)) as u16).collect()
}

fn options(dir: &Path, skin: &str) -> RecordOptions {
    RecordOptions {
        skin: skin.into(),
        services: ServiceChoice::All,
        map_hz: 0.0,
        dir: Some(dir.to_owned()),
        flush_interval: Duration::from_millis(200),
        ..RecordOptions::default()
    }
}

/// A recorded frame: payload bytes, status, sequence number, publication time.
type Frame = (Vec<u8>, u64, u64, u64);

/// Every frame of `path`, per channel.
fn frames(path: &Path) -> BTreeMap<String, Vec<Frame>> {
    let mut stream = RecordStream::open(path).unwrap();
    let (header, first) = read_header(&mut stream).unwrap();
    let mut out: BTreeMap<String, Vec<_>> = BTreeMap::new();
    let mut add = |message: mcap::records::MessageHeader, data: &[u8]| {
        if let Some(channel) = header.channels.get(&message.channel_id) {
            let frame: SkinFrame = skinware_ros2::decode(data, skinware_ros2::SKIN_FRAME).unwrap();
            out.entry(channel.channel.clone()).or_default().push((
                frame.channel_bytes(),
                frame.status,
                frame.seq,
                message.publish_time,
            ));
        }
    };
    if let Some((message, data)) = first {
        add(message, &data);
    }
    while let Some(record) = stream.next_record().unwrap() {
        if let mcap::records::Record::Message { header: message, data } = record {
            add(message, &data);
        }
    }
    out
}

#[test]
fn a_recording_replays_bit_for_bit_and_its_gaps_are_counted() {
    let dir = TempDir::new("roundtrip");
    let sensors = 300usize;
    let (mut layer, mut service) = channels(&dir.0, "rt", sensors as u32);
    let first = dir.0.join("first.mcap");
    let recorder = Recorder::start(&first, options(&dir.0, "rt")).unwrap();
    // The recorder's readers attach before the first frame.
    std::thread::sleep(Duration::from_millis(100));
    for k in 1..=200u64 {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, sensors)).unwrap();
        if k % 50 == 0 {
            frame.set_status(FrameStatus::FAULT);
        }
        frame.publish();
        if k % 4 == 0 {
            let record: Vec<u8> = (0..13).map(|i| (k as u8).wrapping_add(i)).collect();
            service.publish_bytes(&record, FrameStatus::OK).unwrap();
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    // Three frames faster than any reader can take them: a gap.
    for k in 201..=203u64 {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, sensors)).unwrap();
        frame.publish();
    }
    std::thread::sleep(Duration::from_millis(100));
    let summary = recorder.finish().unwrap();
    let recorded = &summary.channels["touch"];
    assert_eq!(recorded.frames + recorded.lost, 203, "every frame is recorded or counted lost: {recorded:?}");
    let events = &summary.channels["events"];
    assert_eq!(events.frames + events.lost, 50, "{events:?}");
    let info = scan(&first).unwrap();
    assert_eq!(info.ending, Ending::Finished);
    assert_eq!(info.channels["touch"].frames, recorded.frames);
    assert_eq!(info.channels["touch"].lost, recorded.lost);
    // Frames 50, 100, 150 and 200 carry a fault: those recorded say so, and only those.
    let touch = &frames(&first)["touch"];
    assert!(touch.iter().all(|f| (f.1 == FrameStatus::FAULT.0) == (f.2 % 50 == 0 && f.2 <= 200)));
    let faulted = touch.iter().filter(|f| f.1 == FrameStatus::FAULT.0).count() as u64;
    assert_eq!(info.channels["touch"].faulted, faulted);
    assert_eq!(recorded.faulted, faulted);
    if summary.lost > 0 {
        let gaps: u64 = summary.channels.values().map(|c| c.gaps).sum();
        assert_eq!(info.topics.get("/skin/rt/gaps").copied().unwrap_or(0), gaps);
    }
    drop((layer, service));

    // Replay under another skin name, recorded again.
    let replay_options = ReplayOptions {
        skin: Some("rt2".into()),
        start_delay: Duration::from_millis(300),
        dir: Some(dir.0.clone()),
        ..ReplayOptions::default()
    };
    let mut replay = Replay::open(&first, replay_options).unwrap();
    let second = dir.0.join("second.mcap");
    let again = Recorder::start(&second, options(&dir.0, "rt2")).unwrap();
    let report = replay.run().unwrap();
    assert_eq!(report.frames, info.frames);
    drop(replay);
    std::thread::sleep(Duration::from_millis(100));
    let summary = again.finish().unwrap();
    // A second recorder as slow as the first may miss frames of the replay
    // too; the replay's sequence numbers start at 1, so its frame k is the
    // first recording's k-th.
    let (a, b) = (frames(&first), frames(&second));
    for (channel, frames_a) in &a {
        let frames_b = &b[channel];
        // The second recorder started before the replay's first frame: it
        // recorded or counted every one.
        assert_eq!(
            frames_a.len() as u64,
            frames_b.len() as u64 + summary.channels[channel].lost,
            "{channel}: {summary:?}"
        );
        for fb in frames_b {
            let at = fb.2 as usize - 1;
            assert_eq!((&frames_a[at].0, frames_a[at].1), (&fb.0, fb.1), "{channel}: payload and status of frame {at}");
        }
    }
}

#[test]
fn a_reader_of_a_replay_sees_the_recorded_description_and_schema() {
    let dir = TempDir::new("schema");
    let (mut layer, mut service) = channels(&dir.0, "sc", 40);
    let path = dir.0.join("rec.mcap");
    let recorder = Recorder::start(&path, options(&dir.0, "sc")).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    for k in 0..20u64 {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, 40)).unwrap();
        frame.publish();
        service.publish_bytes(&[k as u8; 13], FrameStatus::OK).unwrap();
        std::thread::sleep(Duration::from_millis(3));
    }
    std::thread::sleep(Duration::from_millis(50));
    recorder.finish().unwrap();
    drop((layer, service));
    let options = ReplayOptions { dir: Some(dir.0.clone()), at_end: AtEnd::Exit, ..ReplayOptions::default() };
    let replay = Replay::open(&path, options).unwrap();
    let reader_options = ReaderOptions { dir: Some(dir.0.clone()), ..ReaderOptions::default() };
    let reader = Reader::open_with("sc", "events", &reader_options).unwrap();
    assert_eq!(reader.schema(), ("test.records".to_owned(), 3));
    assert_eq!(reader.description(), b"odd-sized records");
    assert_eq!(reader.kind(), ChannelKind::Service);
    let layer = Reader::open_with("sc", "touch", &reader_options).unwrap();
    assert_eq!(layer.topology().unwrap().sensors.len(), 40);
    assert_eq!(layer.writer_period(), Some(Duration::from_millis(5)));
    drop(replay);
}

/// A recording of `count` frames of the layer `touch` of skin `skin`, one every `period`.
fn paced_recording(dir: &Path, skin: &str, count: u64, period: Duration) -> PathBuf {
    // Enough buffers that a recorder thread delayed by the tests running
    // beside it still finds every frame.
    let (mut layer, _service) = channels_with_slots(dir, skin, 50, 32);
    let path = dir.join(format!("{skin}.mcap"));
    let recorder = Recorder::start(&path, options(dir, skin)).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    for k in 1..=count {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, 50)).unwrap();
        frame.publish();
        std::thread::sleep(period);
    }
    std::thread::sleep(Duration::from_millis(50));
    let summary = recorder.finish().unwrap();
    assert_eq!(summary.channels["touch"].frames, count, "a recorder at 10 ms per frame misses none: {summary:?}");
    path
}

/// Replays `path` under skin `as_skin` with `options`, recording the replay;
/// returns the replay's report and the frames of layer `touch` recorded, each
/// with its replayed sequence number (every frame published is either among
/// them or counted lost by the second recorder).
fn replay_and_record(
    dir: &Path,
    path: &Path,
    as_skin: &str,
    options: ReplayOptions,
    stop_after: Option<Duration>,
) -> (skinware_record::ReplayReport, Vec<Frame>, u64) {
    let replay_options = ReplayOptions {
        skin: Some(as_skin.into()),
        start_delay: Duration::from_millis(200),
        dir: Some(dir.to_owned()),
        ..options
    };
    let mut replay = Replay::open(path, replay_options).unwrap();
    let again = dir.join(format!("{as_skin}.mcap"));
    let recorder = Recorder::start(&again, options_for_replay(dir, as_skin)).unwrap();
    let stop = replay.stop_signal().clone();
    let started = wall_clock_ns();
    let running = std::thread::spawn(move || replay.run().unwrap());
    if let Some(after) = stop_after {
        std::thread::sleep(after);
        stop.stop();
    }
    let report = running.join().unwrap();
    std::thread::sleep(Duration::from_millis(100));
    let summary = recorder.finish().unwrap();
    let mut recorded = frames(&again).remove("touch").unwrap();
    assert_eq!(
        recorded.len() as u64 + summary.channels["touch"].lost,
        report.channels["touch"],
        "the second recorder saw or counted every frame replayed: {summary:?}"
    );
    recorded.sort_by_key(|f| f.2);
    (report, recorded, started)
}

/// Now, on the wall clock the recordings' stamps use, ns.
fn wall_clock_ns() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() as u64
}

/// How early a replayed span may seem: its first frame published late by up
/// to this much (tests run beside each other, in the normal scheduler).
const LATE_MARGIN_NS: u64 = 20_000_000;

fn options_for_replay(dir: &Path, skin: &str) -> RecordOptions {
    RecordOptions { services: ServiceChoice::None, ..options(dir, skin) }
}

#[test]
fn from_and_to_replay_exactly_the_frames_between_them() {
    let dir = TempDir::new("window");
    let path = paced_recording(&dir.0, "win", 60, Duration::from_millis(10));
    let original = &frames(&path)["touch"];
    let first = original[0].3;
    let (from_s, to_s) = (0.3, 0.5);
    let expected: Vec<_> = original
        .iter()
        .filter(|f| {
            let offset = (f.3 - first) as f64 / 1e9;
            (from_s..=to_s).contains(&offset)
        })
        .collect();
    assert!(expected.len() >= 10 && expected.len() < 60, "{} frames in the window", expected.len());
    let options = ReplayOptions { from_s: Some(from_s), to_s: Some(to_s), ..ReplayOptions::default() };
    let (report, replayed, started) = replay_and_record(&dir.0, &path, "win2", options, None);
    assert_eq!(report.frames, expected.len() as u64, "the frames between --from and --to, and only those");
    for f in &replayed {
        let of = expected[f.2 as usize - 1];
        assert_eq!((&f.0, f.1), (&of.0, of.1), "replayed frame {} is recorded frame {}", f.2, of.2);
    }
    // The window's first frame comes at the replay's start (after its
    // 200 ms start delay), not --from's 300 ms later.
    let first = &replayed[0];
    let first_due = (expected[first.2 as usize - 1].3 - expected[0].3) / 1_000_000;
    let first_at_ms = (first.3 - started) / 1_000_000;
    assert!(first_at_ms < 200 + first_due + 100, "replayed frame {} came {first_at_ms} ms after the start", first.2);
}

#[test]
fn a_faster_replay_keeps_every_frame_and_compresses_the_time_between_them() {
    let dir = TempDir::new("speed");
    let path = paced_recording(&dir.0, "fast", 60, Duration::from_millis(10));
    let original = &frames(&path)["touch"];
    let speed = 4.0;
    let options = ReplayOptions { speed, ..ReplayOptions::default() };
    let (report, replayed, _) = replay_and_record(&dir.0, &path, "fast2", options, None);
    assert_eq!(report.frames, 60);
    for f in &replayed {
        let of = &original[f.2 as usize - 1];
        assert_eq!(&f.0, &of.0, "frame {}", f.2);
    }
    let (a, b) = (&replayed[0], replayed.last().unwrap());
    let recorded_span = (original[b.2 as usize - 1].3 - original[a.2 as usize - 1].3) as f64;
    let replayed_span = (b.3 - a.3) as f64;
    // Never early (each frame waits for its time, the recorded time over the
    // speed); and far from the recorded pace (that would be 4 times this).
    assert!(
        replayed_span + LATE_MARGIN_NS as f64 >= recorded_span / speed,
        "{replayed_span} ns for {recorded_span} ns recorded"
    );
    assert!(replayed_span < recorded_span / 2.0, "{replayed_span} ns for {recorded_span} ns recorded at speed {speed}");
}

#[test]
fn a_looping_replay_starts_again_from_the_first_frame_until_stopped() {
    let dir = TempDir::new("loop");
    let count = 20;
    let path = paced_recording(&dir.0, "lp", count, Duration::from_millis(10));
    let original = &frames(&path)["touch"];
    let options = ReplayOptions { at_end: AtEnd::Loop, ..ReplayOptions::default() };
    // A pass takes about 0.2 s.
    let (report, replayed, _) = replay_and_record(&dir.0, &path, "lp2", options, Some(Duration::from_millis(1000)));
    assert!(report.passes >= 3, "{report:?}");
    assert!(report.frames >= 2 * count, "{report:?}");
    let mut after_the_first_pass = 0;
    for f in &replayed {
        let at = (f.2 - 1) % count;
        assert_eq!(&f.0, &original[at as usize].0, "replayed frame {} is recorded frame {}", f.2, at + 1);
        after_the_first_pass += u64::from(f.2 > count);
    }
    assert!(after_the_first_pass >= count / 2, "frames recorded after the first pass: {after_the_first_pass}");
}

/// A finished recording's bytes, for the bad-file tests.
fn small_recording(dir: &Path) -> Vec<u8> {
    let (mut layer, _service) = channels(dir, "bad", 64);
    let path = dir.join("small.mcap");
    let recorder =
        Recorder::start(&path, RecordOptions { compression: Compression::Lz4, ..options(dir, "bad") }).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    for k in 0..60u64 {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, 64)).unwrap();
        frame.publish();
        std::thread::sleep(Duration::from_millis(5));
    }
    std::thread::sleep(Duration::from_millis(50));
    recorder.finish().unwrap();
    std::fs::read(&path).unwrap()
}

#[test]
fn a_cut_file_is_read_up_to_its_last_complete_chunk_at_every_length() {
    let dir = TempDir::new("cut");
    let whole = small_recording(&dir.0);
    let full = scan_bytes(&whole).unwrap();
    assert_eq!(full.ending, Ending::Finished);
    let cut = dir.0.join("cut.mcap");
    let mut readable_lengths = 0;
    let mut previous_frames = 0;
    for length in (0..whole.len()).step_by(97) {
        std::fs::write(&cut, &whole[..length]).unwrap();
        match scan(&cut) {
            Ok(info) => {
                readable_lengths += 1;
                assert_ne!(info.ending, Ending::Finished, "a file cut at {length} cannot look finished");
                // Longer cuts never hold fewer frames.
                assert!(info.frames >= previous_frames, "cut at {length}");
                assert!(info.frames <= full.frames);
                previous_frames = info.frames;
            }
            Err(e) => {
                let text = e.to_string();
                assert!(text.contains("cut.mcap"), "errors name the file: {text}");
            }
        }
    }
    assert!(readable_lengths > 0);
    // The recovered copy of a cut file is a finished file with the same frames.
    let at = whole.len() * 2 / 3;
    std::fs::write(&cut, &whole[..at]).unwrap();
    let cut_info = scan(&cut).unwrap();
    let out = dir.0.join("recovered.mcap");
    let recovered = skinware_record::recover(&cut, &out, None).unwrap();
    assert_eq!(recovered.input_ending, Ending::Truncated);
    let info = scan(&out).unwrap();
    assert_eq!(info.ending, Ending::Finished);
    assert_eq!(info.frames, cut_info.frames);
    // A recovered file is never written over.
    assert!(matches!(skinware_record::recover(&cut, &out, None), Err(RecordError::Exists { .. })));
}

fn scan_bytes(bytes: &[u8]) -> Result<skinware_record::RecordingInfo, RecordError> {
    let stream = RecordStream::from_reader(Path::new("bytes.mcap"), std::io::Cursor::new(bytes.to_vec()))?;
    skinware_record::file::scan_stream(stream, bytes.len() as u64)
}

#[test]
fn flipped_bytes_give_errors_or_fewer_frames_never_a_panic() {
    let dir = TempDir::new("flip");
    let whole = small_recording(&dir.0);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    for _ in 0..400 {
        let mut bytes = whole.clone();
        for _ in 0..3 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let at = (state % bytes.len() as u64) as usize;
            bytes[at] ^= 1 << (state >> 61);
        }
        let _ = scan_bytes(&bytes);
    }
}

#[test]
fn foreign_files_get_errors_that_say_what_is_wrong() {
    let dir = TempDir::new("foreign");
    let text = dir.0.join("notes.txt");
    std::fs::write(&text, "skin = \"default\"\n").unwrap();
    let e = scan(&text).unwrap_err().to_string();
    assert!(e.contains("is not an MCAP file"), "{e}");
    let empty = dir.0.join("empty.mcap");
    std::fs::write(&empty, b"").unwrap();
    assert!(scan(&empty).unwrap_err().to_string().contains("is not an MCAP file"));
    let missing = scan(&dir.0.join("nowhere.mcap")).unwrap_err().to_string();
    assert!(missing.contains("cannot open") && missing.contains("nowhere.mcap"), "{missing}");

    // MCAP, but not ours.
    let other = dir.0.join("other.mcap");
    write_mcap(&other, None, None);
    let e = scan(&other).unwrap_err().to_string();
    assert!(e.contains("holds no skinware recording") && e.contains("skinware.recording"), "{e}");

    // Ours, from the future.
    let future = dir.0.join("future.mcap");
    write_mcap(&future, Some("99"), None);
    let e = Replay::open(&future, ReplayOptions { dir: Some(dir.0.clone()), ..ReplayOptions::default() })
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("recording format 99") && e.contains("newer skinware"), "{e}");

    // A skinware topic with a schema we do not know.
    let unknown = dir.0.join("unknown.mcap");
    write_mcap(&unknown, Some("1"), Some("vendor_msgs/msg/Blob"));
    let e = scan(&unknown).unwrap_err().to_string();
    assert!(e.contains("vendor_msgs/msg/Blob") && e.contains("/skin/x/touch") && e.contains("SkinFrame"), "{e}");
}

/// An MCAP file with an optional `skinware.recording` version and a
/// skinware channel with the given schema.
fn write_mcap(path: &Path, version: Option<&str>, schema: Option<&str>) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut writer = mcap::WriteOptions::new().profile("ros2").create(file).unwrap();
    if let Some(version) = version {
        let metadata = [("format_version", version), ("skin", "x")].map(|(k, v)| (k.to_owned(), v.to_owned()));
        writer
            .write_metadata(&mcap::records::Metadata { name: "skinware.recording".into(), metadata: metadata.into() })
            .unwrap();
    }
    let schema_id = writer.add_schema(schema.unwrap_or("std_msgs/msg/String"), "ros2msg", b"string data").unwrap();
    let mut metadata = BTreeMap::new();
    if schema.is_some() {
        metadata.insert("skinware.channel".to_owned(), "touch".to_owned());
        metadata.insert("skinware.kind".to_owned(), "layer".to_owned());
    }
    let channel = writer.add_channel(schema_id, "/skin/x/touch", "cdr", &metadata).unwrap();
    let header = mcap::records::MessageHeader { channel_id: channel, sequence: 1, log_time: 1, publish_time: 1 };
    writer.write_to_known_channel(&header, &[0, 1, 0, 0, 4, 0, 0, 0, b'a', b'b', b'c', 0]).unwrap();
    writer.finish().unwrap();
}

#[test]
#[cfg_attr(skip_not_root, ignore = "needs root: mounts a 1 MiB tmpfs to fill")]
fn a_full_disk_stops_the_recorder_with_a_clear_error_and_keeps_what_was_written() {
    let dir = TempDir::new("full");
    let small = dir.0.join("full");
    std::fs::create_dir_all(&small).unwrap();
    let mounted = std::process::Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=1m", "tmpfs"])
        .arg(&small)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !mounted {
        println!("SKIPPED: cannot mount a 1 MiB tmpfs to fill (needs root); the disk-full path is not exercised");
        return;
    }
    let (mut layer, _service) = channels(&dir.0, "full", 4000);
    let path = small.join("rec.mcap");
    let recorder = Recorder::start(
        &path,
        RecordOptions {
            compression: Compression::None,
            flush_interval: Duration::from_millis(50),
            ..options(&dir.0, "full")
        },
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(50));
    // 8 KB frames, uncompressed: 1 MiB is full after about 130.
    for k in 0..2000u64 {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, 4000)).unwrap();
        frame.publish();
        std::thread::sleep(Duration::from_millis(1));
        if recorder.has_failed() {
            break;
        }
    }
    assert!(recorder.has_failed(), "a 1 MiB disk must fill");
    let e = recorder.finish().unwrap_err().to_string();
    assert!(e.contains("rec.mcap") && e.contains("the disk is full") && e.contains("--recover"), "{e}");
    let info = scan(&path).unwrap();
    assert_ne!(info.ending, Ending::Finished);
    assert!(info.frames > 10, "what was written before the disk filled is readable: {}", info.frames);
}

#[test]
fn an_unwritable_path_or_an_existing_file_is_refused_before_recording() {
    let dir = TempDir::new("unwritable");
    let (_layer, _service) = channels(&dir.0, "uw", 8);
    let nowhere = dir.0.join("no-such-directory").join("rec.mcap");
    let e = Recorder::start(&nowhere, options(&dir.0, "uw")).err().unwrap().to_string();
    assert!(e.contains("cannot create") && e.contains("no-such-directory"), "{e}");
    let existing = dir.0.join("kept.mcap");
    std::fs::write(&existing, b"precious").unwrap();
    let e = Recorder::start(&existing, options(&dir.0, "uw")).err().unwrap().to_string();
    assert!(e.contains("exists") && e.contains("never overwritten"), "{e}");
    assert_eq!(std::fs::read(&existing).unwrap(), b"precious");
    // Nothing to record: a skin that is not running.
    let e = Recorder::start(&dir.0.join("x.mcap"), options(&dir.0, "absent")).err().unwrap().to_string();
    assert!(e.contains("skin absent has no running channel"), "{e}");
    // A layer that does not exist is named, with those that do.
    let e = Recorder::start(
        &dir.0.join("y.mcap"),
        RecordOptions { layers: Some(vec!["tuch".into()]), ..options(&dir.0, "uw") },
    )
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("no running layer \"tuch\"") && e.contains("touch"), "{e}");
}

/// Records `frames` layer frames, one every 4 ms, split by `split`; returns the summary.
fn split_recording(
    dir: &Path,
    skin: &str,
    frames: u64,
    split: skinware_record::Split,
) -> skinware_record::RecordSummary {
    let (mut layer, _service) = channels_with_slots(dir, skin, 50, 32);
    let options =
        RecordOptions { split: Some(split), flush_interval: Duration::from_millis(100), ..options(dir, skin) };
    let recorder = Recorder::start(&dir.join(format!("{skin}.mcap")), options).unwrap();
    std::thread::sleep(Duration::from_millis(50));
    for k in 1..=frames {
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, 50)).unwrap();
        frame.publish();
        std::thread::sleep(Duration::from_millis(4));
    }
    std::thread::sleep(Duration::from_millis(50));
    recorder.finish().unwrap()
}

/// Every part of a split recording is a whole file, and together they hold
/// each frame once, in order.
fn check_parts(summary: &skinware_record::RecordSummary, skin: &str, frames_recorded: u64) {
    assert!(summary.parts.len() >= 3, "{:?}", summary.parts);
    assert_eq!(summary.path, summary.parts[0]);
    let mut sequence = Vec::new();
    let mut bytes = 0;
    for (index, part) in summary.parts.iter().enumerate() {
        assert_eq!(part, &skinware_record::part_path(&summary.path.with_file_name(format!("{skin}.mcap")), index));
        let info = scan(part).unwrap();
        assert_eq!(info.ending, Ending::Finished, "part {index} is finished: {info:?}");
        assert_eq!(info.skin, skin);
        assert!(info.channels.contains_key("touch") && info.channels.contains_key("events"), "{info:?}");
        let touch = frames(part).remove("touch").unwrap_or_default();
        for (bytes, _, seq, _) in &touch {
            let responses: Vec<u16> = bytes.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
            assert_eq!(responses, layer_frame(*seq, 50), "frame {seq} in part {index}");
        }
        sequence.extend(touch.iter().map(|(_, _, seq, _)| *seq));
        bytes += std::fs::metadata(part).unwrap().len();
    }
    let expected: Vec<u64> = (1..=frames_recorded).collect();
    assert_eq!(sequence, expected, "each frame once, in order, over the parts");
    assert_eq!(summary.file_bytes, bytes, "the summary counts every part's bytes");
    assert_eq!(summary.lost, 0);
}

#[test]
fn a_split_recording_goes_on_in_whole_files_and_loses_no_frame_between_them() {
    let dir = TempDir::new("split");
    let by_time = skinware_record::Split { max_duration: Some(Duration::from_millis(300)), max_bytes: None };
    let summary = split_recording(&dir.0, "spl", 300, by_time);
    check_parts(&summary, "spl", 300);
    // By size: a part closes once it holds 8 KB.
    let by_size = skinware_record::Split { max_duration: None, max_bytes: Some(8_000) };
    let summary = split_recording(&dir.0, "spb", 300, by_size);
    check_parts(&summary, "spb", 300);
    // A part that exists already is never overwritten: the recording stops with an error naming it.
    let taken = skinware_record::part_path(&dir.0.join("spt.mcap"), 1);
    std::fs::write(&taken, b"someone else's").unwrap();
    let (mut layer, _service) = channels_with_slots(&dir.0, "spt", 50, 32);
    let split_options =
        RecordOptions { split: Some(by_time), flush_interval: Duration::from_millis(100), ..options(&dir.0, "spt") };
    let recorder = Recorder::start(&dir.0.join("spt.mcap"), split_options).unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let mut k = 0;
    while !recorder.has_failed() && std::time::Instant::now() < deadline {
        k += 1;
        let mut frame = layer.begin();
        frame.write_responses(0, &layer_frame(k, 50)).unwrap();
        frame.publish();
        std::thread::sleep(Duration::from_millis(4));
    }
    let error = recorder.finish().unwrap_err().to_string();
    assert!(error.contains("spt_001.mcap"), "{error}");
    assert_eq!(std::fs::read(&taken).unwrap(), b"someone else's");
    // The part being written when the next could not start is finished, whole.
    let first = skinware_record::part_path(&dir.0.join("spt.mcap"), 0);
    assert_eq!(scan(&first).unwrap().ending, Ending::Finished);
    // Limits that cannot be kept are refused before anything is recorded.
    for split in [
        skinware_record::Split::default(),
        skinware_record::Split { max_bytes: Some(0), max_duration: None },
        skinware_record::Split { max_bytes: None, max_duration: Some(Duration::ZERO) },
    ] {
        let refused = RecordOptions { split: Some(split), ..options(&dir.0, "spt") };
        let error = Recorder::start(&dir.0.join("refused.mcap"), refused).err().unwrap().to_string();
        assert!(error.contains("cannot split the recording"), "{error}");
    }
}

/// A split recording replays whole, as one, under the name it was recorded
/// under: every part's frames in turn, at their times, each once. Parts of
/// two recordings are refused where the second begins.
#[test]
fn a_split_recording_replays_whole_under_its_recorded_name() {
    let dir = TempDir::new("split-replay");
    let by_time = skinware_record::Split { max_duration: Some(Duration::from_millis(250)), max_bytes: None };
    let summary = split_recording(&dir.0, "spr", 200, by_time);
    check_parts(&summary, "spr", 200);
    let named = dir.0.join("spr.mcap");
    assert_eq!(
        skinware_record::recording_parts(&named),
        summary.parts,
        "the name it was recorded under finds its parts"
    );
    let replay_options = ReplayOptions {
        skin: Some("spr2".into()),
        start_delay: Duration::from_millis(300),
        dir: Some(dir.0.clone()),
        ..ReplayOptions::default()
    };
    let mut replay = Replay::open(&named, replay_options.clone()).unwrap();
    let again = dir.0.join("again.mcap");
    let recorder = Recorder::start(&again, options(&dir.0, "spr2")).unwrap();
    let report = replay.run().unwrap();
    drop(replay);
    std::thread::sleep(Duration::from_millis(100));
    let summary_again = recorder.finish().unwrap();
    let replayed: u64 = report.channels.iter().filter(|(c, _)| c.as_str() == "touch").map(|(_, n)| n).sum();
    assert_eq!(replayed, 200, "every part's frames were replayed: {report:?}");
    let touch = frames(&again).remove("touch").unwrap_or_default();
    assert_eq!(touch.len() as u64 + summary_again.channels["touch"].lost, 200, "{summary_again:?}");
    for (bytes, _, seq, _) in &touch {
        let responses: Vec<u16> = bytes.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
        assert_eq!(responses, layer_frame(*seq, 50), "the replay's frame {seq} is the recording's");
    }

    // A part that cannot be read at all (an empty file: a recorder killed as
    // it began the part) is passed over, and the next goes on.
    let damaged = dir.0.join("dmg.mcap");
    std::fs::copy(&summary.parts[0], skinware_record::part_path(&damaged, 0)).unwrap();
    std::fs::write(skinware_record::part_path(&damaged, 1), b"").unwrap();
    std::fs::copy(&summary.parts[1], skinware_record::part_path(&damaged, 2)).unwrap();
    let fast = ReplayOptions { skin: Some("spr4".into()), speed: 4.0, ..replay_options.clone() };
    let report = Replay::open(&damaged, fast).unwrap().run().unwrap();
    let held: usize = summary.parts[..2].iter().map(|part| frames(part).values().map(Vec::len).sum::<usize>()).sum();
    assert_eq!(report.frames as usize, held, "the parts on both sides of the empty one: {report:?}");

    // The first part of one recording, then a part of another (other
    // channels): refused when the replay reaches it, naming it.
    let (_other, _other_service) = channels_with_slots(&dir.0, "oth", 10, 4);
    let other = dir.0.join("oth.mcap");
    let other_options = RecordOptions { flush_interval: Duration::from_millis(100), ..options(&dir.0, "oth") };
    Recorder::start(&other, other_options).unwrap().finish().unwrap();
    let mixed = [summary.parts[0].clone(), other.clone()];
    let replay_options = ReplayOptions { skin: Some("spr3".into()), ..replay_options };
    let error = Replay::open_parts(&mixed, replay_options).unwrap().run().unwrap_err().to_string();
    assert!(error.contains("oth.mcap does not go on from") && error.contains("touch"), "{error}");
}
