//! The frame exchange, in the order a newcomer should read it.
//!
//! A *channel* is the shared memory of one writer (a layer or a service),
//! reached by name through the socket `/dev/shm/skinware.<skin>.<channel>`.
//! The writer publishes frames into it without ever waiting for anyone;
//! readers in any process copy the newest complete frame out of it.
//!
//! 1. [`layout`]: the bytes of a channel: a header (magic, ABI version, sizes,
//!    state, statistics), the description (the topology) and K frame slots,
//!    all read-only for readers; and apart, the doorbell page. Every field is
//!    an atomic.
//! 2. [`ring`]: the seqlock. The writer fills slot `seq % K` between an odd and
//!    an even stamp, then stores `published = seq`; a reader copies the slot
//!    `published` names and keeps the copy only if the stamp did not move.
//!    This is the whole data path, in safe code over atomics, model-checked
//!    with loom.
//! 3. [`copy`]: how payload words move between a slot and private memory
//!    (relaxed atomics, 16 bytes at a time on x86-64), sound while the writer
//!    may be rewriting the slot.
//! 4. [`doorbell`]: the futex protocol by which as-soon-as-available readers
//!    sleep until a publish (the writer makes a system call only when one is
//!    asleep), sporadic writers sleep until a request, and a stop wakes both.
//!    Model-checked with loom for lost wake-ups.
//!    [`ringer`]: the wake handed from the writer to a thread on its CPU
//!    one priority below it, so that the interrupt to another CPU is not on
//!    the acquisition's time line. [`lookout`]: the wake made by a thread
//!    already spinning on another CPU when a periodic writer's frame is due.
//! 5. [`liveness`]: who owns a channel name and whether its writer lives
//!    (open-file-description locks the kernel drops when the writer dies), the
//!    writer's state, and succession: a new writer takes a dead writer's name
//!    and readers follow it.
//! 6. [`segment`]: the memory: two sealed memory files nobody can truncate,
//!    grow or unlink, created complete; validating what a reader receives
//!    (nothing in it is trusted before it is checked).
//! 7. [`handover`]: the writer's socket that gives readers the memory, the
//!    data read-only; its permissions are the channel's read permission.
//! 8. [`registry`]: the directory as the registry: listing channels and
//!    removing dead writers' names.
//! 9. [`succession`]: how readers learn at once that a successor took their
//!    dead writer's name (a watcher thread per reading process, on inotify).
//!
//! [`crate::Writer`] and [`crate::Reader`] are thin public APIs over these
//! parts; [`crate::shm`] and [`crate::os`] hold the only `unsafe` code (the
//! mapping and the system calls), and [`crate::sync`] every atomic.

pub(crate) mod copy;
pub(crate) mod doorbell;
pub(crate) mod lookout;
// The loom models of the doorbell with its ringer and lookout: above all three.
#[cfg(all(test, loom))]
mod models;
pub(crate) mod ring;
pub(crate) mod ringer;

// Under loom only the protocol above is compiled: what maps real memory or
// makes system calls cannot run in the model.
#[cfg(not(loom))]
pub(crate) mod handover;
#[cfg(not(loom))]
pub(crate) mod layout;
#[cfg(not(loom))]
pub(crate) mod liveness;
#[cfg(not(loom))]
pub(crate) mod registry;
#[cfg(not(loom))]
pub(crate) mod segment;
#[cfg(not(loom))]
pub(crate) mod succession;

/// What a channel carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChannelKind {
    /// Sensor responses of one layer, written by a driver.
    Layer = 1,
    /// Processed data published by a service.
    Service = 2,
}

impl ChannelKind {
    /// The lower-case name used by the CLI, its JSON and recordings: `layer|service`.
    pub fn as_str(self) -> &'static str {
        match self {
            ChannelKind::Layer => "layer",
            ChannelKind::Service => "service",
        }
    }

    pub(crate) fn from_code(code: u32) -> Option<ChannelKind> {
        match code {
            1 => Some(ChannelKind::Layer),
            2 => Some(ChannelKind::Service),
            _ => None,
        }
    }
}

/// `skin/channel`, the way channels are named in messages.
pub(crate) fn label(skin: &str, channel: &str) -> String {
    format!("{skin}/{channel}")
}
