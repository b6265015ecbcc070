//! The file's thread: the only owner of the file. It writes what the other
//! threads send, finishes a chunk every flush interval and has a thread of
//! its own sync it to disk, and finishes the file with the summary when they
//! are done.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};

use super::file_start::McapWriter;
use super::summary::Recorded;
use super::{Item, Shared};
use crate::error::{mcap_write_error, write_hint};
use crate::{RecordError, SUMMARY_METADATA};

/// The writer thread's job: owns the file.
pub(super) struct FileJob {
    pub(super) path: PathBuf,
    pub(super) writer: McapWriter,
    /// The same file, to sync what was flushed.
    pub(super) sync: File,
    pub(super) receiver: Receiver<Item>,
    pub(super) flush_interval: Duration,
    pub(super) shared: Arc<Shared>,
    pub(super) channels: Vec<Recorded>,
    /// The nice value the thread asks for, if any.
    pub(super) nice: Option<i32>,
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
        let syncer = Syncer::start(&self.sync, &self.path, &self.shared)?;
        let written = self.write_until_done(&syncer);
        let synced = syncer.finish();
        written.and(synced)
    }

    fn write_until_done(&mut self, syncer: &Syncer) -> Result<(), RecordError> {
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
                // A finished chunk, written: what a killed recorder leaves is
                // readable up to here, and once synced, what a machine that
                // loses power leaves.
                self.writer.flush().map_err(|e| mcap_write_error(&self.path, e))?;
                syncer.request();
                next_flush = Instant::now() + self.flush_interval;
            }
        }
    }

    fn finish(mut self) -> Result<(), RecordError> {
        let mut summary = BTreeMap::new();
        for channel in &self.channels {
            let r = channel.report();
            summary.insert(
                channel.name.clone(),
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
