//! The library's integration tests, as one test binary (one link instead of
//! one per file). The multi-process stress test has its own harness
//! (`tests/stress.rs`), since its child processes are re-executions of it.

// The tests use the standard atomics freely; the rule that every atomic comes
// from `sync` is for the library (see `clippy.toml`).
#![allow(clippy::disallowed_types)]

mod alloc_bound;
mod attacks;
mod bad_input;
mod driver;
mod exchange;
mod neighbours;
mod permissions;
mod util;
mod wire;
