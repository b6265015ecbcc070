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

/// The entry points called as C calls them, on what needs no running skin
/// (topologies, tickers, statuses, bad arguments): also run under Miri,
/// which checks the pointer conversions above.
#[cfg(test)]
mod tests {
    use std::ffi::CStr;
    use std::ptr::{null, null_mut};

    use super::*;
    use crate::status::skinware_status::*;

    fn last_error() -> String {
        // SAFETY: skinware_last_error returns a valid NUL-terminated string.
        unsafe { CStr::from_ptr(skinware_last_error()) }.to_string_lossy().into_owned()
    }

    #[test]
    fn a_uniform_topology_describes_itself_and_finds_uids() {
        let mut topology = null_mut();
        // SAFETY: valid C strings and a valid out-pointer.
        let made =
            unsafe { skinware_topology_uniform(c"hand".as_ptr(), c"pressure".as_ptr(), 50.0, 2, 3, 4, &mut topology) };
        assert_eq!(made, SKINWARE_OK, "{}", last_error());
        let mut summary = std::mem::MaybeUninit::<skinware_topology_summary>::uninit();
        // SAFETY: a live handle and a writable summary.
        assert_eq!(unsafe { skinware_topology_describe(topology, summary.as_mut_ptr()) }, SKINWARE_OK);
        // SAFETY: written on success.
        let summary = unsafe { summary.assume_init() };
        assert_eq!((summary.sensors, summary.modules, summary.patches), (24, 6, 2));
        // SAFETY: the name lives as long as the topology.
        assert_eq!(unsafe { CStr::from_ptr(summary.name) }, c"hand");
        let mut uids = [0u32; 24];
        // SAFETY: room for 24 uids.
        assert_eq!(unsafe { skinware_topology_uids(topology, uids.as_mut_ptr(), 24) }, SKINWARE_OK);
        assert_eq!(uids[23], 23);
        let mut index = 0;
        // SAFETY: a live handle and a writable index.
        assert_eq!(unsafe { skinware_topology_index_of(topology, 17, &mut index) }, SKINWARE_OK);
        assert_eq!(index, 17);
        let mut sensor = skinware_sensor::default();
        // SAFETY: as above.
        assert_eq!(unsafe { skinware_topology_sensor(topology, 17, &mut sensor) }, SKINWARE_OK);
        assert_eq!((sensor.module_index, sensor.patch_index, sensor.patch_id), (4, 1, 1));
        // SAFETY: index 24 is past the end: refused, `sensor` untouched.
        assert_eq!(unsafe { skinware_topology_sensor(topology, 24, &mut sensor) }, SKINWARE_E_NOT_FOUND);
        // SAFETY: closing a live handle, then the same handle again.
        assert_eq!(unsafe { skinware_topology_free(topology) }, SKINWARE_OK);
        // SAFETY: a closed handle is refused, never dereferenced.
        assert_eq!(unsafe { skinware_topology_free(topology) }, SKINWARE_E_INVALID_ARGUMENT);
        assert!(last_error().contains("closed"), "{}", last_error());
    }

    #[test]
    fn a_builder_checks_what_a_driver_builds() {
        let mut builder = null_mut();
        // SAFETY: valid C strings and out-pointer.
        let made =
            unsafe { skinware_topology_builder_new(c"finger".as_ptr(), c"pressure".as_ptr(), 0.0, &mut builder) };
        assert_eq!(made, SKINWARE_OK);
        let uids = [7u32, 8, 9];
        // SAFETY: three readable uids.
        assert_eq!(unsafe { skinware_topology_builder_add_module(builder, 1, 1, uids.as_ptr(), 3) }, SKINWARE_OK);
        // SAFETY: NULL uids with a count: refused.
        let null_uids = unsafe { skinware_topology_builder_add_module(builder, 1, 2, null(), 3) };
        assert_eq!(null_uids, SKINWARE_E_INVALID_ARGUMENT);
        assert!(last_error().contains("uids is NULL"), "{}", last_error());
        // SAFETY: a duplicate uid: the build refuses it.
        assert_eq!(unsafe { skinware_topology_builder_add_module(builder, 1, 2, uids.as_ptr(), 1) }, SKINWARE_OK);
        let mut topology = null_mut();
        // SAFETY: a live builder and a writable out-pointer.
        assert_eq!(unsafe { skinware_topology_builder_build(builder, &mut topology) }, SKINWARE_E_INVALID_ARGUMENT);
        assert!(topology.is_null(), "nothing written on failure");
        // SAFETY: freeing a live builder, then NULL.
        assert_eq!(unsafe { skinware_topology_builder_free(builder) }, SKINWARE_OK);
        // SAFETY: NULL is accepted by every free.
        assert_eq!(unsafe { skinware_topology_builder_free(null_mut()) }, SKINWARE_OK);
    }

    #[test]
    fn bad_arguments_are_codes_with_messages() {
        let mut reader = null_mut();
        // SAFETY: NULL names are refused before anything is read.
        let null_skin = unsafe { skinware_reader_open(null(), c"x".as_ptr(), null(), &mut reader) };
        assert_eq!(null_skin, SKINWARE_E_INVALID_ARGUMENT);
        assert!(last_error().contains("skin is NULL"), "{}", last_error());
        let not_utf8 = [0xffu8, 0xfe, 0];
        // SAFETY: a NUL-terminated string that is not UTF-8.
        let refused = unsafe { skinware_reader_open(not_utf8.as_ptr().cast(), c"x".as_ptr(), null(), &mut reader) };
        assert_eq!(refused, SKINWARE_E_INVALID_ARGUMENT);
        assert!(last_error().contains("not UTF-8"), "{}", last_error());
        let mut buffer = [0u8; 8];
        let made_up = std::ptr::without_provenance_mut::<skinware_reader>(0xdead_beef);
        // SAFETY: a made-up handle is looked up, never dereferenced.
        let latest = unsafe { skinware_reader_latest(made_up, buffer.as_mut_ptr().cast(), 8, null_mut()) };
        assert_eq!(latest, SKINWARE_E_INVALID_ARGUMENT);
        let mut ticker = null_mut();
        // SAFETY: a period of 0 is refused.
        assert_eq!(unsafe { skinware_ticker_new(0, &mut ticker) }, SKINWARE_E_INVALID_ARGUMENT);
        assert!(last_error().contains("1000000 for 1 kHz"), "{}", last_error());
        // SAFETY: a NULL out-pointer is refused.
        assert_eq!(unsafe { skinware_ticker_new(1_000_000, null_mut()) }, SKINWARE_E_INVALID_ARGUMENT);
        // SAFETY: the status names are static strings.
        assert_eq!(unsafe { CStr::from_ptr(skinware_status_name(5)) }, c"SKINWARE_E_TIMEOUT");
        assert_eq!(skinware_abi_version(), crate::SKINWARE_ABI_VERSION);
    }

    #[test]
    #[cfg_attr(miri, ignore = "sleeps through rustix's raw futex system call, which Miri cannot run")]
    fn a_stopped_ticker_returns_at_once() {
        let mut ticker = null_mut();
        // SAFETY: a valid period and out-pointer.
        assert_eq!(unsafe { skinware_ticker_new(1_000_000, &mut ticker) }, SKINWARE_OK);
        let mut tick = std::mem::MaybeUninit::<skinware_tick>::uninit();
        // SAFETY: a live ticker and a writable tick.
        assert_eq!(unsafe { skinware_ticker_wait(ticker, tick.as_mut_ptr()) }, SKINWARE_OK);
        // SAFETY: stopping, then waiting on, a live ticker.
        assert_eq!(unsafe { skinware_ticker_stop(ticker) }, SKINWARE_OK);
        // SAFETY: as above; NULL tick is optional.
        assert_eq!(unsafe { skinware_ticker_wait(ticker, null_mut()) }, SKINWARE_E_STOPPED);
        // SAFETY: freeing a live ticker.
        assert_eq!(unsafe { skinware_ticker_free(ticker) }, SKINWARE_OK);
    }
}
