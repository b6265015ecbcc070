//! The reader: attaches to a channel by name and obtains its newest frames,
//! periodically, as soon as they are published, or on request.

#![forbid(unsafe_code)]

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use crate::anticipate::Anticipation;
use crate::channel::ChannelKind;
use crate::channel::doorbell::{self, WaitEnd};
use crate::channel::layout;
use crate::channel::ring::{Meta, ReadFailure};
use crate::channel::segment::{self, Shared};
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::os::{self, SharedFutex};
use crate::rt::{Stop, Ticker};
use crate::shm;
use crate::stats::{ReaderStats, WriterState, WriterStats};
use crate::sync::Ordering;

/// How a reader attaches.
#[derive(Clone, Debug, Default)]
pub struct ReaderOptions {
    /// Attach even if the channel's writer is gone (to wait for its revival,
    /// or to inspect it). By default a gone writer is an error.
    pub allow_gone: bool,
    /// Require this payload schema (name, version).
    pub expect_schema: Option<(String, u32)>,
    /// Directory of the segments; `None` for [`shm::segment_dir`].
    pub dir: Option<PathBuf>,
    /// As-soon-as-available reads of a periodic writer: wake up this long
    /// before the next frame can be published (the earliest publication
    /// phase on the writer's grid, learnt from the frames read) and spin until
    /// it is, instead of sleeping on the futex until the writer wakes the
    /// reader. The wake-up then costs a timer expiry (what `cyclictest`
    /// measures) rather than a futex wake across CPUs, and the writer makes no
    /// wake syscall. The price is up to three times this much spinning per
    /// frame; a frame later than that is waited for on the futex as usual.
    /// `None` (the default) never spins.
    pub anticipate: Option<Duration>,
}

/// Consecutive laps after which a read gives up with [`Error::Lapped`]. With
/// K ≥ 2 buffers each lap means the writer published K-1 frames during one
/// copy, so this only trips for a reader that is practically stalled.
const MAX_READ_ATTEMPTS: u32 = 1000;

/// A reader of one channel. Its frames are private copies: nothing the reader
/// does, including dying in the middle of a read, affects the writer or other
/// readers. It maps the frames read-only.
pub struct Reader {
    shared: Arc<Shared>,
    buffer: Vec<u64>,
    last: Meta,
    stats: ReaderStats,
    stop: Stop,
    /// Where the channel lives, to follow it if it is re-created.
    skin: String,
    channel: String,
    dir: PathBuf,
    anticipation: Option<Anticipation>,
}

impl std::fmt::Debug for Reader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reader").field("channel", &self.shared.label).field("last_seq", &self.last.seq).finish()
    }
}

impl Reader {
    /// Attaches to `skin`/`channel`, whose writer must be alive.
    pub fn open(skin: &str, channel: &str) -> Result<Reader> {
        Reader::open_with(skin, channel, &ReaderOptions::default())
    }

    /// Attaches with options.
    pub fn open_with(skin: &str, channel: &str, options: &ReaderOptions) -> Result<Reader> {
        let dir = options.dir.clone().unwrap_or_else(shm::segment_dir);
        let shared = segment::open_segment(&dir, skin, channel, false)?;
        let header = shared.header();
        if !options.allow_gone {
            let alive = shared.writer_alive().map_err(|source| Error::Os {
                op: "lock query",
                path: shared.path.clone(),
                source,
            })?;
            if !alive || header.state.load(Ordering::Acquire) == WriterState::STOPPED {
                return Err(Error::WriterGone {
                    channel: shared.label.clone(),
                    pid: header.writer_pid.load(Ordering::Relaxed),
                });
            }
        }
        if let Some((expected, expected_version)) = &options.expect_schema {
            let found = layout::decode_schema(&header.schema_name);
            let found_version = header.schema_version.load(Ordering::Relaxed);
            if &found != expected || found_version != *expected_version {
                return Err(Error::SchemaMismatch {
                    channel: shared.label.clone(),
                    found,
                    found_version,
                    expected: expected.clone(),
                    expected_version: *expected_version,
                });
            }
        }
        let words = shared.ring().payload_words();
        let shared = Arc::new(shared);
        let stop = Stop::new();
        stop.watch(&shared);
        Ok(Reader {
            shared,
            buffer: vec![0; words],
            last: Meta::default(),
            stats: ReaderStats::default(),
            stop,
            skin: skin.to_owned(),
            channel: channel.to_owned(),
            dir,
            anticipation: options
                .anticipate
                .map(|d| Anticipation::new(d.as_nanos().min(u128::from(u64::MAX / 4)) as u64)),
        })
    }

    /// Follows the channel if its writer is gone and a new writer re-created
    /// it (a new segment under the same name, rather than a revival of this
    /// one) with the same frame size and kind. Returns whether it switched.
    /// Sequence numbers start again from 1 in a re-created channel.
    ///
    /// The blocking reads call this on their own when they time out; call it
    /// after [`latest`](Self::latest) keeps returning the same frame.
    pub fn follow_recreated(&mut self) -> bool {
        use std::os::unix::fs::MetadataExt;
        if self.shared.writer_alive().unwrap_or(true) {
            return false;
        }
        let ours = self.shared.file.metadata().ok().map(|m| (m.dev(), m.ino()));
        let current = std::fs::metadata(&self.shared.path).ok().map(|m| (m.dev(), m.ino()));
        if current.is_none() || current == ours {
            return false;
        }
        let Ok(replacement) = segment::open_segment(&self.dir, &self.skin, &self.channel, false) else {
            return false;
        };
        let same_shape = replacement.layout.payload_bytes == self.shared.layout.payload_bytes
            && replacement.kind == self.shared.kind
            && replacement
                .header()
                .schema_name
                .iter()
                .zip(&self.shared.header().schema_name)
                .all(|(a, b)| a.load(Ordering::Relaxed) == b.load(Ordering::Relaxed))
            && replacement.header().schema_version.load(Ordering::Relaxed)
                == self.shared.header().schema_version.load(Ordering::Relaxed)
            // A service's description says what each record is (its labels):
            // a typed reader must not read another's records with its old labels.
            && (replacement.kind != ChannelKind::Service || replacement.description() == self.shared.description());
        if !same_shape || !replacement.writer_alive().unwrap_or(false) {
            return false;
        }
        let replacement = Arc::new(replacement);
        self.stop.watch(&replacement);
        tracing::info!(channel = %replacement.label, "following the re-created channel");
        self.shared = replacement;
        self.last = Meta::default();
        true
    }

    /// `skin/channel`.
    pub fn label(&self) -> &str {
        &self.shared.label
    }

    /// The segment file.
    pub fn path(&self) -> &Path {
        &self.shared.path
    }

    /// What the channel carries.
    pub fn kind(&self) -> ChannelKind {
        self.shared.kind
    }

    /// Payload bytes of one frame.
    pub fn payload_bytes(&self) -> usize {
        self.shared.layout.payload_bytes as usize
    }

    /// Frame buffers in the channel (K).
    pub fn slots(&self) -> usize {
        self.shared.layout.slot_count as usize
    }

    /// The channel's static description (the topology, for a layer).
    pub fn description(&self) -> Vec<u8> {
        self.shared.description()
    }

    /// The layer topology published by the writer (for a layer channel).
    pub fn topology(&self) -> Result<crate::LayerTopology, crate::TopologyError> {
        crate::LayerTopology::decode(&self.shared.description(), &self.shared.label)
    }

    /// The payload schema (name, version).
    pub fn schema(&self) -> (String, u32) {
        let header = self.shared.header();
        (layout::decode_schema(&header.schema_name), header.schema_version.load(Ordering::Relaxed))
    }

    /// The writer's nominal period, or `None` for a sporadic writer.
    pub fn writer_period(&self) -> Option<Duration> {
        match self.shared.header().period_ns.load(Ordering::Relaxed) {
            0 => None,
            ns => Some(Duration::from_nanos(ns)),
        }
    }

    /// Whether the writer is running, paused, faulted or gone. One `fcntl`
    /// query; not part of reading frames.
    pub fn writer_state(&self) -> WriterState {
        self.shared.writer_state()
    }

    /// The process id of the current (or last) writer.
    pub fn writer_pid(&self) -> u32 {
        self.shared.header().writer_pid.load(Ordering::Relaxed)
    }

    /// How many writers have owned the channel (revivals add one each).
    pub fn writer_generation(&self) -> u64 {
        self.shared.header().generation.load(Ordering::Relaxed)
    }

    /// The writer's statistics.
    pub fn writer_stats(&self) -> WriterStats {
        WriterStats::load(&self.shared.header().stats)
    }

    /// This reader's statistics.
    pub fn stats(&self) -> &ReaderStats {
        &self.stats
    }

    /// Sequence number of the newest published frame, without reading it.
    pub fn published_seq(&self) -> u64 {
        self.shared.ring().published()
    }

    /// Makes `stop` interrupt this reader's blocking calls (in addition to its own).
    pub fn set_stop(&mut self, stop: &Stop) {
        stop.watch(&self.shared);
        self.stop = stop.clone();
    }

    /// The stop signal this reader's blocking calls watch.
    pub fn stop_signal(&self) -> &Stop {
        &self.stop
    }

    /// On request: the newest complete frame, now. Lock-free; never blocks.
    pub fn latest(&mut self) -> Result<Frame<'_>> {
        let started = os::monotonic_ns();
        match self.shared.ring().read_latest(&mut self.buffer, MAX_READ_ATTEMPTS) {
            Ok((meta, retries)) => {
                let fresh = meta.seq != self.last.seq;
                if let (true, Some(anticipation)) = (fresh, &mut self.anticipation) {
                    let period = self.shared.header().period_ns.load(Ordering::Relaxed);
                    anticipation.observe(meta.published_ns, period);
                }
                let skipped = if fresh && self.last.seq != 0 { meta.seq.saturating_sub(self.last.seq + 1) } else { 0 };
                self.stats.record(os::monotonic_ns() - started, retries, skipped);
                self.last = meta;
                Ok(self.frame(skipped, fresh))
            }
            Err(ReadFailure::Empty) => Err(Error::NoFrameYet { channel: self.shared.label.clone() }),
            Err(ReadFailure::Lapped(retries)) => {
                self.stats.retries += u64::from(retries);
                Err(Error::Lapped { channel: self.shared.label.clone(), retries, slots: self.slots() as u32 })
            }
        }
    }

    fn frame(&self, skipped: u64, fresh: bool) -> Frame<'_> {
        let bytes: &[u8] = bytemuck::cast_slice(&self.buffer);
        Frame { meta: self.last, skipped, fresh, payload: &bytes[..self.payload_bytes()] }
    }

    /// As soon as available: waits (asleep on a futex, no spinning) for a frame
    /// newer than the last one this reader obtained, then returns it.
    ///
    /// A writer that is gone when the timeout passes gives
    /// [`Error::WriterGone`] (a living, silent one [`Error::Timeout`]), never
    /// later than the timeout. A channel re-created meanwhile is followed
    /// within the same timeout.
    pub fn wait_newer(&mut self, timeout: Duration) -> Result<Frame<'_>> {
        let deadline = deadline_after(timeout);
        loop {
            match self.wait_beyond(self.last.seq, deadline, timeout) {
                Ok(()) => return self.latest(),
                // Followed: what the new channel already has counts, and
                // the wait goes on to the same deadline.
                Err(Error::Timeout { .. }) if self.follow_recreated() => {}
                Err(Error::Timeout { .. }) => return Err(self.timed_out(timeout)),
                Err(e) => return Err(e),
            }
        }
    }

    /// On request: asks for a frame newer than any published now and waits for
    /// it. A sporadic writer acquires one on the request; a periodic writer's
    /// next frame answers it. Timeouts and a gone writer as in
    /// [`wait_newer`](Self::wait_newer).
    pub fn request(&mut self, timeout: Duration) -> Result<Frame<'_>> {
        let deadline = deadline_after(timeout);
        loop {
            let after = self.published_seq();
            if self.writer_period().is_none() {
                doorbell::request(&self.shared.doorbell().requests, &SharedFutex);
            }
            match self.wait_beyond(after, deadline, timeout) {
                Ok(()) => return self.latest(),
                // Followed: what the new channel already has counts, and
                // the wait goes on to the same deadline.
                Err(Error::Timeout { .. }) if self.follow_recreated() => {}
                Err(Error::Timeout { .. }) => return Err(self.timed_out(timeout)),
                Err(e) => return Err(e),
            }
        }
    }

    /// The error for a wait that reached its timeout: the writer is gone, or
    /// merely silent.
    fn timed_out(&self, timeout: Duration) -> Error {
        if self.writer_state() == WriterState::Gone {
            Error::WriterGone { channel: self.shared.label.clone(), pid: self.writer_pid() }
        } else {
            Error::Timeout { channel: self.shared.label.clone(), timeout }
        }
    }

    /// Periodic: waits for the next tick of `ticker` (absolute time), then
    /// returns the newest frame, which may be the same as last time
    /// ([`Frame::is_fresh`] tells).
    pub fn next_periodic(&mut self, ticker: &mut Ticker) -> Result<Frame<'_>> {
        if ticker.wait(&self.stop).is_none() {
            return Err(Error::Stopped { channel: self.shared.label.clone() });
        }
        self.latest()
    }

    /// With [`ReaderOptions::anticipate`]: sleeps (without announcing itself
    /// to the writer) until shortly before the frame after `after` is due,
    /// then spins until it is published. `Ok(true)` if it was; `Ok(false)`
    /// leaves the wait to the futex.
    fn anticipate(&self, after: u64, deadline: u64) -> Result<bool> {
        let Some(anticipation) = &self.anticipation else {
            return Ok(false);
        };
        if self.last.seq != after || self.last.published_ns == 0 || self.writer_period().is_none() {
            return Ok(false);
        }
        let Some(expected) = anticipation.next_expected(self.last.published_ns) else {
            return Ok(false);
        };
        let window = anticipation.window_ns;
        let now = os::monotonic_ns();
        if expected.saturating_add(2 * window) <= now || expected.saturating_sub(window) >= deadline {
            return Ok(false);
        }
        if expected.saturating_sub(window) > now && !self.stop.sleep_until(expected - window) {
            return Err(Error::Stopped { channel: self.shared.label.clone() });
        }
        let ring = self.shared.ring();
        // The writer's own wake-up jitter makes most frames later than the
        // earliest expected: spin twice as long after it as before.
        let spin_until = expected.saturating_add(2 * window).min(deadline);
        while os::monotonic_ns() < spin_until {
            if ring.published() > after {
                return Ok(true);
            }
            std::hint::spin_loop();
        }
        Ok(false)
    }

    /// Sleeps until a frame with sequence number above `after` is published,
    /// or the absolute `deadline` (CLOCK_MONOTONIC ns) of a wait of `timeout`.
    fn wait_beyond(&self, after: u64, deadline: u64, timeout: Duration) -> Result<()> {
        if self.anticipate(after, deadline)? {
            return Ok(());
        }
        let ring = self.shared.ring();
        let stop = &self.stop;
        let notify = &self.shared.doorbell().notify;
        match doorbell::wait_for_frame(notify, || ring.published(), after, deadline, || stop.is_stopped(), &SharedFutex)
        {
            Ok(WaitEnd::Ready) => Ok(()),
            Ok(WaitEnd::TimedOut) => Err(Error::Timeout { channel: self.shared.label.clone(), timeout }),
            Ok(WaitEnd::Stopped) => Err(Error::Stopped { channel: self.shared.label.clone() }),
            Err(source) => Err(Error::Os { op: "futex wait", path: self.shared.path.clone(), source }),
        }
    }
}

/// The CLOCK_MONOTONIC deadline `timeout` from now.
fn deadline_after(timeout: Duration) -> u64 {
    os::monotonic_ns().saturating_add(timeout.as_nanos().min(u64::MAX as u128) as u64)
}
