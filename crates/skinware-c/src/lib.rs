//! The C API of skinware: `libskinware` (shared and static, built by
//! `cargo cbuild`/`cargo cinstall`) and its header `skinware.h` (made by
//! cbindgen from this crate, committed in `include/`), plus the header-only
//! C++17 wrapper `include/skinware.hpp` over it. `docs/c.md` is the guide.
//!
//! The shape of every entry point:
//!
//! * it returns a [`skinware_status`]: `SKINWARE_OK`, or an error code whose
//!   message, naming the thing and the fix, [`api::skinware_last_error`]
//!   gives on the same thread until its next failing call;
//! * results go through out-pointers, written only on success;
//! * nothing unwinds into C: every entry point runs under `catch_unwind`,
//!   and a panic becomes `SKINWARE_E_PANIC` with its message;
//! * handles are opaque and freed by the one function named for them
//!   (`skinware_reader_close`, `skinware_topology_free`, ...), which accepts
//!   NULL. A handle may be used from any thread; the calls on one handle take
//!   turns (a mutex), except `*_stop`, which wakes a call blocked in another
//!   thread.
//!
//! `unsafe` lives in the `api` modules only, where C's pointers become
//! references (each conversion with the contract it rests on); everything
//! behind them (`handles`, `status`) forbids it.

pub mod api;
mod handles;
mod registry;
mod status;

pub use api::*;
pub use status::skinware_status;

/// The version of the C API's binary interface: the header's
/// `SKINWARE_ABI_VERSION`, and the shared library's soname
/// (`libskinware.so.1`). It changes when a function's signature, a struct's
/// layout or a constant's meaning changes; a program built against another
/// version must be rebuilt (`skinware_abi_version()` tells at run time).
pub const SKINWARE_ABI_VERSION: u32 = 1;
