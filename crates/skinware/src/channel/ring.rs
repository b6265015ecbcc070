//! The seqlock ring: the publish/read protocol, and nothing else.
//!
//! A ring is `slot_count` slots of `slot_words` 64-bit words plus one `published`
//! counter. Slot `seq % slot_count` holds frame `seq` (sequence numbers start at 1).
//! Word [`STAMP`] of a slot is its seqlock stamp:
//!
//! * `0`: the slot has never held a frame;
//! * `2 * seq + 1` (odd): frame `seq` is being written into it;
//! * `2 * seq` (even): it holds complete frame `seq`.
//!
//! The writer fills slot `seq % K` and then stores `published = seq`. A reader
//! loads `published`, copies that slot and checks that its stamp did not move. The
//! writer never reads anything a reader writes, so it is wait-free and its cost
//! does not depend on readers; a reader only retries when the writer has wrapped
//! around the ring and is rewriting the very slot it is copying, which takes
//! `K - 1` whole frames.
//!
//! Every word is accessed atomically on both sides (relaxed loads and stores plus
//! fences), so a reader racing a writer is a benign race in Rust's memory model
//! rather than undefined behaviour; the stamp check throws such a copy away.
//! Payloads are moved by [`super::copy`], which does those relaxed accesses
//! 16 bytes at a time where the hardware allows it.

#![forbid(unsafe_code)]

use crate::sync::{AtomicU64, Ordering, fence};

/// Word index of the seqlock stamp in a slot.
pub(crate) const STAMP: usize = 0;
/// Word index of the frame's sequence number.
pub(crate) const SEQ: usize = 1;
/// Word index of the acquisition timestamp (CLOCK_MONOTONIC ns).
pub(crate) const ACQUIRED_NS: usize = 2;
/// Word index of the publish timestamp (CLOCK_MONOTONIC ns).
pub(crate) const PUBLISHED_NS: usize = 3;
/// Word index of the frame's status flags.
pub(crate) const STATUS: usize = 4;
/// Words of per-frame metadata before the payload (one cache line).
pub(crate) const META_WORDS: usize = 8;

/// A view of a ring laid out in some memory (shared memory, or the heap in tests).
#[derive(Clone, Copy)]
pub(crate) struct Ring<'a> {
    /// Sequence number of the newest complete frame; 0 before the first.
    published: &'a AtomicU64,
    /// `slot_count * slot_words` words.
    slots: &'a [AtomicU64],
    slot_words: usize,
    slot_count: u64,
}

/// Metadata of a frame, as written by the writer.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Meta {
    pub seq: u64,
    pub acquired_ns: u64,
    pub published_ns: u64,
    pub status: u64,
}

/// Where a read copies a frame's payload: the reader's own aligned words, or a
/// caller's bytes.
pub(crate) trait Destination {
    /// Copies `src` in (up to the shorter), atomically word by word.
    fn fill_from(&mut self, src: &[AtomicU64]);
}

impl Destination for [u64] {
    fn fill_from(&mut self, src: &[AtomicU64]) {
        super::copy::load_words(self, src);
    }
}

impl Destination for Vec<u64> {
    fn fill_from(&mut self, src: &[AtomicU64]) {
        super::copy::load_words(self, src);
    }
}

impl<const N: usize> Destination for [u64; N] {
    fn fill_from(&mut self, src: &[AtomicU64]) {
        super::copy::load_words(self, src);
    }
}

impl Destination for [u8] {
    fn fill_from(&mut self, src: &[AtomicU64]) {
        super::copy::load_bytes(self, src);
    }
}

/// Why a read attempt did not produce a frame.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum ReadFailure {
    /// Nothing has been published yet.
    Empty,
    /// The writer kept overwriting the slot; gave up after this many attempts.
    Lapped(u32),
}

impl<'a> Ring<'a> {
    /// Views `slots` as a ring of `slot_count` slots.
    ///
    /// The caller guarantees `slots.len() == slot_count * slot_words` and
    /// `slot_words > META_WORDS`; the channel validated both before building one.
    pub(crate) fn new(published: &'a AtomicU64, slots: &'a [AtomicU64], slot_count: usize) -> Self {
        debug_assert!(slot_count >= 2);
        let slot_words = slots.len() / slot_count;
        debug_assert_eq!(slot_words * slot_count, slots.len());
        debug_assert!(slot_words > META_WORDS);
        Ring { published, slots, slot_words, slot_count: slot_count as u64 }
    }

    fn slot(&self, seq: u64) -> &'a [AtomicU64] {
        let index = (seq % self.slot_count) as usize;
        &self.slots[index * self.slot_words..(index + 1) * self.slot_words]
    }

    /// Payload words per slot.
    pub(crate) fn payload_words(&self) -> usize {
        self.slot_words - META_WORDS
    }

    /// The newest published sequence number (0 if none).
    pub(crate) fn published(&self) -> u64 {
        // Acquire: pairs with the Release store in `publish`, so that a reader who
        // sees `seq` also sees slot `seq`'s even stamp.
        self.published.load(Ordering::Acquire)
    }

    /// Writer: opens slot `seq` for writing and returns its payload words.
    ///
    /// Only the single writer may call this, with `seq == published() + 1`.
    pub(crate) fn begin(&self, seq: u64) -> &'a [AtomicU64] {
        let slot = self.slot(seq);
        slot[STAMP].store(2 * seq + 1, Ordering::Relaxed);
        // Release fence: a reader whose Acquire fence follows a load of any payload
        // store below is guaranteed to then see the odd stamp (or a later one).
        fence(Ordering::Release);
        slot[SEQ].store(seq, Ordering::Relaxed);
        &slot[META_WORDS..]
    }

    /// Writer: finishes slot `meta.seq` and makes it the newest frame.
    pub(crate) fn publish(&self, meta: &Meta) {
        let slot = self.slot(meta.seq);
        slot[ACQUIRED_NS].store(meta.acquired_ns, Ordering::Relaxed);
        slot[PUBLISHED_NS].store(meta.published_ns, Ordering::Relaxed);
        slot[STATUS].store(meta.status, Ordering::Relaxed);
        // Release: everything written into the slot happens-before a reader's
        // Acquire load that sees this even stamp.
        slot[STAMP].store(2 * meta.seq, Ordering::Release);
        // Release: pairs with the Acquire load in `published`.
        self.published.store(meta.seq, Ordering::Release);
    }

    /// Reader: copies the newest complete frame's payload into `out` (up to its
    /// length) and returns its metadata and the number of retries it took.
    ///
    /// Lock-free: it retries only when the writer lapped it, at most `max_attempts` times.
    pub(crate) fn read_latest<D: Destination + ?Sized>(
        &self,
        out: &mut D,
        max_attempts: u32,
    ) -> Result<(Meta, u32), ReadFailure> {
        let mut attempt = 0;
        loop {
            let seq = self.published();
            if seq == 0 {
                return Err(ReadFailure::Empty);
            }
            let slot = self.slot(seq);
            // Acquire: pairs with the Release stamp store in `publish`.
            let stamp = slot[STAMP].load(Ordering::Acquire);
            // A stamp, or a slot's own sequence word, that disagrees with
            // `published` is a frame in the making, or memory written by
            // someone other than the writer: never returned.
            if stamp == seq.wrapping_mul(2) && slot[SEQ].load(Ordering::Relaxed) == seq {
                let meta = Meta {
                    seq,
                    acquired_ns: slot[ACQUIRED_NS].load(Ordering::Relaxed),
                    published_ns: slot[PUBLISHED_NS].load(Ordering::Relaxed),
                    status: slot[STATUS].load(Ordering::Relaxed),
                };
                out.fill_from(&slot[META_WORDS..]);
                // Acquire fence: if any load above read a store made after the
                // writer's Release fence in `begin`, the stamp load below sees that
                // writer's odd stamp or a later one, and the copy is discarded.
                fence(Ordering::Acquire);
                if slot[STAMP].load(Ordering::Relaxed) == stamp {
                    return Ok((meta, attempt));
                }
            }
            // The stamp was already past `seq` (lapped before we started) or moved
            // during the copy (lapped while copying): the writer has a newer frame.
            attempt += 1;
            if attempt >= max_attempts {
                return Err(ReadFailure::Lapped(attempt));
            }
            #[cfg(loom)]
            loom::thread::yield_now();
        }
    }

    /// Reader: copies frame `seq` into `out` if its slot still holds it, with
    /// the same checks as [`read_latest`](Self::read_latest) but one attempt
    /// (wait-free): `None` if the writer has reused the slot since, is
    /// rewriting it, or never published `seq`.
    ///
    /// This is how a reader that woke late catches up on the frames between
    /// its previous one and the newest: each stays readable until the writer
    /// comes back to its slot, K-1 frames later.
    pub(crate) fn read_seq<D: Destination + ?Sized>(&self, seq: u64, out: &mut D) -> Option<Meta> {
        if seq == 0 || seq > self.published() {
            return None;
        }
        let slot = self.slot(seq);
        // Acquire: pairs with the Release stamp store in `publish`.
        let stamp = slot[STAMP].load(Ordering::Acquire);
        if stamp != seq.wrapping_mul(2) || slot[SEQ].load(Ordering::Relaxed) != seq {
            return None;
        }
        let meta = Meta {
            seq,
            acquired_ns: slot[ACQUIRED_NS].load(Ordering::Relaxed),
            published_ns: slot[PUBLISHED_NS].load(Ordering::Relaxed),
            status: slot[STATUS].load(Ordering::Relaxed),
        };
        out.fill_from(&slot[META_WORDS..]);
        // As in `read_latest`: a copy that raced the writer's reuse of the
        // slot sees the stamp move, and is discarded.
        fence(Ordering::Acquire);
        (slot[STAMP].load(Ordering::Relaxed) == stamp).then_some(meta)
    }
}

/// Writes `bytes` into payload `words` starting at byte `offset`, a word at a time.
///
/// Partial words at either end are read, merged and stored back; this is only
/// sound for the single writer, which is the only caller. Callers check the
/// range against the payload first (and report it as an error), so a range
/// past the end here is a bug in this crate.
pub(crate) fn store_bytes(words: &[AtomicU64], offset: usize, bytes: &[u8]) {
    assert!(
        offset.checked_add(bytes.len()).is_some_and(|end| end <= words.len() * 8),
        "store_bytes: {} bytes at offset {offset} past a {}-byte payload",
        bytes.len(),
        words.len() * 8
    );
    let mut pos = offset;
    let mut rest = bytes;
    while !rest.is_empty() {
        let word = pos / 8;
        let within = pos % 8;
        if within == 0 && rest.len() >= 8 {
            let stored = super::copy::store_words(&words[word..], rest);
            pos += stored * 8;
            rest = &rest[stored * 8..];
            continue;
        }
        let take = (8 - within).min(rest.len());
        let mut current = words[word].load(Ordering::Relaxed).to_ne_bytes();
        current[within..within + take].copy_from_slice(&rest[..take]);
        words[word].store(u64::from_ne_bytes(current), Ordering::Relaxed);
        pos += take;
        rest = &rest[take..];
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    fn ring_memory(slot_count: usize, payload_words: usize) -> (AtomicU64, Vec<AtomicU64>) {
        let words = slot_count * (META_WORDS + payload_words);
        (AtomicU64::new(0), (0..words).map(|_| AtomicU64::new(0)).collect())
    }

    fn write_frame(ring: &Ring<'_>, seq: u64) {
        let payload = ring.begin(seq);
        let bytes: Vec<u8> =
            (0..payload.len()).flat_map(|i| (seq.wrapping_mul(1_000_003) ^ i as u64).to_ne_bytes()).collect();
        store_bytes(payload, 0, &bytes);
        ring.publish(&Meta { seq, acquired_ns: seq * 10, published_ns: seq * 10 + 1, status: 0 });
    }

    fn consistent(seq: u64, payload: &[u64]) -> bool {
        payload.iter().enumerate().all(|(i, &w)| w == seq.wrapping_mul(1_000_003) ^ i as u64)
    }

    #[test]
    fn empty_ring_reports_empty() {
        let (published, slots) = ring_memory(3, 4);
        let ring = Ring::new(&published, &slots, 3);
        let mut out = [0u64; 4];
        assert_eq!(ring.read_latest(&mut out, 8), Err(ReadFailure::Empty));
    }

    #[test]
    fn reader_gets_the_newest_frame_and_its_metadata() {
        let (published, slots) = ring_memory(3, 4);
        let ring = Ring::new(&published, &slots, 3);
        for seq in 1..=7 {
            write_frame(&ring, seq);
        }
        let mut out = [0u64; 4];
        let (meta, retries) = ring.read_latest(&mut out, 8).unwrap();
        assert_eq!(meta, Meta { seq: 7, acquired_ns: 70, published_ns: 71, status: 0 });
        assert_eq!(retries, 0);
        assert!(consistent(7, &out));
    }

    #[test]
    fn a_frame_being_written_is_never_returned() {
        let (published, slots) = ring_memory(2, 4);
        let ring = Ring::new(&published, &slots, 2);
        write_frame(&ring, 1);
        write_frame(&ring, 2);
        // The writer starts frame 3 in slot 1 (frame 1's slot) and stalls midway:
        // the newest complete frame is still 2.
        let payload = ring.begin(3);
        payload[0].store(0xdead, Ordering::Relaxed);
        let mut out = [0u64; 4];
        let (meta, _) = ring.read_latest(&mut out, 8).unwrap();
        assert_eq!(meta.seq, 2);
        assert!(consistent(2, &out));
    }

    #[test]
    fn a_slot_whose_sequence_word_disagrees_is_never_returned() {
        let (published, slots) = ring_memory(3, 2);
        let ring = Ring::new(&published, &slots, 3);
        write_frame(&ring, 1);
        write_frame(&ring, 2);
        // Someone other than the writer forges the slot's sequence word.
        ring.slot(2)[SEQ].store(1_270_000_000_000_000_000, Ordering::Relaxed);
        let mut out = [0u64; 2];
        assert!(matches!(ring.read_latest(&mut out, 8), Err(ReadFailure::Lapped(8))));
        // Once the writer publishes again, reading is sound again.
        write_frame(&ring, 3);
        assert_eq!(ring.read_latest(&mut out, 8).unwrap().0.seq, 3);
    }

    #[test]
    fn an_older_frame_is_readable_until_its_slot_is_reused() {
        let (published, slots) = ring_memory(3, 4);
        let ring = Ring::new(&published, &slots, 3);
        let mut out = [0u64; 4];
        assert_eq!(ring.read_seq(1, &mut out), None, "not published yet");
        for seq in 1..=5 {
            write_frame(&ring, seq);
        }
        // Slots hold 3, 4 and 5; 1 and 2 were overwritten.
        for seq in 3..=5 {
            assert_eq!(ring.read_seq(seq, &mut out).map(|m| m.seq), Some(seq));
            assert!(consistent(seq, &out));
        }
        assert_eq!(ring.read_seq(2, &mut out), None);
        assert_eq!(ring.read_seq(6, &mut out), None);
        assert_eq!(ring.read_seq(0, &mut out), None);
        // The writer starts frame 6 in frame 3's slot: 3 is gone at once.
        let payload = ring.begin(6);
        payload[0].store(0xdead, Ordering::Relaxed);
        assert_eq!(ring.read_seq(3, &mut out), None);
        assert_eq!(ring.read_seq(4, &mut out).map(|m| m.seq), Some(4));
    }

    #[test]
    fn store_bytes_handles_unaligned_edges() {
        let words: Vec<AtomicU64> = (0..3).map(|_| AtomicU64::new(u64::MAX)).collect();
        store_bytes(&words, 3, &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10]);
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.load(Ordering::Relaxed).to_ne_bytes()).collect();
        assert_eq!(&bytes[..3], &[255, 255, 255]);
        assert_eq!(&bytes[3..13], &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10]);
        assert!(bytes[13..].iter().all(|&b| b == 255));
    }

    #[test]
    #[should_panic(expected = "past a 16-byte payload")]
    fn store_bytes_refuses_a_range_past_the_payload() {
        // Word-aligned, so without the check the wide path would find no words
        // left and never advance.
        let words: Vec<AtomicU64> = (0..2).map(|_| AtomicU64::new(0)).collect();
        store_bytes(&words, 0, &[0; 24]);
    }

    #[test]
    fn concurrent_readers_never_see_a_torn_frame() {
        let frames: u64 = if cfg!(miri) { 60 } else { 200_000 };
        // 37 words: two of the wide copy's 16-word blocks and a ragged tail.
        let (published, slots) = ring_memory(3, 37);
        let ring = Ring::new(&published, &slots, 3);
        std::thread::scope(|scope| {
            let readers: Vec<_> = (0..2)
                .map(|_| {
                    scope.spawn(move || {
                        let mut out = [0u64; 37];
                        let mut last = 0;
                        let mut reads = 0u64;
                        while last < frames {
                            match ring.read_latest(&mut out, u32::MAX) {
                                Ok((meta, _)) => {
                                    assert!(consistent(meta.seq, &out), "torn frame {}", meta.seq);
                                    assert!(meta.seq >= last, "sequence went back");
                                    last = meta.seq;
                                    reads += 1;
                                }
                                Err(ReadFailure::Empty) => std::hint::spin_loop(),
                                Err(other) => panic!("{other:?}"),
                            }
                        }
                        reads
                    })
                })
                .collect();
            for seq in 1..=frames {
                write_frame(&ring, seq);
            }
            for reader in readers {
                assert!(reader.join().unwrap() > 0);
            }
        });
    }
}

#[cfg(all(test, loom))]
mod loom_tests {
    use super::*;

    fn env_or(name: &str, default: u64) -> u64 {
        std::env::var(name).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
    }

    /// A two-slot ring of one payload word each.
    struct Memory {
        published: AtomicU64,
        slots: Vec<AtomicU64>,
    }

    fn two_slot_memory() -> loom::sync::Arc<Memory> {
        loom::sync::Arc::new(Memory {
            published: AtomicU64::new(0),
            slots: (0..2 * (META_WORDS + 1)).map(|_| AtomicU64::new(0)).collect(),
        })
    }

    /// The writer: frames 1..=`frames`, payload `seq * 100`, acquired at `seq * 7`.
    fn publish_frames(memory: &Memory, frames: u64) {
        let ring = Ring::new(&memory.published, &memory.slots, 2);
        for seq in 1..=frames {
            let payload = ring.begin(seq);
            payload[0].store(seq * 100, Ordering::Relaxed);
            ring.publish(&Meta { seq, acquired_ns: seq * 7, published_ns: 0, status: 0 });
        }
    }

    fn model() -> loom::model::Builder {
        let mut model = loom::model::Builder::new();
        if model.preemption_bound.is_none() {
            model.preemption_bound = Some(2);
        }
        model
    }

    /// One writer publishes frames into a two-slot ring (three frames lap the
    /// slot of frame 1) while two readers read: every frame read is whole, with
    /// its own metadata, and a reader's later read never returns an older frame.
    #[test]
    fn loom_single_writer_two_readers() {
        let frames = env_or("SKINWARE_LOOM_FRAMES", 3);
        let readers = env_or("SKINWARE_LOOM_READERS", 2);
        let reads = env_or("SKINWARE_LOOM_READS", 1);
        model().check(move || {
            let memory = two_slot_memory();
            let handles: Vec<_> = (0..readers)
                .map(|_| {
                    let memory = memory.clone();
                    loom::thread::spawn(move || {
                        let ring = Ring::new(&memory.published, &memory.slots, 2);
                        let mut last = 0;
                        for _ in 0..reads {
                            let mut out = [0u64; 1];
                            if let Ok((meta, _)) = ring.read_latest(&mut out, 2) {
                                assert_eq!(out[0], meta.seq * 100, "torn payload");
                                assert_eq!(meta.acquired_ns, meta.seq * 7, "torn metadata");
                                assert!(meta.seq >= last, "sequence went back");
                                last = meta.seq;
                            }
                        }
                    })
                })
                .collect();
            publish_frames(&memory, frames);
            for handle in handles {
                handle.join().unwrap();
            }
        });
    }

    /// A reader catching up on frame 1 (`read_seq`) while the writer laps
    /// its slot in a two-slot ring: it gets frame 1 whole, or nothing.
    #[test]
    fn loom_catch_up_read_is_whole_or_nothing() {
        let frames = env_or("SKINWARE_LOOM_FRAMES", 3);
        model().check(move || {
            let memory = two_slot_memory();
            let reader = {
                let memory = memory.clone();
                loom::thread::spawn(move || {
                    let ring = Ring::new(&memory.published, &memory.slots, 2);
                    let mut out = [0u64; 1];
                    if let Some(meta) = ring.read_seq(1, &mut out) {
                        assert_eq!(meta.seq, 1);
                        assert_eq!(out[0], 100, "torn payload");
                        assert_eq!(meta.acquired_ns, 7, "torn metadata");
                    }
                })
            };
            publish_frames(&memory, frames);
            reader.join().unwrap();
        });
    }
}
