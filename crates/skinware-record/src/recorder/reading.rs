//! The reader threads: one per recorded channel, reading each frame as soon
//! as it is published and handing it, encoded, to the file's thread. Frames
//! it could not get (the writer lapped it, or the queue to the file was
//! full) are counted and written as a gap.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::TrySendError;
use std::thread::JoinHandle;

use skinware::{ChannelKind, Error, FrameStatus, Reader};
use skinware_ros2::{Gap, SkinFrameRef, Time, unix_ns};

use super::file_start::Started;
use super::queue::QueueSender;
use super::summary::{Counters, Recorded};
use super::{Item, READ_SLICE, Shared, spawn};
use crate::RecordError;

/// Starts one reader thread per channel; `readers` and `channels` are in
/// the same order. The recording starts now, the file ready: every frame
/// after the newest published is recorded or counted as lost.
pub(super) fn start_readers(
    readers: Vec<Reader>,
    channels: &[Recorded],
    started: &Started,
    sender: &QueueSender<Item>,
    shared: &Arc<Shared>,
    priority: u8,
) -> Result<Vec<JoinHandle<()>>, RecordError> {
    let starts: Vec<u64> = readers.iter().map(Reader::published_seq).collect();
    let mut threads = Vec::new();
    for (((reader, recorded), &channel_id), last_seq) in
        readers.into_iter().zip(channels).zip(&started.frame_channels).zip(starts)
    {
        let is_layer = reader.kind() != ChannelKind::Service;
        let job = ChannelJob {
            reader,
            last_seq,
            priority,
            out: Emitter {
                name: recorded.name.clone(),
                channel_id,
                gap_channel: started.gap_channel,
                counters: recorded.counters.clone(),
                clock_offset_ns: started.clock_offset_ns,
                sender: sender.clone(),
                shared: shared.clone(),
                is_layer,
                responses: Vec::new(),
                size_hint: 64,
            },
        };
        threads.push(spawn(&format!("rec-{}", recorded.name), move || job.run())?);
    }
    Ok(threads)
}

/// A reader thread's job.
struct ChannelJob {
    reader: Reader,
    /// The newest frame written (or, at the start, published when the recording started).
    last_seq: u64,
    /// The SCHED_FIFO priority the thread asks for (0: the normal scheduler).
    priority: u8,
    out: Emitter,
}

/// What a reader thread writes its frames with (apart from the reader, so
/// that a frame borrowed from the reader can be encoded as it is).
struct Emitter {
    name: String,
    channel_id: u16,
    gap_channel: u16,
    counters: Arc<Counters>,
    clock_offset_ns: i64,
    sender: QueueSender<Item>,
    shared: Arc<Shared>,
    is_layer: bool,
    /// A layer's responses as `u16`s, reused from frame to frame.
    responses: Vec<u16>,
    /// The last message's size, the next one's first allocation.
    size_hint: usize,
}

/// The parts of a frame a message is made of, borrowed from the reader's
/// frame or from a copy of it.
struct FrameParts<'a> {
    seq: u64,
    acquired_ns: u64,
    published_ns: u64,
    status: FrameStatus,
    bytes: &'a [u8],
}

impl<'a> FrameParts<'a> {
    fn of(frame: &skinware::Frame<'a>) -> FrameParts<'a> {
        FrameParts {
            seq: frame.seq(),
            acquired_ns: frame.acquired_ns(),
            published_ns: frame.published_ns(),
            status: frame.status(),
            bytes: frame.bytes(),
        }
    }
}

/// A frame copied out of the reader, kept while the frames before it are caught up.
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

    fn parts(&self) -> FrameParts<'_> {
        FrameParts {
            seq: self.seq,
            acquired_ns: self.acquired_ns,
            published_ns: self.published_ns,
            status: self.status,
            bytes: &self.bytes,
        }
    }
}

impl ChannelJob {
    fn run(mut self) {
        self.reader.set_stop(&self.out.shared.stop);
        self.take_priority();
        while !self.out.shared.stop.is_stopped() {
            self.out.counters.state.store(self.reader.writer_state().code(), Ordering::Relaxed);
            let last_seq = self.last_seq;
            let (newest, skipped) = match self.reader.wait_newer(READ_SLICE) {
                // The next frame, as it should be: encoded straight from the reader's copy.
                // (The starting number was read from the writer's memory: checked, not trusted.)
                Ok(frame)
                    if last_seq.checked_add(1) == Some(frame.seq())
                        || (frame.seq() <= last_seq && frame.skipped() == 0) =>
                {
                    if !self.out.emit(&FrameParts::of(&frame), 0) {
                        return;
                    }
                    self.last_seq = frame.seq();
                    continue;
                }
                // Counted from the last frame written, so that frames published
                // between the start and this thread's first read count too;
                // a writer that started again (its numbers restarted) is
                // counted by the reader.
                Ok(frame) if frame.seq() > last_seq => (Copied::of(&frame), frame.seq() - last_seq - 1),
                Ok(frame) => (Copied::of(&frame), frame.skipped()),
                Err(Error::Timeout { .. } | Error::WriterGone { .. } | Error::Lapped { .. }) => continue,
                Err(Error::Stopped { .. }) => break,
                Err(e) => {
                    tracing::warn!(channel = %self.out.name, error = %e, "read failed; retrying");
                    std::thread::sleep(READ_SLICE);
                    continue;
                }
            };
            // Woken late: the frames between the previous one and the newest
            // stay in the writer's buffers for K-1 frames each. Copy those
            // still there first, oldest first, since the writer keeps
            // reusing the oldest buffer; encoding and queueing them one by
            // one would let it reuse the next ones meanwhile. The rest are
            // missed, and so is anything older than the buffers hold.
            let reachable = skipped.min(self.reader.slots().saturating_sub(1) as u64);
            let first = newest.seq.saturating_sub(reachable);
            let caught: Vec<Option<Copied>> =
                (first..newest.seq).map(|seq| self.reader.read_seq(seq).map(|frame| Copied::of(&frame))).collect();
            let mut missed = skipped - reachable;
            for older in caught {
                match older {
                    Some(older) => {
                        if !self.out.emit(&older.parts(), missed) {
                            return;
                        }
                        missed = 0;
                    }
                    None => missed += 1,
                }
            }
            if !self.out.emit(&newest.parts(), missed) {
                return;
            }
            self.last_seq = newest.seq;
        }
    }

    /// Moves this thread into SCHED_FIFO at the recording's priority. A
    /// reader in the normal scheduler can be kept off its CPU for longer
    /// than the writer keeps a frame (K-1 periods: 2 ms for 3 slots at
    /// 1 kHz) by the file's thread compressing; a real-time one is not, and
    /// its work per frame is short (one copy and an encoding). Refused (no
    /// privilege), it reads in the normal scheduler and says so once.
    fn take_priority(&self) {
        let counters = &self.out.counters;
        if self.priority == 0 {
            return;
        }
        match skinware::os::set_fifo_priority(self.priority) {
            Ok(()) => counters.realtime.store(true, Ordering::Relaxed),
            Err(e) => {
                if !self.out.shared.priority_refused.swap(true, Ordering::Relaxed) {
                    tracing::warn!(
                        priority = self.priority,
                        error = %e,
                        "the recorder's readers stay in the normal scheduler (SCHED_FIFO refused: run as root, \
                         or give the user an rtprio limit in /etc/security/limits.conf); at high rates they may \
                         miss frames while the file's thread compresses"
                    );
                }
            }
        }
    }
}

impl Emitter {
    /// Writes one frame, `missed` frames after the previous one written;
    /// `false` once the file is gone.
    fn emit(&mut self, frame: &FrameParts<'_>, missed: u64) -> bool {
        let stamp = unix_ns(frame.acquired_ns, self.clock_offset_ns);
        let published = unix_ns(frame.published_ns, self.clock_offset_ns);
        if self.is_layer {
            self.responses.clear();
            self.responses.extend(frame.bytes.chunks_exact(2).map(|b| u16::from_ne_bytes([b[0], b[1]])));
        }
        let message = SkinFrameRef {
            stamp: Time::from_ns(stamp),
            published: Time::from_ns(published),
            seq: frame.seq,
            status: frame.status.0,
            skipped: missed,
            responses: if self.is_layer { &self.responses } else { &[] },
            payload: if self.is_layer { &[] } else { frame.bytes },
        };
        let data = match skinware_ros2::encode(&message, self.size_hint) {
            Ok(data) => data,
            Err(e) => {
                self.shared.fail(e.into());
                return false;
            }
        };
        self.size_hint = data.len();
        if frame.status.contains(FrameStatus::FAULT) {
            self.counters.faulted.fetch_add(1, Ordering::Relaxed);
        }
        if missed > 0 {
            self.counters.lost.fetch_add(missed, Ordering::Relaxed);
            self.counters.gaps.fetch_add(1, Ordering::Relaxed);
            let gap = Gap {
                stamp: Time::from_ns(stamp),
                channel: self.name.clone(),
                first_seq: frame.seq.saturating_sub(missed),
                count: missed,
            };
            if let Ok(data) = skinware_ros2::encode(&gap, 64) {
                let item =
                    Item { channel_id: self.gap_channel, sequence: 0, log_time: stamp, publish_time: published, data };
                if !self.send(item) {
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
        if !self.send(item) {
            return false;
        }
        self.counters.frames.fetch_add(1, Ordering::Relaxed);
        self.counters.latency_ns.fetch_add(frame.published_ns.saturating_sub(frame.acquired_ns), Ordering::Relaxed);
        true
    }

    /// Hands `item` to the file's thread, waiting while its queue is full
    /// (counted: the frames missed meanwhile were lost to the file, not to
    /// the reader); `false` once the file is gone.
    fn send(&self, item: Item) -> bool {
        match self.sender.try_send(item) {
            Ok(()) => true,
            Err(TrySendError::Full(item)) => {
                self.counters.file_waits.fetch_add(1, Ordering::Relaxed);
                self.sender.send(item).is_ok()
            }
            Err(TrySendError::Disconnected(_)) => false,
        }
    }
}
