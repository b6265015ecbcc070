//! Reading recordings: a record stream that works on finished and unfinished
//! files alike, the scan behind `skin info`, and recovery of an unfinished file.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::records::{Metadata, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use serde::{Deserialize, Serialize};
use skinware::ChannelKind;
use skinware_ros2::Time;

use crate::error::write_hint;
use crate::{
    DESCRIPTION_ATTACHMENT_PREFIX, FORMAT_VERSION, GEOMETRY_ATTACHMENT, MESSAGE_ENCODING, RECORDING_METADATA,
    RecordError, SCHEMA_ENCODING, SUMMARY_METADATA, channel_keys,
};

/// The most a single read asks for, so that a damaged length field cannot
/// make the reader allocate more than the file holds.
const READ_STEP: usize = 1 << 20;
/// The longest record accepted, and the most a chunk may hold uncompressed.
/// skinware writes chunks of up to 8 MiB; ROS 2 bags write a few MiB.
const RECORD_LIMIT: usize = 256 << 20;

/// How a record stream ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Ending {
    /// With the MCAP footer and end magic: the recorder finished the file.
    Finished,
    /// Before the footer: the recorder was killed or the disk filled. Every
    /// complete chunk before the cut was read.
    Truncated,
    /// At damage (a bad checksum or record) after which nothing is trusted.
    Damaged,
}

/// One step of the reader.
enum Step {
    Read(usize),
    Record(Record<'static>),
    Chunk(std::collections::VecDeque<Record<'static>>),
    End(Ending),
    Failed(String),
}

/// The records of an MCAP file, in file order, with chunks opened.
pub struct RecordStream<R = File> {
    path: PathBuf,
    file: R,
    reader: LinearReader,
    fed: u64,
    ending: Option<Ending>,
    damage: Option<String>,
    /// The records of the chunk being read, in order.
    chunk: std::collections::VecDeque<Record<'static>>,
}

impl RecordStream<File> {
    /// Opens `path`, checking that it is MCAP.
    pub fn open(path: &Path) -> Result<RecordStream<File>, RecordError> {
        let file = skinware::shm::open_named_file(path).map_err(|source| RecordError::Io {
            op: "open",
            path: path.to_owned(),
            source,
            hint: String::new(),
        })?;
        RecordStream::from_reader(path, file)
    }
}

impl<R: Read> RecordStream<R> {
    /// Reads MCAP from `file`, named `path` in errors, checking that it is MCAP.
    pub fn from_reader(path: &Path, mut file: R) -> Result<RecordStream<R>, RecordError> {
        let io = |op, source| RecordError::Io { op, path: path.to_owned(), source, hint: String::new() };
        let mut start = Vec::with_capacity(8);
        (&mut file).take(8).read_to_end(&mut start).map_err(|e| io("read", e))?;
        if start != mcap::MAGIC {
            return Err(RecordError::NotMcap { path: path.to_owned(), start });
        }
        let options = LinearReaderOptions::default()
            .with_skip_start_magic(true)
            // Chunks are opened here (`open_chunk`), not by the reader.
            .with_emit_chunks(true)
            .with_record_length_limit(RECORD_LIMIT);
        Ok(RecordStream {
            path: path.to_owned(),
            file,
            reader: LinearReader::new_with_options(options),
            fed: 8,
            ending: None,
            damage: None,
            chunk: Default::default(),
        })
    }

    /// How the stream ended, once [`next_record`](Self::next_record) has returned `None`.
    pub fn ending(&self) -> Option<Ending> {
        self.ending
    }

    /// What the damage was, for [`Ending::Damaged`].
    pub fn damage(&self) -> Option<&str> {
        self.damage.as_deref()
    }

    /// Bytes of the file read so far.
    pub fn bytes_read(&self) -> u64 {
        self.fed
    }

    /// The next record; `None` at the end of the file, finished or cut short.
    pub fn next_record(&mut self) -> Result<Option<Record<'static>>, RecordError> {
        loop {
            if let Some(record) = self.chunk.pop_front() {
                return Ok(Some(record));
            }
            if self.ending.is_some() {
                return Ok(None);
            }
            let step = match self.reader.next_event() {
                None => Step::End(Ending::Finished),
                Some(Err(mcap::McapError::UnexpectedEof)) => Step::End(Ending::Truncated),
                // The writer streams a chunk into the file with a placeholder
                // length (all ones) and fills it in when the chunk is done: a
                // chunk with that length is where a killed recorder stopped.
                Some(Err(mcap::McapError::RecordTooLarge { opcode: CHUNK, len: u64::MAX })) => {
                    Step::End(Ending::Truncated)
                }
                Some(Err(e)) => Step::Failed(e.to_string()),
                Some(Ok(LinearReadEvent::ReadRequest(need))) => Step::Read(need),
                Some(Ok(LinearReadEvent::Record { opcode: CHUNK, data })) => match open_chunk(data) {
                    Ok(records) => Step::Chunk(records),
                    Err(reason) => Step::Failed(reason),
                },
                Some(Ok(LinearReadEvent::Record { opcode, data })) => match parse(opcode, data) {
                    Ok(record) => Step::Record(record),
                    Err(reason) => Step::Failed(reason),
                },
            };
            match step {
                Step::End(ending) => {
                    self.ending = Some(ending);
                    return Ok(None);
                }
                // The writer fills in a chunk's lengths when it finishes it:
                // a recorder killed while writing one leaves a chunk that
                // ends inside a record. At the end of the file that is a cut,
                // not damage.
                Step::Failed(reason) => {
                    if self.at_end_of_file() {
                        self.ending = Some(Ending::Truncated);
                        return Ok(None);
                    }
                    self.ending = Some(Ending::Damaged);
                    return Err(self.damaged(reason));
                }
                Step::Record(record) => return Ok(Some(record)),
                Step::Chunk(records) => self.chunk = records,
                Step::Read(need) => {
                    let buffer = self.reader.insert(need.clamp(1, READ_STEP));
                    let read = self.file.read(buffer).map_err(|source| RecordError::Io {
                        op: "read",
                        path: self.path.clone(),
                        source,
                        hint: String::new(),
                    })?;
                    self.reader.notify_read(read);
                    self.fed += read as u64;
                }
            }
        }
    }

    /// Whether nothing is left to read.
    fn at_end_of_file(&mut self) -> bool {
        let mut probe = [0u8; 1];
        matches!(self.file.read(&mut probe), Ok(0))
    }

    fn damaged(&self, reason: String) -> RecordError {
        RecordError::Damaged { path: self.path.clone(), offset: self.fed, reason }
    }
}

/// Opcode of a chunk record.
const CHUNK: u8 = 0x06;

/// A record, parsed once its lengths are known to fit.
fn parse(opcode: u8, data: &[u8]) -> Result<Record<'static>, String> {
    lengths_fit(opcode, data)?;
    mcap::parse_record(opcode, data).map(Record::into_owned).map_err(|e| e.to_string())
}

/// The records of a chunk: decompressed, its checksum checked, and each
/// inner record's length checked against what is left of the chunk.
///
/// Chunks are opened here rather than by the `mcap` crate's linear reader:
/// that reader subtracts an inner record's length from what is left of an
/// uncompressed chunk without checking it (an overflow panic in builds with
/// overflow checks, found by the `recording` fuzz target; a wrap that reads
/// past the chunk without them).
fn open_chunk(data: &[u8]) -> Result<std::collections::VecDeque<Record<'static>>, String> {
    lengths_fit(CHUNK, data)?;
    let Record::Chunk { header, data } = mcap::parse_record(CHUNK, data).map_err(|e| e.to_string())? else {
        return Err("a chunk record that is not a chunk".into());
    };
    let size = usize::try_from(header.uncompressed_size).ok().filter(|&n| n <= RECORD_LIMIT).ok_or_else(|| {
        format!("a chunk of {} bytes uncompressed, more than the {RECORD_LIMIT} accepted", header.uncompressed_size)
    })?;
    // Decompressed output grows as it is produced, never to the size the
    // header claims up front: a damaged header would otherwise allocate up to
    // the limit for a chunk of a few bytes (found by the `recording` fuzz
    // target). One byte past the claimed size is read, to tell a chunk that
    // holds more than its header says.
    let room = size as u64 + 1;
    let content: std::borrow::Cow<'_, [u8]> = match header.compression.as_str() {
        "" => data,
        "zstd" => {
            let mut out = Vec::new();
            let decoder = zstd::stream::read::Decoder::with_buffer(&data[..])
                .map_err(|e| format!("a zstd chunk does not open: {e}"))?;
            decoder.take(room).read_to_end(&mut out).map_err(|e| format!("a zstd chunk does not decompress: {e}"))?;
            out.into()
        }
        "lz4" => {
            let mut out = Vec::new();
            let decoder = lz4::Decoder::new(&data[..]).map_err(|e| format!("an lz4 chunk does not open: {e}"))?;
            decoder.take(room).read_to_end(&mut out).map_err(|e| format!("an lz4 chunk does not decompress: {e}"))?;
            out.into()
        }
        other => {
            return Err(format!(
                "a chunk compressed with {other:?}, which this reader does not know (zstd, lz4 or none)"
            ));
        }
    };
    if content.len() != size {
        return Err(format!("a chunk holds {} bytes, but its header says {size}", content.len()));
    }
    if header.uncompressed_crc != 0 && crc32fast::hash(&content) != header.uncompressed_crc {
        return Err("a chunk's checksum does not match its content".into());
    }
    let mut records = std::collections::VecDeque::new();
    let mut rest: &[u8] = &content;
    while !rest.is_empty() {
        let Some((&opcode, after)) = rest.split_first() else { break };
        let Some((length, after)) = after.split_first_chunk::<8>() else {
            return Err("a chunk ends inside a record's header".into());
        };
        let length = usize::try_from(u64::from_le_bytes(*length)).unwrap_or(usize::MAX);
        if length > after.len() {
            return Err(format!("a record of {length} bytes in a chunk with {} bytes left", after.len()));
        }
        let (body, after) = after.split_at(length);
        records.push_back(parse(opcode, body)?);
        rest = after;
    }
    Ok(records)
}

/// Checks that every length inside a record fits in the record, before the
/// `mcap` crate parses it: its parser allocates whatever a string's length
/// field says first (found by the `recording` fuzz target: a 3.5 GB string
/// in a 100-byte record), and a damaged or hostile file must not make us
/// allocate gigabytes. Field layouts from the MCAP specification.
fn lengths_fit(opcode: u8, data: &[u8]) -> Result<(), String> {
    let mut f = Fields(data);
    match opcode {
        // Header: profile, library.
        0x01 => {
            f.string()?;
            f.string()
        }
        // Schema: id, name, encoding, data (4-byte length).
        0x03 => {
            f.skip(2)?;
            f.string()?;
            f.string()?;
            f.string()
        }
        // Channel: id, schema id, topic, message encoding, metadata.
        0x04 => {
            f.skip(4)?;
            f.string()?;
            f.string()?;
            f.map(true)
        }
        // Chunk: times, uncompressed size and crc, compression, records (8-byte length).
        0x06 => {
            f.skip(28)?;
            f.string()?;
            let n = f.length(8)?;
            f.skip(n)
        }
        // Message index: channel id, (time, offset) array.
        0x07 => {
            f.skip(2)?;
            f.map(false)
        }
        // Chunk index: 4 u64s, message index offsets, length, compression, sizes.
        0x08 => {
            f.skip(32)?;
            f.map(false)?;
            f.skip(8)?;
            f.string()
        }
        // Attachment: times, name, media type, data (8-byte length), crc.
        0x09 => {
            f.skip(16)?;
            f.string()?;
            f.string()?;
            let n = f.length(8)?;
            f.skip(n)?;
            f.skip(4)
        }
        // Attachment index: 5 u64s, name, media type.
        0x0A => {
            f.skip(40)?;
            f.string()?;
            f.string()
        }
        // Statistics: counts, then the per-channel counts.
        0x0B => {
            f.skip(8 + 2 + 4 * 4 + 8 + 8)?;
            f.map(false)
        }
        // Metadata: name, map.
        0x0C => {
            f.string()?;
            f.map(true)
        }
        // Metadata index: offset, length, name.
        0x0D => {
            f.skip(16)?;
            f.string()
        }
        _ => Ok(()),
    }
}

/// The fields of a record not yet checked, for [`lengths_fit`].
struct Fields<'a>(&'a [u8]);

impl Fields<'_> {
    fn skip(&mut self, n: u64) -> Result<(), String> {
        let n = usize::try_from(n)
            .ok()
            .filter(|&n| n <= self.0.len())
            .ok_or_else(|| format!("a field of {n} bytes in a record with {} bytes left", self.0.len()))?;
        self.0 = &self.0[n..];
        Ok(())
    }

    fn length(&mut self, bytes: usize) -> Result<u64, String> {
        let field = self.0.get(..bytes).ok_or("a record too short for its fields")?;
        let value = field.iter().rev().fold(0u64, |v, &b| v << 8 | u64::from(b));
        self.0 = &self.0[bytes..];
        Ok(value)
    }

    /// A string, or bytes with a 4-byte length.
    fn string(&mut self) -> Result<(), String> {
        let n = self.length(4)?;
        self.skip(n)
    }

    /// A map or array with a 4-byte length in bytes; `strings` if its entries are strings.
    fn map(&mut self, strings: bool) -> Result<(), String> {
        let n = self.length(4)?;
        let inner = self.0.get(..usize::try_from(n).unwrap_or(usize::MAX)).ok_or("a map longer than its record")?;
        self.skip(n)?;
        let mut inner = Fields(inner);
        while strings && !inner.0.is_empty() {
            inner.string()?;
            inner.string()?;
        }
        Ok(())
    }
}

/// One recorded skinware channel.
#[derive(Clone, Debug, Serialize)]
pub struct RecordedChannel {
    /// MCAP channel id of its frames.
    pub id: u16,
    /// Its topic.
    pub topic: String,
    /// The skinware channel's name.
    pub channel: String,
    /// Layer or service.
    #[serde(serialize_with = "kind_name")]
    pub kind: ChannelKind,
    /// Frame size in bytes.
    pub payload_bytes: usize,
    /// The writer's frame buffers.
    pub slots: usize,
    /// The writer's period in ns (0: sporadic).
    pub period_ns: u64,
    /// Payload schema name and version.
    pub schema: (String, u32),
    /// Its description (a layer's topology, a service's labels).
    #[serde(skip)]
    pub description: Vec<u8>,
}

fn kind_name<S: serde::Serializer>(kind: &ChannelKind, s: S) -> Result<S::Ok, S::Error> {
    s.serialize_str(kind.as_str())
}

/// What the start of a recording says: everything the recorder writes before
/// the first frame.
#[derive(Clone, Debug, Default)]
pub struct RecordingHeader {
    /// The recorded skin.
    pub skin: String,
    /// Wall-clock time minus CLOCK_MONOTONIC time on the recording machine, ns:
    /// every stamp in the file is wall-clock; subtracting this gives the
    /// machine's monotonic time.
    pub clock_offset_ns: i64,
    /// The `skinware.recording` metadata.
    pub metadata: BTreeMap<String, String>,
    /// The skinware channels recorded, by MCAP channel id.
    pub channels: BTreeMap<u16, RecordedChannel>,
    /// The skin's geometry file, if it was published when recording.
    pub geometry: Option<Vec<u8>>,
    /// Every topic seen before the first message, by MCAP channel id.
    pub topics: BTreeMap<u16, String>,
}

/// A message as read: its header and CDR bytes.
pub type RawMessage = (mcap::records::MessageHeader, Vec<u8>);

/// Reads the header of a recording from `stream`, up to and including the
/// first message (returned, if there is one).
pub fn read_header<R: Read>(
    stream: &mut RecordStream<R>,
) -> Result<(RecordingHeader, Option<RawMessage>), RecordError> {
    let mut collector = HeaderCollector::default();
    while let Some(record) = stream.next_record()? {
        if let Record::Message { header, data } = record {
            let header_out = collector.finish(&stream.path)?;
            return Ok((header_out, Some((header, data.into_owned()))));
        }
        collector.add(record)?;
    }
    Ok((collector.finish(&stream.path)?, None))
}

#[derive(Default)]
struct HeaderCollector {
    schemas: BTreeMap<u16, (String, String)>,
    channels: BTreeMap<u16, mcap::records::Channel>,
    metadata: Option<BTreeMap<String, String>>,
    geometry: Option<Vec<u8>>,
    descriptions: BTreeMap<String, Vec<u8>>,
}

impl HeaderCollector {
    fn add(&mut self, record: Record<'static>) -> Result<(), RecordError> {
        match record {
            Record::Schema { header, .. } => {
                self.schemas.insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(channel) => {
                self.channels.insert(channel.id, channel);
            }
            Record::Metadata(Metadata { name, metadata }) if name == RECORDING_METADATA => {
                self.metadata = Some(metadata);
            }
            Record::Attachment { header, data, .. } => {
                if header.name == GEOMETRY_ATTACHMENT {
                    self.geometry = Some(data.into_owned());
                } else if let Some(channel) = header.name.strip_prefix(DESCRIPTION_ATTACHMENT_PREFIX) {
                    self.descriptions.insert(channel.to_owned(), data.into_owned());
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn finish(mut self, path: &Path) -> Result<RecordingHeader, RecordError> {
        let not_recording =
            |reason: &str| RecordError::NotARecording { path: path.to_owned(), reason: reason.to_owned() };
        let metadata = self
            .metadata
            .take()
            .ok_or_else(|| not_recording("no `skinware.recording` metadata before the first message"))?;
        let version: u32 = metadata
            .get("format_version")
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| not_recording("`skinware.recording` has no numeric format_version"))?;
        if version > FORMAT_VERSION {
            return Err(RecordError::FutureVersion {
                path: path.to_owned(),
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        let skin = metadata.get("skin").cloned().ok_or_else(|| not_recording("`skinware.recording` names no skin"))?;
        let clock_offset_ns = metadata.get("clock_offset_ns").and_then(|v| v.parse().ok()).unwrap_or(0);
        let mut channels = BTreeMap::new();
        for (id, channel) in &self.channels {
            let Some(name) = channel.metadata.get(channel_keys::CHANNEL) else {
                continue;
            };
            let (schema, encoding) = self.schemas.get(&channel.schema_id).cloned().unwrap_or_default();
            if schema != skinware_ros2::SKIN_FRAME
                || encoding != SCHEMA_ENCODING
                || channel.message_encoding != MESSAGE_ENCODING
            {
                return Err(RecordError::UnknownSchema {
                    topic: channel.topic.clone(),
                    schema,
                    encoding: format!("{encoding}/{}", channel.message_encoding),
                    expected: format!("{} ({}/{})", skinware_ros2::SKIN_FRAME, SCHEMA_ENCODING, MESSAGE_ENCODING),
                });
            }
            let number = |key: &str| -> Result<u64, RecordError> {
                channel.metadata.get(key).and_then(|v| v.parse().ok()).ok_or_else(|| RecordError::NotARecording {
                    path: path.to_owned(),
                    reason: format!("topic {}: metadata {key} is missing or not a number", channel.topic),
                })
            };
            let kind = match channel.metadata.get(channel_keys::KIND).map(String::as_str) {
                Some("service") => ChannelKind::Service,
                Some("layer") => ChannelKind::Layer,
                other => {
                    return Err(not_recording(&format!(
                        "topic {}: skinware.kind {other:?} is not layer or service",
                        channel.topic
                    )));
                }
            };
            channels.insert(
                *id,
                RecordedChannel {
                    id: *id,
                    topic: channel.topic.clone(),
                    channel: name.clone(),
                    kind,
                    payload_bytes: number(channel_keys::PAYLOAD_BYTES)? as usize,
                    slots: number(channel_keys::SLOTS)? as usize,
                    period_ns: number(channel_keys::PERIOD_NS)?,
                    schema: (
                        channel.metadata.get(channel_keys::SCHEMA_NAME).cloned().unwrap_or_default(),
                        number(channel_keys::SCHEMA_VERSION)? as u32,
                    ),
                    description: self.descriptions.remove(name).unwrap_or_default(),
                },
            );
        }
        let topics = self.channels.iter().map(|(id, c)| (*id, c.topic.clone())).collect();
        Ok(RecordingHeader { skin, clock_offset_ns, metadata, channels, geometry: self.geometry, topics })
    }
}

/// What a recording holds, per channel.
#[derive(Clone, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct ChannelSummary {
    /// Layer or service.
    pub kind: String,
    /// Frames in the file.
    pub frames: u64,
    /// Frames the recorder missed (the sum of the frames' `skipped`).
    pub lost: u64,
    /// Gaps: runs of missed frames.
    pub gaps: u64,
    /// Frames with a fault status.
    pub faulted: u64,
    /// Acquisition time of the first and last frame, wall clock ns.
    pub first_ns: u64,
    /// See `first_ns`.
    pub last_ns: u64,
    /// Frame payload bytes.
    pub payload_bytes: usize,
}

/// What `skin info` says about a file.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingInfo {
    /// The file.
    pub path: PathBuf,
    /// Its size.
    pub file_bytes: u64,
    /// Finished, or cut short.
    pub ending: Ending,
    /// Where and how the file is damaged, if it is.
    pub damage: Option<String>,
    /// The recorded skin.
    pub skin: String,
    /// The `skinware.recording` metadata.
    pub metadata: BTreeMap<String, String>,
    /// Whether the geometry is in the file.
    pub has_geometry: bool,
    /// Per skinware channel.
    pub channels: BTreeMap<String, ChannelSummary>,
    /// Messages per topic (every topic, the map and statistics too).
    pub topics: BTreeMap<String, u64>,
    /// First to last frame, seconds.
    pub duration_s: f64,
    /// Every frame.
    pub frames: u64,
    /// Every frame missed.
    pub lost: u64,
    /// The `skinware.summary` the recorder wrote on finishing, if it did.
    pub recorder_summary: Option<BTreeMap<String, String>>,
}

impl ChannelSummary {
    /// Counts one frame of the channel.
    fn count(&mut self, head: &FrameHead) {
        let stamp = head.stamp.to_ns();
        if self.frames == 0 {
            self.first_ns = stamp;
        }
        self.last_ns = self.last_ns.max(stamp);
        self.frames += 1;
        self.lost = self.lost.saturating_add(head.skipped);
        self.gaps += u64::from(head.skipped > 0);
        self.faulted += u64::from(head.status & skinware::FrameStatus::FAULT.0 != 0);
    }
}

/// The first fields of a `SkinFrame`, decoded without its arrays.
#[derive(Deserialize)]
struct FrameHead {
    stamp: Time,
    _published: Time,
    _seq: u64,
    status: u64,
    skipped: u64,
}

/// Reads `path` from start to end and says what it holds. An unfinished file
/// is read up to its last complete chunk (see [`RecordingInfo::ending`]).
pub fn scan(path: &Path) -> Result<RecordingInfo, RecordError> {
    let stream = RecordStream::open(path)?;
    let file_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    scan_stream(stream, file_bytes)
}

/// [`scan`] of any stream of MCAP bytes (`file_bytes` long).
pub fn scan_stream<R: Read>(mut stream: RecordStream<R>, file_bytes: u64) -> Result<RecordingInfo, RecordError> {
    let path = stream.path.clone();
    let (header, first) = read_header(&mut stream)?;
    let mut topics_by_id: BTreeMap<u16, String> = header.topics.clone();
    let mut topics: BTreeMap<String, u64> = BTreeMap::new();
    let mut channels: BTreeMap<String, ChannelSummary> = header
        .channels
        .values()
        .map(|c| {
            let summary = ChannelSummary {
                kind: c.kind.as_str().to_owned(),
                payload_bytes: c.payload_bytes,
                ..Default::default()
            };
            (c.channel.clone(), summary)
        })
        .collect();
    for c in header.channels.values() {
        topics_by_id.insert(c.id, c.topic.clone());
    }
    let mut recorder_summary = None;
    let mut pending = first;
    loop {
        let (message, data) = match pending.take() {
            Some(first) => first,
            None => match stream.next_record() {
                Ok(Some(Record::Message { header, data })) => (header, data.into_owned()),
                Ok(Some(Record::Channel(channel))) => {
                    topics_by_id.entry(channel.id).or_insert(channel.topic);
                    continue;
                }
                Ok(Some(Record::Metadata(Metadata { name, metadata }))) if name == SUMMARY_METADATA => {
                    recorder_summary = Some(metadata);
                    continue;
                }
                Ok(Some(_)) => continue,
                Ok(None) => break,
                Err(RecordError::Damaged { offset, reason, .. }) => {
                    stream.ending = Some(Ending::Damaged);
                    stream.damage = Some(format!("at byte {offset}: {reason}"));
                    break;
                }
                Err(e) => return Err(e),
            },
        };
        if let Some(channel) = header.channels.get(&message.channel_id) {
            let head: FrameHead = match skinware_ros2::decode(&data, skinware_ros2::SKIN_FRAME) {
                Ok(head) => head,
                // A frame that does not decode is damage: what came before is read.
                Err(e) => {
                    stream.ending = Some(Ending::Damaged);
                    stream.damage = Some(format!("near byte {}: topic {}: {e}", stream.fed, channel.topic));
                    break;
                }
            };
            channels.entry(channel.channel.clone()).or_default().count(&head);
        }
        let topic = topics_by_id.get(&message.channel_id).cloned();
        *topics.entry(topic.unwrap_or_else(|| format!("channel {}", message.channel_id))).or_default() += 1;
    }
    let ending = stream.ending().unwrap_or(Ending::Truncated);
    let first_ns = channels.values().filter(|c| c.frames > 0).map(|c| c.first_ns).min().unwrap_or(0);
    let last_ns = channels.values().map(|c| c.last_ns).max().unwrap_or(0);
    Ok(RecordingInfo {
        path,
        file_bytes,
        ending,
        damage: stream.damage.clone(),
        skin: header.skin,
        metadata: header.metadata,
        has_geometry: header.geometry.is_some(),
        frames: channels.values().map(|c| c.frames).sum(),
        lost: channels.values().fold(0u64, |sum, c| sum.saturating_add(c.lost)),
        channels,
        topics,
        duration_s: last_ns.saturating_sub(first_ns) as f64 / 1e9,
        recorder_summary,
    })
}

/// What [`recover`] saved.
#[derive(Clone, Debug, Serialize)]
pub struct Recovered {
    /// The file written.
    pub out: PathBuf,
    /// How the input ended.
    pub input_ending: Ending,
    /// Messages copied.
    pub messages: u64,
    /// Frames copied, per skinware channel.
    pub frames: BTreeMap<String, u64>,
    /// Attachments and metadata records copied.
    pub attachments: u64,
    /// Metadata records copied.
    pub metadata: u64,
    /// Acquisition time of the last message, wall clock ns.
    pub last_log_time_ns: u64,
    /// Why reading stopped early, if it did (damage rather than a cut).
    pub stopped_by: Option<String>,
}

/// Writes every complete record of `input` (typically a recording whose
/// recorder was killed) into a new, finished MCAP file `out`.
pub fn recover(input: &Path, out: &Path, compression: Option<mcap::Compression>) -> Result<Recovered, RecordError> {
    let mut stream = RecordStream::open(input)?;
    let output = crate::error::create_new(out)?;
    let write_error = |e: mcap::McapError| crate::error::mcap_write_error(out, e);
    let mut writer = mcap::WriteOptions::new()
        .profile("ros2")
        .compression(compression)
        .create(std::io::BufWriter::new(output))
        .map_err(write_error)?;
    let mut skin_channels: BTreeMap<u16, String> = BTreeMap::new();
    let mut report = Recovered {
        out: out.to_owned(),
        input_ending: Ending::Truncated,
        messages: 0,
        frames: BTreeMap::new(),
        attachments: 0,
        metadata: 0,
        last_log_time_ns: 0,
        stopped_by: None,
    };
    loop {
        let record = match stream.next_record() {
            Ok(Some(record)) => record,
            Ok(None) => break,
            Err(e) => {
                report.stopped_by = Some(e.to_string());
                report.input_ending = Ending::Damaged;
                break;
            }
        };
        copy_record(&mut writer, record, &mut skin_channels, &mut report).map_err(write_error)?;
    }
    if let Some(ending) = stream.ending() {
        report.input_ending = ending;
    }
    let mut recovery = BTreeMap::new();
    recovery.insert("from".to_owned(), input.display().to_string());
    recovery.insert("input_ending".to_owned(), format!("{:?}", report.input_ending).to_lowercase());
    recovery.insert("messages".to_owned(), report.messages.to_string());
    writer.write_metadata(&Metadata { name: "skinware.recovery".into(), metadata: recovery }).map_err(write_error)?;
    writer.finish().map_err(write_error)?;
    close(writer.into_inner(), out)?;
    Ok(report)
}

/// Copies one record of [`recover`]'s input into its output, counting it in
/// `report`; `skin_channels` names the skinware channel of each MCAP channel seen.
fn copy_record<W: std::io::Write + std::io::Seek>(
    writer: &mut mcap::Writer<W>,
    record: Record<'_>,
    skin_channels: &mut BTreeMap<u16, String>,
    report: &mut Recovered,
) -> Result<(), mcap::McapError> {
    match record {
        Record::Schema { header, data } => {
            writer.add_schema_with_id(header.id, &header.name, &header.encoding, &data)?;
        }
        Record::Channel(channel) => {
            if let Some(name) = channel.metadata.get(channel_keys::CHANNEL) {
                skin_channels.insert(channel.id, name.clone());
            }
            writer.add_channel_with_id(
                channel.id,
                channel.schema_id,
                &channel.topic,
                &channel.message_encoding,
                &channel.metadata,
            )?;
        }
        Record::Message { header, data } => {
            writer.write_to_known_channel(&header, &data)?;
            report.messages += 1;
            report.last_log_time_ns = report.last_log_time_ns.max(header.log_time);
            if let Some(name) = skin_channels.get(&header.channel_id) {
                *report.frames.entry(name.clone()).or_default() += 1;
            }
        }
        Record::Attachment { header, data, .. } => {
            let attachment = mcap::Attachment {
                log_time: header.log_time,
                create_time: header.create_time,
                name: header.name,
                media_type: header.media_type,
                data,
            };
            writer.attach(&attachment)?;
            report.attachments += 1;
        }
        Record::Metadata(metadata) => {
            writer.write_metadata(&metadata)?;
            report.metadata += 1;
        }
        _ => {}
    }
    Ok(())
}

/// Flushes and syncs a finished file, so that its end is on disk when we say it is.
pub(crate) fn close<W: std::io::Write + std::borrow::Borrow<File>>(
    buffered: std::io::BufWriter<W>,
    path: &Path,
) -> Result<(), RecordError> {
    let io =
        |op, source: std::io::Error| RecordError::Io { op, path: path.to_owned(), hint: write_hint(&source), source };
    let file = buffered.into_inner().map_err(|e| io("write", e.into_error()))?;
    file.borrow().sync_all().map_err(|e| io("sync", e))
}

#[cfg(test)]
mod tests {
    use super::lengths_fit;

    #[test]
    fn a_string_longer_than_its_record_is_refused_before_parsing() {
        // Metadata: a name of 3.5 GB in a record of 12 bytes (the fuzzer's find).
        let mut record = 3_500_000_000u32.to_le_bytes().to_vec();
        record.extend([0u8; 8]);
        assert!(lengths_fit(0x0C, &record).is_err());
        // The same record, honest: name "ab", an empty map.
        let mut record = 2u32.to_le_bytes().to_vec();
        record.extend(b"ab");
        record.extend(0u32.to_le_bytes());
        assert!(lengths_fit(0x0C, &record).is_ok());
        assert!(mcap::parse_record(0x0C, &record).is_ok());
        // A map whose entries overrun it.
        let mut record = 0u32.to_le_bytes().to_vec();
        record.extend(8u32.to_le_bytes());
        record.extend(100u32.to_le_bytes());
        record.extend([0u8; 4]);
        assert!(lengths_fit(0x0C, &record).is_err());
        // An attachment without the 4-byte checksum after its data (the
        // mcap crate slices `body.len() - 4` without looking).
        let mut record = vec![0u8; 16];
        record.extend(0u32.to_le_bytes());
        record.extend(0u32.to_le_bytes());
        record.extend(0u64.to_le_bytes());
        assert!(lengths_fit(0x09, &record).is_err());
        record.extend(0u32.to_le_bytes());
        assert!(lengths_fit(0x09, &record).is_ok());
        assert!(mcap::parse_record(0x09, &record).is_ok());
    }
}
