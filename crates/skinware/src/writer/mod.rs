//! The writer: creates a channel (taking over a dead writer's name) and
//! publishes frames into it.

#![forbid(unsafe_code)]

mod fault_log;
mod wakers;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use crate::channel::doorbell::{self, WaitEnd};
use crate::channel::handover::Server;
use crate::channel::layout::{Layout, SCHEMA_NAME_BYTES};
use crate::channel::liveness::{self, NameLock, NameRecord};
use crate::channel::ring::{self, Meta};
use crate::channel::segment::{self, SegmentInit, Shared};
use crate::channel::{self, ChannelKind};
use crate::error::{Error, Result};
use crate::frame::FrameStatus;
use crate::os::{self, SHARED_FUTEX};
use crate::rt::{ReaderWake, Stop, Ticker};
use crate::shm;
use crate::stats::{self, WriterState, WriterStats};
use crate::sync::{AtomicU64, Ordering};
use wakers::{Lookout, Publishing, Ringer};

/// How a channel is created.
#[derive(Clone, Debug)]
pub struct WriterOptions {
    /// Frame buffers, K (2..=64). With K buffers a reader has K-1 whole frame
    /// periods to copy a frame before the writer comes back to its buffer.
    pub slots: usize,
    /// The nominal period of a periodic writer, or `None` for a sporadic one
    /// (which publishes when pushed or when a reader requests a frame).
    pub period: Option<Duration>,
    /// What the channel carries.
    pub kind: ChannelKind,
    /// Payload schema name (at most 32 bytes) that readers may check.
    pub schema_name: String,
    /// Payload schema version.
    pub schema_version: u32,
    /// Who may read the channel (by default, only the writer's own user).
    pub access: Access,
    /// Remove the channel's name (its socket and name lock) when the writer
    /// is dropped. A writer that dies without dropping leaves the name, and
    /// readers attached wait there for a successor to follow.
    pub unlink_on_drop: bool,
    /// Directory of the segments; `None` for [`shm::segment_dir`].
    pub dir: Option<PathBuf>,
    /// Which thread wakes the readers asleep for a frame.
    pub reader_wake: ReaderWake,
}

/// How many publishes with readers asleep had them woken by which thread.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct WakeCounts {
    /// Wakes handed to the writer's ringer.
    pub by_ringer: u64,
    /// Wakes the writer's lookout made.
    pub by_lookout: u64,
    /// Wakes the writer made itself: with [`ReaderWake::Writer`], or because
    /// its ringer had not yet rung the previous publish (with a lookout: and
    /// the lookout was not watching for this one).
    pub by_writer: u64,
}

impl Default for WriterOptions {
    fn default() -> Self {
        WriterOptions {
            slots: DEFAULT_SLOTS,
            period: None,
            kind: ChannelKind::Layer,
            schema_name: String::new(),
            schema_version: 0,
            access: Access::Owner,
            unlink_on_drop: true,
            dir: None,
            reader_wake: ReaderWake::default(),
        }
    }
}

/// Who may read a channel. Readers need nothing more than this: they map the
/// frames read-only and write only the doorbell. `docs/security.md` says what
/// each can break at worst.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Access {
    /// Only the writer's user (and root): socket `0600`.
    #[default]
    Owner,
    /// Also the writer's group: socket `0660`.
    Group,
    /// Every local user: socket `0666`.
    Everyone,
}

impl Access {
    /// Permissions of the channel's socket: connecting needs write permission
    /// on it, so "may read the channel" is the socket's write bit.
    pub fn socket_mode(self) -> u32 {
        match self {
            Access::Owner => 0o600,
            Access::Group => 0o660,
            Access::Everyone => 0o666,
        }
    }

    /// Permissions of the data memory file: read-only for everyone but the
    /// writer's user (which the write seal stops as well).
    pub fn data_mode(self) -> u32 {
        match self {
            Access::Owner => 0o600,
            Access::Group => 0o640,
            Access::Everyone => 0o644,
        }
    }
}

/// Default number of frame buffers. Three lets a reader take up to two whole
/// periods to copy a frame before it is lapped, while one buffer is being
/// written; more only costs memory.
pub const DEFAULT_SLOTS: usize = 3;

/// How long a fast periodic writer's frames stay readable when its slots
/// are chosen by [`slots_for_history`]: a reader kept off its CPU for less
/// (a hypervisor's stall, a burst of interrupts; 1–20 ms on a virtual
/// machine) still finds every frame it missed, so a recorder loses none.
pub const READABLE_HISTORY: Duration = Duration::from_millis(20);

/// Frame buffers that keep [`READABLE_HISTORY`] of a writer's frames at
/// `period`: at least [`DEFAULT_SLOTS`], at most [`MAX_SLOTS`](crate::MAX_SLOTS).
/// 3 up to 100 Hz, 21 at 1 kHz, 41 at 2 kHz; a sporadic writer (`None`)
/// gets [`DEFAULT_SLOTS`]. More slots cost memory only: a frame's size
/// each, and nothing per read or publish.
pub fn slots_for_history(period: Option<Duration>) -> usize {
    let Some(period) = period.filter(|period| !period.is_zero()) else { return DEFAULT_SLOTS };
    // The frames of the history, plus the one being written.
    let frames = READABLE_HISTORY.as_nanos().div_ceil(period.as_nanos()).saturating_add(1);
    usize::try_from(frames).unwrap_or(usize::MAX).clamp(DEFAULT_SLOTS, crate::MAX_SLOTS)
}

/// The single writer of a channel.
///
/// Publishing is wait-free: it never takes a lock, never waits for a reader and
/// reads nothing readers write; the only syscall it may make is one futex wake
/// (of its ringer on its own CPU, or of the readers: [`ReaderWake`]), and only
/// when a reader is sleeping on the channel. The ringer (or lookout) thread
/// starts at the first frame.
pub struct Writer {
    shared: Arc<Shared>,
    publishing: Publishing,
    served_requests: u32,
    /// What of the source's faults has been said in the log.
    fault_log: fault_log::FaultLog,
    stop: Stop,
    unlink_on_drop: bool,
    revived: bool,
    /// Answers readers' requests for the channel and keeps its name lock;
    /// stopped on drop, and the name released last.
    server: Option<Server>,
}

impl std::fmt::Debug for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Writer")
            .field("channel", &self.shared.label)
            .field("next_seq", &self.publishing.next_seq)
            .finish()
    }
}

impl Writer {
    /// Creates channel `skin`/`channel` with frames of `payload_bytes` and the
    /// given description. If a dead writer left the name, the new channel
    /// takes its place (its generation one higher) and the readers still
    /// attached to the old one follow it, its sequence numbers starting again
    /// from 1.
    pub fn create(
        skin: &str,
        channel: &str,
        payload_bytes: usize,
        description: &[u8],
        options: &WriterOptions,
    ) -> Result<Writer> {
        shm::validate_name("skin", skin)?;
        shm::validate_name("channel", channel)?;
        let label = channel::label(skin, channel);
        let layout = Layout::compute(payload_bytes as u64, options.slots as u64, description.len() as u64)
            .map_err(|reason| Error::InvalidLayout { channel: label.clone(), reason })?;
        if options.schema_name.len() > SCHEMA_NAME_BYTES {
            return Err(Error::InvalidLayout {
                channel: label,
                reason: format!("schema name {:?} is longer than 32 bytes", options.schema_name),
            });
        }
        let dir = options.dir.clone().unwrap_or_else(shm::segment_dir);
        let path = shm::segment_path(&dir, skin, channel);
        refuse_foreign_file(&path, &label)?;
        let mut name = NameLock::acquire(&dir, skin, channel, &label)?;
        let previous = name.record();
        let generation = previous.generation.saturating_add(1);
        name.write_record(NameRecord { generation, writer_pid: std::process::id(), ..NameRecord::default() })?;
        let init = SegmentInit {
            kind: options.kind,
            description,
            schema_name: &options.schema_name,
            schema_version: options.schema_version,
            data_mode: options.access.data_mode(),
            bell_mode: options.access.socket_mode(),
        };
        let shared = segment::create_segment(&path, label.clone(), layout, &init)?;
        liveness::introduce_writer(shared.header(), options.period.map_or(0, |p| p.as_nanos() as u64), generation);
        segment::go_live(&shared)?;
        let readers_data = segment::reopen_read_only(&shared)?;
        let readers_bell =
            shared.bell().try_clone().map_err(|source| Error::Os { op: "dup", path: path.clone(), source })?;
        // A new doorbell: requests made to the dead writer are re-made by
        // their readers when they follow this channel. Read before the socket
        // is bound: a reader can follow (and ask) the moment it is, and its
        // request must not count as served (issue #38's flaky test).
        let served_requests = doorbell::requests_served(&shared.doorbell().requests);
        let server = Server::start(path, options.access.socket_mode(), label, name, readers_data, readers_bell.into())?;
        let revived = generation > 1;
        let shared = Arc::new(shared);
        let stop = Stop::new();
        stop.watch(&shared);
        if revived {
            tracing::info!(channel = %shared.label, generation, previous_pid = previous.writer_pid, "took over the channel name of a dead writer");
        }
        Ok(Writer {
            shared,
            publishing: Publishing {
                next_seq: 1,
                last_published_ns: 0,
                woken_by_writer: 0,
                handed_to_ringer: 0,
                woken_by_lookout: 0,
                reader_wake: options.reader_wake,
                ringer: None,
                lookout: None,
                period_ns: options.period.map(|p| p.as_nanos().min(u128::from(u64::MAX)) as u64).filter(|&p| p > 0),
                period_deadline_ns: None,
            },
            served_requests,
            fault_log: fault_log::FaultLog::default(),
            stop,
            unlink_on_drop: options.unlink_on_drop,
            revived,
            server: Some(server),
        })
    }

    /// `skin/channel`.
    pub fn label(&self) -> &str {
        &self.shared.label
    }

    /// The channel's socket, where readers ask for it.
    pub fn path(&self) -> &Path {
        &self.shared.path
    }

    /// Whether this writer took over a channel name a dead (or dropped) writer left.
    pub fn revived(&self) -> bool {
        self.revived
    }

    /// Whether this writer still owns its channel's name. `false` once
    /// someone removed the name's lock file and another writer took the name
    /// (the hand-over thread checks every 250 ms): readers attached before
    /// keep reading this writer, new readers attach to the other one, and
    /// this writer no longer binds the socket again or removes the name when
    /// dropped. Stop one of the two writers.
    pub fn owns_name(&self) -> bool {
        self.server.as_ref().is_some_and(|server| !server.name_lost())
    }

    /// Payload bytes of one frame.
    pub fn payload_bytes(&self) -> usize {
        self.shared.layout.payload_bytes as usize
    }

    /// Sequence number of the last frame published (0 if none).
    pub fn last_seq(&self) -> u64 {
        self.publishing.next_seq - 1
    }

    /// When the last frame became visible to readers (CLOCK_MONOTONIC ns; 0
    /// before the first). A periodic writer's time from its period's start
    /// to here is what its readers wait for.
    pub fn last_published_ns(&self) -> u64 {
        self.publishing.last_published_ns
    }

    /// Which thread woke the readers asleep for this writer's frames, so far.
    pub fn wake_counts(&self) -> WakeCounts {
        WakeCounts {
            by_ringer: self.publishing.handed_to_ringer,
            by_lookout: self.publishing.woken_by_lookout,
            by_writer: self.publishing.woken_by_writer,
        }
    }

    /// Opens the next frame for filling, in place in shared memory. It is
    /// published by [`FrameWriter::publish`]; dropped or
    /// [`discard`](FrameWriter::discard)ed, it is abandoned and no reader ever
    /// sees it (so an early `?` return or a panic never publishes half a frame).
    ///
    /// The buffer still holds an older frame (K frames back): write every
    /// response, or readers get a mix of new and old values.
    pub fn begin(&mut self) -> FrameWriter<'_> {
        // Before the frame's time starts: the first frame starts a thread.
        match self.publishing.reader_wake {
            ReaderWake::Ringer if self.publishing.ringer.is_none() => self.start_ringer(),
            ReaderWake::Lookout if self.publishing.lookout.is_none() => self.start_lookout(),
            _ => {}
        }
        let started_ns = os::monotonic_ns();
        let Writer { shared, publishing, .. } = self;
        let ring = shared.ring();
        let payload = ring.begin(publishing.next_seq);
        FrameWriter {
            shared,
            publishing,
            payload,
            payload_bytes: shared.layout.payload_bytes as usize,
            started_ns,
            acquired_ns: None,
            status: FrameStatus::OK,
            withheld: false,
        }
    }

    /// Publishes one frame copied from `bytes` (a convenience over [`begin`](Self::begin)).
    pub fn publish_bytes(&mut self, bytes: &[u8], status: FrameStatus) -> Result<u64> {
        let mut frame = self.begin();
        if let Err(e) = frame.write_bytes(0, bytes) {
            frame.discard();
            return Err(e);
        }
        frame.set_status(status);
        Ok(frame.publish())
    }

    /// Tells readers what the writer is doing: running, paused or faulted.
    /// (`Gone` is what readers see once the writer is dropped or dies.)
    pub fn set_state(&self, state: WriterState) {
        liveness::set_state(self.shared.header(), state);
    }

    /// The state this writer last set.
    pub fn state(&self) -> WriterState {
        self.shared.stored_state()
    }

    /// Whether dropping the writer removes its channel.
    pub fn set_unlink_on_drop(&mut self, unlink: bool) {
        self.unlink_on_drop = unlink;
    }

    /// A handle that sets this writer's state from another thread (a watchdog).
    pub fn state_handle(&self) -> WriterStateHandle {
        WriterStateHandle { shared: self.shared.clone() }
    }

    /// The writer statistics in shared memory.
    pub fn stats(&self) -> WriterStats {
        WriterStats::load(&self.shared.header().stats)
    }

    /// Counts a failed acquisition (when no frame is published for it).
    pub fn record_fault(&self) {
        stats::bump(&self.shared.header().stats.faults, 1);
    }

    /// Makes `stop` interrupt this writer's blocking calls (in addition to its own).
    pub fn set_stop(&mut self, stop: &Stop) {
        stop.watch(&self.shared);
        self.stop = stop.clone();
    }

    /// The stop signal this writer's blocking calls watch.
    pub fn stop_signal(&self) -> &Stop {
        &self.stop
    }

    /// Sporadic writers: waits until a reader requests a frame. `Ok(true)` on a
    /// request, `Ok(false)` on timeout, [`Error::Stopped`] when stopped.
    pub fn wait_request(&mut self, timeout: Duration) -> Result<bool> {
        let deadline = os::monotonic_ns().saturating_add(timeout.as_nanos().min(u64::MAX as u128) as u64);
        let stop = &self.stop;
        let requests = &self.shared.doorbell().requests;
        match doorbell::wait_for_request(
            requests,
            &mut self.served_requests,
            deadline,
            || stop.is_stopped(),
            &SHARED_FUTEX,
        ) {
            Ok(WaitEnd::Ready) => Ok(true),
            Ok(WaitEnd::TimedOut) => Ok(false),
            Ok(WaitEnd::Stopped) => Err(Error::Stopped { channel: self.shared.label.clone() }),
            Err(source) => Err(Error::Os { op: "futex wait", path: self.shared.path.clone(), source }),
        }
    }

    /// Runs a periodic acquisition loop until the stop signal: on every tick of
    /// `ticker` (absolute time, no drift) it calls `fill` on a new frame. `Ok`
    /// publishes it; `Err` discards it, counts a fault and marks the channel
    /// faulted until a fill succeeds again. Overruns and lateness are recorded
    /// in the shared statistics.
    pub fn run_periodic<E, F>(&mut self, mut ticker: Ticker, mut fill: F) -> Result<()>
    where
        E: std::fmt::Display,
        F: FnMut(&mut FrameWriter<'_>) -> Result<(), E>,
    {
        let stop = self.stop.clone();
        while let Some(tick) = ticker.wait(&stop) {
            stats::record_tick(&self.shared.header().stats, tick.lateness_ns, tick.missed);
            self.publishing.period_deadline_ns = Some(tick.deadline_ns);
            self.fill_once(&mut fill);
            self.publishing.period_deadline_ns = None;
        }
        Ok(())
    }

    /// Runs a sporadic loop until the stop signal: every reader request produces
    /// one frame through `fill`, handled as in [`run_periodic`](Self::run_periodic).
    pub fn run_sporadic<E, F>(&mut self, mut fill: F) -> Result<()>
    where
        E: std::fmt::Display,
        F: FnMut(&mut FrameWriter<'_>) -> Result<(), E>,
    {
        loop {
            match self.wait_request(Duration::from_secs(3600)) {
                Ok(true) => self.fill_once(&mut fill),
                Ok(false) => {}
                Err(Error::Stopped { .. }) => return Ok(()),
                Err(other) => return Err(other),
            }
        }
    }

    /// Starts the ringer from the writer's thread, which it copies the
    /// real-time priority of. A writer in the normal scheduler wakes its
    /// readers itself: a ringer there could preempt it as soon as it is woken,
    /// and the writer would pay for both. So does one whose system refuses a
    /// thread.
    fn start_ringer(&mut self) {
        let Some(priority) = os::current_realtime_priority() else {
            self.publishing.reader_wake = ReaderWake::Writer;
            return;
        };
        match Ringer::start(&self.shared, priority) {
            Ok(ringer) => self.publishing.ringer = Some(ringer),
            Err(error) => {
                tracing::warn!(channel = %self.shared.label, %error, "cannot start the ringer thread; the writer wakes its readers itself");
                self.publishing.reader_wake = ReaderWake::Writer;
            }
        }
    }

    /// Starts the lookout from the writer's thread, as [`start_ringer`]
    /// does the ringer; a writer it cannot serve (sporadic, alone on its
    /// CPUs) uses the ringer instead.
    ///
    /// [`start_ringer`]: Self::start_ringer
    fn start_lookout(&mut self) {
        let Some(priority) = os::current_realtime_priority() else {
            self.publishing.reader_wake = ReaderWake::Writer;
            return;
        };
        let Some(period_ns) = self.publishing.period_ns else {
            tracing::info!(channel = %self.shared.label, "a sporadic writer has no lookout; its ringer wakes its readers");
            self.publishing.reader_wake = ReaderWake::Ringer;
            self.start_ringer();
            return;
        };
        let others = os::allowed_cpus().map(|cpus| cpus.len() > 1);
        if !matches!(others, Ok(true)) {
            tracing::info!(channel = %self.shared.label, "the writer may run on one CPU only: no lookout, its ringer wakes its readers");
            self.publishing.reader_wake = ReaderWake::Ringer;
            self.start_ringer();
            return;
        }
        match Lookout::start(&self.shared, priority, period_ns) {
            Ok(lookout) => {
                self.publishing.lookout = Some(lookout);
                // For the frames the lookout is not watching for: a wake
                // on the writer's own CPU rather than one to another.
                match Ringer::start(&self.shared, priority) {
                    Ok(ringer) => self.publishing.ringer = Some(ringer),
                    Err(error) => {
                        tracing::warn!(channel = %self.shared.label, %error, "cannot start the ringer thread; the writer wakes the readers its lookout does not");
                    }
                }
            }
            Err(error) => {
                tracing::warn!(channel = %self.shared.label, %error, "cannot start the lookout thread; the writer wakes its readers itself");
                self.publishing.reader_wake = ReaderWake::Writer;
            }
        }
    }

    fn fill_once<E, F>(&mut self, fill: &mut F)
    where
        E: std::fmt::Display,
        F: FnMut(&mut FrameWriter<'_>) -> Result<(), E>,
    {
        let mut frame = self.begin();
        match fill(&mut frame) {
            Ok(()) if frame.withheld => frame.discard(),
            Ok(()) => {
                frame.publish();
                let recovered = self.state() == WriterState::Faulted;
                if recovered {
                    self.set_state(WriterState::Running);
                }
                // The publish time just taken: no clock read of our own.
                let now_ns = self.publishing.last_published_ns;
                for line in self.fault_log.succeeded(now_ns, recovered) {
                    fault_log::log(&self.shared.label, &line);
                }
            }
            Err(e) => {
                frame.discard();
                self.record_fault();
                let became_faulted = self.state() != WriterState::Faulted;
                if became_faulted {
                    self.set_state(WriterState::Faulted);
                }
                for line in self.fault_log.failed(os::monotonic_ns(), became_faulted, &e) {
                    fault_log::log(&self.shared.label, &line);
                }
            }
        }
    }
}

/// Sets a live writer's state from another thread (see [`Writer::state_handle`]).
#[derive(Clone)]
pub struct WriterStateHandle {
    shared: Arc<Shared>,
}

impl WriterStateHandle {
    /// Sets the state readers see.
    pub fn set(&self, state: WriterState) {
        liveness::set_state(self.shared.header(), state);
    }

    /// The state last set.
    pub fn get(&self) -> WriterState {
        self.shared.stored_state()
    }

    /// `skin/channel`.
    pub fn label(&self) -> &str {
        &self.shared.label
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        liveness::retire_writer(self.shared.header());
        // Readers asleep re-check, see no new frame, and `writer_state` tells them why.
        doorbell::nudge(&self.shared.doorbell().notify, &SHARED_FUTEX);
        // No new reader from here on; then the name goes, or stays for a successor.
        let name = self.server.take().and_then(Server::stop);
        if let Some(name) = name
            && self.unlink_on_drop
        {
            name.lock.remove(&self.shared.path, name.socket);
        }
    }
}

/// A writer must not replace a file that is not a channel socket (a file of
/// an older skinware, or somebody else's).
fn refuse_foreign_file(path: &Path, label: &str) -> Result<()> {
    use std::os::unix::fs::FileTypeExt;
    match std::fs::symlink_metadata(path) {
        Ok(meta) if !meta.file_type().is_socket() => Err(Error::NotAChannel {
            channel: label.to_owned(),
            path: path.to_owned(),
            found: if meta.is_file() { "regular file" } else { "file that is not a socket" },
        }),
        _ => Ok(()),
    }
}

/// A frame being filled in place in shared memory: [`publish`](Self::publish)
/// it; dropping it abandons it.
///
/// Responses are stored with atomic stores because readers may be copying an
/// older frame out of the same buffer at the same moment (they then discard
/// their copy); handing out a plain `&mut [u16]` would make that a data race.
pub struct FrameWriter<'w> {
    shared: &'w Shared,
    publishing: &'w mut Publishing,
    payload: &'w [AtomicU64],
    payload_bytes: usize,
    started_ns: u64,
    acquired_ns: Option<u64>,
    status: FrameStatus,
    /// Set by [`withhold`](Self::withhold): the periodic loops discard the
    /// frame instead of publishing it, and count no fault.
    withheld: bool,
}

impl FrameWriter<'_> {
    /// The sequence number this frame will have.
    pub fn seq(&self) -> u64 {
        self.publishing.next_seq
    }

    /// Payload bytes of the frame.
    pub fn len_bytes(&self) -> usize {
        self.payload_bytes
    }

    /// Number of `u16` responses the frame holds.
    pub fn len_responses(&self) -> usize {
        self.payload_bytes / 2
    }

    fn too_large(&self, given: usize) -> Error {
        Error::PayloadTooLarge { channel: self.shared.label.clone(), given, capacity: self.payload_bytes }
    }

    /// Sets response `index`.
    pub fn set_response(&mut self, index: usize, value: u16) -> Result<()> {
        if index >= self.len_responses() {
            return Err(self.too_large((index + 1) * 2));
        }
        let word = &self.payload[index / 4];
        // Readers see the payload as native-order u16s (`Frame::responses`).
        let lane = if cfg!(target_endian = "little") { index % 4 } else { 3 - index % 4 };
        let shift = lane * 16;
        let current = word.load(Ordering::Relaxed);
        let updated = (current & !(0xffff << shift)) | (u64::from(value) << shift);
        word.store(updated, Ordering::Relaxed);
        Ok(())
    }

    /// Writes `values` as responses `first..first + values.len()`.
    pub fn write_responses(&mut self, first: usize, values: &[u16]) -> Result<()> {
        if first.saturating_add(values.len()) > self.len_responses() {
            return Err(self.too_large((first + values.len()) * 2));
        }
        // Responses are u16 in native byte order, so they are the payload's bytes.
        ring::store_bytes(self.payload, first * 2, bytemuck::cast_slice(values));
        Ok(())
    }

    /// Writes raw payload bytes at byte `offset`.
    pub fn write_bytes(&mut self, offset: usize, bytes: &[u8]) -> Result<()> {
        if offset.saturating_add(bytes.len()) > self.payload_bytes {
            return Err(self.too_large(offset + bytes.len()));
        }
        ring::store_bytes(self.payload, offset, bytes);
        Ok(())
    }

    /// Writes a plain-old-data value at the start of the payload.
    pub fn write_pod<T: bytemuck::NoUninit>(&mut self, value: &T) -> Result<()> {
        self.write_bytes(0, bytemuck::bytes_of(value))
    }

    /// The deadline (CLOCK_MONOTONIC ns) of the period this frame is filled
    /// for, when [`Writer::run_periodic`] fills it; `None` otherwise. A
    /// driver whose bus cycles on its own can schedule them from it, so that
    /// each cycle's data is there just before the writer looks.
    pub fn period_deadline_ns(&self) -> Option<u64> {
        self.publishing.period_deadline_ns
    }

    /// Sets the acquisition time (CLOCK_MONOTONIC ns); by default, the moment
    /// the frame was begun.
    pub fn set_acquired_ns(&mut self, ns: u64) {
        self.acquired_ns = Some(ns);
    }

    /// The acquisition time a driver set with
    /// [`set_acquired_ns`](FrameWriter::set_acquired_ns), if it did.
    pub fn acquired_ns(&self) -> Option<u64> {
        self.acquired_ns
    }

    /// Sets the frame's status flags.
    pub fn set_status(&mut self, status: FrameStatus) {
        self.status = status;
    }

    /// Publishes the frame and returns its sequence number.
    pub fn publish(mut self) -> u64 {
        self.finish()
    }

    /// Abandons the frame: readers keep seeing the previous one. (Dropping the
    /// guard does the same.)
    pub fn discard(self) {}

    /// For a fill of [`Writer::run_periodic`] or [`Writer::run_sporadic`]
    /// that has nothing to publish yet and nothing wrong to report (boards
    /// still starting, not all of them heard from): the loop discards the
    /// frame when the fill returns `Ok`, publishes nothing and counts no
    /// fault. The writer's state does not change.
    pub fn withhold(&mut self) {
        self.withheld = true;
    }

    /// Whether [`withhold`](Self::withhold) was called.
    pub fn is_withheld(&self) -> bool {
        self.withheld
    }

    fn finish(&mut self) -> u64 {
        let publishing = &mut *self.publishing;
        let seq = publishing.next_seq;
        let published_ns = os::monotonic_ns();
        self.shared.ring().publish(&Meta {
            seq,
            acquired_ns: self.acquired_ns.unwrap_or(self.started_ns),
            published_ns,
            status: self.status.0,
        });
        publishing.next_seq += 1;
        publishing.last_published_ns = published_ns;
        let notify = &self.shared.doorbell().notify;
        let announced = doorbell::announce(notify, seq);
        publishing.wake_sleepers(&self.shared.label, notify, announced, published_ns);
        let header = self.shared.header();
        stats::record_write(&header.stats, os::monotonic_ns() - self.started_ns, self.status.is_fault());
        seq
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slots_for_history_keep_twenty_milliseconds_within_the_channels_range() {
        let at_hz = |hz: u64| slots_for_history(Some(Duration::from_nanos(1_000_000_000 / hz)));
        assert_eq!(slots_for_history(None), DEFAULT_SLOTS);
        assert_eq!(slots_for_history(Some(Duration::ZERO)), DEFAULT_SLOTS);
        assert_eq!(at_hz(30), DEFAULT_SLOTS);
        assert_eq!(at_hz(100), 3);
        assert_eq!(at_hz(500), 11);
        assert_eq!(at_hz(1_000), 21);
        assert_eq!(at_hz(2_000), 41);
        assert_eq!(at_hz(1_000_000), crate::MAX_SLOTS);
        assert_eq!(slots_for_history(Some(Duration::from_nanos(1))), crate::MAX_SLOTS);
        assert_eq!(slots_for_history(Some(Duration::MAX)), DEFAULT_SLOTS);
    }
}
