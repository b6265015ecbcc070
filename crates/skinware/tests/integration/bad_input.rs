//! Every way opening or creating a channel can be given bad input gets its own
//! typed error, with a message naming the channel and what to do.

use std::io::{Seek, SeekFrom, Write};
use std::os::unix::fs::PermissionsExt;

use crate::util::SegmentDir;
use skinware::{Error, Reader, ReaderOptions, Writer, WriterOptions, WriterState};

/// Byte offsets of header fields (see `channel/layout.rs`), for corrupting them.
const ABI_VERSION_OFFSET: u64 = 8;
const SLOT_BYTES_OFFSET: u64 = 56;

fn leave_behind(dir: &SegmentDir, skin: &str, channel: &str) {
    let options = WriterOptions { unlink_on_drop: false, ..dir.writer() };
    let mut writer = Writer::create(skin, channel, 64, b"topology", &options).unwrap();
    writer.publish_bytes(&[1; 64], skinware::FrameStatus::OK).unwrap();
}

fn poke_u32(path: &std::path::Path, offset: u64, value: u32) {
    let mut file = std::fs::OpenOptions::new().write(true).open(path).unwrap();
    file.seek(SeekFrom::Start(offset)).unwrap();
    file.write_all(&value.to_le_bytes()).unwrap();
}

fn open_gone(dir: &SegmentDir, skin: &str, channel: &str) -> Result<Reader, Error> {
    Reader::open_with(skin, channel, &ReaderOptions { allow_gone: true, ..dir.reader() })
}

#[test]
fn missing_channel() {
    let dir = SegmentDir::new("missing");
    let err = Reader::open_with("skin", "nothing", &dir.reader()).unwrap_err();
    assert!(matches!(err, Error::Missing { ref channel, .. } if channel == "skin/nothing"), "{err}");
    assert!(err.to_string().contains("start its writer"), "{err}");
}

#[test]
fn file_that_is_not_ours() {
    let dir = SegmentDir::new("foreign");
    std::fs::write(dir.segment("skin", "foreign"), vec![0x42; 20_000]).unwrap();
    let err = open_gone(&dir, "skin", "foreign").unwrap_err();
    assert!(matches!(err, Error::NotOurs { found: 0x4242_4242_4242_4242, .. }), "{err}");
    assert!(err.to_string().contains("not a skinware channel"), "{err}");
}

#[test]
fn abi_version_mismatch() {
    let dir = SegmentDir::new("abi");
    leave_behind(&dir, "skin", "old");
    poke_u32(&dir.segment("skin", "old"), ABI_VERSION_OFFSET, 999);
    let err = open_gone(&dir, "skin", "old").unwrap_err();
    assert!(matches!(err, Error::VersionMismatch { found: 999, expected: skinware::ABI_VERSION, .. }), "{err}");
}

#[test]
fn header_never_finished() {
    let dir = SegmentDir::new("unfinished");
    leave_behind(&dir, "skin", "half");
    poke_u32(&dir.segment("skin", "half"), ABI_VERSION_OFFSET, 0);
    let err = open_gone(&dir, "skin", "half").unwrap_err();
    assert!(matches!(err, Error::Unfinished { .. }), "{err}");
}

#[test]
fn truncated_header() {
    let dir = SegmentDir::new("short-header");
    std::fs::write(dir.segment("skin", "short"), b"SKINWARE and then nothing").unwrap();
    let err = open_gone(&dir, "skin", "short").unwrap_err();
    assert!(matches!(err, Error::Truncated { actual: 25, needed: 8192, .. }), "{err}");
}

#[test]
fn truncated_frames() {
    let dir = SegmentDir::new("short-body");
    leave_behind(&dir, "skin", "cut");
    let path = dir.segment("skin", "cut");
    let full = std::fs::metadata(&path).unwrap().len();
    std::fs::OpenOptions::new().write(true).open(&path).unwrap().set_len(full - 64).unwrap();
    let err = open_gone(&dir, "skin", "cut").unwrap_err();
    assert!(matches!(err, Error::Truncated { actual, needed, .. } if needed == full && actual == full - 64), "{err}");
}

#[test]
fn corrupt_header() {
    let dir = SegmentDir::new("corrupt");
    leave_behind(&dir, "skin", "bent");
    poke_u32(&dir.segment("skin", "bent"), SLOT_BYTES_OFFSET, 12345);
    let err = open_gone(&dir, "skin", "bent").unwrap_err();
    assert!(matches!(err, Error::Corrupt { ref reason, .. } if reason.contains("slot_bytes")), "{err}");
}

#[test]
fn writer_gone() {
    let dir = SegmentDir::new("gone");
    leave_behind(&dir, "skin", "orphan");
    let err = Reader::open_with("skin", "orphan", &dir.reader()).unwrap_err();
    assert!(matches!(err, Error::WriterGone { pid, .. } if pid == std::process::id()), "{err}");
    // Tools may still attach, and see it as gone.
    let reader = open_gone(&dir, "skin", "orphan").unwrap();
    assert_eq!(reader.writer_state(), WriterState::Gone);
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
fn revival_with_another_layout_is_refused() {
    let dir = SegmentDir::new("relayout");
    leave_behind(&dir, "skin", "layer");
    let err = Writer::create("skin", "layer", 128, b"topology", &dir.writer()).unwrap_err();
    assert!(matches!(err, Error::LayoutMismatch { field: "frame bytes", .. }), "{err}");
    let err = Writer::create("skin", "layer", 64, b"other topology", &dir.writer()).unwrap_err();
    assert!(matches!(err, Error::LayoutMismatch { field: "description (topology)", .. }), "{err}");
    let options = WriterOptions { slots: 5, ..dir.writer() };
    let err = Writer::create("skin", "layer", 64, b"topology", &options).unwrap_err();
    assert!(matches!(err, Error::LayoutMismatch { field: "frame buffers", .. }), "{err}");
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
fn segments_are_private_unless_group_access_is_asked() {
    let dir = SegmentDir::new("modes");
    let _private = Writer::create("skin", "private", 8, b"", &dir.writer()).unwrap();
    let group = WriterOptions { group_access: true, ..dir.writer() };
    let _shared = Writer::create("skin", "group", 8, b"", &group).unwrap();
    let mode = |channel| std::fs::metadata(dir.segment("skin", channel)).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode("private"), 0o600);
    assert_eq!(mode("group"), 0o660);
}
