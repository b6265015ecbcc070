//! What recording and replaying can fail with.

use std::path::PathBuf;

/// Errors of recording, reading and replaying.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// The output file exists.
    #[error("{path} exists; choose another name, or remove it first (a recording is never overwritten)")]
    Exists {
        /// The file.
        path: PathBuf,
    },
    /// A split recording's limits (`RecordOptions::split`) that cannot be
    /// kept, or a part that could not be started like the first.
    #[error("cannot split the recording: {reason}")]
    Split {
        /// What is wrong.
        reason: String,
    },
    /// A file could not be created, written, read or synced.
    #[error("cannot {op} {path}: {source}{hint}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
        /// What to do about it.
        hint: String,
    },
    /// The file is not an MCAP file at all.
    #[error("{path} is not an MCAP file (it starts with {start:02x?}, not the MCAP magic 89 4d 43 41 50 30 0d 0a)")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// Its first bytes.
        start: Vec<u8>,
    },
    /// The file is MCAP but damaged where it is not merely truncated.
    #[error("{path} is damaged at byte {offset}: {reason}")]
    Damaged {
        /// The file.
        path: PathBuf,
        /// Where.
        offset: u64,
        /// The MCAP reader's complaint.
        reason: String,
    },
    /// The file is MCAP but holds no skinware recording.
    #[error("{path} holds no skinware recording ({reason}); record one with `skin record`")]
    NotARecording {
        /// The file.
        path: PathBuf,
        /// What is missing.
        reason: String,
    },
    /// The file was written by a newer skinware.
    #[error(
        "{path} is recording format {found}, newer than this skinware's {supported}; read it with a newer skinware"
    )]
    FutureVersion {
        /// The file.
        path: PathBuf,
        /// Its version.
        found: u32,
        /// Ours.
        supported: u32,
    },
    /// A skinware topic whose schema this version does not know.
    #[error("topic {topic} has schema {schema:?} ({encoding}), which skinware cannot replay; expected {expected}")]
    UnknownSchema {
        /// The topic.
        topic: String,
        /// Its schema's name.
        schema: String,
        /// Its schema's encoding.
        encoding: String,
        /// What skinware writes.
        expected: String,
    },
    /// The recording's geometry attachment does not decode.
    #[error("the recording's geometry attachment does not decode: {0}")]
    BadGeometry(#[source] skinware::wire::DecodeError),
    /// The recording's geometry could not be published for the replay.
    #[error("cannot publish the geometry: {0}")]
    PublishGeometry(#[source] skinware_geometry::GeometryError),
    /// A recorded frame that does not decode.
    #[error(
        "{path}: a frame of channel {channel} does not decode ({source}); `skin record --recover {path}` keeps what came before it"
    )]
    BadFrame {
        /// The file.
        path: PathBuf,
        /// The frame's channel.
        channel: String,
        /// Why.
        source: skinware_ros2::DecodeError,
    },
    /// A message that does not fit its channel.
    #[error("{context}")]
    Mismatch {
        /// What does not fit what.
        context: String,
    },
    /// A message could not be encoded.
    #[error(transparent)]
    Encode(#[from] skinware_ros2::EncodeError),
    /// The MCAP writer failed.
    #[error("writing {path} failed: {source}{hint}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The writer's error.
        source: mcap::McapError,
        /// What to do about it.
        hint: String,
    },
    /// One of the recorder's or the replay's threads could not be started.
    #[error("cannot start {thread}: {source}")]
    Thread {
        /// Which thread.
        thread: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// One of the recorder's threads panicked.
    #[error("{thread} panicked")]
    Panicked {
        /// Which thread.
        thread: &'static str,
    },
    /// A channel of the skin could not be read or created.
    #[error(transparent)]
    Channel(#[from] skinware::Error),
    /// Nothing to record.
    #[error("{0}")]
    Nothing(String),
}

/// The advice for an I/O error while writing a recording.
pub(crate) fn write_hint(error: &std::io::Error) -> String {
    use std::io::ErrorKind;
    match error.kind() {
        ErrorKind::StorageFull | ErrorKind::QuotaExceeded | ErrorKind::FileTooLarge => format!(
            "; no room is left ({}). Everything up to the last complete chunk (the last second) is in the file: \
             `skin record --recover FILE --out ELSEWHERE.mcap` writes a finished copy",
            match error.kind() {
                ErrorKind::StorageFull => "the disk is full",
                ErrorKind::QuotaExceeded => "the disk quota is exceeded",
                _ => "the file size limit is reached",
            }
        ),
        ErrorKind::PermissionDenied => "; permission denied: record into a directory you may write".to_owned(),
        ErrorKind::ReadOnlyFilesystem => "; the file system is read-only: record elsewhere".to_owned(),
        _ => String::new(),
    }
}

/// Creates `path` for a new recording, never over an existing file.
pub(crate) fn create_new(path: &std::path::Path) -> Result<std::fs::File, RecordError> {
    std::fs::OpenOptions::new().write(true).create_new(true).open(path).map_err(|source| {
        if source.kind() == std::io::ErrorKind::AlreadyExists {
            RecordError::Exists { path: path.to_owned() }
        } else {
            RecordError::Io { op: "create", path: path.to_owned(), hint: write_hint(&source), source }
        }
    })
}

/// An error of the MCAP writer on `path`, with advice for I/O errors.
pub(crate) fn mcap_write_error(path: &std::path::Path, e: mcap::McapError) -> RecordError {
    RecordError::Write {
        path: path.to_owned(),
        hint: match &e {
            mcap::McapError::Io(io) => write_hint(io),
            _ => String::new(),
        },
        source: e,
    }
}
