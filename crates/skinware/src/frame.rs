//! What a reader gets: one frame, with its metadata, borrowed from the reader.

#![forbid(unsafe_code)]

use crate::channel::ring::Meta;

/// Status flags carried by every frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct FrameStatus(pub u64);

impl FrameStatus {
    /// A good frame.
    pub const OK: FrameStatus = FrameStatus(0);
    /// The acquisition failed: the responses are not valid.
    pub const FAULT: FrameStatus = FrameStatus(1);
    /// Some sensors did not answer: their responses are the previous ones.
    pub const PARTIAL: FrameStatus = FrameStatus(1 << 1);
    /// (Services) an input layer or service is faulted or gone.
    pub const INPUT_FAULTED: FrameStatus = FrameStatus(1 << 2);

    /// Whether every flag of `other` is set.
    pub fn contains(self, other: FrameStatus) -> bool {
        self.0 & other.0 == other.0
    }

    /// Whether the frame is faulted (its data must not be used).
    pub fn is_fault(self) -> bool {
        self.contains(FrameStatus::FAULT)
    }
}

impl std::ops::BitOr for FrameStatus {
    type Output = FrameStatus;
    fn bitor(self, rhs: FrameStatus) -> FrameStatus {
        FrameStatus(self.0 | rhs.0)
    }
}

/// What a read says about the frame it copied, apart from the payload: what
/// [`Reader::latest_into`](crate::Reader::latest_into) and the other reads
/// into a caller's buffer return, and [`Frame::info`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameInfo {
    /// Sequence number: 1 for the channel's first frame, +1 per frame.
    pub seq: u64,
    /// When the data was acquired (CLOCK_MONOTONIC ns).
    pub acquired_ns: u64,
    /// When the frame was published (CLOCK_MONOTONIC ns).
    pub published_ns: u64,
    /// Status flags.
    pub status: FrameStatus,
    /// Frames published between the reader's previous frame and this one.
    pub skipped: u64,
    /// `false` when this is the frame the reader got last time.
    pub fresh: bool,
}

impl FrameInfo {
    pub(crate) fn new(meta: Meta, skipped: u64, fresh: bool) -> FrameInfo {
        FrameInfo {
            seq: meta.seq,
            acquired_ns: meta.acquired_ns,
            published_ns: meta.published_ns,
            status: FrameStatus(meta.status),
            skipped,
            fresh,
        }
    }
}

/// One frame as a reader obtained it: a private copy, so it stays valid and
/// whole however long the reader keeps it (until its next read).
#[derive(Clone, Copy, Debug)]
pub struct Frame<'r> {
    pub(crate) meta: Meta,
    pub(crate) skipped: u64,
    pub(crate) fresh: bool,
    pub(crate) payload: &'r [u8],
}

impl<'r> Frame<'r> {
    /// Sequence number: 1 for the channel's first frame, +1 per frame, continued across revivals.
    pub fn seq(&self) -> u64 {
        self.meta.seq
    }

    /// When the data was acquired (CLOCK_MONOTONIC ns).
    pub fn acquired_ns(&self) -> u64 {
        self.meta.acquired_ns
    }

    /// When the frame was published (CLOCK_MONOTONIC ns).
    pub fn published_ns(&self) -> u64 {
        self.meta.published_ns
    }

    /// Status flags.
    pub fn status(&self) -> FrameStatus {
        FrameStatus(self.meta.status)
    }

    /// Frames published between this reader's previous frame and this one.
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// `false` when this is the same frame the reader got last time (a periodic
    /// reader faster than its writer sees each frame more than once).
    pub fn is_fresh(&self) -> bool {
        self.fresh
    }

    /// Everything but the payload.
    pub fn info(&self) -> FrameInfo {
        FrameInfo::new(self.meta, self.skipped, self.fresh)
    }

    /// The payload bytes.
    pub fn bytes(&self) -> &'r [u8] {
        self.payload
    }

    /// The payload as sensor responses (native-endian `u16`, one per sensor, in
    /// layer order).
    pub fn responses(&self) -> &'r [u16] {
        let even = self.payload.len() & !1;
        // The payload is the start of an 8-byte-aligned buffer, so this cast
        // cannot fail; an empty slice would be the answer if it ever did.
        bytemuck::try_cast_slice(&self.payload[..even]).unwrap_or(&[])
    }

    /// The payload as a plain-old-data value of type `T`, or `None` if the
    /// payload is smaller than `T`.
    pub fn pod<T: bytemuck::AnyBitPattern>(&self) -> Option<T> {
        self.payload.get(..size_of::<T>()).map(bytemuck::pod_read_unaligned)
    }

    /// The payload as consecutive plain-old-data records of type `T` (a
    /// service's per-region records): as many whole ones as it holds, a
    /// partial one at the end left out.
    pub fn records<T: bytemuck::AnyBitPattern>(&self) -> Vec<T> {
        self.payload.chunks_exact(size_of::<T>().max(1)).map(bytemuck::pod_read_unaligned).collect()
    }
}
