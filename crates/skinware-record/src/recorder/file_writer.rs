//! The file's thread: the only owner of the file. It writes what the other
//! threads send, finishes a chunk every flush interval and has a thread of
//! its own sync it to disk, and finishes the file with the summary when they
//! are done. A split recording's file thread also closes each part when
//! it is complete and goes on in the next.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};

use super::discovery::Sources;
use super::file_start::{ChannelIds, McapWriter, Part, write_start};
use super::queue::QueueReceiver;
use super::summary::Recorded;
use super::{Item, RecordOptions, Shared, Split, part_path};
use crate::error::{mcap_write_error, write_hint};
use crate::{RecordError, SUMMARY_METADATA};

/// The writer thread's job: owns the file.
pub(super) struct FileJob {
    /// The file being written.
    pub(super) path: PathBuf,
    /// How to go on in a new file, if the recording is split.
    pub(super) parts: Option<Parts>,
    pub(super) writer: McapWriter,
    /// The same file, to sync what was flushed.
    pub(super) sync: File,
    pub(super) receiver: QueueReceiver<Item>,
    pub(super) flush_interval: Duration,
    pub(super) shared: Arc<Shared>,
    pub(super) channels: Vec<Recorded>,
    /// The nice value the thread asks for, if any.
    pub(super) nice: Option<i32>,
}

/// A split recording's parts: when to start the next, and what starts it.
pub(super) struct Parts {
    /// When a part is complete.
    pub(super) split: Split,
    /// The recording's path, which the parts are named after.
    pub(super) base: PathBuf,
    /// The number of the part being written.
    pub(super) index: usize,
    /// When it started.
    pub(super) started: Instant,
    /// What starts every part (no readers).
    pub(super) sources: Sources,
    /// The recording's options, which every part's start says.
    pub(super) options: RecordOptions,
    /// The skin's segment directory.
    pub(super) dir: PathBuf,
    /// The first part's channel ids, which every part must give.
    pub(super) ids: ChannelIds,
    /// The first part's clock offset, with which every message is stamped.
    pub(super) clock_offset_ns: i64,
}

/// Why the writing stopped short.
struct Stopped {
    error: RecordError,
    /// The part being written is sound and should be finished: only the
    /// next one could not be started.
    finish_current: bool,
}

impl From<RecordError> for Stopped {
    fn from(error: RecordError) -> Stopped {
        Stopped { error, finish_current: false }
    }
}

/// A finished part handed to [`close_part`].
struct Finished {
    writer: McapWriter,
    path: PathBuf,
    /// Its summary's counts.
    summary: BTreeMap<String, String>,
    /// Its size when handed over, already counted among the finished parts' bytes.
    counted_bytes: u64,
}

/// Why [`FileJob::write_until_done`] returned.
enum Written {
    /// The readers are done.
    All,
    /// The part is complete: the next one goes on.
    Part,
}

impl FileJob {
    pub(super) fn run(mut self) -> Result<(), RecordError> {
        if let Some(nice) = self.nice
            && let Err(e) = skinware::os::set_thread_nice(nice)
        {
            tracing::warn!(
                nice,
                error = %e,
                "the recorder's file thread keeps the normal weight (run as root, or allow a lower nice in \
                 /etc/security/limits.conf); beside other busy programs it may fall behind at high rates"
            );
        }
        let result = self.write_all();
        if let Err(Stopped { error, finish_current }) = result {
            // Unblock the readers: they stop on the signal, and their sends fail once the receiver is gone.
            self.shared.fail(error);
            drop(self.receiver);
            if finish_current {
                // Only the next part failed to start: this one is whole.
                let _ = finish_file(self.writer, &self.path, summary_metadata(&self.channels));
                return Ok(());
            }
            // A file that could not be written is not finished: that would
            // write more into a full or failing disk. What it holds is
            // readable up to its last complete chunk.
            drop(self.writer.into_inner());
            return Ok(());
        }
        self.finish()
    }

    fn write_all(&mut self) -> Result<(), Stopped> {
        let mut syncer = Syncer::start(&self.sync, &self.path, &self.shared)?;
        let mut closing: Option<JoinHandle<Result<(), RecordError>>> = None;
        loop {
            let written = self.write_until_done(&syncer);
            if let Ok(Written::Part) = written {
                // The part before has long been closed; its error, if any, stops the recording.
                join_closing(closing.take())?;
                let finished = match self.next_part() {
                    Ok(finished) => finished,
                    Err(error) => {
                        let _ = syncer.finish();
                        return Err(Stopped { error, finish_current: true });
                    }
                };
                let finished_syncer =
                    std::mem::replace(&mut syncer, Syncer::start(&self.sync, &self.path, &self.shared)?);
                closing = Some(close_part(finished, finished_syncer, &self.shared)?);
                continue;
            }
            let synced = syncer.finish();
            let closed = join_closing(closing);
            return Ok(written.and(closed).and(synced).map(drop)?);
        }
    }

    /// Whether the part being written is complete (never, unsplit).
    fn part_is_complete(&self) -> bool {
        self.parts.as_ref().is_some_and(|parts| {
            let bytes = self.sync.metadata().map_or(0, |m| m.len());
            parts.split.is_reached(bytes, parts.started.elapsed())
        })
    }

    /// Starts the next part, and returns the one being written for
    /// [`close_part`]. The frames the other threads send meanwhile wait in
    /// their queue: each frame is in one part only, and none is dropped at
    /// the switch (a queue that fills meanwhile makes readers miss frames,
    /// counted as always).
    fn next_part(&mut self) -> Result<Finished, RecordError> {
        let Some(parts) = self.parts.as_mut() else {
            return Err(RecordError::Split { reason: "the recording is not split".into() });
        };
        let path = part_path(&parts.base, parts.index + 1);
        let file = crate::error::create_new(&path)?;
        let part = Part::Later { clock_offset_ns: parts.clock_offset_ns };
        let started = write_start(&path, &file, &parts.options, &parts.sources, (&parts.dir, part))
            .and_then(|started| {
                // The same start gives the same ids; anything else is a bug here.
                (ChannelIds::of(&started) == parts.ids).then_some(started).ok_or_else(|| RecordError::Split {
                    reason: format!("{} numbered its channels differently from the first part", path.display()),
                })
            })
            .inspect_err(|_| {
                // Half a start is no part: the recording ends with the one before.
                let _ = std::fs::remove_file(&path);
            })?;
        parts.index += 1;
        parts.started = Instant::now();
        // Counted now, so that the progress never drops by a part while it closes.
        let counted_bytes = self.sync.metadata().map_or(0, |m| m.len());
        self.shared.finished_part_bytes.fetch_add(counted_bytes, Ordering::Relaxed);
        let summary = summary_metadata(&self.channels);
        let finished_path = std::mem::replace(&mut self.path, path.clone());
        let writer = std::mem::replace(&mut self.writer, started.writer);
        self.sync = file;
        skinware::lock(&self.shared.parts).push(path);
        Ok(Finished { writer, path: finished_path, summary, counted_bytes })
    }

    fn write_until_done(&mut self, syncer: &Syncer) -> Result<Written, RecordError> {
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
                Err(RecvTimeoutError::Disconnected) => return Ok(Written::All),
            }
            if Instant::now() >= next_flush {
                // A finished chunk, written: what a killed recorder leaves is
                // readable up to here, and once synced, what a machine that
                // loses power leaves.
                self.writer.flush().map_err(|e| mcap_write_error(&self.path, e))?;
                syncer.request();
                next_flush = Instant::now() + self.flush_interval;
                if self.part_is_complete() {
                    return Ok(Written::Part);
                }
            }
        }
    }

    /// Finishes the last file. Its size is not added to the finished
    /// parts': the recorder's progress reads the last part's own.
    fn finish(self) -> Result<(), RecordError> {
        finish_file(self.writer, &self.path, summary_metadata(&self.channels)).map(drop)
    }
}

/// What each channel counted since the recording started, as a file's
/// summary metadata says it (a part's: the running totals at its end).
fn summary_metadata(channels: &[Recorded]) -> BTreeMap<String, String> {
    let mut summary = BTreeMap::new();
    for channel in channels {
        let r = channel.report();
        summary.insert(
            channel.name.clone(),
            format!("kind={} frames={} lost={} gaps={} faulted={}", r.kind, r.frames, r.lost, r.gaps, r.faulted),
        );
    }
    summary
}

/// Finishes a file: `summary`, the MCAP summary and index, and the file
/// closed and synced. Its size.
fn finish_file(mut writer: McapWriter, path: &Path, summary: BTreeMap<String, String>) -> Result<u64, RecordError> {
    let write = |e| mcap_write_error(path, e);
    writer.write_metadata(&Metadata { name: SUMMARY_METADATA.into(), metadata: summary }).map_err(write)?;
    writer.finish().map_err(write)?;
    crate::file::close(writer.into_inner(), path)?;
    Ok(std::fs::metadata(path).map_or(0, |m| m.len()))
}

/// Closes a finished part in a thread of its own: the wait for its last
/// sync, its summary and index, and the sync of those take the disk a
/// while (a second or more for a part of a few GB), and on the file's
/// thread they held up the next part while the readers' queue filled. An
/// error stops the recording; [`join_closing`] reports it.
fn close_part(
    finished: Finished,
    syncer: Syncer,
    shared: &Arc<Shared>,
) -> Result<JoinHandle<Result<(), RecordError>>, RecordError> {
    let shared = shared.clone();
    std::thread::Builder::new()
        .name("rec-close".into())
        .spawn(move || {
            let Finished { writer, path, summary, counted_bytes } = finished;
            let closed = syncer.finish().and_then(|()| finish_file(writer, &path, summary));
            match closed {
                Ok(bytes) => {
                    shared.finished_part_bytes.fetch_add(bytes.saturating_sub(counted_bytes), Ordering::Relaxed);
                    Ok(())
                }
                Err(e) => {
                    // Everyone stops now; the file's thread reports the error.
                    shared.stop.stop();
                    Err(e)
                }
            }
        })
        .map_err(|source| RecordError::Thread { thread: "the part-closing thread".into(), source })
}

/// Waits for a part being closed, if any; its error.
fn join_closing(closing: Option<JoinHandle<Result<(), RecordError>>>) -> Result<(), RecordError> {
    match closing.map(JoinHandle::join) {
        None | Some(Ok(Ok(()))) => Ok(()),
        Some(Ok(Err(e))) => Err(e),
        Some(Err(_)) => Err(RecordError::Panicked { thread: "the part-closing thread" }),
    }
}

/// A thread that syncs the file to disk when asked. Syncing a second's worth
/// of an uncompressed recording (100 MB at the paper's skin at 1 kHz) takes
/// the disk a while; on the file's thread it stopped the writing for that
/// long, and the readers' queue filled.
struct Syncer {
    requests: SyncSender<()>,
    thread: JoinHandle<Result<(), RecordError>>,
}

impl Syncer {
    fn start(file: &File, path: &std::path::Path, shared: &Arc<Shared>) -> Result<Syncer, RecordError> {
        let file = file.try_clone().map_err(|source| RecordError::Io {
            op: "open a second handle to",
            path: path.to_owned(),
            hint: String::new(),
            source,
        })?;
        let (requests, received) = sync_channel::<()>(1);
        let (path, shared) = (path.to_owned(), shared.clone());
        let thread = std::thread::Builder::new()
            .name("rec-sync".into())
            .spawn(move || {
                while received.recv().is_ok() {
                    if let Err(source) = file.sync_data() {
                        // Everyone stops now; the file's thread reports the error.
                        shared.stop.stop();
                        return Err(RecordError::Io { op: "sync", hint: write_hint(&source), path, source });
                    }
                }
                Ok(())
            })
            .map_err(|source| RecordError::Thread { thread: "the file-syncing thread".into(), source })?;
        Ok(Syncer { requests, thread })
    }

    /// Asks for a sync of everything written so far; a sync still under way
    /// (or one asked for and not begun) covers it.
    fn request(&self) {
        match self.requests.try_send(()) {
            Ok(()) | Err(TrySendError::Full(())) | Err(TrySendError::Disconnected(())) => {}
        }
    }

    /// Waits for the last sync asked for; the error of one that failed.
    fn finish(self) -> Result<(), RecordError> {
        drop(self.requests);
        self.thread.join().unwrap_or(Err(RecordError::Panicked { thread: "the file-syncing thread" }))
    }
}
