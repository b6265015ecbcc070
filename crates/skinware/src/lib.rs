//! Skinware: a real-time middleware that acquires tactile data from large robot
//! skins and hands it to any number of applications, in any process, without
//! ever slowing acquisition.
//!
//! This crate is the core exchange. A [`Writer`] (one per layer or service)
//! creates a named shared-memory channel and publishes frames into a seqlock
//! ring of K buffers; [`Reader`]s in other processes attach by name and obtain
//! the newest complete frame periodically ([`Reader::next_periodic`]), as soon
//! as it is published ([`Reader::wait_newer`]) or on request
//! ([`Reader::latest`], [`Reader::request`]).
//!
//! * The writer is wait-free and nothing readers write decides what it does:
//!   its cost per frame does not depend on how many readers exist or what they
//!   do. Readers get the frames read-only, in sealed memory nobody can truncate
//!   (`docs/security.md`).
//! * Readers are lock-free, never see a torn frame, and keep no state in shared
//!   memory on the data path: a reader killed or stopped mid-read harms no one.
//! * A writer holds an open-file-description lock that the kernel drops when
//!   its process dies, so readers can tell a gone writer; a new writer takes
//!   the channel's name and readers follow it.
//!
//! ```
//! use std::time::Duration;
//! use skinware::{FrameStatus, Reader, Writer, WriterOptions};
//!
//! # let skin = format!("doc{}", std::process::id());
//! // A driver process: a layer of 4 taxels, one u16 response each.
//! let mut writer = Writer::create(&skin, "pressure", 2 * 4, b"4 taxels", &WriterOptions::default())?;
//! // Any application process:
//! let mut reader = Reader::open(&skin, "pressure")?;
//!
//! let mut frame = writer.begin(); // filled in place, in shared memory
//! frame.write_responses(0, &[10, 20, 30, 40])?;
//! frame.publish();
//!
//! let frame = reader.wait_newer(Duration::from_secs(1))?;
//! assert_eq!(frame.responses(), &[10, 20, 30, 40]);
//! assert_eq!(frame.seq(), 1);
//! assert_eq!(frame.status(), FrameStatus::OK);
//! # Ok::<(), skinware::Error>(())
//! ```
//!
//! Cargo features: none yet; the crate depends only on `rustix`, `libc`,
//! `thiserror`, `bytemuck` and `tracing`.

#![cfg_attr(loom, allow(dead_code, unused_imports))]

/// The README's examples, compiled as doc-tests.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeExamples;

#[cfg(not(loom))]
mod anticipate;
mod channel;

mod sync;

#[cfg(not(loom))]
pub mod driver;
#[cfg(not(loom))]
mod error;
#[cfg(not(loom))]
mod frame;
// The one poison-tolerant lock helper.
mod locks;
#[cfg(not(loom))]
pub mod os;
#[cfg(not(loom))]
mod reader;
#[cfg(not(loom))]
pub mod rt;
#[cfg(not(loom))]
pub mod shm;
#[cfg(not(loom))]
mod stats;
#[cfg(not(loom))]
pub mod topology;
#[cfg(not(loom))]
pub mod wire;
#[cfg(not(loom))]
mod writer;

#[cfg(not(loom))]
pub use channel::ChannelKind;
#[cfg(not(loom))]
pub use channel::layout::{ABI_VERSION, MAX_SLOTS, MIN_SLOTS};
#[cfg(not(loom))]
pub use channel::registry::{
    ChannelInfo, WriterRecord, list_channels, list_channels_where, list_skin_channels, remove_channel_if_stale,
    remove_stale_channels,
};
#[cfg(not(loom))]
pub use driver::{Driver, DriverError, DriverHandler, HandlerOptions, LayerSource, LayerSpec};
#[cfg(not(loom))]
pub use error::{Error, Result};
#[cfg(not(loom))]
pub use frame::{Frame, FrameInfo, FrameStatus};
/// The one way skinware takes a lock whose holder panicked.
pub use locks::lock;
#[cfg(not(loom))]
pub use reader::{Reader, ReaderOptions};
#[cfg(not(loom))]
pub use rt::{ReaderWake, RtOptions, Stop, Tick, Ticker};
#[cfg(not(loom))]
pub use stats::{ReaderStats, UnknownWriterState, WriterState, WriterStats, histogram_quantile};
#[cfg(not(loom))]
pub use topology::{LayerTopology, TopologyBuilder, TopologyError};
#[cfg(not(loom))]
pub use writer::{
    Access, DEFAULT_SLOTS, FrameWriter, READABLE_HISTORY, WakeCounts, Writer, WriterOptions, WriterStateHandle,
    slots_for_history,
};
