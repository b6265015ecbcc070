//! The file's thread: the only owner of the file. It writes what the other
//! threads send, finishes a chunk and syncs it every flush interval, and
//! finishes the file with the summary when they are done.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::{Receiver, RecvTimeoutError};
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
}

impl FileJob {
    pub(super) fn run(mut self) -> Result<(), RecordError> {
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
