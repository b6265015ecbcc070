//! The entry points C calls, and the only place where C's pointers are
//! trusted. Every pointer argument is either refused when NULL (with
//! `SKINWARE_E_INVALID_ARGUMENT` and a message naming it) or documented as
//! optional; a non-NULL pointer must be valid, aligned and large enough for
//! what the function says, for the duration of the call. Handles are not
//! pointers into Rust memory at all (see `registry`): a closed or made-up
//! handle is refused, never dereferenced.

#![allow(non_camel_case_types, reason = "the C API's names are C's: skinware_reader, skinware_frame_info")]
#![allow(
    clippy::missing_safety_doc,
    reason = "one contract for every entry point's pointers, stated in the module docs and in the header's preamble"
)]

use std::ffi::{CStr, c_char, c_void};
use std::sync::Arc;

use crate::handles::{
    BuilderHandle, ChannelList, GeometryHandle, ReaderHandle, TickerHandle, TopologyHandle, WriterHandle,
};
use crate::registry::Registry;
use crate::status::{self, Failure, guard, skinware_status};

mod model;
mod read;
mod write;

pub use model::*;
pub use read::*;
pub use write::*;

/// An open reader of one channel (a layer or a service). Made by
/// `skinware_reader_open` (and `skinware_contacts_open`, ...), freed by
/// `skinware_reader_close`.
pub struct skinware_reader {
    _opaque: [u8; 0],
}

/// A periodic schedule on absolute time. Made by `skinware_ticker_new` or
/// `skinware_writer_ticker`, freed by `skinware_ticker_free`.
pub struct skinware_ticker {
    _opaque: [u8; 0],
}

/// A layer's topology: patches, modules, sensors. Made by
/// `skinware_reader_topology`, `skinware_topology_builder_build` or
/// `skinware_topology_uniform`, freed by `skinware_topology_free`.
pub struct skinware_topology {
    _opaque: [u8; 0],
}

/// A topology under construction (a driver's). Made by
/// `skinware_topology_builder_new`, freed by `skinware_topology_builder_free`.
pub struct skinware_topology_builder {
    _opaque: [u8; 0],
}

/// The writer of one layer: a driver written in C. Made by
/// `skinware_writer_create`, freed by `skinware_writer_close`.
pub struct skinware_writer {
    _opaque: [u8; 0],
}

/// The skin's geometry: positions, normals, the 2-D map, neighbours,
/// regions. Made by `skinware_geometry_open`, freed by `skinware_geometry_free`.
pub struct skinware_geometry {
    _opaque: [u8; 0],
}

/// A listing of the channels that exist. Made by `skinware_list_channels`,
/// freed by `skinware_channel_list_free`.
pub struct skinware_channel_list {
    _opaque: [u8; 0],
}

static READERS: Registry<ReaderHandle> = Registry::new(1);
static TICKERS: Registry<TickerHandle> = Registry::new(2);
static TOPOLOGIES: Registry<TopologyHandle> = Registry::new(3);
static BUILDERS: Registry<BuilderHandle> = Registry::new(4);
static WRITERS: Registry<WriterHandle> = Registry::new(5);
static GEOMETRIES: Registry<GeometryHandle> = Registry::new(6);
static LISTS: Registry<ChannelList> = Registry::new(7);

/// Keeps `value` in `registry` and returns the C handle for it.
fn register<T, C>(registry: &Registry<T>, value: T, what: &str) -> Result<*mut C, Failure> {
    registry.insert(value).map(std::ptr::without_provenance_mut).ok_or_else(|| {
        Failure::new(
            skinware_status::SKINWARE_E_INVALID_ARGUMENT,
            format!("16777216 {what}s are open; close the ones no longer used (a leak?)"),
        )
    })
}

/// The live object behind C handle `handle`.
fn live<T, C>(registry: &Registry<T>, handle: *const C, function: &str, what: &str) -> Result<Arc<T>, Failure> {
    if handle.is_null() {
        return Err(Failure::null(function, what));
    }
    registry.get(handle.addr()).ok_or_else(|| {
        Failure::invalid(
            function,
            format_args!("the {what} handle {handle:p} is closed, or is not a {what}; use a handle from its open or create function, once"),
        )
    })
}

/// Closes C handle `handle`: NULL is ignored; a closed or made-up handle is
/// an error (a double close).
fn release<T, C>(
    registry: &Registry<T>,
    handle: *const C,
    function: &str,
    what: &str,
) -> Result<Option<Arc<T>>, Failure> {
    if handle.is_null() {
        return Ok(None);
    }
    registry.remove(handle.addr()).map(Some).ok_or_else(|| {
        Failure::invalid(function, format_args!("the {what} handle {handle:p} was closed already, or is not a {what}"))
    })
}

/// A C string argument as UTF-8.
///
/// Sound only for a pointer satisfying the module's contract: NULL, or a
/// NUL-terminated string valid during the call. Only entry points call it.
fn text<'a>(pointer: *const c_char, function: &str, argument: &str) -> Result<&'a str, Failure> {
    if pointer.is_null() {
        return Err(Failure::null(function, argument));
    }
    // SAFETY: non-NULL, and by the entry point's contract a NUL-terminated
    // string that outlives the call ('a is never longer than the call).
    let raw = unsafe { CStr::from_ptr(pointer) };
    raw.to_str().map_err(|_| Failure::invalid(function, format_args!("{argument} is not UTF-8")))
}

/// An optional C string argument (NULL: none).
fn optional_text<'a>(pointer: *const c_char, function: &str, argument: &str) -> Result<Option<&'a str>, Failure> {
    if pointer.is_null() { Ok(None) } else { text(pointer, function, argument).map(Some) }
}

/// Where an entry point writes a result: checked before anything is done,
/// written once on success.
struct Out<T>(*mut T);

impl<T> Out<T> {
    /// A required out-pointer.
    fn new(pointer: *mut T, function: &str, argument: &str) -> Result<Out<T>, Failure> {
        if pointer.is_null() {
            return Err(Failure::null(function, argument));
        }
        if !pointer.is_aligned() {
            return Err(Failure::invalid(function, format_args!("{argument} {pointer:p} is misaligned")));
        }
        Ok(Out(pointer))
    }

    /// An optional out-pointer (NULL: not wanted).
    fn optional(pointer: *mut T, function: &str, argument: &str) -> Result<Option<Out<T>>, Failure> {
        if pointer.is_null() { Ok(None) } else { Out::new(pointer, function, argument).map(Some) }
    }

    /// Writes the result.
    ///
    /// Sound only for a pointer satisfying the module's contract (valid
    /// for writing a `T` during the call); `new` checked NULL and alignment.
    fn put(self, value: T) {
        // SAFETY: non-NULL and aligned (checked in `new`), and by the entry
        // point's contract valid for writes of one T. `write` does not read
        // or drop what was there (C memory, possibly uninitialised).
        unsafe { self.0.write(value) }
    }
}

/// A caller's buffer to fill.
///
/// Sound only for a pointer satisfying the module's contract (valid for
/// writes of `bytes` bytes during the call, not aliased by the library).
fn buffer<'a>(pointer: *mut c_void, bytes: usize, function: &str) -> Result<&'a mut [u8], Failure> {
    if pointer.is_null() {
        return Err(Failure::null(function, "buffer"));
    }
    if bytes > isize::MAX as usize {
        return Err(Failure::invalid(function, format_args!("buffer_bytes {bytes} is not a size")));
    }
    // SAFETY: non-NULL, `bytes` fits an allocation, and by the entry point's
    // contract the memory is the caller's, writable for `bytes` bytes, and not
    // touched by anyone else during the call. Bytes have no alignment.
    Ok(unsafe { std::slice::from_raw_parts_mut(pointer.cast::<u8>(), bytes) })
}

/// A caller's array of `count` values to read.
///
/// Sound only for a pointer satisfying the module's contract (valid for
/// reads of `count` values of T during the call).
fn array<'a, T>(pointer: *const T, count: usize, function: &str, argument: &str) -> Result<&'a [T], Failure> {
    if count == 0 {
        return Ok(&[]);
    }
    if pointer.is_null() {
        return Err(Failure::null(function, argument));
    }
    if !pointer.is_aligned() || count > isize::MAX as usize / size_of::<T>().max(1) {
        return Err(Failure::invalid(
            function,
            format_args!("{argument} {pointer:p} with {count} values is misaligned or too large"),
        ));
    }
    // SAFETY: non-NULL, aligned, the size fits an allocation, and by the
    // entry point's contract valid for reads of `count` values during the call.
    Ok(unsafe { std::slice::from_raw_parts(pointer, count) })
}

/// A caller's array of `count` values to fill.
///
/// Sound only for a pointer satisfying the module's contract.
fn array_mut<'a, T: Copy>(
    pointer: *mut T,
    count: usize,
    function: &str,
    argument: &str,
) -> Result<&'a mut [T], Failure> {
    if count == 0 {
        return Ok(&mut []);
    }
    if pointer.is_null() {
        return Err(Failure::null(function, argument));
    }
    if !pointer.is_aligned() || count > isize::MAX as usize / size_of::<T>().max(1) {
        return Err(Failure::invalid(
            function,
            format_args!("{argument} {pointer:p} with {count} values is misaligned or too large"),
        ));
    }
    // SAFETY: as in `array`, for writes; T is Copy (plain C values), so
    // overwriting what was there drops nothing.
    Ok(unsafe { std::slice::from_raw_parts_mut(pointer, count) })
}

/// A caller's input struct, or `None` for NULL.
///
/// Sound only for a pointer satisfying the module's contract.
fn input<'a, T>(pointer: *const T, function: &str, argument: &str) -> Result<Option<&'a T>, Failure> {
    if pointer.is_null() {
        return Ok(None);
    }
    if !pointer.is_aligned() {
        return Err(Failure::invalid(function, format_args!("{argument} {pointer:p} is misaligned")));
    }
    // SAFETY: non-NULL, aligned, and by the entry point's contract a valid,
    // initialised T during the call (plain C integers and floats: every bit
    // pattern of its fields is a valid value).
    Ok(Some(unsafe { &*pointer }))
}

/// The version of the C ABI this library implements: compare it with the
/// header's `SKINWARE_ABI_VERSION` (`skinware_abi_compatible()` does).
#[unsafe(no_mangle)]
pub extern "C" fn skinware_abi_version() -> u32 {
    crate::SKINWARE_ABI_VERSION
}

/// The library's version, e.g. "0.1.0" (static storage; never free it).
#[unsafe(no_mangle)]
pub extern "C" fn skinware_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// The message of this thread's last failed call: what went wrong, naming
/// the thing and the fix. "" if no call failed on this thread. Valid until
/// this thread's next failing call; never free it.
#[unsafe(no_mangle)]
pub extern "C" fn skinware_last_error() -> *const c_char {
    status::with_last_error(|message| message.as_ptr()).unwrap_or(c"".as_ptr())
}

/// The name of a status code, e.g. "SKINWARE_E_TIMEOUT" (static storage).
#[unsafe(no_mangle)]
pub extern "C" fn skinware_status_name(status: i32) -> *const c_char {
    status::status_name(status).as_ptr()
}

/// The clock frames are stamped with: CLOCK_MONOTONIC, ns.
#[unsafe(no_mangle)]
pub extern "C" fn skinware_monotonic_ns() -> u64 {
    skinware::os::monotonic_ns()
}

/// Runs `body` as an entry point (no panic escapes) and returns its status.
fn entry(body: impl FnOnce() -> Result<(), Failure>) -> skinware_status {
    guard(body)
}
