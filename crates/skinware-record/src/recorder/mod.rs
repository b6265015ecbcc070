//! `skin record`: every frame of the chosen channels into an MCAP file.
//!
//! One reader thread per channel reads as soon as each frame is published and
//! encodes it; a writer thread owns the file. The reader threads hand frames
//! over through a bounded queue: if the disk cannot keep up, a reader thread
//! waits, its next read reports the frames it missed (`skipped`), and those
//! are counted and written as a gap. Nothing ever waits on the skin's writers.
//!
//! The pieces, in the order a recording runs them: `discovery` opens the
//! channels, `file_start` writes everything before the first frame,
//! `reading` runs the reader threads, `watcher` the map image and the
//! statistics (and, through `ros_view`, the messages for ROS tools), `file_writer` the file's thread, and `summary` holds what
//! they count.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use skinware::WriterState;
use skinware::rt::Stop;

use crate::RecordError;

mod discovery;
mod file_start;
mod file_writer;
mod queue;
mod reading;
mod ros_view;
mod summary;
mod watcher;

use discovery::Sources;
use file_start::Started;
use file_writer::FileJob;
use summary::Recorded;
pub use summary::{ChannelReport, Progress, RecordSummary};
use watcher::Watcher;

/// Bytes of messages the queue between the reader threads and the file may
/// hold before a reader waits: at the paper's skin at 1 kHz (about 100 MB/s
/// of messages) a third of a second of the disk or the compression falling
/// behind, and a bound on the recorder's memory whatever the skin.
const QUEUE_BYTES: usize = 32 << 20;
/// The queue's length in frames, whatever their size.
const QUEUE_FRAMES: std::ops::RangeInclusive<usize> = 256..=8192;
/// The reader threads' SCHED_FIFO priority unless told otherwise: above
/// every normal thread (the file's, applications), below the drivers' 80.
pub const DEFAULT_READER_PRIORITY: u8 = 20;
/// The file thread's nice value when the readers are real-time: it writes
/// and compresses (zstd takes about half a core at 100 MB/s of messages),
/// and beside busy programs of nice 0 (a browser, a compiler) it got too
/// little of a core to keep up. -10 weighs about 9 times a nice-0 thread.
/// SCHED_FIFO below the readers was tried, and lost more frames
/// (`docs/bench/record.md`, "The queue that spun").
const FILE_THREAD_NICE: i32 = -10;
/// Uncompressed bytes per chunk, at most (a chunk is also finished every
/// flush interval). The MCAP writer keeps an index entry per chunk in memory
/// until the file's summary, about 650 bytes each: with 1 MiB chunks the
/// recorder grew 0.06 MiB/s (230 MB an hour) at the paper's skin at 1 kHz,
/// with 8 MiB chunks about 10 KB/s. The chunk is not held in memory: the
/// writer streams it to the file as it fills (it seeks back to its head at
/// the end), so its size costs no memory.
const CHUNK_BYTES: u64 = 8 << 20;
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
    /// Its name, as `skin record --compression` takes it and the summary gives it.
    pub fn name(self) -> &'static str {
        match self {
            Compression::Zstd => "zstd",
            Compression::Lz4 => "lz4",
            Compression::None => "none",
        }
    }

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
    /// Point clouds and contact markers per second for ROS tools (0: none,
    /// and no diagnostics or `/tf_static` either); see `docs/recording.md`.
    pub ros2_hz: f64,
    /// The frame every link hangs from in `/tf_static`, and the frame of a
    /// contact whose link is unknown.
    pub root_frame: String,
    /// Chunk compression.
    pub compression: Compression,
    /// How often the current chunk is finished, written and synced to disk:
    /// at most this much is lost if the recorder is killed or the power fails.
    pub flush_interval: Duration,
    /// Segment directory; `None` for the default.
    pub dir: Option<PathBuf>,
    /// The command line, kept in the file's metadata.
    pub command: String,
    /// SCHED_FIFO priority of the reader threads (1 to 99; 0: the normal
    /// scheduler). Without the privilege they stay in the normal scheduler,
    /// with a warning. The file's thread, which compresses, never takes it:
    /// with real-time readers it runs at nice -10 instead (if allowed).
    pub reader_priority: u8,
    /// When to go on in a new file (`None`: one file).
    pub split: Option<Split>,
}

/// When a recording goes on in a new file. Each part is a whole MCAP file
/// of its own (schemas, channels, metadata, geometry, `/tf_static`,
/// summary and index), named after the recording's path with its number:
/// `run.mcap` is written as `run_000.mcap`, `run_001.mcap`, ... ([`part_path`]).
///
/// The MCAP writer keeps an index entry for every chunk in memory until it
/// writes the file's summary, at the file's end: about 650 bytes per chunk;
/// a single file's recorder grew 10-16 KB/s at the paper's skin at 1 kHz
/// (`docs/bench/record.md`). Parts bound that, and so the
/// recorder's memory, however long it records. A part is closed at the
/// first flush (every [`RecordOptions::flush_interval`]) after it reaches
/// either limit, so it may be up to a flush interval longer.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Split {
    /// Close a part once it holds this many bytes.
    pub max_bytes: Option<u64>,
    /// Close a part once it has recorded this long.
    pub max_duration: Option<Duration>,
}

impl Split {
    /// A limit to keep: at least one, and neither zero.
    fn check(&self) -> Result<(), RecordError> {
        let reason = match (self.max_bytes, self.max_duration) {
            (None, None) => "no limit is set: give a part's largest size, its longest duration, or both",
            (Some(0), _) => "a part of at most 0 bytes: give a size of 1 or more",
            (_, Some(duration)) if duration.is_zero() => "a part of at most 0 s: give a duration of 1 s or more",
            _ => return Ok(()),
        };
        Err(RecordError::Split { reason: reason.to_owned() })
    }

    /// Whether a part of `bytes` bytes started `elapsed` ago is complete.
    fn is_reached(&self, bytes: u64, elapsed: Duration) -> bool {
        self.max_bytes.is_some_and(|max| bytes >= max) || self.max_duration.is_some_and(|max| elapsed >= max)
    }
}

/// The path of part `index` of a split recording at `path`: `_` and the
/// number, three digits at least, before the extension (`run.mcap`, 2:
/// `run_002.mcap`): the first 1,000 parts sort in order by name, and
/// `ls -v` sorts any number.
pub fn part_path(path: &Path, index: usize) -> PathBuf {
    let mut name = path.file_stem().map(std::ffi::OsStr::to_os_string).unwrap_or_default();
    name.push(format!("_{index:03}"));
    if let Some(extension) = path.extension() {
        name.push(".");
        name.push(extension);
    }
    path.with_file_name(name)
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            skin: "default".into(),
            layers: None,
            services: ServiceChoice::None,
            map_hz: 4.0,
            map_width: 480,
            ros2_hz: 10.0,
            root_frame: "base_link".into(),
            compression: Compression::Zstd,
            flush_interval: Duration::from_secs(1),
            dir: None,
            command: String::new(),
            reader_priority: DEFAULT_READER_PRIORITY,
            split: None,
        }
    }
}

/// Adds the schema of ROS 2 message `name` (its ros2msg text) to `writer`.
fn add_schema<W: std::io::Write + std::io::Seek>(
    writer: &mut mcap::Writer<W>,
    name: &str,
) -> Result<u16, mcap::McapError> {
    let text = skinware_ros2::schema_text(name).unwrap_or_default();
    writer.add_schema(name, crate::SCHEMA_ENCODING, text.as_bytes())
}

/// What the writer thread writes.
struct Item {
    channel_id: u16,
    sequence: u32,
    log_time: u64,
    publish_time: u64,
    data: Vec<u8>,
}

/// What every thread of a recording shares.
struct Shared {
    stop: Stop,
    /// The first error that stopped the recording.
    failure: Mutex<Option<RecordError>>,
    message_bytes: AtomicU64,
    images: AtomicU64,
    /// The files written so far, the one being written last.
    parts: Mutex<Vec<PathBuf>>,
    /// The bytes of the parts already finished.
    finished_part_bytes: AtomicU64,
    /// Set by the first reader thread refused its real-time priority (one warning).
    priority_refused: AtomicBool,
}

impl Shared {
    fn fail(&self, error: RecordError) {
        let mut failure = skinware::lock(&self.failure);
        if failure.is_none() {
            *failure = Some(error);
        }
        self.stop.stop();
    }
}

/// A recording under way.
pub struct Recorder {
    /// Its first file.
    path: PathBuf,
    skin: String,
    compression: Compression,
    reader_priority: u8,
    queue_frames: usize,
    started: Instant,
    shared: Arc<Shared>,
    channels: Vec<Recorded>,
    readers: Vec<JoinHandle<()>>,
    writer: Option<JoinHandle<Result<(), RecordError>>>,
}

impl Recorder {
    /// Starts recording the chosen channels of `options.skin` into a new
    /// file `path`, or, split, into its parts ([`part_path`]).
    pub fn start(path: &Path, options: RecordOptions) -> Result<Recorder, RecordError> {
        if let Some(split) = options.split {
            split.check()?;
        }
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        let sources = discovery::open_sources(&dir, &options)?;
        let first = if options.split.is_some() { part_path(path, 0) } else { path.to_owned() };
        let file = crate::error::create_new(&first)?;
        let started = file_start::write_start(&first, &file, &options, &sources, (&dir, file_start::Part::First))?;
        Recorder::run(path, options, dir, sources, file, started)
    }

    /// Starts the threads on a file whose start is written.
    fn run(
        path: &Path,
        options: RecordOptions,
        dir: PathBuf,
        sources: Sources,
        file: std::fs::File,
        started: Started,
    ) -> Result<Recorder, RecordError> {
        let shared = Arc::new(Shared {
            stop: Stop::new(),
            failure: Mutex::new(None),
            message_bytes: AtomicU64::new(0),
            images: AtomicU64::new(0),
            parts: Mutex::new(Vec::new()),
            finished_part_bytes: AtomicU64::new(0),
            priority_refused: AtomicBool::new(false),
        });
        let first = if options.split.is_some() { part_path(path, 0) } else { path.to_owned() };
        skinware::lock(&shared.parts).push(first.clone());
        let parts = options.split.map(|split| file_writer::Parts {
            split,
            base: path.to_owned(),
            index: 0,
            started: Instant::now(),
            sources: sources.without_readers(),
            options: options.clone(),
            dir: dir.clone(),
            ids: file_start::ChannelIds::of(&started),
            clock_offset_ns: started.clock_offset_ns,
        });
        let channels: Vec<Recorded> = sources.readers.iter().map(Recorded::of).collect();
        let queue_frames = queue_frames(sources.readers.iter().map(skinware::Reader::payload_bytes));
        let (sender, receiver) = queue::bounded::<Item>(queue_frames);
        let mut threads =
            reading::start_readers(sources.readers, &channels, &started, &sender, &shared, options.reader_priority)?;
        let Started { writer, stats_channels, map, ros, clock_offset_ns, .. } = started;
        let watcher = Watcher {
            skin: options.skin.clone(),
            dir,
            geometry: sources.geometry,
            map,
            map_hz: options.map_hz,
            ros,
            ros2_hz: options.ros2_hz,
            channels: channels.clone(),
            stats_channels,
            clock_offset_ns,
            sender,
            shared: shared.clone(),
        };
        threads.push(spawn("rec-map", move || watcher.run())?);
        let file_job = FileJob {
            path: first.clone(),
            parts,
            writer,
            sync: file,
            receiver,
            flush_interval: options.flush_interval,
            shared: shared.clone(),
            channels: channels.clone(),
            nice: (options.reader_priority > 0).then_some(FILE_THREAD_NICE),
        };
        let writer = std::thread::Builder::new()
            .name("rec-file".into())
            .spawn(move || file_job.run())
            .map_err(|source| RecordError::Thread { thread: "the file-writing thread".into(), source })?;
        Ok(Recorder {
            path: first,
            skin: options.skin,
            compression: options.compression,
            reader_priority: options.reader_priority,
            queue_frames,
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
        self.channels.iter().all(|c| c.counters.state.load(Ordering::Relaxed) == WriterState::Gone.code())
    }

    /// How far the recording has got.
    pub fn progress(&self) -> Progress {
        Progress {
            seconds: self.started.elapsed().as_secs_f64(),
            frames: self.channels.iter().map(|c| c.counters.frames.load(Ordering::Relaxed)).sum(),
            lost: self.channels.iter().map(|c| c.counters.lost.load(Ordering::Relaxed)).sum(),
            message_bytes: self.shared.message_bytes.load(Ordering::Relaxed),
            file_bytes: self.shared.finished_part_bytes.load(Ordering::Relaxed)
                + skinware::lock(&self.shared.parts)
                    .last()
                    .and_then(|current| std::fs::metadata(current).ok())
                    .map_or(0, |m| m.len()),
        }
    }

    /// The files written so far, the one being written last: one unless
    /// the recording is split ([`RecordOptions::split`]).
    pub fn parts(&self) -> Vec<PathBuf> {
        skinware::lock(&self.shared.parts).clone()
    }

    /// Stops reading, writes what was read, finishes the file and says what it holds.
    /// After a failure (disk full), the error, with what the file keeps.
    pub fn finish(mut self) -> Result<RecordSummary, RecordError> {
        let written = self.shutdown();
        let seconds = self.started.elapsed().as_secs_f64();
        if let Some(error) = skinware::lock(&self.shared.failure).take() {
            return Err(error);
        }
        written?;
        let progress = self.progress();
        Ok(RecordSummary {
            path: self.path.clone(),
            parts: self.parts(),
            skin: self.skin.clone(),
            seconds,
            frames: progress.frames,
            lost: progress.lost,
            message_bytes: progress.message_bytes,
            file_bytes: progress.file_bytes,
            frames_per_s: progress.frames as f64 / seconds.max(1e-9),
            mb_per_s: progress.message_bytes as f64 / 1e6 / seconds.max(1e-9),
            images: self.shared.images.load(Ordering::Relaxed),
            channels: self.channels.iter().map(|c| (c.name.clone(), c.report())).collect(),
            compression: self.compression.name().to_owned(),
            reader_priority: self.reader_priority,
            readers_realtime: self.channels.iter().all(|c| c.counters.realtime.load(Ordering::Relaxed)),
            queue_frames: self.queue_frames,
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
            Some(Err(_)) => Err(RecordError::Panicked { thread: "the file-writing thread" }),
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

/// The queue's length for channels whose frames have these sizes: what
/// [`QUEUE_BYTES`] holds of their average frame, within [`QUEUE_FRAMES`].
fn queue_frames(frame_bytes: impl Iterator<Item = usize>) -> usize {
    let (count, total) = frame_bytes.fold((0usize, 0usize), |(n, sum), bytes| (n + 1, sum.saturating_add(bytes)));
    let average = (total / count.max(1)).max(1);
    (QUEUE_BYTES / average).clamp(*QUEUE_FRAMES.start(), *QUEUE_FRAMES.end())
}

fn spawn(name: &str, job: impl FnOnce() + Send + 'static) -> Result<JoinHandle<()>, RecordError> {
    std::thread::Builder::new()
        .name(name.chars().take(15).collect())
        .spawn(job)
        .map_err(|source| RecordError::Thread { thread: format!("thread {name}"), source })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_queue_holds_its_bytes_within_its_frame_bounds_whatever_the_sizes() {
        // The paper's skin at 1 kHz: 5 layers of about 12 KB, 3 service channels.
        let paper = [12_338, 12_340, 12_338, 12_340, 12_340, 3_024, 30_848, 560];
        let frames = queue_frames(paper.into_iter());
        assert!(frames * paper.iter().sum::<usize>() / paper.len() <= QUEUE_BYTES, "{frames}");
        assert!(frames > 2_000, "{frames}");
        // Tiny frames, no frames, and sizes a hostile writer claims.
        assert_eq!(queue_frames([8usize; 4].into_iter()), *QUEUE_FRAMES.end());
        assert_eq!(queue_frames(std::iter::empty()), *QUEUE_FRAMES.end());
        assert_eq!(queue_frames([usize::MAX, usize::MAX].into_iter()), *QUEUE_FRAMES.start());
    }
}
