//! `skin record`: every frame of the chosen channels into an MCAP file.
//!
//! One reader thread per channel reads as soon as each frame is published and
//! encodes it; a writer thread owns the file. The reader threads hand frames
//! over through a bounded queue: if the disk cannot keep up, a reader thread
//! waits, its next read reports the frames it missed (`skipped`), and those
//! are counted and written as a gap. Nothing ever waits on the skin's writers.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};
use serde::Serialize;
use skinware::rt::{Stop, Ticker};
use skinware::{ChannelKind, Error, FrameStatus, Reader, ReaderOptions, WriterState};
use skinware_geometry::SkinGeometry;

use crate::error::{mcap_write_error, write_hint};
use crate::file::kind_str;
use crate::heatmap::{HeatMap, LayerLook};
use crate::msgs::{self, Gap, Header, Image, LayerStats, SkinFrameRef, Time};
use crate::{
    DESCRIPTION_ATTACHMENT_PREFIX, FORMAT_VERSION, GEOMETRY_ATTACHMENT, LAYOUT_METADATA, RECORDING_METADATA,
    RecordError, SUMMARY_METADATA, channel_keys,
};

/// Frames queued between the reader threads and the file before a reader waits.
const QUEUE: usize = 512;
/// Uncompressed bytes per chunk. Smaller chunks compress a little worse, but
/// each is written with shorter system calls, which matters to real-time
/// threads on a kernel without full preemption.
const CHUNK_BYTES: u64 = 1 << 20;
/// How often the statistics messages are written.
const STATS_INTERVAL: Duration = Duration::from_secs(1);
/// How long a blocking read waits before it looks at the stop signal and the writer's state.
const READ_SLICE: Duration = Duration::from_millis(200);

/// Chunk compression.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Compression {
    /// zstd: the smallest files (the default).
    #[default]
    Zstd,
    /// lz4: faster, larger.
    Lz4,
    /// None.
    None,
}

impl Compression {
    /// The MCAP compression.
    pub fn mcap(self) -> Option<mcap::Compression> {
        match self {
            Compression::Zstd => Some(mcap::Compression::Zstd),
            Compression::Lz4 => Some(mcap::Compression::Lz4),
            Compression::None => None,
        }
    }
}

/// Which services to record.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum ServiceChoice {
    /// None.
    #[default]
    None,
    /// Every service of the skin.
    All,
    /// These.
    Named(Vec<String>),
}

/// How to record.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// The skin.
    pub skin: String,
    /// The layers to record; `None` for all.
    pub layers: Option<Vec<String>>,
    /// The services to record.
    pub services: ServiceChoice,
    /// Map images per second (0: none).
    pub map_hz: f64,
    /// Width of the map image, pixels.
    pub map_width: usize,
    /// Chunk compression.
    pub compression: Compression,
    /// How often the current chunk is finished, written and synced to disk:
    /// at most this much is lost if the recorder is killed or the power fails.
    pub flush_interval: Duration,
    /// Segment directory; `None` for the default.
    pub dir: Option<PathBuf>,
    /// The command line, kept in the file's metadata.
    pub command: String,
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            skin: "default".into(),
            layers: None,
            services: ServiceChoice::None,
            map_hz: 4.0,
            map_width: 480,
            compression: Compression::Zstd,
            flush_interval: Duration::from_secs(1),
            dir: None,
            command: String::new(),
        }
    }
}

/// Counters of one recorded channel, shared by its reader thread and the rest.
#[derive(Default)]
struct Counters {
    frames: AtomicU64,
    lost: AtomicU64,
    gaps: AtomicU64,
    faulted: AtomicU64,
    latency_ns: AtomicU64,
    state: AtomicU32,
}

struct Recorded {
    name: String,
    kind: ChannelKind,
    counters: Arc<Counters>,
}

/// What the writer thread writes.
struct Item {
    channel_id: u16,
    sequence: u32,
    log_time: u64,
    publish_time: u64,
    data: Vec<u8>,
}

/// Progress of a recording.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Progress {
    /// Since the start.
    pub seconds: f64,
    /// Frames written.
    pub frames: u64,
    /// Frames missed.
    pub lost: u64,
    /// Message bytes handed to the file (before compression).
    pub message_bytes: u64,
    /// The file's size now.
    pub file_bytes: u64,
}

/// One channel in the summary.
#[derive(Clone, Debug, Serialize)]
pub struct ChannelReport {
    /// Layer or service.
    pub kind: &'static str,
    /// Frames written.
    pub frames: u64,
    /// Frames missed.
    pub lost: u64,
    /// Runs of missed frames.
    pub gaps: u64,
    /// Frames with a fault status.
    pub faulted: u64,
}

/// What a finished recording holds.
#[derive(Clone, Debug, Serialize)]
pub struct RecordSummary {
    /// The file.
    pub path: PathBuf,
    /// The skin.
    pub skin: String,
    /// Recording time.
    pub seconds: f64,
    /// Frames written.
    pub frames: u64,
    /// Frames missed.
    pub lost: u64,
    /// Message bytes (before compression).
    pub message_bytes: u64,
    /// The finished file's size.
    pub file_bytes: u64,
    /// Frames per second.
    pub frames_per_s: f64,
    /// Message MB per second (before compression).
    pub mb_per_s: f64,
    /// Map images written.
    pub images: u64,
    /// Per channel.
    pub channels: BTreeMap<String, ChannelReport>,
    /// The compression.
    pub compression: String,
}

struct Shared {
    stop: Stop,
    failure: Mutex<Option<RecordError>>,
    message_bytes: AtomicU64,
    images: AtomicU64,
}

impl Shared {
    fn fail(&self, error: RecordError) {
        let mut failure = self.failure.lock().unwrap_or_else(|p| p.into_inner());
        if failure.is_none() {
            *failure = Some(error);
        }
        self.stop.stop();
    }
}

/// A recording under way.
pub struct Recorder {
    path: PathBuf,
    skin: String,
    compression: Compression,
    started: Instant,
    shared: Arc<Shared>,
    channels: Vec<Recorded>,
    readers: Vec<JoinHandle<()>>,
    writer: Option<JoinHandle<Result<(), RecordError>>>,
}

impl Recorder {
    /// Starts recording the chosen channels of `options.skin` into a new file `path`.
    pub fn start(path: &Path, options: RecordOptions) -> Result<Recorder, RecordError> {
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        let chosen = choose_channels(&dir, &options)?;
        let reader_options = ReaderOptions { dir: Some(dir.clone()), ..ReaderOptions::default() };
        let mut readers = Vec::new();
        for name in &chosen {
            readers.push(Reader::open_with(&options.skin, name, &reader_options)?);
        }
        let geometry_path = SkinGeometry::published_path(&dir, &options.skin);
        let geometry_bytes = skinware::shm::read_regular(&geometry_path, SkinGeometry::MAX_PUBLISHED_BYTES).ok();
        let geometry = geometry_bytes.as_deref().and_then(|bytes| match SkinGeometry::decode(bytes) {
            Ok(geometry) => Some(geometry),
            Err(e) => {
                tracing::warn!(skin = %options.skin, error = %e, "the published geometry does not decode; recording without it");
                None
            }
        });

        let file = crate::error::create_new(path)?;
        let write_error = |e: mcap::McapError| mcap_write_error(path, e);
        let mut writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("skinware-record/", env!("CARGO_PKG_VERSION")))
            .compression(options.compression.mcap())
            .chunk_size(Some(CHUNK_BYTES))
            .create(BufWriter::with_capacity(
                256 << 10,
                file.try_clone().map_err(|source| RecordError::Io {
                    op: "open a second handle to",
                    path: path.to_owned(),
                    hint: String::new(),
                    source,
                })?,
            ))
            .map_err(write_error)?;
        let schema = |writer: &mut mcap::Writer<_>, name: &str| {
            let text = msgs::schema_text(name).unwrap_or_default();
            writer.add_schema(name, msgs::SCHEMA_ENCODING, text.as_bytes())
        };
        let frame_schema = schema(&mut writer, msgs::SKIN_FRAME).map_err(write_error)?;
        let gap_schema = schema(&mut writer, msgs::GAP).map_err(write_error)?;
        let stats_schema = schema(&mut writer, msgs::LAYER_STATS).map_err(write_error)?;

        let clock_offset_ns = clock_offset_ns();
        let started_unix_ns = wall(skinware::os::monotonic_ns(), clock_offset_ns);
        let mut recording = BTreeMap::new();
        recording.insert("format_version".to_owned(), FORMAT_VERSION.to_string());
        recording.insert("skin".to_owned(), options.skin.clone());
        recording.insert("clock_offset_ns".to_owned(), clock_offset_ns.to_string());
        recording.insert("started_unix_ns".to_owned(), started_unix_ns.to_string());
        recording.insert("skinware_version".to_owned(), env!("CARGO_PKG_VERSION").to_owned());
        recording.insert("host".to_owned(), hostname());
        recording.insert("command".to_owned(), options.command.clone());
        recording.insert("compression".to_owned(), format!("{:?}", options.compression).to_lowercase());
        writer
            .write_metadata(&Metadata { name: RECORDING_METADATA.into(), metadata: recording })
            .map_err(write_error)?;

        let mut frame_channels = Vec::new();
        let mut stats_channels = Vec::new();
        let mut layout = BTreeMap::new();
        for reader in &readers {
            let name = reader.label().rsplit('/').next().unwrap_or_default().to_owned();
            let (schema_name, schema_version) = reader.schema();
            let mut metadata = BTreeMap::new();
            metadata.insert(channel_keys::CHANNEL.to_owned(), name.clone());
            metadata.insert(channel_keys::KIND.to_owned(), kind_str(reader.kind()).to_owned());
            metadata.insert(channel_keys::PAYLOAD_BYTES.to_owned(), reader.payload_bytes().to_string());
            metadata.insert(channel_keys::SLOTS.to_owned(), reader.slots().to_string());
            let period = reader.writer_period().map_or(0, |p| p.as_nanos() as u64);
            metadata.insert(channel_keys::PERIOD_NS.to_owned(), period.to_string());
            metadata.insert(channel_keys::SCHEMA_NAME.to_owned(), schema_name.clone());
            metadata.insert(channel_keys::SCHEMA_VERSION.to_owned(), schema_version.to_string());
            let topic = crate::frame_topic(&options.skin, &name);
            frame_channels.push(
                writer.add_channel(frame_schema, &topic, msgs::MESSAGE_ENCODING, &metadata).map_err(write_error)?,
            );
            let stats_topic = crate::stats_topic(&options.skin, &name);
            stats_channels.push(
                writer
                    .add_channel(stats_schema, &stats_topic, msgs::MESSAGE_ENCODING, &BTreeMap::new())
                    .map_err(write_error)?,
            );
            layout.insert(name.clone(), describe(reader, &topic));
        }
        let gap_channel = writer
            .add_channel(gap_schema, &crate::gaps_topic(&options.skin), msgs::MESSAGE_ENCODING, &BTreeMap::new())
            .map_err(write_error)?;
        let map = match (&geometry, options.map_hz > 0.0) {
            (Some(geometry), true) => {
                let image_schema = schema(&mut writer, msgs::IMAGE).map_err(write_error)?;
                let id = writer
                    .add_channel(
                        image_schema,
                        &crate::map_topic(&options.skin),
                        msgs::MESSAGE_ENCODING,
                        &BTreeMap::new(),
                    )
                    .map_err(write_error)?;
                Some((id, HeatMap::new(geometry, options.map_width)))
            }
            (None, true) => {
                tracing::warn!(skin = %options.skin, "no geometry is published for this skin: recording without the map image");
                None
            }
            _ => None,
        };
        writer.write_metadata(&Metadata { name: LAYOUT_METADATA.into(), metadata: layout }).map_err(write_error)?;
        let attach = |writer: &mut mcap::Writer<_>, name: String, media_type: &str, data: &[u8]| {
            writer.attach(&mcap::Attachment {
                log_time: started_unix_ns,
                create_time: started_unix_ns,
                name,
                media_type: media_type.to_owned(),
                data: std::borrow::Cow::Borrowed(data),
            })
        };
        if let Some(bytes) = &geometry_bytes {
            attach(&mut writer, GEOMETRY_ATTACHMENT.to_owned(), "application/x-skinware-geometry", bytes)
                .map_err(write_error)?;
        }
        for reader in &readers {
            let name = reader.label().rsplit('/').next().unwrap_or_default();
            let description = reader.description();
            attach(
                &mut writer,
                format!("{DESCRIPTION_ATTACHMENT_PREFIX}{name}"),
                "application/x-skinware-description",
                &description,
            )
            .map_err(write_error)?;
        }
        writer.flush().map_err(write_error)?;

        let shared = Arc::new(Shared {
            stop: Stop::new(),
            failure: Mutex::new(None),
            message_bytes: AtomicU64::new(0),
            images: AtomicU64::new(0),
        });
        let channels: Vec<Recorded> = readers
            .iter()
            .map(|r| Recorded {
                name: r.label().rsplit('/').next().unwrap_or_default().to_owned(),
                kind: r.kind(),
                counters: Arc::new(Counters::default()),
            })
            .collect();
        let (sender, receiver) = sync_channel::<Item>(QUEUE);
        let mut threads = Vec::new();
        // The recording starts now, the file ready: every frame after these
        // is recorded or counted as lost.
        let starts: Vec<u64> = readers.iter().map(Reader::published_seq).collect();
        for (((reader, recorded), &channel_id), last_seq) in
            readers.into_iter().zip(&channels).zip(&frame_channels).zip(starts)
        {
            let job = ChannelJob {
                reader,
                last_seq,
                name: recorded.name.clone(),
                channel_id,
                gap_channel,
                counters: recorded.counters.clone(),
                clock_offset_ns,
                sender: sender.clone(),
                shared: shared.clone(),
            };
            threads.push(spawn(&format!("rec-{}", recorded.name), move || job.run())?);
        }
        let watcher = Watcher {
            skin: options.skin.clone(),
            dir,
            geometry,
            map,
            map_hz: options.map_hz,
            channels: channels.iter().map(|c| (c.name.clone(), c.kind, c.counters.clone())).collect(),
            stats_channels,
            clock_offset_ns,
            sender,
            shared: shared.clone(),
        };
        threads.push(spawn("rec-map", move || watcher.run())?);
        let file_job = FileJob {
            path: path.to_owned(),
            writer,
            sync: file,
            receiver,
            flush_interval: options.flush_interval,
            shared: shared.clone(),
            channels: channels.iter().map(|c| (c.name.clone(), c.kind, c.counters.clone())).collect(),
        };
        let writer = std::thread::Builder::new()
            .name("rec-file".into())
            .spawn(move || file_job.run())
            .map_err(|e| RecordError::Nothing(format!("cannot start the file-writing thread: {e}")))?;
        Ok(Recorder {
            path: path.to_owned(),
            skin: options.skin,
            compression: options.compression,
            started: Instant::now(),
            shared,
            channels,
            readers: threads,
            writer: Some(writer),
        })
    }

    /// The names of the channels being recorded.
    pub fn channels(&self) -> Vec<String> {
        self.channels.iter().map(|c| c.name.clone()).collect()
    }

    /// The signal that stops the recording (from a signal handler, say).
    pub fn stop_signal(&self) -> &Stop {
        &self.shared.stop
    }

    /// Whether the recording stopped on its own (an error: see [`finish`](Self::finish)).
    pub fn has_failed(&self) -> bool {
        self.shared.failure.lock().map(|f| f.is_some()).unwrap_or(true)
    }

    /// Whether every recorded channel's writer is gone.
    pub fn all_gone(&self) -> bool {
        self.channels.iter().all(|c| c.counters.state.load(Ordering::Relaxed) == state_code(WriterState::Gone))
    }

    /// How far the recording has got.
    pub fn progress(&self) -> Progress {
        Progress {
            seconds: self.started.elapsed().as_secs_f64(),
            frames: self.channels.iter().map(|c| c.counters.frames.load(Ordering::Relaxed)).sum(),
            lost: self.channels.iter().map(|c| c.counters.lost.load(Ordering::Relaxed)).sum(),
            message_bytes: self.shared.message_bytes.load(Ordering::Relaxed),
            file_bytes: std::fs::metadata(&self.path).map(|m| m.len()).unwrap_or(0),
        }
    }

    /// Stops reading, writes what was read, finishes the file and says what it holds.
    /// After a failure (disk full), the error, with what the file keeps.
    pub fn finish(mut self) -> Result<RecordSummary, RecordError> {
        let written = self.shutdown();
        let seconds = self.started.elapsed().as_secs_f64();
        if let Some(error) = self.shared.failure.lock().unwrap_or_else(|p| p.into_inner()).take() {
            return Err(error);
        }
        written?;
        let progress = self.progress();
        Ok(RecordSummary {
            path: self.path.clone(),
            skin: self.skin.clone(),
            seconds,
            frames: progress.frames,
            lost: progress.lost,
            message_bytes: progress.message_bytes,
            file_bytes: progress.file_bytes,
            frames_per_s: progress.frames as f64 / seconds.max(1e-9),
            mb_per_s: progress.message_bytes as f64 / 1e6 / seconds.max(1e-9),
            images: self.shared.images.load(Ordering::Relaxed),
            channels: self.channels.iter().map(|c| (c.name.clone(), report(c.kind, &c.counters))).collect(),
            compression: format!("{:?}", self.compression).to_lowercase(),
        })
    }

    /// Stops the threads and waits for the file to be finished (once).
    fn shutdown(&mut self) -> Result<(), RecordError> {
        self.shared.stop.stop();
        for thread in self.readers.drain(..) {
            let _ = thread.join();
        }
        match self.writer.take().map(JoinHandle::join) {
            None => Ok(()),
            Some(Ok(result)) => result,
            Some(Err(_)) => Err(RecordError::Nothing("the file-writing thread panicked".into())),
        }
    }
}

impl Drop for Recorder {
    /// A recorder dropped without [`finish`](Recorder::finish) (an early
    /// return, a panic) still finishes its file before it goes.
    fn drop(&mut self) {
        let _ = self.shutdown();
    }
}

fn report(kind: ChannelKind, counters: &Counters) -> ChannelReport {
    ChannelReport {
        kind: kind_str(kind),
        frames: counters.frames.load(Ordering::Relaxed),
        lost: counters.lost.load(Ordering::Relaxed),
        gaps: counters.gaps.load(Ordering::Relaxed),
        faulted: counters.faulted.load(Ordering::Relaxed),
    }
}

fn spawn(name: &str, job: impl FnOnce() + Send + 'static) -> Result<JoinHandle<()>, RecordError> {
    std::thread::Builder::new()
        .name(name.chars().take(15).collect())
        .spawn(job)
        .map_err(|e| RecordError::Nothing(format!("cannot start thread {name}: {e}")))
}

/// The channels of `options.skin` to record, by name, layers first.
fn choose_channels(dir: &Path, options: &RecordOptions) -> Result<Vec<String>, RecordError> {
    let listed = skinware::list_skin_channels(dir, &options.skin)?;
    let live: Vec<_> = listed
        .iter()
        .filter(|c| c.skin == options.skin && c.state != WriterState::Gone && c.problem.is_none())
        .collect();
    let of_kind = |kind: ChannelKind| -> Vec<String> {
        live.iter().filter(|c| c.kind == Some(kind)).map(|c| c.channel.clone()).collect()
    };
    let (layers, services) = (of_kind(ChannelKind::Layer), of_kind(ChannelKind::Service));
    let pick = |wanted: &[String], available: &[String], what: &str| -> Result<Vec<String>, RecordError> {
        for name in wanted {
            if !available.contains(name) {
                return Err(RecordError::Nothing(format!(
                    "skin {} has no running {what} {name:?}; its {what}s: {}",
                    options.skin,
                    if available.is_empty() { "none".to_owned() } else { available.join(", ") }
                )));
            }
        }
        Ok(wanted.to_vec())
    };
    let mut chosen = match &options.layers {
        None => layers.clone(),
        Some(wanted) => pick(wanted, &layers, "layer")?,
    };
    chosen.extend(match &options.services {
        ServiceChoice::None => Vec::new(),
        ServiceChoice::All => services,
        ServiceChoice::Named(wanted) => pick(wanted, &services, "service")?,
    });
    if chosen.is_empty() {
        return Err(RecordError::Nothing(format!(
            "skin {} has no running channel to record in {}; start it first (`skin run`; `skin record --wait 60` waits for it), or name the skin with --skin",
            options.skin,
            dir.display()
        )));
    }
    Ok(chosen)
}

/// The `skin.layout` entry of a channel: a readable outline.
fn describe(reader: &Reader, topic: &str) -> String {
    match (reader.kind(), reader.topology()) {
        (ChannelKind::Layer, Ok(t)) => format!(
            "layer {}: topic {topic}, {} sensors of type {} in {} modules on {} patches, {} Hz",
            t.name,
            t.sensors.len(),
            t.sensor_type,
            t.modules.len(),
            t.patches.len(),
            t.rate_hz
        ),
        (kind, _) => {
            let (schema, version) = reader.schema();
            format!(
                "{} {}: topic {topic}, {} bytes per frame, schema {schema} v{version}",
                kind_str(kind),
                reader.label(),
                reader.payload_bytes()
            )
        }
    }
}

/// Wall-clock time minus CLOCK_MONOTONIC time, ns, from the closest of a few readings.
/// CLOCK_REALTIME minus CLOCK_MONOTONIC, ns: what turns a frame's monotonic
/// times into wall-clock ones (the best of five readings).
pub fn clock_offset_ns() -> i64 {
    let mut best = (u64::MAX, 0i64);
    for _ in 0..5 {
        let before = skinware::os::monotonic_ns();
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
        let after = skinware::os::monotonic_ns();
        if after - before < best.0 {
            best = (after - before, now - (before / 2 + after / 2) as i64);
        }
    }
    best.1
}

fn wall(monotonic_ns: u64, offset_ns: i64) -> u64 {
    (monotonic_ns as i64).saturating_add(offset_ns).max(0) as u64
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_owned()).unwrap_or_default()
}

fn state_code(state: WriterState) -> u32 {
    match state {
        WriterState::Running => 1,
        WriterState::Paused => 2,
        WriterState::Faulted => 3,
        WriterState::Gone => 4,
    }
}

fn state_of(code: u32) -> WriterState {
    match code {
        2 => WriterState::Paused,
        3 => WriterState::Faulted,
        4 => WriterState::Gone,
        _ => WriterState::Running,
    }
}

/// A reader thread's job.
struct ChannelJob {
    reader: Reader,
    /// The newest frame written (or, at the start, published when the recording started).
    last_seq: u64,
    name: String,
    channel_id: u16,
    gap_channel: u16,
    counters: Arc<Counters>,
    clock_offset_ns: i64,
    sender: SyncSender<Item>,
    shared: Arc<Shared>,
}

/// A frame copied out of the reader.
struct Copied {
    seq: u64,
    acquired_ns: u64,
    published_ns: u64,
    status: FrameStatus,
    bytes: Vec<u8>,
}

impl Copied {
    fn of(frame: &skinware::Frame<'_>) -> Copied {
        Copied {
            seq: frame.seq(),
            acquired_ns: frame.acquired_ns(),
            published_ns: frame.published_ns(),
            status: frame.status(),
            bytes: frame.bytes().to_vec(),
        }
    }
}

impl ChannelJob {
    fn run(mut self) {
        self.reader.set_stop(&self.shared.stop);
        let is_layer = self.reader.kind() != ChannelKind::Service;
        let mut responses: Vec<u16> = Vec::new();
        let mut size_hint = 64;
        while !self.shared.stop.is_stopped() {
            self.counters.state.store(state_code(self.reader.writer_state()), Ordering::Relaxed);
            let (newest, skipped) = match self.reader.wait_newer(READ_SLICE) {
                // Counted from the last frame written, so that frames published
                // between the start and this thread's first read count too;
                // a writer that started again (its numbers restarted) is
                // counted by the reader.
                Ok(frame) if frame.seq() > self.last_seq => (Copied::of(&frame), frame.seq() - self.last_seq - 1),
                Ok(frame) => (Copied::of(&frame), frame.skipped()),
                Err(Error::Timeout { .. } | Error::WriterGone { .. } | Error::Lapped { .. }) => continue,
                Err(Error::Stopped { .. }) => break,
                Err(e) => {
                    tracing::warn!(channel = %self.name, error = %e, "read failed; retrying");
                    std::thread::sleep(READ_SLICE);
                    continue;
                }
            };
            // Woken late: the frames between the previous one and the newest
            // stay in the writer's buffers for K-1 frames each; copy those
            // still there, and count the rest as missed.
            let mut missed = 0;
            for seq in newest.seq - skipped..newest.seq {
                match self.reader.read_seq(seq).map(|frame| Copied::of(&frame)) {
                    Some(older) => {
                        if !self.emit(&older, missed, is_layer, &mut responses, &mut size_hint) {
                            return;
                        }
                        missed = 0;
                    }
                    None => missed += 1,
                }
            }
            if !self.emit(&newest, missed, is_layer, &mut responses, &mut size_hint) {
                return;
            }
            self.last_seq = newest.seq;
        }
    }

    /// Writes one frame, `missed` frames after the previous one written;
    /// `false` once the file is gone.
    fn emit(
        &self,
        frame: &Copied,
        missed: u64,
        is_layer: bool,
        responses: &mut Vec<u16>,
        size_hint: &mut usize,
    ) -> bool {
        let stamp = wall(frame.acquired_ns, self.clock_offset_ns);
        let published = wall(frame.published_ns, self.clock_offset_ns);
        if is_layer {
            responses.clear();
            responses.extend(frame.bytes.chunks_exact(2).map(|b| u16::from_ne_bytes([b[0], b[1]])));
        }
        let message = SkinFrameRef {
            stamp: Time::from_ns(stamp),
            published: Time::from_ns(published),
            seq: frame.seq,
            status: frame.status.0,
            skipped: missed,
            responses: if is_layer { responses } else { &[] },
            payload: if is_layer { &[] } else { &frame.bytes },
        };
        let data = match msgs::encode(&message, *size_hint) {
            Ok(data) => data,
            Err(e) => {
                self.shared.fail(e);
                return false;
            }
        };
        *size_hint = data.len();
        if frame.status.contains(FrameStatus::FAULT) {
            self.counters.faulted.fetch_add(1, Ordering::Relaxed);
        }
        if missed > 0 {
            self.counters.lost.fetch_add(missed, Ordering::Relaxed);
            self.counters.gaps.fetch_add(1, Ordering::Relaxed);
            let gap = Gap {
                stamp: Time::from_ns(stamp),
                channel: self.name.clone(),
                first_seq: frame.seq - missed,
                count: missed,
            };
            if let Ok(data) = msgs::encode(&gap, 64) {
                let item =
                    Item { channel_id: self.gap_channel, sequence: 0, log_time: stamp, publish_time: published, data };
                if self.sender.send(item).is_err() {
                    return false;
                }
            }
        }
        let item = Item {
            channel_id: self.channel_id,
            sequence: frame.seq as u32,
            log_time: stamp,
            publish_time: published,
            data,
        };
        if self.sender.send(item).is_err() {
            return false;
        }
        self.counters.frames.fetch_add(1, Ordering::Relaxed);
        self.counters.latency_ns.fetch_add(frame.published_ns.saturating_sub(frame.acquired_ns), Ordering::Relaxed);
        true
    }
}

/// The map image and the statistics, from readers of its own.
struct Watcher {
    skin: String,
    dir: PathBuf,
    geometry: Option<SkinGeometry>,
    map: Option<(u16, HeatMap)>,
    map_hz: f64,
    channels: Vec<(String, ChannelKind, Arc<Counters>)>,
    stats_channels: Vec<u16>,
    clock_offset_ns: i64,
    sender: SyncSender<Item>,
    shared: Arc<Shared>,
}

impl Watcher {
    fn run(mut self) {
        let options = ReaderOptions { dir: Some(self.dir.clone()), allow_gone: true, ..ReaderOptions::default() };
        // The map needs every layer of the geometry, recorded or not; the statistics every recorded layer.
        let layer_names: Vec<String> = match &self.geometry {
            Some(g) => g.layers.iter().map(|l| l.name.clone()).collect(),
            None => self.channels.iter().filter(|c| c.1 == ChannelKind::Layer).map(|c| c.0.clone()).collect(),
        };
        let mut readers: Vec<Option<Reader>> =
            layer_names.iter().map(|name| Reader::open_with(&self.skin, name, &options).ok()).collect();
        let mut newest: Vec<Option<(Vec<u16>, LayerLook)>> = vec![None; layer_names.len()];
        let hz = if self.map.is_some() { self.map_hz.clamp(0.1, 60.0) } else { 1.0 };
        let mut ticker = Ticker::from_hz(hz);
        let mut last_stats = Instant::now();
        let mut previous: Vec<(u64, u64)> = self.channels.iter().map(|_| (0, 0)).collect();
        while ticker.wait(&self.shared.stop).is_some() {
            for ((reader, slot), name) in readers.iter_mut().zip(&mut newest).zip(&layer_names) {
                if reader.is_none() {
                    *reader = Reader::open_with(&self.skin, name, &options).ok();
                }
                let Some(reader) = reader else { continue };
                let state = reader.writer_state();
                match reader.latest() {
                    Ok(frame) => {
                        let look = match state {
                            WriterState::Gone => LayerLook::Gone,
                            WriterState::Faulted => LayerLook::Faulted,
                            _ if frame.status().contains(FrameStatus::FAULT) => LayerLook::Faulted,
                            _ => LayerLook::Live,
                        };
                        let values: Vec<u16> =
                            frame.bytes().chunks_exact(2).map(|b| u16::from_ne_bytes([b[0], b[1]])).collect();
                        *slot = Some((values, look));
                    }
                    Err(_) => {
                        if let Some((_, look)) = slot {
                            *look = LayerLook::Gone;
                        }
                    }
                }
            }
            let now_ns = wall(skinware::os::monotonic_ns(), self.clock_offset_ns);
            if let Some((channel_id, heat)) = &mut self.map {
                let layers: Vec<(Option<&[u16]>, LayerLook)> = newest
                    .iter()
                    .map(|n| match n {
                        Some((values, look)) => (Some(values.as_slice()), *look),
                        None => (None, LayerLook::Gone),
                    })
                    .collect();
                let pixels = heat.render(&layers);
                let (width, height) = heat.dimensions();
                let image = Image {
                    header: Header { stamp: Time::from_ns(now_ns), frame_id: format!("skin/{}/map", self.skin) },
                    height,
                    width,
                    encoding: "rgb8".into(),
                    is_bigendian: 0,
                    step: 3 * width,
                    data: pixels,
                };
                if let Ok(data) = msgs::encode(&image, image.data.len() + 64) {
                    let item =
                        Item { channel_id: *channel_id, sequence: 0, log_time: now_ns, publish_time: now_ns, data };
                    if self.sender.send(item).is_err() {
                        break;
                    }
                    self.shared.images.fetch_add(1, Ordering::Relaxed);
                }
            }
            let elapsed = last_stats.elapsed();
            if elapsed >= STATS_INTERVAL {
                last_stats = Instant::now();
                for (k, (name, _, counters)) in self.channels.iter().enumerate() {
                    let frames = counters.frames.load(Ordering::Relaxed);
                    let latency = counters.latency_ns.load(Ordering::Relaxed);
                    let (frames_before, latency_before) = previous[k];
                    previous[k] = (frames, latency);
                    let new_frames = frames - frames_before;
                    let (min, max, mean) = layer_names
                        .iter()
                        .position(|l| l == name)
                        .and_then(|l| newest[l].as_ref())
                        .filter(|(values, _)| !values.is_empty())
                        .map_or((0, 0, 0.0), |(values, _)| {
                            let sum: u64 = values.iter().map(|&v| u64::from(v)).sum();
                            (
                                *values.iter().min().unwrap_or(&0),
                                *values.iter().max().unwrap_or(&0),
                                sum as f64 / values.len() as f64,
                            )
                        });
                    let stats = LayerStats {
                        stamp: Time::from_ns(now_ns),
                        channel: name.clone(),
                        state: state_of(counters.state.load(Ordering::Relaxed)).as_str().to_owned(),
                        frames,
                        lost: counters.lost.load(Ordering::Relaxed),
                        faulted: counters.faulted.load(Ordering::Relaxed),
                        rate_hz: new_frames as f64 / elapsed.as_secs_f64(),
                        latency_ms: if new_frames == 0 {
                            0.0
                        } else {
                            (latency - latency_before) as f64 / new_frames as f64 / 1e6
                        },
                        min_response: min,
                        max_response: max,
                        mean_response: mean,
                    };
                    if let Ok(data) = msgs::encode(&stats, 128) {
                        let item = Item {
                            channel_id: self.stats_channels[k],
                            sequence: 0,
                            log_time: now_ns,
                            publish_time: now_ns,
                            data,
                        };
                        if self.sender.send(item).is_err() {
                            return;
                        }
                    }
                }
            }
        }
    }
}

/// The writer thread's job: owns the file.
struct FileJob {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    /// The same file, to sync what was flushed.
    sync: File,
    receiver: Receiver<Item>,
    flush_interval: Duration,
    shared: Arc<Shared>,
    channels: Vec<(String, ChannelKind, Arc<Counters>)>,
}

impl FileJob {
    fn run(mut self) -> Result<(), RecordError> {
        let result = self.write_all();
        if let Err(e) = result {
            // Unblock the readers: they stop on the signal, and their sends fail once the receiver is gone.
            self.shared.fail(e);
            drop(self.receiver);
            // A file that could not be written is not finished: that would
            // write more into a full or failing disk. What it holds is
            // readable up to its last complete chunk.
            drop(self.writer.into_inner());
            return Ok(());
        }
        self.finish()
    }

    fn write_all(&mut self) -> Result<(), RecordError> {
        let mut next_flush = Instant::now() + self.flush_interval;
        loop {
            let wait = next_flush.saturating_duration_since(Instant::now());
            match self.receiver.recv_timeout(wait) {
                Ok(item) => {
                    let header = MessageHeader {
                        channel_id: item.channel_id,
                        sequence: item.sequence,
                        log_time: item.log_time,
                        publish_time: item.publish_time,
                    };
                    self.writer
                        .write_to_known_channel(&header, &item.data)
                        .map_err(|e| mcap_write_error(&self.path, e))?;
                    self.shared.message_bytes.fetch_add(item.data.len() as u64, Ordering::Relaxed);
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => return Ok(()),
            }
            if Instant::now() >= next_flush {
                // A finished chunk, on disk: what a killed recorder (or a
                // machine that loses power) leaves is readable up to here.
                self.writer.flush().map_err(|e| mcap_write_error(&self.path, e))?;
                self.sync.sync_data().map_err(|source| RecordError::Io {
                    op: "sync",
                    path: self.path.clone(),
                    hint: write_hint(&source),
                    source,
                })?;
                next_flush = Instant::now() + self.flush_interval;
            }
        }
    }

    fn finish(mut self) -> Result<(), RecordError> {
        let mut summary = BTreeMap::new();
        for (name, kind, counters) in &self.channels {
            let r = report(*kind, counters);
            summary.insert(
                name.clone(),
                format!("kind={} frames={} lost={} gaps={} faulted={}", r.kind, r.frames, r.lost, r.gaps, r.faulted),
            );
        }
        let write = |e| mcap_write_error(&self.path, e);
        self.writer.write_metadata(&Metadata { name: SUMMARY_METADATA.into(), metadata: summary }).map_err(write)?;
        self.writer.finish().map_err(write)?;
        let path = self.path.clone();
        crate::file::close(self.writer.into_inner(), &path)
    }
}
