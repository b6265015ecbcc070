//! The one place atomics come from, so that `loom` can replace them in model tests.
//!
//! Under `--cfg loom` the seqlock ring is compiled against loom's atomics and
//! checked exhaustively; everything that maps real shared memory is compiled out.

#![forbid(unsafe_code)]

#[cfg(loom)]
pub(crate) use loom::sync::atomic::{AtomicU64, Ordering, fence};

#[cfg(not(loom))]
pub(crate) use std::sync::atomic::{AtomicU64, Ordering, fence};
