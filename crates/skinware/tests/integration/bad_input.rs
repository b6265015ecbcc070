//! Every way opening or creating a channel can be given bad input gets its own
//! typed error, with a message naming the channel and what to do.

use std::os::unix::fs::PermissionsExt;

use crate::util::{Answer, FakeWriter, SegmentDir, capture_memory};
use skinware::{Access, Error, Reader, ReaderOptions, Writer, WriterOptions, WriterState};

/// Byte offsets of header fields (see `channel/layout.rs`), for corrupting them.
const ABI_VERSION_OFFSET: usize = 8;
const SLOT_BYTES_OFFSET: usize = 56;

/// The frames memory of a sound channel with one frame, to corrupt and serve.
fn sound_memory(dir: &SegmentDir) -> Vec<u8> {
    let mut writer = Writer::create("skin", "model", 64, b"topology", &dir.writer()).unwrap();
    writer.publish_bytes(&[1; 64], skinware::FrameStatus::OK).unwrap();
    capture_memory(dir, "skin", "model")
}

fn poke_u32(bytes: &mut [u8], offset: usize, value: u32) {
    bytes[offset..offset + 4].copy_from_slice(&value.to_le_bytes());
}

fn open(dir: &SegmentDir, skin: &str, channel: &str) -> Result<Reader, Error> {
    Reader::open_with(skin, channel, &dir.reader())
}

#[test]
fn missing_channel() {
    let dir = SegmentDir::new("missing");
    let err = Reader::open_with("skin", "nothing", &dir.reader()).unwrap_err();
    assert!(matches!(err, Error::Missing { ref channel, .. } if channel == "skin/nothing"), "{err}");
    assert!(err.to_string().contains("start its writer"), "{err}");
}

#[test]
fn a_regular_file_under_a_channel_name() {
    let dir = SegmentDir::new("regular-file");
    std::fs::write(dir.segment("skin", "old"), vec![0x42; 20_000]).unwrap();
    let err = open(&dir, "skin", "old").unwrap_err();
    assert!(matches!(err, Error::NotAChannel { found: "regular file", .. }), "{err}");
    assert!(err.to_string().contains("skin clean --force"), "{err}");
    // A writer does not replace it either.
    let err = Writer::create("skin", "old", 8, b"", &dir.writer()).unwrap_err();
    assert!(matches!(err, Error::NotAChannel { .. }), "{err}");
    assert_eq!(std::fs::read(dir.segment("skin", "old")).unwrap().len(), 20_000);
}

#[test]
fn memory_that_is_not_ours() {
    let dir = SegmentDir::new("foreign");
    let _fake = FakeWriter::serve(&dir, "skin", "foreign", Answer::Memory { data: vec![0x42; 20_000], sealed: true });
    let err = open(&dir, "skin", "foreign").unwrap_err();
    assert!(matches!(err, Error::NotOurs { found: 0x4242_4242_4242_4242, .. }), "{err}");
    assert!(err.to_string().contains("does not serve a skinware channel"), "{err}");
}

#[test]
fn abi_version_mismatch() {
    let dir = SegmentDir::new("abi");
    for version in [999, 0] {
        let mut bytes = sound_memory(&dir);
        poke_u32(&mut bytes, ABI_VERSION_OFFSET, version);
        let _fake = FakeWriter::serve(&dir, "skin", "old", Answer::Memory { data: bytes, sealed: true });
        let err = open(&dir, "skin", "old").unwrap_err();
        assert!(
            matches!(err, Error::VersionMismatch { found, expected: skinware::ABI_VERSION, .. } if found == version),
            "{err}"
        );
    }
}

#[test]
fn truncated_header() {
    let dir = SegmentDir::new("short-header");
    let data = b"SKINWARE and then nothing".to_vec();
    let _fake = FakeWriter::serve(&dir, "skin", "short", Answer::Memory { data, sealed: true });
    let err = open(&dir, "skin", "short").unwrap_err();
    assert!(matches!(err, Error::Truncated { actual: 25, needed: 4096, .. }), "{err}");
}

#[test]
fn truncated_frames() {
    let dir = SegmentDir::new("short-body");
    let mut bytes = sound_memory(&dir);
    let full = bytes.len() as u64;
    bytes.truncate(bytes.len() - 64);
    let _fake = FakeWriter::serve(&dir, "skin", "cut", Answer::Memory { data: bytes, sealed: true });
    let err = open(&dir, "skin", "cut").unwrap_err();
    assert!(matches!(err, Error::Truncated { actual, needed, .. } if needed == full && actual == full - 64), "{err}");
}

#[test]
fn corrupt_header() {
    let dir = SegmentDir::new("corrupt");
    let mut bytes = sound_memory(&dir);
    poke_u32(&mut bytes, SLOT_BYTES_OFFSET, 12345);
    let _fake = FakeWriter::serve(&dir, "skin", "bent", Answer::Memory { data: bytes, sealed: true });
    let err = open(&dir, "skin", "bent").unwrap_err();
    assert!(matches!(err, Error::Corrupt { ref reason, .. } if reason.contains("slot_bytes")), "{err}");
}

/// Memory that its sender could shrink under the reader is refused before it
/// is mapped: mapping it would hand the sender a way to kill the reader.
#[test]
fn unsealed_memory_is_refused() {
    let dir = SegmentDir::new("unsealed");
    let bytes = sound_memory(&dir);
    let _fake = FakeWriter::serve(&dir, "skin", "loose", Answer::Memory { data: bytes, sealed: false });
    let err = open(&dir, "skin", "loose").unwrap_err();
    assert!(matches!(err, Error::Unsealed { what: "frames", .. }), "{err}");
    assert!(err.to_string().contains("SIGBUS"), "{err}");
}

#[test]
fn a_socket_that_answers_something_else() {
    let dir = SegmentDir::new("other-program");
    let _fake = FakeWriter::serve(&dir, "skin", "web", Answer::Bytes(b"HTTP/1.1 400 Bad Request\r\n\r\n".to_vec()));
    let err = open(&dir, "skin", "web").unwrap_err();
    assert!(matches!(err, Error::Corrupt { ref reason, .. } if reason.contains("not a skinware hand-over")), "{err}");
}

#[test]
fn a_writer_that_never_answers() {
    let dir = SegmentDir::new("silent");
    let _fake = FakeWriter::serve(&dir, "skin", "hung", Answer::Silence);
    let started = std::time::Instant::now();
    let err = open(&dir, "skin", "hung").unwrap_err();
    assert!(matches!(err, Error::NotAnswering { .. }), "{err}");
    assert!(started.elapsed() < std::time::Duration::from_secs(5), "waited {:?}", started.elapsed());
}

#[test]
fn writer_gone() {
    let dir = SegmentDir::new("gone");
    let options = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    let mut writer = Writer::create("skin", "orphan", 64, b"topology", &options).unwrap();
    writer.publish_bytes(&[1; 64], skinware::FrameStatus::OK).unwrap();
    drop(writer);
    for options in [dir.reader(), ReaderOptions { allow_gone: true, ..dir.reader() }] {
        let err = Reader::open_with("skin", "orphan", &options).unwrap_err();
        assert!(matches!(err, Error::WriterGone { pid, .. } if pid == std::process::id()), "{err}");
    }
    let listed = skinware::list_channels(&dir.path).unwrap();
    assert_eq!(listed.len(), 1);
    assert_eq!(
        (listed[0].state, listed[0].writer_pid, listed[0].generation),
        (WriterState::Gone, std::process::id(), 1)
    );
}

#[test]
fn invalid_names() {
    let dir = SegmentDir::new("names");
    let long = "x".repeat(65);
    for (skin, channel, reason) in [
        ("a/b", "c", "'/'"),
        ("..", "c", "'..'"),
        ("skin", "", "empty"),
        ("skin", long.as_str(), "too long"),
        ("sk.in", "c", "character"),
        ("skin", "c\0", "character"),
    ] {
        let err = Writer::create(skin, channel, 8, b"", &dir.writer()).unwrap_err();
        assert!(matches!(err, Error::InvalidName { .. }), "{skin:?}/{channel:?}: {err}");
        assert!(err.to_string().contains(reason), "{err}");
        let err = Reader::open_with(skin, channel, &dir.reader()).unwrap_err();
        assert!(matches!(err, Error::InvalidName { .. }), "{err}");
    }
    assert!(dir.files().is_empty(), "a refused name created {:?}", dir.files());
}

#[test]
fn second_live_writer_is_refused() {
    let dir = SegmentDir::new("busy");
    let _first = Writer::create("skin", "taken", 8, b"", &dir.writer()).unwrap();
    let err = Writer::create("skin", "taken", 8, b"", &dir.writer()).unwrap_err();
    assert!(matches!(err, Error::Busy { pid, .. } if pid == std::process::id()), "{err}");
}

#[test]
fn a_successor_may_change_the_layout() {
    let dir = SegmentDir::new("relayout");
    let options = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    drop(Writer::create("skin", "layer", 64, b"topology", &options).unwrap());
    let second = Writer::create("skin", "layer", 128, b"other topology", &dir.writer()).unwrap();
    assert!(second.revived());
    let reader = open(&dir, "skin", "layer").unwrap();
    assert_eq!((reader.payload_bytes(), reader.writer_generation()), (128, 2));
}

#[test]
fn schema_mismatch() {
    let dir = SegmentDir::new("schema");
    let options = WriterOptions { schema_name: "motion".into(), schema_version: 2, ..dir.writer() };
    let _writer = Writer::create("skin", "motion", 32, b"", &options).unwrap();
    let wrong = ReaderOptions { expect_schema: Some(("motion".into(), 1)), ..dir.reader() };
    let err = Reader::open_with("skin", "motion", &wrong).unwrap_err();
    assert!(matches!(err, Error::SchemaMismatch { found_version: 2, expected_version: 1, .. }), "{err}");
    let right = ReaderOptions { expect_schema: Some(("motion".into(), 2)), ..dir.reader() };
    assert!(Reader::open_with("skin", "motion", &right).is_ok());
}

#[test]
fn out_of_range_layout() {
    let dir = SegmentDir::new("layout");
    let one_slot = WriterOptions { slots: 1, ..dir.writer() };
    let err = Writer::create("skin", "k1", 8, b"", &one_slot).unwrap_err();
    assert!(matches!(err, Error::InvalidLayout { .. }), "{err}");
    let err = Writer::create("skin", "empty", 0, b"", &dir.writer()).unwrap_err();
    assert!(matches!(err, Error::InvalidLayout { .. }), "{err}");
    assert!(dir.files().is_empty(), "{:?}", dir.files());
}

#[test]
fn oversized_writes() {
    let dir = SegmentDir::new("oversized");
    let mut writer = Writer::create("skin", "small", 8, b"", &dir.writer()).unwrap();
    let err = writer.publish_bytes(&[0; 9], skinware::FrameStatus::OK).unwrap_err();
    assert!(matches!(err, Error::PayloadTooLarge { given: 9, capacity: 8, .. }), "{err}");
    let mut frame = writer.begin();
    assert!(matches!(frame.set_response(4, 1), Err(Error::PayloadTooLarge { .. })));
    assert!(matches!(frame.write_responses(2, &[1, 2, 3]), Err(Error::PayloadTooLarge { .. })));
    frame.discard();
    assert_eq!(writer.last_seq(), 0, "a refused write published a frame");
}

#[test]
fn channels_are_private_unless_access_is_widened() {
    let dir = SegmentDir::new("modes");
    let mut writers = Vec::new();
    for (channel, access) in [("private", Access::Owner), ("group", Access::Group), ("everyone", Access::Everyone)] {
        writers.push(Writer::create("skin", channel, 8, b"", &WriterOptions { access, ..dir.writer() }).unwrap());
    }
    let mode = |channel| std::fs::metadata(dir.segment("skin", channel)).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode("private"), 0o600);
    assert_eq!(mode("group"), 0o660);
    assert_eq!(mode("everyone"), 0o666);
}
