//! `skin replay`: a recording back into live channels, at its recorded times.
//!
//! The channels are created anew with the recorded names, frame sizes,
//! descriptions and schemas, and the recorded geometry is published, so that
//! readers, services and the viewer find what they found on the live skin.
//! Each frame is published at its recorded publication time (scaled by the
//! speed) with its recorded payload and status, and an acquisition time as far
//! before that as it was when recorded. Sequence numbers are the replay
//! writers' own: they start at 1, as those of a skin just started do.

use std::cmp::Reverse;
use std::collections::{BTreeMap, BinaryHeap};
use std::path::{Path, PathBuf};
use std::time::Duration;

use mcap::records::Record;
use serde::Serialize;
use skinware::rt::{RtOptions, Stop};
use skinware::{Access, ChannelKind, FrameStatus, LayerTopology, Writer, WriterOptions, WriterState};
use skinware_geometry::SkinGeometry;
use skinware_ros2::SkinFrame;

use crate::RecordError;
use crate::file::{RawMessage, RecordStream, RecordedChannel, RecordingHeader, read_header};

/// How far ahead of publication the file is read, to put frames from different
/// channels (queued by different recorder threads) back in time order.
const REORDER_WINDOW_NS: u64 = 250_000_000;

/// What the replay does after the last frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AtEnd {
    /// Stop, and remove the channels.
    #[default]
    Exit,
    /// Keep the channels, paused, with their last frames, until stopped.
    Hold,
    /// Start again from the first frame.
    Loop,
}

/// How to replay.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    /// Publish under this skin name instead of the recorded one.
    pub skin: Option<String>,
    /// Playback speed: 2 plays twice as fast.
    pub speed: f64,
    /// After the last frame.
    pub at_end: AtEnd,
    /// Start this many seconds after the first frame.
    pub from_s: Option<f64>,
    /// Stop this many seconds after the first frame.
    pub to_s: Option<f64>,
    /// Replay the recorded services too (else only the layers, for live services to read).
    pub services: bool,
    /// Publish the recorded geometry (else whoever runs the replay publishes one).
    pub publish_geometry: bool,
    /// Wait this long after creating the channels before the first frame, so
    /// that readers started alongside catch it.
    pub start_delay: Duration,
    /// Who may read the channels.
    pub access: Access,
    /// Segment directory; `None` for the default.
    pub dir: Option<PathBuf>,
    /// Real-time settings of the publishing thread.
    pub rt: RtOptions,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            skin: None,
            speed: 1.0,
            at_end: AtEnd::Exit,
            from_s: None,
            to_s: None,
            services: true,
            publish_geometry: true,
            start_delay: Duration::ZERO,
            access: Access::Owner,
            dir: None,
            rt: RtOptions::default(),
        }
    }
}

/// What a replay did.
#[derive(Clone, Debug, Default, Serialize)]
pub struct ReplayReport {
    /// Frames published.
    pub frames: u64,
    /// Frames published per channel.
    pub channels: BTreeMap<String, u64>,
    /// Passes over the recording.
    pub passes: u64,
    /// How late each frame was published after its scheduled time: p50, ns.
    pub late_p50_ns: u64,
    /// p99, ns.
    pub late_p99_ns: u64,
    /// Worst, ns.
    pub late_max_ns: u64,
    /// p99.9, ns.
    pub late_p999_ns: u64,
    /// Mean, ns.
    pub late_mean_ns: f64,
    /// Standard deviation, ns.
    pub late_std_ns: f64,
    /// Replay time, seconds.
    pub seconds: f64,
}

/// Lateness of each frame after its schedule, in 1 µs buckets up to
/// [`LATENESS_BUCKETS`] µs: a fixed size, however long the replay loops, and
/// allocated (and its pages touched) before the first frame, so that the
/// publishing thread neither allocates nor faults to record a sample.
struct Lateness {
    /// Bucket `i` counts lateness in `[i, i+1)` µs; the last, anything longer.
    counts: Vec<u64>,
    samples: u64,
    max_ns: u64,
    sum_ns: f64,
    sum_squares_ns: f64,
}

/// 1 µs buckets: 10 ms of lateness, then one overflow bucket.
const LATENESS_BUCKETS: usize = 10_000;

impl Lateness {
    fn new() -> Lateness {
        let mut counts = vec![0u64; LATENESS_BUCKETS + 1];
        // Zeroed memory may be mapped lazily: a write to each page maps it here.
        for count in counts.iter_mut().step_by(512) {
            *count = std::hint::black_box(0);
        }
        Lateness { counts, samples: 0, max_ns: 0, sum_ns: 0.0, sum_squares_ns: 0.0 }
    }

    fn add(&mut self, ns: u64) {
        let bucket = usize::try_from(ns / 1000).unwrap_or(usize::MAX).min(LATENESS_BUCKETS);
        self.counts[bucket] += 1;
        self.samples += 1;
        self.max_ns = self.max_ns.max(ns);
        self.sum_ns += ns as f64;
        self.sum_squares_ns += (ns as f64) * (ns as f64);
    }

    /// The upper edge of the 1 µs bucket holding the `q`-quantile, ns (the
    /// worst sample's for a quantile beyond the buckets).
    fn quantile_ns(&self, q: f64) -> u64 {
        let rank = ((q * self.samples as f64).ceil() as u64).clamp(1, self.samples.max(1));
        let mut seen = 0;
        for (bucket, &count) in self.counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return if bucket == LATENESS_BUCKETS { self.max_ns } else { (bucket as u64 + 1) * 1000 };
            }
        }
        0
    }

    fn fill(&self, report: &mut ReplayReport) {
        if self.samples == 0 {
            return;
        }
        report.late_p50_ns = self.quantile_ns(0.5);
        report.late_p99_ns = self.quantile_ns(0.99);
        report.late_p999_ns = self.quantile_ns(0.999);
        report.late_max_ns = self.max_ns;
        let n = self.samples as f64;
        report.late_mean_ns = self.sum_ns / n;
        report.late_std_ns = (self.sum_squares_ns / n - report.late_mean_ns.powi(2)).max(0.0).sqrt();
    }
}

struct Target {
    recorded: RecordedChannel,
    writer: Writer,
    state: WriterState,
    /// Frames published, over all passes.
    published: u64,
}

/// The files of the recording at `path`, in order: `path` itself if
/// something is there; otherwise, if `skin record --split-*` wrote it in
/// parts, its parts from `_000` on ([`crate::part_path`]), as many as follow
/// one another; otherwise `path` (whose open then says it is missing).
pub fn recording_parts(path: &Path) -> Vec<PathBuf> {
    let here = |path: &Path| std::fs::symlink_metadata(path).is_ok();
    if here(path) || !here(&crate::part_path(path, 0)) {
        return vec![path.to_owned()];
    }
    let parts: Vec<PathBuf> = (0..).map(|index| crate::part_path(path, index)).take_while(|part| here(part)).collect();
    let missing = crate::part_path(path, parts.len());
    if let Some(later) =
        (parts.len() + 1..parts.len() + 100).map(|index| crate::part_path(path, index)).find(|p| here(p))
    {
        tracing::warn!(
            missing = %missing.display(),
            found = %later.display(),
            "a part of the recording is missing: replaying the parts before it only (name the parts to replay the others)"
        );
    }
    parts
}

/// A recording being replayed.
pub struct Replay {
    /// Its files in order: one, or the parts of a split recording.
    parts: Vec<PathBuf>,
    options: ReplayOptions,
    header: RecordingHeader,
    skin: String,
    targets: BTreeMap<u16, Target>,
    geometry: Option<PathBuf>,
    stop: Stop,
}

impl Replay {
    /// Reads the recording's header, creates its channels and publishes its
    /// geometry. A recording split into parts (`run.mcap` written as
    /// `run_000.mcap`, `run_001.mcap`, ...) is replayed whole when `path`
    /// is the name it was recorded under ([`recording_parts`]).
    pub fn open(path: &Path, options: ReplayOptions) -> Result<Replay, RecordError> {
        Replay::open_parts(&recording_parts(path), options)
    }

    /// [`open`](Self::open) of a recording in several files, `parts`, played
    /// one after the other as one recording: the parts of a split
    /// recording, in order. The first part's header (channels, geometry)
    /// is the recording's; every later part must record the same channels,
    /// which is checked as the replay reaches it.
    pub fn open_parts(parts: &[PathBuf], options: ReplayOptions) -> Result<Replay, RecordError> {
        let Some(path) = parts.first() else {
            return Err(RecordError::Mismatch { context: "no recording to replay: give at least one file".into() });
        };
        let path = path.as_path();
        if !(options.speed.is_finite() && options.speed > 0.0) {
            return Err(RecordError::Mismatch {
                context: format!("speed {} must be a positive number", options.speed),
            });
        }
        if let (Some(from), Some(to)) = (options.from_s, options.to_s)
            && to <= from
        {
            return Err(RecordError::Mismatch { context: format!("--to {to} must be after --from {from}") });
        }
        let mut stream = RecordStream::open(path)?;
        let (header, _) = read_header(&mut stream)?;
        let skin = options.skin.clone().unwrap_or_else(|| header.skin.clone());
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        let mut targets = BTreeMap::new();
        for (id, recorded) in &header.channels {
            if recorded.kind == ChannelKind::Service && !options.services {
                continue;
            }
            let writer_options = WriterOptions {
                slots: recorded.slots.clamp(skinware::MIN_SLOTS, skinware::MAX_SLOTS),
                period: (recorded.period_ns > 0).then(|| Duration::from_nanos(recorded.period_ns)),
                kind: recorded.kind,
                schema_name: recorded.schema.0.clone(),
                schema_version: recorded.schema.1,
                access: options.access,
                unlink_on_drop: true,
                dir: Some(dir.clone()),
                reader_wake: skinware::ReaderWake::default(),
            };
            let writer = Writer::create(
                &skin,
                &recorded.channel,
                recorded.payload_bytes,
                &recorded.description,
                &writer_options,
            )?;
            targets
                .insert(*id, Target { recorded: recorded.clone(), writer, state: WriterState::Running, published: 0 });
        }
        if targets.is_empty() {
            let services = header.channels.values().filter(|c| c.kind == ChannelKind::Service).count();
            if services > 0 {
                return Err(RecordError::Mismatch {
                    context: format!(
                        "{} records only services ({services}) and no layer; replay them too: drop --no-services \
                         (or set `services = true` in a replay driver)",
                        path.display()
                    ),
                });
            }
            return Err(RecordError::NotARecording { path: path.to_owned(), reason: "it records no channel".into() });
        }
        let mut published = None;
        if options.publish_geometry
            && let Some(bytes) = &header.geometry
        {
            let mut geometry = SkinGeometry::decode(bytes).map_err(RecordError::BadGeometry)?;
            geometry.skin = skin.clone();
            let at = geometry.publish(&dir).map_err(RecordError::PublishGeometry)?;
            published = Some(at);
        }
        Ok(Replay { parts: parts.to_vec(), options, header, skin, targets, geometry: published, stop: Stop::new() })
    }

    /// The skin being replayed into.
    pub fn skin(&self) -> &str {
        &self.skin
    }

    /// The recorded skin's name.
    pub fn recorded_skin(&self) -> &str {
        &self.header.skin
    }

    /// The replayed layers' topologies.
    pub fn layers(&self) -> Vec<LayerTopology> {
        self.targets
            .values()
            .filter(|t| t.recorded.kind == ChannelKind::Layer)
            .filter_map(|t| LayerTopology::decode(&t.recorded.description, &t.recorded.channel).ok())
            .collect()
    }

    /// The names of the channels replayed.
    pub fn channels(&self) -> Vec<String> {
        self.targets.values().map(|t| t.recorded.channel.clone()).collect()
    }

    /// The signal that stops the replay.
    pub fn stop_signal(&self) -> &Stop {
        &self.stop
    }

    /// Publishes the frames at their times until the end (see [`AtEnd`]) or the stop signal.
    pub fn run(&mut self) -> Result<ReplayReport, RecordError> {
        for refusal in self.options.rt.apply() {
            tracing::warn!("{refusal}");
        }
        let started = skinware::os::monotonic_ns();
        let mut report = ReplayReport::default();
        // Reserved, so that the publishing thread does not reallocate it mid-pass.
        let mut lateness = Lateness::new();
        let mut pass_start = started + self.options.start_delay.as_nanos() as u64;
        let mut result = Ok(());
        while !self.stop.is_stopped() {
            report.passes += 1;
            match self.pass(pass_start, &mut report, &mut lateness) {
                Ok(Some(end)) if self.options.at_end == AtEnd::Loop && report.frames > 0 => {
                    // The next pass starts one typical period after this one's last frame.
                    pass_start = end + self.typical_period_ns();
                }
                Ok(_) => break,
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        if result.is_ok() && self.options.at_end == AtEnd::Hold {
            for target in self.targets.values() {
                target.writer.set_state(WriterState::Paused);
            }
            while self.stop.sleep_until(u64::MAX) {}
        }
        report.channels =
            self.targets.values().map(|t| (t.recorded.channel.clone(), t.published)).filter(|c| c.1 > 0).collect();
        lateness.fill(&mut report);
        report.seconds = (skinware::os::monotonic_ns() - started) as f64 / 1e9;
        result.map(|()| report)
    }

    /// Starts the thread that loads the file ahead of [`pass`](Self::pass).
    fn start_loader(
        &self,
        sender: std::sync::mpsc::SyncSender<Result<Due, RecordError>>,
        recycled: std::sync::mpsc::Receiver<Vec<u8>>,
    ) -> Result<std::thread::JoinHandle<()>, RecordError> {
        let loader = Loader {
            parts: self.parts.clone(),
            sizes: self
                .targets
                .iter()
                .map(|(id, t)| (*id, (t.recorded.channel.clone(), t.recorded.payload_bytes)))
                .collect(),
            from_ns: self.options.from_s.map(|s| (s * 1e9) as u64),
            to_ns: self.options.to_s.map(|s| (s * 1e9) as u64),
            stop: self.stop.clone(),
            recycled,
        };
        std::thread::Builder::new()
            .name("replay-load".into())
            .spawn(move || loader.run(sender))
            .map_err(|source| RecordError::Thread { thread: "the replay's loader thread".into(), source })
    }

    /// Publishes `due` into its channel, acquired `at` minus its recorded
    /// latency; `false` for a frame of a channel not replayed.
    fn publish_due(&mut self, due: &Due, at: u64) -> Result<bool, RecordError> {
        let Some(target) = self.targets.get_mut(&due.channel_id) else { return Ok(false) };
        let status = FrameStatus(due.status);
        let state = if status.contains(FrameStatus::FAULT) { WriterState::Faulted } else { WriterState::Running };
        if state != target.state {
            target.writer.set_state(state);
            target.state = state;
        }
        let mut out = target.writer.begin();
        out.write_bytes(0, &due.bytes)?;
        out.set_acquired_ns(at.saturating_sub(due.latency_ns));
        out.set_status(status);
        out.publish();
        target.published += 1;
        Ok(true)
    }

    fn typical_period_ns(&self) -> u64 {
        self.targets.values().map(|t| t.recorded.period_ns).filter(|&p| p > 0).min().unwrap_or(20_000_000)
    }

    /// One pass over the file, its first frame at `start_ns`; returns when its
    /// last frame was due, or `None` if stopped.
    ///
    /// A loader thread reads, decompresses and decodes the file ahead of time
    /// (a chunk takes milliseconds to decompress); this thread only sleeps until
    /// each frame is due and copies it into its channel. It neither allocates
    /// nor frees: each frame's buffer goes back to the loader, to be filled
    /// again or freed there. (Freeing a buffer that another thread allocated
    /// takes that thread's malloc arena lock, which the loader, in the normal
    /// scheduler, may hold while preempted.)
    fn pass(
        &mut self,
        start_ns: u64,
        report: &mut ReplayReport,
        lateness: &mut Lateness,
    ) -> Result<Option<u64>, RecordError> {
        let (sender, receiver) = std::sync::mpsc::sync_channel::<Result<Due, RecordError>>(LOAD_AHEAD);
        // Bounded, so its slots exist before the first frame: a send never allocates.
        let (recycle, recycled) = std::sync::mpsc::sync_channel::<Vec<u8>>(LOAD_AHEAD + 2);
        let loading = self.start_loader(sender, recycled)?;
        let speed = self.options.speed;
        let mut outcome = Ok(Some(start_ns));
        // The schedule starts when the first frame is ready (opening the file
        // and decompressing its first chunk take a while), not before.
        let mut start_ns = Some(start_ns);
        let mut origin = 0;
        for due in receiver.iter() {
            let due = match due {
                Ok(due) => due,
                Err(e) => {
                    outcome = Err(e);
                    break;
                }
            };
            if let Some(planned) = start_ns.take() {
                origin = planned.max(skinware::os::monotonic_ns());
            }
            let at = origin.saturating_add((due.offset_ns as f64 / speed) as u64);
            if at.saturating_sub(skinware::os::monotonic_ns()) > PAUSE_NS {
                // A pause in the recording: say so, rather than look hung.
                for target in self.targets.values_mut().filter(|t| t.state != WriterState::Paused) {
                    target.writer.set_state(WriterState::Paused);
                    target.state = WriterState::Paused;
                }
            }
            if !self.stop.sleep_until(at) {
                outcome = Ok(None);
                break;
            }
            if self.publish_due(&due, at)? {
                lateness.add(skinware::os::monotonic_ns().saturating_sub(at));
                report.frames += 1;
                outcome = Ok(Some(at));
            }
            // The loader takes the buffer back until the pass ends, and always
            // has room for it: it sent at most LOAD_AHEAD + 1 not yet returned.
            let _ = recycle.try_send(due.bytes);
        }
        // Unblocks a loader still sending, ends its wait for buffers to free, then waits for it.
        drop(receiver);
        drop(recycle);
        if loading.join().is_err() && outcome.is_ok() {
            return Err(RecordError::Mismatch {
                context: format!(
                    "reading {} failed (the loader thread panicked); replayed up to there",
                    self.parts[0].display()
                ),
            });
        }
        outcome
    }
}

/// A wait for the next frame longer than this marks the channels paused
/// until their next frames (a supervisor takes silent running writers for hung).
const PAUSE_NS: u64 = 500_000_000;

/// Frames decoded ahead of their publication.
const LOAD_AHEAD: usize = 1024;

/// A frame ready to publish.
struct Due {
    channel_id: u16,
    /// After the pass's first frame (before the speed is applied).
    offset_ns: u64,
    /// Its recorded publication latency.
    latency_ns: u64,
    status: u64,
    bytes: Vec<u8>,
}

/// Reads one pass's frames in publication order.
struct Loader {
    /// The recording's files, in order.
    parts: Vec<PathBuf>,
    /// Channel name and frame size, by MCAP channel id, of the channels replayed.
    sizes: BTreeMap<u16, (String, usize)>,
    from_ns: Option<u64>,
    to_ns: Option<u64>,
    stop: Stop,
    /// Buffers of frames published, to fill again.
    recycled: std::sync::mpsc::Receiver<Vec<u8>>,
}

impl Loader {
    fn run(self, sender: std::sync::mpsc::SyncSender<Result<Due, RecordError>>) {
        if let Err(e) = self.load(&sender) {
            let _ = sender.send(Err(e));
        }
        // The publisher sees the end of the pass only once this is gone.
        drop(sender);
        // The buffers of the last frames still come back: they are freed
        // here, not on the publishing thread, until it ends the pass.
        while self.recycled.recv().is_ok() {}
    }

    fn load(&self, sender: &std::sync::mpsc::SyncSender<Result<Due, RecordError>>) -> Result<(), RecordError> {
        // Publication time, file order, channel id, acquisition time, part, CDR bytes.
        type Pending = Reverse<(u64, u64, u16, u64, usize, Vec<u8>)>;
        let mut pending: BinaryHeap<Pending> = BinaryHeap::new();
        let mut order = 0u64;
        let mut push = |pending: &mut BinaryHeap<_>, part, header: mcap::records::MessageHeader, data: Vec<u8>| {
            order += 1;
            pending.push(Reverse((header.publish_time, order, header.channel_id, header.log_time, part, data)));
        };
        let mut part = 0;
        let (mut stream, first) = self.open_part(part)?;
        if let Some((header, data)) = first
            && self.sizes.contains_key(&header.channel_id)
        {
            push(&mut pending, part, header, data);
        }
        let (mut newest_read, mut exhausted, mut sent) = (0u64, false, 0u64);
        let mut base: Option<u64> = None;
        while !self.stop.is_stopped() {
            while !exhausted
                && pending.peek().is_none_or(|Reverse(top)| newest_read < top.0.saturating_add(REORDER_WINDOW_NS))
            {
                let end_of_part = match stream.next_record() {
                    Ok(Some(Record::Message { header, data })) if self.sizes.contains_key(&header.channel_id) => {
                        newest_read = newest_read.max(header.publish_time);
                        push(&mut pending, part, header, data.into_owned());
                        false
                    }
                    Ok(Some(_)) => false,
                    Ok(None) => true,
                    // A damaged tail is where the part ends (a recorder
                    // killed while writing it): on to the next, if any.
                    Err(e) if sent > 0 || part > 0 => {
                        tracing::warn!(error = %e, "the recording is damaged here; replaying what came before");
                        true
                    }
                    Err(e) => return Err(e),
                };
                if end_of_part {
                    match self.next_part(&mut part)? {
                        None => exhausted = true,
                        Some((next, first)) => {
                            stream = next;
                            if let Some((header, data)) = first
                                && self.sizes.contains_key(&header.channel_id)
                            {
                                newest_read = newest_read.max(header.publish_time);
                                push(&mut pending, part, header, data);
                            }
                        }
                    }
                }
            }
            let Some(Reverse((publish_time, _, channel_id, log_time, from_part, data))) = pending.pop() else {
                return Ok(());
            };
            let since_first = publish_time.saturating_sub(*base.get_or_insert(publish_time));
            if self.from_ns.is_some_and(|from| since_first < from) {
                continue;
            }
            if self.to_ns.is_some_and(|to| since_first > to) {
                return Ok(());
            }
            let offset_ns = since_first - self.from_ns.unwrap_or(0);
            let latency_ns = publish_time.saturating_sub(log_time);
            let due = self.decode(&self.parts[from_part], channel_id, offset_ns, latency_ns, &data)?;
            if sender.send(Ok(due)).is_err() {
                return Ok(());
            }
            sent += 1;
        }
        Ok(())
    }
}

/// A part of the recording, open after its header, and its first message.
type OpenedPart = (RecordStream<std::fs::File>, Option<RawMessage>);

impl Loader {
    /// The frame of channel `channel_id` recorded in `data` (CDR, from the
    /// file at `path`), due `offset_ns` into the replay.
    fn decode(
        &self,
        path: &Path,
        channel_id: u16,
        offset_ns: u64,
        latency_ns: u64,
        data: &[u8],
    ) -> Result<Due, RecordError> {
        let (channel, size) = &self.sizes[&channel_id];
        let frame: SkinFrame = skinware_ros2::decode(data, skinware_ros2::SKIN_FRAME)
            .map_err(|source| RecordError::BadFrame { path: path.to_owned(), channel: channel.clone(), source })?;
        let mut bytes = self.recycled.try_recv().unwrap_or_default();
        frame.channel_bytes_into(&mut bytes);
        if bytes.len() != *size {
            return Err(RecordError::Mismatch {
                context: format!(
                    "{}: a frame of channel {channel} holds {} bytes, but the channel's frames are {size} bytes: \
                     the recording is corrupt",
                    path.display(),
                    bytes.len()
                ),
            });
        }
        Ok(Due { channel_id, offset_ns, latency_ns, status: frame.status, bytes })
    }

    /// Opens the part after `part` that can be read, moving `part` on to it;
    /// `None` after the last. A part that cannot be read at all (a recorder
    /// killed as it began the part leaves an empty or cut file) is passed
    /// over with a warning; one that records other channels stops the replay.
    fn next_part(&self, part: &mut usize) -> Result<Option<OpenedPart>, RecordError> {
        while *part + 1 < self.parts.len() {
            *part += 1;
            match self.open_part(*part) {
                Ok(opened) => return Ok(Some(opened)),
                Err(e @ RecordError::Mismatch { .. }) => return Err(e),
                Err(e) => tracing::warn!(
                    part = %self.parts[*part].display(),
                    error = %e,
                    "a part of the recording cannot be read; going on with the next"
                ),
            }
        }
        Ok(None)
    }

    /// Opens part `index` and reads its header; a part after the first must
    /// record the replayed channels under the same ids, names and frame
    /// sizes as the first (it is the same recording going on).
    fn open_part(&self, index: usize) -> Result<OpenedPart, RecordError> {
        let path = &self.parts[index];
        let mut stream = RecordStream::open(path)?;
        let (header, first) = read_header(&mut stream)?;
        if index > 0 {
            for (id, (channel, size)) in &self.sizes {
                let same = header.channels.get(id).is_some_and(|c| &c.channel == channel && c.payload_bytes == *size);
                if !same {
                    return Err(RecordError::Mismatch {
                        context: format!(
                            "{} does not go on from {}: it does not record channel {channel} ({size}-byte frames) \
                             as channel id {id}; give the parts of one recording, in order",
                            path.display(),
                            self.parts[0].display()
                        ),
                    });
                }
            }
        }
        Ok((stream, first))
    }
}

impl Drop for Replay {
    fn drop(&mut self) {
        if let Some(path) = &self.geometry {
            let _ = std::fs::remove_file(path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lateness_quantiles_are_the_upper_edges_of_microsecond_buckets() {
        let mut lateness = Lateness::new();
        // 1..=1000 µs, each once, and one sample past the buckets.
        for us in 1..=1000u64 {
            lateness.add(us * 1000 - 1);
        }
        lateness.add(25_000_000);
        let mut report = ReplayReport::default();
        lateness.fill(&mut report);
        assert_eq!(report.late_p50_ns, 501_000);
        assert_eq!(report.late_p99_ns, 991_000);
        assert_eq!(report.late_p999_ns, 1_000_000);
        assert_eq!(report.late_max_ns, 25_000_000);
        let mean = (500_500_000.0 - 1000.0 + 25_000_000.0) / 1001.0;
        assert!((report.late_mean_ns - mean).abs() < 1.0, "{}", report.late_mean_ns);
        // Past the buckets, a quantile is the worst sample.
        assert_eq!(lateness.quantile_ns(1.0), 25_000_000);
    }
}
