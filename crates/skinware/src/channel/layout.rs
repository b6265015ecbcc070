//! The byte layout of a channel segment, shared by every process that maps it.
//!
//! A channel is two sealed memory files ([`super::segment`]):
//!
//! ```text
//! data (readers map it read-only)
//! offset 0             Header      (one page; written by the writer only)
//! offset PAGE          description (opaque bytes, immutable after creation)
//! ring_offset          K slots of slot_bytes: 8 metadata words + payload words
//!
//! doorbell (everybody maps it read-write)
//! offset 0             Doorbell    (one page; the only memory readers write)
//! ```
//!
//! Every field is an atomic, so that any process may read any field at any time
//! without a data race, even of a segment that is foreign or being torn down.

use crate::sync::{AtomicU32, AtomicU64};
use std::mem::{align_of, size_of};

use crate::channel::ring::META_WORDS;

/// "SKINWARE" as a little-endian word: the first eight bytes of every segment.
pub(crate) const MAGIC: u64 = u64::from_le_bytes(*b"SKINWARE");

/// Version of this layout. Bump it on any change of the structures below.
pub const ABI_VERSION: u32 = 2;

/// Page size the layout is built on (mapping offsets must be page-aligned).
pub(crate) const PAGE: u64 = 4096;

/// Fewest frame buffers a channel may have: one being written, one being read.
pub const MIN_SLOTS: usize = 2;
/// Most frame buffers a channel may have.
pub const MAX_SLOTS: usize = 64;
/// Largest frame payload, in bytes.
pub const MAX_PAYLOAD_BYTES: u64 = 256 << 20;
/// Largest description, in bytes.
pub const MAX_DESCRIPTION_BYTES: u64 = 64 << 20;
/// Bytes of a payload schema name.
pub const SCHEMA_NAME_BYTES: usize = 32;
/// Buckets of the shared write-time and lateness histograms (bucket `i` counts
/// durations in `[2^i, 2^(i+1))` ns; the last one also counts everything longer).
pub const HISTOGRAM_BUCKETS: usize = 32;

/// Types that may be placed in a shared segment.
///
/// # Safety
/// Implementors are `#[repr(C)]`, contain only atomics (so any bit pattern is
/// valid and concurrent access from other processes is not a data race), fit in
/// one page and need at most 64-byte alignment.
pub(crate) unsafe trait SharedMemorySafe: Sized {
    /// Compile-time check of the size and alignment promises.
    const CHECK: () = assert!(size_of::<Self>() as u64 <= PAGE && align_of::<Self>() <= 64);
}

/// Segment header. Written by the creator and by the current writer only.
///
/// Invariant: once `abi_version` is non-zero, the layout fields (`file_bytes`
/// through `schema_version`) never change again.
#[repr(C, align(64))]
pub(crate) struct Header {
    /// Always [`MAGIC`].
    pub magic: AtomicU64,
    /// [`ABI_VERSION`]; stored last, with Release, when the segment is complete.
    pub abi_version: AtomicU32,
    /// 1 for a layer, 2 for a service.
    pub kind: AtomicU32,
    /// Total bytes of the segment.
    pub file_bytes: AtomicU64,
    /// Offset of the description area.
    pub description_offset: AtomicU64,
    /// Bytes of description.
    pub description_bytes: AtomicU64,
    /// Offset of the first slot.
    pub ring_offset: AtomicU64,
    /// Number of slots (frame buffers), K.
    pub slot_count: AtomicU64,
    /// Bytes per slot, metadata included.
    pub slot_bytes: AtomicU64,
    /// Payload bytes of one frame.
    pub payload_bytes: AtomicU64,
    /// Payload schema name, NUL-padded UTF-8.
    pub schema_name: [AtomicU64; SCHEMA_NAME_BYTES / 8],
    /// Payload schema version.
    pub schema_version: AtomicU32,
    /// Unused; keeps the fields after it 8-byte aligned.
    pub _reserved: AtomicU32,
    /// CLOCK_MONOTONIC ns when the segment was created.
    pub created_ns: AtomicU64,

    // Mutable, owned by the live writer.
    /// Process id of the current (or last) writer.
    pub writer_pid: AtomicU32,
    /// A [`crate::WriterState`] code.
    pub state: AtomicU32,
    /// Nominal period of the writer in ns; 0 for a sporadic writer.
    pub period_ns: AtomicU64,
    /// How many writers have owned the channel's name, this one included.
    pub generation: AtomicU64,
    /// CLOCK_MONOTONIC ns of the last state change.
    pub state_changed_ns: AtomicU64,

    /// Sequence number of the newest complete frame (its own cache line, since
    /// every reader loads it on every read).
    pub published: CacheLine,
    /// Writer statistics.
    pub stats: SharedStats,
}

/// One atomic alone in a cache line.
#[repr(C, align(64))]
pub(crate) struct CacheLine(pub AtomicU64);

/// Writer statistics, updated by the writer after every frame with plain
/// (non-RMW) atomic stores.
#[repr(C, align(64))]
pub(crate) struct SharedStats {
    pub frames: AtomicU64,
    pub overruns: AtomicU64,
    pub missed_periods: AtomicU64,
    pub faults: AtomicU64,
    pub write_ns_min: AtomicU64,
    pub write_ns_max: AtomicU64,
    pub write_ns_sum: AtomicU64,
    pub write_ns_last: AtomicU64,
    pub lateness_ns_max: AtomicU64,
    pub lateness_ns_sum: AtomicU64,
    pub lateness_samples: AtomicU64,
    pub write_histogram: [AtomicU64; HISTOGRAM_BUCKETS],
    pub lateness_histogram: [AtomicU64; HISTOGRAM_BUCKETS],
}

/// The one page readers may write, in its own memory file. Nothing here is on
/// the data path: a reader killed at any point leaves at most a stale "someone
/// waits" bit (costing the writer one spare wake, after which it is clear) or
/// one spare request, and a hostile one can at worst delay other readers'
/// wake-ups to their re-check interval or ask a sporadic writer for frames.
#[repr(C, align(64))]
pub(crate) struct Doorbell {
    /// Futex word for as-soon-as-available readers: `(seq << 1) | waiters`.
    /// The writer swaps in the new sequence on every publish and wakes only if
    /// the waiters bit was set.
    pub notify: AtomicU32,
    _pad: [AtomicU32; 15],
    /// Futex word counting requests to a sporadic writer.
    pub requests: AtomicU32,
}

// SAFETY: repr(C), atomics only, size and alignment checked by `CHECK`.
unsafe impl SharedMemorySafe for Header {}
// SAFETY: repr(C), atomics only, size and alignment checked by `CHECK`.
unsafe impl SharedMemorySafe for Doorbell {}

const _: () = <Header as SharedMemorySafe>::CHECK;
const _: () = <Doorbell as SharedMemorySafe>::CHECK;

/// Where everything lives in a segment, computed from the three things a writer
/// chooses. Creators write it; openers recompute it and compare.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Layout {
    pub payload_bytes: u64,
    pub slot_count: u64,
    pub description_bytes: u64,
    pub slot_bytes: u64,
    pub description_offset: u64,
    pub ring_offset: u64,
    pub file_bytes: u64,
}

fn round_up(value: u64, to: u64) -> u64 {
    value.div_ceil(to) * to
}

impl Layout {
    /// Computes a layout, or says which parameter is out of range.
    pub(crate) fn compute(payload_bytes: u64, slot_count: u64, description_bytes: u64) -> Result<Layout, String> {
        if !(MIN_SLOTS as u64..=MAX_SLOTS as u64).contains(&slot_count) {
            return Err(format!("{slot_count} frame buffers requested, {MIN_SLOTS} to {MAX_SLOTS} are allowed"));
        }
        if payload_bytes == 0 || payload_bytes > MAX_PAYLOAD_BYTES {
            return Err(format!("frame of {payload_bytes} bytes requested, 1 to {MAX_PAYLOAD_BYTES} are allowed"));
        }
        if description_bytes > MAX_DESCRIPTION_BYTES {
            return Err(format!(
                "description of {description_bytes} bytes, at most {MAX_DESCRIPTION_BYTES} are allowed"
            ));
        }
        let slot_bytes = round_up(META_WORDS as u64 * 8 + round_up(payload_bytes, 8), 64);
        let description_offset = PAGE;
        let ring_offset = round_up(description_offset + description_bytes, PAGE);
        let file_bytes = ring_offset + slot_count * slot_bytes;
        Ok(Layout {
            payload_bytes,
            slot_count,
            description_bytes,
            slot_bytes,
            description_offset,
            ring_offset,
            file_bytes,
        })
    }

    /// Words per slot.
    pub fn slot_words(&self) -> usize {
        (self.slot_bytes / 8) as usize
    }

    /// Reads the layout a header declares, checking it is self-consistent.
    pub(crate) fn from_header(header: &Header) -> Result<Layout, String> {
        use crate::sync::Ordering::Relaxed;
        let declared = Layout {
            payload_bytes: header.payload_bytes.load(Relaxed),
            slot_count: header.slot_count.load(Relaxed),
            description_bytes: header.description_bytes.load(Relaxed),
            slot_bytes: header.slot_bytes.load(Relaxed),
            description_offset: header.description_offset.load(Relaxed),
            ring_offset: header.ring_offset.load(Relaxed),
            file_bytes: header.file_bytes.load(Relaxed),
        };
        let expected = Layout::compute(declared.payload_bytes, declared.slot_count, declared.description_bytes)?;
        for (field, found, wanted) in [
            ("slot_bytes", declared.slot_bytes, expected.slot_bytes),
            ("description_offset", declared.description_offset, expected.description_offset),
            ("ring_offset", declared.ring_offset, expected.ring_offset),
            ("file_bytes", declared.file_bytes, expected.file_bytes),
        ] {
            if found != wanted {
                return Err(format!("{field} is {found}, the other sizes imply {wanted}"));
            }
        }
        Ok(declared)
    }
}

/// Encodes a schema name into header words (NUL-padded, truncated to fit).
pub(crate) fn encode_schema(name: &str) -> [u64; SCHEMA_NAME_BYTES / 8] {
    let mut bytes = [0u8; SCHEMA_NAME_BYTES];
    let len = name.len().min(SCHEMA_NAME_BYTES);
    bytes[..len].copy_from_slice(&name.as_bytes()[..len]);
    let mut words = [0u64; SCHEMA_NAME_BYTES / 8];
    for (word, chunk) in words.iter_mut().zip(bytes.chunks_exact(8)) {
        *word = u64::from_le_bytes(chunk.try_into().unwrap_or([0; 8]));
    }
    words
}

/// Decodes a schema name from header words.
pub(crate) fn decode_schema(words: &[AtomicU64; SCHEMA_NAME_BYTES / 8]) -> String {
    let bytes: Vec<u8> = words
        .iter()
        .flat_map(|w| w.load(crate::sync::Ordering::Relaxed).to_le_bytes())
        .take_while(|&b| b != 0)
        .collect();
    String::from_utf8_lossy(&bytes).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_places_everything_aligned_and_in_order() {
        let layout = Layout::compute(30_848 * 2, 3, 5000).unwrap();
        assert_eq!(layout.slot_bytes % 64, 0);
        assert!(layout.slot_bytes >= 64 + 30_848 * 2);
        assert_eq!(layout.ring_offset % PAGE, 0);
        assert!(layout.ring_offset >= layout.description_offset + 5000);
        assert_eq!(layout.file_bytes, layout.ring_offset + 3 * layout.slot_bytes);
    }

    #[test]
    fn layout_rejects_out_of_range_parameters() {
        assert!(Layout::compute(100, 1, 0).unwrap_err().contains("frame buffers"));
        assert!(Layout::compute(0, 3, 0).unwrap_err().contains("frame of 0 bytes"));
        assert!(Layout::compute(100, 3, MAX_DESCRIPTION_BYTES + 1).unwrap_err().contains("description"));
    }

    #[test]
    fn schema_names_round_trip() {
        let words = encode_schema("motion/v1");
        let atomics = words.map(AtomicU64::new);
        assert_eq!(decode_schema(&atomics), "motion/v1");
    }
}
