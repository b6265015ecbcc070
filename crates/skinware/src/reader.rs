//! The reader: attaches to a channel by name and obtains its newest frames,
//! periodically, as soon as they are published, or on request.

#![forbid(unsafe_code)]

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use crate::anticipate::Anticipation;
use crate::channel::ChannelKind;
use crate::channel::doorbell::{self, WaitEnd};
use crate::channel::handover::ANSWER_TIMEOUT;
use crate::channel::layout;
use crate::channel::liveness::NameRecord;
use crate::channel::ring::{Meta, ReadFailure};
use crate::channel::segment::{self, Opened, Shared};
use crate::channel::succession::{self, Follower};
use crate::error::{Error, Result};
use crate::frame::{Frame, FrameInfo};
use crate::os::{self, SHARED_FUTEX};
use crate::rt::{Stop, Ticker};
use crate::shm;
use crate::stats::{ReaderStats, WriterState, WriterStats};
use crate::sync::Ordering;

/// How a reader attaches.
#[derive(Clone, Debug, Default)]
pub struct ReaderOptions {
    /// Attach even if the channel's writer has stopped (it is being dropped
    /// but still answers). A channel whose writer is dead cannot be attached
    /// to: its memory is reachable only through its writer. `open` then
    /// returns [`Error::WriterGone`]; try again later. Readers attached before
    /// the writer died keep the channel and follow its successor.
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
    /// Do not watch the segment directory for a successor of a dead writer:
    /// find one only by re-checking every 100 ms in blocking reads (and by
    /// [`Reader::follow_recreated`]), as readers did before the watcher. For
    /// comparisons (`skin bench follow`); by default (`false`) a reader in
    /// any mode follows a successor within a millisecond of its appearance.
    pub no_successor_watch: bool,
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
    /// The frame whose whole, checked copy `buffer` holds, if it holds one:
    /// a failed read may leave it half-copied.
    copied: Option<Meta>,
    last: Meta,
    stats: ReaderStats,
    stop: Stop,
    /// Where the channel lives, to follow it if it is re-created.
    skin: String,
    channel: String,
    dir: PathBuf,
    anticipation: Option<Anticipation>,
    /// Channels followed since it attached.
    follows: u64,
    /// Where the process's watcher leaves a successor of a dead writer
    /// ([`crate::channel::succession`]); `None` without a watcher.
    follower: Option<Arc<Follower>>,
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
        let shared = match segment::open_segment(&dir, skin, channel, ANSWER_TIMEOUT)? {
            Opened::Live(shared) => shared,
            Opened::NoWriter => {
                let pid = NameRecord::load(&dir, skin, channel).unwrap_or_default().writer_pid;
                return Err(Error::WriterGone { channel: crate::channel::label(skin, channel), pid });
            }
        };
        let header = shared.header();
        let alive = shared.writer_alive().map_err(|source| Error::Os {
            op: "lock query",
            path: shared.path.clone(),
            source,
        })?;
        if !alive || (!options.allow_gone && header.state.load(Ordering::Acquire) == WriterState::STOPPED) {
            return Err(Error::WriterGone {
                channel: shared.label.clone(),
                pid: header.writer_pid.load(Ordering::Relaxed),
            });
        }
        Reader::attach(shared, skin, channel, dir, options)
    }

    /// A reader of memory handed over by whoever the caller got it from:
    /// what the fuzz target opens arbitrary bytes with, without a socket
    /// round trip per input. Only in fuzzing builds.
    #[cfg(fuzzing)]
    #[doc(hidden)]
    pub fn from_memory(data: std::os::fd::OwnedFd, bell: std::os::fd::OwnedFd, anticipate: bool) -> Result<Reader> {
        let dir = std::env::temp_dir();
        let shared = segment::map_received("fuzz/layer".into(), dir.join("fuzz"), data, bell)?;
        let anticipate = anticipate.then_some(Duration::from_micros(1));
        let options = ReaderOptions { allow_gone: true, anticipate, ..ReaderOptions::default() };
        Reader::attach(shared, "fuzz", "layer", dir, &options)
    }

    /// Checks what a reader was handed and starts reading it.
    fn attach(shared: Shared, skin: &str, channel: &str, dir: PathBuf, options: &ReaderOptions) -> Result<Reader> {
        let header = shared.header();
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
        let follower = if options.no_successor_watch || cfg!(fuzzing) {
            None
        } else {
            succession::follow(&dir, skin, channel, &shared)
        };
        Ok(Reader {
            follower,
            shared,
            buffer: vec![0; words],
            copied: None,
            last: Meta::default(),
            stats: ReaderStats::default(),
            stop,
            skin: skin.to_owned(),
            channel: channel.to_owned(),
            dir,
            follows: 0,
            anticipation: options
                .anticipate
                .map(|d| Anticipation::new(d.as_nanos().min(u128::from(u64::MAX / 4)) as u64)),
        })
    }

    /// Follows the channel if its writer is gone and a new writer took its
    /// name (new memory under the same name) with the same frame size and
    /// kind. Returns whether it switched. Sequence numbers start again from 1
    /// in the new channel; [`writer_generation`](Self::writer_generation) is
    /// one higher.
    ///
    /// Every read does this on its own, at once, when the process's watcher
    /// has seen a successor appear ([`crate::channel::succession`]), and the
    /// blocking reads also re-check every 100 ms; a call is needed only
    /// where the watcher cannot run (see
    /// [`ReaderOptions::no_successor_watch`]). It asks the socket's writer
    /// (waiting up to a second for a stopped one).
    pub fn follow_recreated(&mut self) -> bool {
        if self.follow_successor() {
            return true;
        }
        if self.shared.writer_alive().unwrap_or(true) {
            return false;
        }
        let Ok(Opened::Live(replacement)) = segment::open_segment(&self.dir, &self.skin, &self.channel, ANSWER_TIMEOUT)
        else {
            return false;
        };
        self.switch_to(Arc::new(replacement))
    }

    /// Takes the successor the watcher left, if it left one: `true` if the
    /// reader now reads it. Costs one relaxed load when there is none.
    fn follow_successor(&mut self) -> bool {
        let Some(follower) = self.follower.as_ref().filter(|f| f.flagged()) else {
            return false;
        };
        match follower.take() {
            Some(successor) => self.switch_to(successor),
            None => false,
        }
    }

    /// Switches to `replacement` if it is new memory of the same shape and
    /// this reader's writer is dead.
    fn switch_to(&mut self, replacement: Arc<Shared>) -> bool {
        if replacement.identity() == self.shared.identity() || self.shared.writer_alive().unwrap_or(true) {
            return false;
        }
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
        self.stop.watch(&replacement);
        if let Some(follower) = &self.follower {
            follower.set_current(&replacement);
        }
        tracing::info!(channel = %replacement.label, "following the re-created channel");
        self.shared = replacement;
        self.last = Meta::default();
        self.copied = None;
        self.follows += 1;
        // The successor's grid is its own: learn it afresh.
        if let Some(anticipation) = &mut self.anticipation {
            *anticipation = Anticipation::new(anticipation.window_ns);
        }
        true
    }

    /// `skin/channel`.
    pub fn label(&self) -> &str {
        &self.shared.label
    }

    /// The channel's socket.
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

    /// The state the writer last stored, without asking the kernel whether
    /// it still lives (which [`writer_state`](Self::writer_state) does, with
    /// a system call): enough while new frames keep coming, or while the
    /// newest is younger than the writer's period, since a writer that
    /// published that recently was alive a period ago.
    pub fn stored_writer_state(&self) -> WriterState {
        self.shared.stored_state()
    }

    /// The process id of the current (or last) writer.
    pub fn writer_pid(&self) -> u32 {
        self.shared.header().writer_pid.load(Ordering::Relaxed)
    }

    /// How many times this reader followed a re-created channel (see
    /// [`follow_recreated`](Self::follow_recreated)). The writer generation
    /// cannot tell: a writer that stopped cleanly removes the channel's name,
    /// and its successor starts again at generation 1.
    pub fn follows(&self) -> u64 {
        self.follows
    }

    /// How many writers have owned the channel (each successor under the name adds one).
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
    ///
    /// If the writer died and a successor took its name, this reads the
    /// successor (whose frames start again from 1): the process's watcher has
    /// seen it appear, and the check costs an unchanged channel one relaxed
    /// load.
    pub fn latest(&mut self) -> Result<Frame<'_>> {
        let (skipped, fresh) = self.read_newest(None)?;
        Ok(self.frame(skipped, fresh))
    }

    /// [`latest`](Self::latest), copied straight into `out` (one copy, no
    /// allocation): for a caller that keeps frames in its own memory, such as
    /// the C API. `out` must hold [`payload_bytes`](Self::payload_bytes); only
    /// that many bytes are written. After an error `out` may hold a partial
    /// copy, and [`last_frame`](Self::last_frame) is `None` after any read
    /// into a caller's buffer (the reader's own copy is not refreshed).
    pub fn latest_into(&mut self, out: &mut [u8]) -> Result<FrameInfo> {
        let (skipped, fresh) = self.read_newest(Some(out))?;
        Ok(FrameInfo::new(self.last, skipped, fresh))
    }

    /// Copies the newest frame into the reader's buffer or into `into`, and
    /// accounts for it: returns its skipped count and freshness.
    fn read_newest(&mut self, into: Option<&mut [u8]>) -> Result<(u64, bool)> {
        self.follow_successor();
        let started = os::monotonic_ns();
        let payload = self.payload_bytes();
        let ring = self.shared.ring();
        let read = match into {
            // The newest frame is the one whose checked copy the buffer
            // holds (a reader faster than its writer): copying it again
            // would give the same bytes, at the cost of the whole frame's
            // cache misses. A forged writer that rewrote the slot under the
            // same number gets this reader's checked copy, never a torn one.
            None => match self.copied.filter(|copied| copied.seq == ring.published()) {
                Some(copied) => Ok((copied, 0)),
                None => {
                    let read = ring.read_latest(&mut self.buffer, MAX_READ_ATTEMPTS);
                    self.copied = read.as_ref().ok().map(|(meta, _)| *meta);
                    read
                }
            },
            Some(out) => {
                self.copied = None;
                let Some(out) = out.get_mut(..payload) else {
                    return Err(Error::BufferTooSmall {
                        channel: self.shared.label.clone(),
                        needed: payload,
                        given: out.len(),
                    });
                };
                ring.read_latest(out, MAX_READ_ATTEMPTS)
            }
        };
        match read {
            Ok((meta, retries)) => {
                // Sequence numbers only go backwards if the channel's memory
                // was written by someone other than its writer: start counting
                // afresh from what the writer says now.
                if meta.seq < self.last.seq {
                    self.last = Meta::default();
                }
                let fresh = meta.seq != self.last.seq;
                if let (true, Some(anticipation)) = (fresh, &mut self.anticipation) {
                    let period = self.shared.header().period_ns.load(Ordering::Relaxed);
                    anticipation.observe(meta.published_ns, period);
                }
                let skipped = if fresh && self.last.seq != 0 {
                    meta.seq.saturating_sub(self.last.seq.saturating_add(1))
                } else {
                    0
                };
                self.stats.record(os::monotonic_ns() - started, retries, skipped);
                self.last = meta;
                Ok((skipped, fresh))
            }
            Err(ReadFailure::Empty) => Err(Error::NoFrameYet { channel: self.shared.label.clone() }),
            Err(ReadFailure::Lapped(retries)) => {
                self.stats.retries += u64::from(retries);
                Err(Error::Lapped { channel: self.shared.label.clone(), retries, slots: self.slots() as u32 })
            }
        }
    }

    /// An older frame, `seq`, if the writer has not reused its buffer yet.
    /// A reader that woke late gets the newest frame with
    /// [`Frame::skipped`] > 0; the frames in between stay readable until the
    /// writer comes back to their buffers (K-1 frames after each), and this
    /// copies one of them. Wait-free, like [`latest`](Self::latest); `None`
    /// when the frame is gone (or was never published). It does not change
    /// which frame the other reads count as this reader's newest, but it is
    /// what [`last_frame`](Self::last_frame) shows next (nothing, if it failed).
    pub fn read_seq(&mut self, seq: u64) -> Option<Frame<'_>> {
        self.copied = self.shared.ring().read_seq(seq, &mut self.buffer);
        let meta = self.copied?;
        let bytes: &[u8] = bytemuck::cast_slice(&self.buffer);
        Some(Frame { meta, skipped: 0, fresh: true, payload: &bytes[..self.payload_bytes()] })
    }

    /// The frame this reader copied last, again, from its own copy (the
    /// channel is not touched): for a caller that reads several channels
    /// first and then looks at each one's frame, without copying it again.
    /// `None` before the first frame, and after a read that failed (which may
    /// have left the copy incomplete) or a [`follow_recreated`](Self::follow_recreated)
    /// that switched channels. It was obtained before: [`Frame::is_fresh`]
    /// is false and [`Frame::skipped`] 0.
    pub fn last_frame(&self) -> Option<Frame<'_>> {
        let meta = self.copied?;
        let bytes: &[u8] = bytemuck::cast_slice(&self.buffer);
        Some(Frame { meta, skipped: 0, fresh: false, payload: &bytes[..self.payload_bytes()] })
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
        self.wait_for_newer(timeout)?;
        self.latest()
    }

    /// [`wait_newer`](Self::wait_newer), copied into `out` as
    /// [`latest_into`](Self::latest_into) does.
    pub fn wait_newer_into(&mut self, timeout: Duration, out: &mut [u8]) -> Result<FrameInfo> {
        self.wait_for_newer(timeout)?;
        self.latest_into(out)
    }

    fn wait_for_newer(&mut self, timeout: Duration) -> Result<()> {
        let deadline = deadline_after(timeout);
        loop {
            // What was published is the reference, unless this reader saw a
            // number the writer has not reached (forged, or a previous channel).
            let after = self.last.seq.min(self.published_seq());
            match self.wait_slices(after, deadline, timeout) {
                Ok(Waited::Frame) => return Ok(()),
                // Followed: what the new channel already has counts, and
                // the wait goes on to the same deadline.
                Ok(Waited::Followed) => {}
                Err(e) => return Err(e),
            }
        }
    }

    /// On request: asks for a frame newer than any published now and waits for
    /// it. A sporadic writer acquires one on the request; a periodic writer's
    /// next frame answers it. Timeouts and a gone writer as in
    /// [`wait_newer`](Self::wait_newer); a request made while the writer is
    /// gone is made again to its successor.
    pub fn request(&mut self, timeout: Duration) -> Result<Frame<'_>> {
        self.wait_for_requested(timeout)?;
        self.latest()
    }

    /// [`request`](Self::request), copied into `out` as
    /// [`latest_into`](Self::latest_into) does.
    pub fn request_into(&mut self, timeout: Duration, out: &mut [u8]) -> Result<FrameInfo> {
        self.wait_for_requested(timeout)?;
        self.latest_into(out)
    }

    fn wait_for_requested(&mut self, timeout: Duration) -> Result<()> {
        let deadline = deadline_after(timeout);
        loop {
            let after = self.published_seq();
            if self.writer_period().is_none() {
                doorbell::request(&self.shared.doorbell().requests, &SHARED_FUTEX);
            }
            match self.wait_slices(after, deadline, timeout) {
                Ok(Waited::Frame) => return Ok(()),
                Ok(Waited::Followed) => {}
                Err(e) => return Err(e),
            }
        }
    }

    /// Waits for a frame above `after` until `deadline`, in slices of at most
    /// [`RECHECK_NS`]: between them it checks that the writer lives and
    /// follows a successor if it died, so that a reader notices a new writer
    /// promptly even when nothing wakes it.
    fn wait_slices(&mut self, after: u64, deadline: u64, timeout: Duration) -> Result<Waited> {
        loop {
            let slice_end = os::monotonic_ns().saturating_add(RECHECK_NS).min(deadline);
            match self.wait_beyond(after, slice_end, timeout) {
                Ok(Woke::Frame) => return Ok(Waited::Frame),
                Ok(Woke::Successor) => {
                    if self.follow_successor() {
                        return Ok(Waited::Followed);
                    }
                }
                Err(Error::Timeout { .. }) => {
                    if self.follow_recreated() {
                        return Ok(Waited::Followed);
                    }
                    if os::monotonic_ns() >= deadline {
                        return Err(self.timed_out(timeout));
                    }
                }
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
    /// Or until the watcher leaves a successor ([`Woke::Successor`]).
    fn wait_beyond(&self, after: u64, deadline: u64, timeout: Duration) -> Result<Woke> {
        if self.anticipate(after, deadline)? {
            return Ok(Woke::Frame);
        }
        let ring = self.shared.ring();
        let stop = &self.stop;
        let follower = self.follower.as_deref();
        let successor_waits = || follower.is_some_and(Follower::flagged);
        let notify = &self.shared.doorbell().notify;
        match doorbell::wait_for_frame(
            notify,
            || ring.published(),
            after,
            deadline,
            // The watcher nudges the doorbell after raising the flag, so a
            // sleeper sees it like a stop.
            || stop.is_stopped() || successor_waits(),
            &SHARED_FUTEX,
        ) {
            Ok(WaitEnd::Ready) => Ok(Woke::Frame),
            Ok(WaitEnd::TimedOut) => Err(Error::Timeout { channel: self.shared.label.clone(), timeout }),
            Ok(WaitEnd::Stopped) if !stop.is_stopped() => Ok(Woke::Successor),
            Ok(WaitEnd::Stopped) => Err(Error::Stopped { channel: self.shared.label.clone() }),
            Err(source) => Err(Error::Os { op: "futex wait", path: self.shared.path.clone(), source }),
        }
    }
}

/// Longest single sleep of a blocking read before it checks on its writer.
/// A wake-up this often costs an idle reader nothing measurable, and it
/// bounds how long a reader can sleep past a publish if a hostile process
/// clears the doorbell's "someone waits" bit.
const RECHECK_NS: u64 = 100_000_000;

/// Why a wait on the doorbell ended well.
enum Woke {
    /// A frame above the one waited beyond was published.
    Frame,
    /// The watcher left a successor of the dead writer.
    Successor,
}

/// How a sliced wait ended well.
enum Waited {
    /// A frame above the one waited beyond was published.
    Frame,
    /// The writer was gone and the reader now follows its successor.
    Followed,
}

/// The CLOCK_MONOTONIC deadline `timeout` from now.
fn deadline_after(timeout: Duration) -> u64 {
    os::monotonic_ns().saturating_add(timeout.as_nanos().min(u64::MAX as u128) as u64)
}
