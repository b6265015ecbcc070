//! Everything a recording holds before its first frame, written and flushed
//! before any frame is read: the schemas, the recording's metadata, one MCAP
//! channel per topic (those for ROS tools too, and their `/tf_static`), the
//! layout outline, and the geometry and every channel's description as
//! attachments. A recorder killed at its first
//! frame leaves a file that still says what it was recording.
//!
//! The order of the records is the order of their ids (schemas and channels
//! are numbered as they are added), which is what readers of older files
//! saw: keep it.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;

use mcap::records::Metadata;
use skinware_geometry::SkinGeometry;
use skinware_ros2::{GAP, HeatMap, IMAGE, LAYER_STATS, SKIN_FRAME, clock_offset_ns, unix_ns};

use super::discovery::{ChannelFacts, Sources};
use super::ros_view::{RosView, add_view};
use super::{CHUNK_BYTES, RecordOptions, add_schema};
use crate::error::mcap_write_error;
use crate::{
    DESCRIPTION_ATTACHMENT_PREFIX, FORMAT_VERSION, GEOMETRY_ATTACHMENT, LAYOUT_METADATA, MESSAGE_ENCODING,
    RECORDING_METADATA, RecordError,
};

/// zstd's level: 2 (see `create_writer`).
const ZSTD_LEVEL: u32 = 2;

/// The file's writer.
pub(super) type McapWriter = mcap::Writer<BufWriter<BoundedWrites>>;

/// The largest write the file gets in one system call. The MCAP writer
/// streams each chunk through the file's 256 KiB buffer, which writes
/// itself out in one call when full, and a message larger than the buffer
/// goes straight through. On a kernel without full preemption
/// (`preempt=none`, as here) a writer thread woken during a `write` into
/// the page cache waits for it to end: `perf sched` of the 100,000-taxel
/// skin at 1 kHz found the file thread holding woken writers for
/// 0.44-0.60 ms in its writes. 128 KiB halves the buffer's write, for
/// about 2,400 calls a second at 312 MB/s.
const LARGEST_WRITE: usize = 128 << 10;

/// The recording's file, written at most [`LARGEST_WRITE`] bytes per call.
pub(super) struct BoundedWrites(pub(super) File);

impl Write for BoundedWrites {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.0.write(&bytes[..bytes.len().min(LARGEST_WRITE)])
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.0.flush()
    }
}

impl Seek for BoundedWrites {
    fn seek(&mut self, position: SeekFrom) -> std::io::Result<u64> {
        self.0.seek(position)
    }
}

impl std::borrow::Borrow<File> for BoundedWrites {
    fn borrow(&self) -> &File {
        &self.0
    }
}

/// A recording's file, its start written: where each kind of message goes.
pub(super) struct Started {
    pub(super) writer: McapWriter,
    /// The MCAP channel of each reader's frames, in the readers' order.
    pub(super) frame_channels: Vec<u16>,
    /// The MCAP channel of each reader's statistics, in the readers' order.
    pub(super) stats_channels: Vec<u16>,
    pub(super) gap_channel: u16,
    /// The map image's channel and its renderer, if the map is recorded
    /// (the renderer in the first part only: the recording's threads use it).
    pub(super) map: Option<(u16, HeatMap)>,
    /// The map image's channel, in every part.
    pub(super) map_channel: Option<u16>,
    /// The messages for ROS tools, if wanted.
    pub(super) ros: Option<RosView>,
    /// CLOCK_REALTIME minus CLOCK_MONOTONIC, as written in the metadata.
    pub(super) clock_offset_ns: i64,
}

/// The MCAP channel ids a file's start gave the messages the recording's
/// threads send. Every part of a split recording must give the same: the
/// threads keep sending to these.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(super) struct ChannelIds {
    frames: Vec<u16>,
    stats: Vec<u16>,
    gaps: u16,
    map: Option<u16>,
    ros: Option<Vec<u16>>,
}

impl ChannelIds {
    /// The ids `started` gave.
    pub(super) fn of(started: &Started) -> ChannelIds {
        ChannelIds {
            frames: started.frame_channels.clone(),
            stats: started.stats_channels.clone(),
            gaps: started.gap_channel,
            map: started.map_channel,
            ros: started.ros.as_ref().map(RosView::channel_ids),
        }
    }
}

/// Per reader, its topics' MCAP channels and its line in the layout outline.
struct Topics {
    frame_channels: Vec<u16>,
    stats_channels: Vec<u16>,
    layout: BTreeMap<String, String>,
}

/// Which part of a recording a file's start begins.
#[derive(Clone, Copy, Debug)]
pub(super) enum Part {
    /// The first (or only) file: the clock offset is measured now, and the
    /// map's renderer is built for the recording's threads.
    First,
    /// A later part of a split recording, whose messages keep being stamped
    /// with the first part's clock offset: its metadata says that one.
    Later {
        /// CLOCK_REALTIME minus CLOCK_MONOTONIC, as the first part measured it.
        clock_offset_ns: i64,
    },
}

/// Writes the start of `part` of a recording of `sources` into `file` (new and empty).
pub(super) fn write_start(
    path: &Path,
    file: &File,
    options: &RecordOptions,
    sources: &Sources,
    (dir, part): (&Path, Part),
) -> Result<Started, RecordError> {
    let write_error = |e: mcap::McapError| mcap_write_error(path, e);
    let mut writer = create_writer(path, file, options)?;
    let frame_schema = add_schema(&mut writer, SKIN_FRAME).map_err(write_error)?;
    let gap_schema = add_schema(&mut writer, GAP).map_err(write_error)?;
    let stats_schema = add_schema(&mut writer, LAYER_STATS).map_err(write_error)?;

    let clock_offset_ns = match part {
        Part::First => clock_offset_ns(),
        Part::Later { clock_offset_ns } => clock_offset_ns,
    };
    let started_unix_ns = unix_ns(skinware::os::monotonic_ns(), clock_offset_ns);
    let recording = recording_metadata(options, clock_offset_ns, started_unix_ns);
    writer.write_metadata(&Metadata { name: RECORDING_METADATA.into(), metadata: recording }).map_err(write_error)?;

    let topics =
        add_topics(&mut writer, &options.skin, &sources.facts, frame_schema, stats_schema).map_err(write_error)?;
    let gap_channel = writer
        .add_channel(gap_schema, &skinware_ros2::gaps_topic(&options.skin), MESSAGE_ENCODING, &BTreeMap::new())
        .map_err(write_error)?;
    let (map_channel, map) =
        add_map(&mut writer, options, sources.geometry.as_ref(), matches!(part, Part::First)).map_err(write_error)?;
    let mut ros = add_view(&mut writer, options, sources, dir.to_owned(), started_unix_ns).map_err(write_error)?;
    writer.write_metadata(&Metadata { name: LAYOUT_METADATA.into(), metadata: topics.layout }).map_err(write_error)?;
    attach(&mut writer, started_unix_ns, sources).map_err(write_error)?;
    if let Some(ros) = &mut ros {
        ros.write_static(&mut writer, started_unix_ns).map_err(write_error)?;
    }
    writer.flush().map_err(write_error)?;
    Ok(Started {
        writer,
        frame_channels: topics.frame_channels,
        stats_channels: topics.stats_channels,
        gap_channel,
        map,
        map_channel,
        ros,
        clock_offset_ns,
    })
}

/// An MCAP writer in the `ros2` profile on a second handle to `file` (the
/// first is kept to sync what it flushes).
fn create_writer(path: &Path, file: &File, options: &RecordOptions) -> Result<McapWriter, RecordError> {
    let second_handle = file.try_clone().map_err(|source| RecordError::Io {
        op: "open a second handle to",
        path: path.to_owned(),
        hint: String::new(),
        source,
    })?;
    mcap::WriteOptions::new()
        .profile("ros2")
        .library(concat!("skinware-record/", env!("CARGO_PKG_VERSION")))
        .compression(options.compression.mcap())
        .chunk_size(Some(CHUNK_BYTES))
        // zstd in the file's thread, at level 2: at most one core (the
        // crate's default is a worker thread per physical core), and on
        // skin frames 1.46x as fast as the default level 3 for files no
        // larger (docs/bench/record.md). lz4 keeps its fast level, 0.
        .compression_threads(0)
        .compression_level(if options.compression == super::Compression::Zstd { ZSTD_LEVEL } else { 0 })
        .create(BufWriter::with_capacity(256 << 10, BoundedWrites(second_handle)))
        .map_err(|e| mcap_write_error(path, e))
}

/// The `skinware.recording` metadata: what was recorded, when, where and how.
fn recording_metadata(options: &RecordOptions, clock_offset_ns: i64, started_unix_ns: u64) -> BTreeMap<String, String> {
    let mut recording = BTreeMap::new();
    recording.insert("format_version".to_owned(), FORMAT_VERSION.to_string());
    recording.insert("skin".to_owned(), options.skin.clone());
    recording.insert("clock_offset_ns".to_owned(), clock_offset_ns.to_string());
    recording.insert("started_unix_ns".to_owned(), started_unix_ns.to_string());
    recording.insert("skinware_version".to_owned(), env!("CARGO_PKG_VERSION").to_owned());
    recording.insert("host".to_owned(), hostname());
    recording.insert("command".to_owned(), options.command.clone());
    recording.insert("compression".to_owned(), format!("{:?}", options.compression).to_lowercase());
    recording
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_owned()).unwrap_or_default()
}

/// Each recorded channel's frame topic (its channel's metadata says what
/// it records) and statistics topic, added in turn.
fn add_topics(
    writer: &mut McapWriter,
    skin: &str,
    facts: &[ChannelFacts],
    frame_schema: u16,
    stats_schema: u16,
) -> Result<Topics, mcap::McapError> {
    let mut topics = Topics { frame_channels: Vec::new(), stats_channels: Vec::new(), layout: BTreeMap::new() };
    for channel in facts {
        let topic = skinware_ros2::frame_topic(skin, &channel.name);
        topics.frame_channels.push(writer.add_channel(frame_schema, &topic, MESSAGE_ENCODING, &channel.metadata)?);
        let stats_topic = skinware_ros2::stats_topic(skin, &channel.name);
        topics.stats_channels.push(writer.add_channel(
            stats_schema,
            &stats_topic,
            MESSAGE_ENCODING,
            &BTreeMap::new(),
        )?);
        topics.layout.insert(channel.name.clone(), channel.outline.clone());
    }
    Ok(topics)
}

/// The map image's channel and its renderer, where there is one.
type MapRenderer = Option<(u16, HeatMap)>;

/// The map image's schema and channel, if images are wanted and the skin
/// publishes the geometry to draw them from, and, for the `first` part,
/// its renderer (the others' would go unused; and a missing geometry is
/// said once).
fn add_map(
    writer: &mut McapWriter,
    options: &RecordOptions,
    geometry: Option<&SkinGeometry>,
    first: bool,
) -> Result<(Option<u16>, MapRenderer), mcap::McapError> {
    match (geometry, options.map_hz > 0.0) {
        (Some(geometry), true) => {
            let image_schema = add_schema(writer, IMAGE)?;
            let topic = skinware_ros2::map_topic(&options.skin);
            let id = writer.add_channel(image_schema, &topic, MESSAGE_ENCODING, &BTreeMap::new())?;
            Ok((Some(id), first.then(|| (id, HeatMap::new(geometry, options.map_width)))))
        }
        (None, true) => {
            if first {
                tracing::warn!(skin = %options.skin, "no geometry is published for this skin: recording without the map image");
            }
            Ok((None, None))
        }
        _ => Ok((None, None)),
    }
}

/// The geometry file and every channel's description, byte for byte, so
/// that a replay recreates the channels as they were.
fn attach(writer: &mut McapWriter, started_unix_ns: u64, sources: &Sources) -> Result<(), mcap::McapError> {
    let mut attach_one = |name: String, media_type: &str, data: &[u8]| {
        writer.attach(&mcap::Attachment {
            log_time: started_unix_ns,
            create_time: started_unix_ns,
            name,
            media_type: media_type.to_owned(),
            data: std::borrow::Cow::Borrowed(data),
        })
    };
    if let Some(bytes) = &sources.geometry_bytes {
        attach_one(GEOMETRY_ATTACHMENT.to_owned(), "application/x-skinware-geometry", bytes)?;
    }
    for channel in &sources.facts {
        attach_one(
            format!("{DESCRIPTION_ATTACHMENT_PREFIX}{}", channel.name),
            "application/x-skinware-description",
            &channel.description,
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chunk_reaches_the_file_in_writes_of_at_most_largest_write() {
        let path = std::env::temp_dir().join(format!("skinware-bounded-writes-{}", std::process::id()));
        let mut file = BoundedWrites(File::create(&path).unwrap());
        let chunk: Vec<u8> = (0..(CHUNK_BYTES as usize + 12_345)).map(|i| i as u8).collect();
        assert_eq!(file.write(&chunk).unwrap(), LARGEST_WRITE);
        file.write_all(&chunk[LARGEST_WRITE..]).unwrap();
        drop(file);
        assert!(std::fs::read(&path).unwrap() == chunk, "the file holds the chunk, in order");
        let _ = std::fs::remove_file(&path);
    }
}
