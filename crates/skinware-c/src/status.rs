//! Status codes, the per-thread last error, and the guard every entry point
//! runs in (no panic crosses into C).

#![forbid(unsafe_code)]
#![allow(non_camel_case_types, reason = "the C API's names are C's: skinware_status, SKINWARE_OK")]

use std::cell::RefCell;
use std::ffi::CString;
use std::panic::{AssertUnwindSafe, catch_unwind};

/// What a call of the C API did: `SKINWARE_OK` (0) or why it failed.
/// `skinware_last_error()` then says more, on the same thread.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum skinware_status {
    /// Success.
    SKINWARE_OK = 0,
    /// A bad argument: a NULL pointer, a size that does not fit, a value out of range, a name that is not UTF-8.
    SKINWARE_E_INVALID_ARGUMENT = 1,
    /// The caller's buffer is smaller than the channel's frames (`payload_bytes`).
    SKINWARE_E_BUFFER_TOO_SMALL = 2,
    /// No such skin, channel, region, uid or index.
    SKINWARE_E_NOT_FOUND = 3,
    /// The channel's writer is gone and no successor took its place.
    SKINWARE_E_WRITER_GONE = 4,
    /// Nothing new before the timeout; the writer lives.
    SKINWARE_E_TIMEOUT = 5,
    /// The writer has not published its first frame yet.
    SKINWARE_E_NO_FRAME_YET = 6,
    /// The handle was stopped (`*_stop`): blocked and later waits return this.
    SKINWARE_E_STOPPED = 7,
    /// The operating system refused access (permissions of the channel's socket or memory).
    SKINWARE_E_ACCESS_DENIED = 8,
    /// Another live writer has the channel's name.
    SKINWARE_E_BUSY = 9,
    /// The channel is not what was asked for: a layer read as a service, another schema or record size.
    SKINWARE_E_SCHEMA_MISMATCH = 10,
    /// The writer kept overwriting the frame being copied (a reader stalled for K-1 frames, many times).
    SKINWARE_E_LAPPED = 11,
    /// The skin's geometry could not be opened or is inconsistent.
    SKINWARE_E_GEOMETRY = 12,
    /// Any other failure of the exchange (a foreign or corrupt channel, an OS error).
    SKINWARE_E_CHANNEL = 13,
    /// A bug in skinware: a panic, caught at the boundary. The message says where.
    SKINWARE_E_PANIC = 14,
}

use skinware_status::*;

/// A failed call: its code and its message.
#[derive(Debug)]
pub(crate) struct Failure {
    pub(crate) status: skinware_status,
    pub(crate) message: String,
}

impl Failure {
    pub(crate) fn new(status: skinware_status, message: impl Into<String>) -> Failure {
        Failure { status, message: message.into() }
    }

    /// A bad argument of function `function`.
    pub(crate) fn invalid(function: &str, message: impl std::fmt::Display) -> Failure {
        Failure::new(SKINWARE_E_INVALID_ARGUMENT, format!("{function}: {message}"))
    }

    /// A NULL where `function` needs `argument`.
    pub(crate) fn null(function: &str, argument: &str) -> Failure {
        Failure::invalid(function, format_args!("{argument} is NULL; pass a valid pointer"))
    }

    pub(crate) fn not_found(message: impl Into<String>) -> Failure {
        Failure::new(SKINWARE_E_NOT_FOUND, message)
    }
}

impl From<skinware::Error> for Failure {
    fn from(error: skinware::Error) -> Failure {
        use skinware::Error as E;
        let status = match &error {
            E::BufferTooSmall { .. } => SKINWARE_E_BUFFER_TOO_SMALL,
            E::Missing { .. } => SKINWARE_E_NOT_FOUND,
            E::WriterGone { .. } => SKINWARE_E_WRITER_GONE,
            E::Timeout { .. } => SKINWARE_E_TIMEOUT,
            E::NoFrameYet { .. } => SKINWARE_E_NO_FRAME_YET,
            E::Stopped { .. } => SKINWARE_E_STOPPED,
            E::AccessDenied { .. } => SKINWARE_E_ACCESS_DENIED,
            E::Busy { .. } => SKINWARE_E_BUSY,
            E::SchemaMismatch { .. } | E::NotThisService { .. } => SKINWARE_E_SCHEMA_MISMATCH,
            E::Lapped { .. } => SKINWARE_E_LAPPED,
            E::InvalidName { .. } | E::InvalidLayout { .. } | E::PayloadTooLarge { .. } => SKINWARE_E_INVALID_ARGUMENT,
            _ => SKINWARE_E_CHANNEL,
        };
        Failure::new(status, error.to_string())
    }
}

impl From<skinware_geometry::GeometryError> for Failure {
    fn from(error: skinware_geometry::GeometryError) -> Failure {
        Failure::new(SKINWARE_E_GEOMETRY, error.to_string())
    }
}

thread_local! {
    /// The message of this thread's last failed call.
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

/// Records `failure` as this thread's last error and returns its code.
fn record(failure: Failure) -> skinware_status {
    // A message with a NUL byte (from a hostile name) keeps what precedes it.
    let text = failure.message.split('\0').next().unwrap_or_default().to_owned();
    let text = CString::new(text).unwrap_or_default();
    // `try_with` fails only while the thread is exiting; the code still says what happened.
    let _ = LAST_ERROR.try_with(|last| *last.borrow_mut() = text);
    failure.status
}

/// Runs an entry point's body: its failure, or a panic, becomes a status and
/// this thread's last error.
pub(crate) fn guard(body: impl FnOnce() -> Result<(), Failure>) -> skinware_status {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => SKINWARE_OK,
        Ok(Err(failure)) => record(failure),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "a panic without a message".to_owned());
            record(Failure::new(
                SKINWARE_E_PANIC,
                format!("skinware panicked (a bug; please report it with this message): {what}"),
            ))
        }
    }
}

/// Runs `f` with this thread's last error message (empty if none).
pub(crate) fn with_last_error<T>(f: impl FnOnce(&CString) -> T) -> Option<T> {
    LAST_ERROR.try_with(|last| f(&last.borrow())).ok()
}

/// The constant name of `status`, as C writes it.
pub(crate) fn status_name(status: i32) -> &'static std::ffi::CStr {
    match status {
        0 => c"SKINWARE_OK",
        1 => c"SKINWARE_E_INVALID_ARGUMENT",
        2 => c"SKINWARE_E_BUFFER_TOO_SMALL",
        3 => c"SKINWARE_E_NOT_FOUND",
        4 => c"SKINWARE_E_WRITER_GONE",
        5 => c"SKINWARE_E_TIMEOUT",
        6 => c"SKINWARE_E_NO_FRAME_YET",
        7 => c"SKINWARE_E_STOPPED",
        8 => c"SKINWARE_E_ACCESS_DENIED",
        9 => c"SKINWARE_E_BUSY",
        10 => c"SKINWARE_E_SCHEMA_MISMATCH",
        11 => c"SKINWARE_E_LAPPED",
        12 => c"SKINWARE_E_GEOMETRY",
        13 => c"SKINWARE_E_CHANNEL",
        14 => c"SKINWARE_E_PANIC",
        _ => c"SKINWARE_E_UNKNOWN",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_a_status_and_a_message() {
        let status = guard(|| panic!("the sky fell"));
        assert_eq!(status, SKINWARE_E_PANIC);
        let message = with_last_error(|m| m.to_string_lossy().into_owned()).unwrap();
        assert!(message.contains("the sky fell"), "{message}");
    }

    #[test]
    fn a_message_with_a_nul_keeps_what_precedes_it() {
        let status = guard(|| Err(Failure::not_found("no channel a\0b")));
        assert_eq!(status, SKINWARE_E_NOT_FOUND);
        assert_eq!(with_last_error(|m| m.to_str().unwrap().to_owned()).unwrap(), "no channel a");
    }

    #[test]
    fn every_status_has_its_name() {
        for status in 0..=14 {
            assert_ne!(status_name(status), c"SKINWARE_E_UNKNOWN", "{status}");
        }
        assert_eq!(status_name(SKINWARE_E_TIMEOUT as i32), c"SKINWARE_E_TIMEOUT");
    }
}
