//! The reader threads: one per recorded channel, reading each frame as soon
//! as it is published and handing it, encoded, to the file's thread. Frames
//! it could not get (the writer lapped it, or the queue to the file was
//! full) are counted and written as a gap.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::SyncSender;
use std::thread::JoinHandle;

use skinware::{ChannelKind, Error, FrameStatus, Reader};
use skinware_ros2::{Gap, SkinFrameRef, Time, unix_ns};

use super::file_start::Started;
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
    sender: &SyncSender<Item>,
    shared: &Arc<Shared>,
) -> Result<Vec<JoinHandle<()>>, RecordError> {
    let starts: Vec<u64> = readers.iter().map(Reader::published_seq).collect();
    let mut threads = Vec::new();
    for (((reader, recorded), &channel_id), last_seq) in
        readers.into_iter().zip(channels).zip(&started.frame_channels).zip(starts)
    {
        let job = ChannelJob {
            reader,
            last_seq,
            name: recorded.name.clone(),
            channel_id,
            gap_channel: started.gap_channel,
            counters: recorded.counters.clone(),
            clock_offset_ns: started.clock_offset_ns,
            sender: sender.clone(),
            shared: shared.clone(),
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
            self.counters.state.store(self.reader.writer_state().code(), Ordering::Relaxed);
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
        let stamp = unix_ns(frame.acquired_ns, self.clock_offset_ns);
        let published = unix_ns(frame.published_ns, self.clock_offset_ns);
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
        let data = match skinware_ros2::encode(&message, *size_hint) {
            Ok(data) => data,
            Err(e) => {
                self.shared.fail(e.into());
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
            if let Ok(data) = skinware_ros2::encode(&gap, 64) {
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
