//! The compact encoding of a layer's responses in an update (protocol 3,
//! `docs/viewer.md`): per block of [`BLOCK`] taxels, the block's minimum
//! and a bit width, then each value minus the minimum in that many bits,
//! packed LSB-first into little-endian 32-bit words. A skin at rest varies
//! by a few dozen counts around its baseline, so a block needs 5 to 8 bits
//! per taxel instead of 16: the paper's virtual skin packs into 44 % of its
//! raw bytes.
//!
//! Everything is a 32-bit word, so that the page reads a layer's responses
//! with one `Uint32Array` over the message (every array of the protocol
//! starts aligned to its element size):
//!
//! - a block's head: bits 0–15 the minimum, bits 16–23 the width (0 to 16),
//!   bits 24–31 zero;
//! - then `ceil(n × width / 32)` words holding the block's `n` values
//!   (256, fewer in a layer's last block): value `i`'s bits start at bit
//!   `i × width` of those words, counted from bit 0 of the first, and may
//!   run on into the next word. Width 0: every value equals the minimum, no
//!   words follow. Width 16 is the raw values (4 bytes more per block), which
//!   is what a block that does not pack gets: no separate raw form.
//!
//! Our own packer, not the `bitpacking` crate's: its SIMD layouts
//! interleave the values of 4 or 8 lanes across words, which the page
//! would have to undo in JavaScript; this layout is one shift and mask per
//! value there. Packing 32 values at a time with the width a constant
//! (one function per width) lets the compiler unroll the shifts, so that it
//! costs about what the `bitpacking` crate's did in the probe of
//! `docs/bench/viewer.md` (measured by `packing_cost_against_a_copy`).

#![forbid(unsafe_code)]

/// Taxels per block: each block has its own minimum and width.
pub const BLOCK: usize = 256;
/// Bytes of a block's head (one word).
pub const BLOCK_HEAD_BYTES: usize = 4;
/// The widest a value gets: a response is a `u16`.
pub const MAX_WIDTH: u32 = 16;

/// Bytes of the encoding of `values` at most (every block 16 bits wide),
/// for a buffer reserved once.
pub fn max_encoded_bytes(values: usize) -> usize {
    values.div_ceil(BLOCK) * BLOCK_HEAD_BYTES + 4 * (values * MAX_WIDTH as usize).div_ceil(32)
}

/// Appends the encoding of `values` to `out` (which keeps whatever it
/// held). Two passes per block: the minimum and maximum, then the packing,
/// into a block's worth of words on the stack, appended at once.
/// Allocates only if `out` lacks [`max_encoded_bytes`] of spare capacity.
pub fn encode(values: &[u16], out: &mut Vec<u8>) {
    // A block's head and its values at 16 bits.
    let mut words = [0u32; 1 + BLOCK * MAX_WIDTH as usize / 32];
    for block in values.chunks(BLOCK) {
        // Two plain reductions, which the compiler vectorises (one fold
        // of both it did not).
        let min = block.iter().copied().min().unwrap_or(0);
        let max = block.iter().copied().max().unwrap_or(0);
        let width = MAX_WIDTH - (max - min).leading_zeros();
        words[0] = u32::from(min) | width << 16;
        let packed = &mut words[1..];
        let used = 1 + match width {
            0 => 0,
            1 => pack_block::<1>(block, min, packed),
            2 => pack_block::<2>(block, min, packed),
            3 => pack_block::<3>(block, min, packed),
            4 => pack_block::<4>(block, min, packed),
            5 => pack_block::<5>(block, min, packed),
            6 => pack_block::<6>(block, min, packed),
            7 => pack_block::<7>(block, min, packed),
            8 => pack_block::<8>(block, min, packed),
            9 => pack_block::<9>(block, min, packed),
            10 => pack_block::<10>(block, min, packed),
            11 => pack_block::<11>(block, min, packed),
            12 => pack_block::<12>(block, min, packed),
            13 => pack_block::<13>(block, min, packed),
            14 => pack_block::<14>(block, min, packed),
            15 => pack_block::<15>(block, min, packed),
            _ => pack_block::<16>(block, min, packed),
        };
        let words = &mut words[..used];
        // Little-endian on the wire (nothing to do on a little-endian machine).
        for word in words.iter_mut() {
            *word = word.to_le();
        }
        out.extend_from_slice(bytemuck::cast_slice(words));
    }
}

/// Packs one block, whose values are all at least `min` and less than
/// `min + 2^W`, into `words` in groups of 32 values (W words each); a last
/// group of fewer is padded with `min` and cut to the words its values
/// need. Returns the words written.
fn pack_block<const W: usize>(block: &[u16], min: u16, words: &mut [u32]) -> usize {
    let mut groups = block.chunks_exact(32);
    let mut at = 0;
    for group in &mut groups {
        let group: &[u16; 32] = group.try_into().unwrap_or(&[0; 32]);
        words[at..at + W].copy_from_slice(&pack_group::<W>(group, min));
        at += W;
    }
    let rest = groups.remainder();
    if !rest.is_empty() {
        let mut group = [min; 32];
        group[..rest.len()].copy_from_slice(rest);
        let used = (rest.len() * W).div_ceil(32);
        words[at..at + used].copy_from_slice(&pack_group::<W>(&group, min)[..used]);
        at += used;
    }
    at
}

/// 32 values of W bits (minus `min`) in W words, LSB-first: one statement
/// per value, each with constant word indices and shifts once W is known
/// (LLVM did not unroll the loop over 32 values that this was first, which
/// cost 45 µs per board of the paper's skin).
#[inline(always)]
fn pack_group<const W: usize>(group: &[u16; 32], min: u16) -> [u32; W] {
    let mut words = [0u32; W];
    macro_rules! pack {
        ($($index:literal)*) => {$({
            let delta = u32::from(group[$index].wrapping_sub(min));
            let (word, shift) = ($index * W / 32, $index * W % 32);
            words[word] |= delta << shift;
            // A value that runs on into the next word (shift > 16 then,
            // so the shift below is by less than 16).
            if shift + W > 32 {
                words[word + 1] |= delta >> (32 - shift);
            }
        })*};
    }
    pack!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14 15 16 17 18 19 20 21 22 23 24 25 26 27 28 29 30 31);
    words
}

/// Why bytes are not a layer's compact responses.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CompactError {
    /// The bytes end inside a block.
    #[error("compact responses cut short: block {block} needs {needed} bytes from offset {at}, {left} are left")]
    Truncated {
        /// The block (from 0) that does not fit.
        block: usize,
        /// Where it starts.
        at: usize,
        /// Bytes it needs.
        needed: usize,
        /// Bytes there are.
        left: usize,
    },
    /// A block's head has a width over 16 or its reserved byte set.
    #[error("compact responses: block {block}'s head {head:#010x} is not a minimum and a width of 0 to 16")]
    BadHead {
        /// The block (from 0).
        block: usize,
        /// Its head word.
        head: u32,
    },
    /// A block's minimum plus a value's bits is over 65,535.
    #[error("compact responses: value {index} of block {block} is {min} + {delta}, over 65535")]
    Overflow {
        /// The block (from 0).
        block: usize,
        /// The value within the block.
        index: usize,
        /// The block's minimum.
        min: u16,
        /// The value's bits.
        delta: u32,
    },
}

/// Decodes `out.len()` values from the start of `bytes` into `out`, and
/// returns how many bytes they took (where the next layer's start). The
/// reference the page's decoder is checked against, and what the bench's
/// and the browser test's clients read updates with.
pub fn decode(bytes: &[u8], out: &mut [u16]) -> Result<usize, CompactError> {
    let mut at = 0;
    for (block, values) in out.chunks_mut(BLOCK).enumerate() {
        let word_at = |offset: usize| {
            bytes.get(offset..offset + 4).map(|word| u32::from_le_bytes([word[0], word[1], word[2], word[3]]))
        };
        let truncated = |needed: usize| CompactError::Truncated { block, at, needed, left: bytes.len() - at };
        let head = word_at(at).ok_or_else(|| truncated(BLOCK_HEAD_BYTES))?;
        let (min, width) = (head as u16, head >> 16);
        if width > MAX_WIDTH {
            return Err(CompactError::BadHead { block, head });
        }
        let words = (values.len() * width as usize).div_ceil(32);
        let needed = BLOCK_HEAD_BYTES + 4 * words;
        if bytes.len() - at < needed {
            return Err(truncated(needed));
        }
        let packed = &bytes[at + BLOCK_HEAD_BYTES..at + needed];
        let word = |index: usize| u32::from_le_bytes(packed[4 * index..4 * index + 4].try_into().unwrap_or([0; 4]));
        let mask = ((1u64 << width) - 1) as u32;
        for (index, value) in values.iter_mut().enumerate() {
            let bit = index * width as usize;
            let (first, shift) = (bit / 32, bit % 32);
            let mut delta = if width == 0 { 0 } else { word(first) >> shift };
            if shift + width as usize > 32 {
                delta |= word(first + 1) << (32 - shift);
            }
            let delta = delta & mask;
            *value = u16::try_from(u32::from(min) + delta).map_err(|_| CompactError::Overflow {
                block,
                index,
                min,
                delta,
            })?;
        }
        at += needed;
    }
    Ok(at)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn round_trip(values: &[u16]) -> Vec<u8> {
        let mut encoded = vec![0xEE; 3];
        encode(values, &mut encoded);
        let encoded = encoded.split_off(3);
        assert!(encoded.len() <= max_encoded_bytes(values.len()));
        assert_eq!(encoded.len() % 4, 0, "a layer's encoding is whole words");
        let mut decoded = vec![0xAAAA; values.len()];
        assert_eq!(decode(&encoded, &mut decoded), Ok(encoded.len()));
        assert_eq!(decoded, values);
        encoded
    }

    proptest! {
        #[test]
        fn any_values_of_any_length_come_back(values in prop::collection::vec(any::<u16>(), 0..1_000)) {
            round_trip(&values);
        }

        #[test]
        fn values_close_together_come_back(
            base in any::<u16>(),
            deltas in prop::collection::vec(0u16..300, 0..1_100),
        ) {
            let values: Vec<u16> = deltas.iter().map(|d| base.saturating_add(*d)).collect();
            round_trip(&values);
        }
    }

    #[test]
    fn lengths_widths_and_the_full_range_come_back_in_the_documented_bytes() {
        assert!(round_trip(&[]).is_empty());
        assert_eq!(round_trip(&[7]), 7u32.to_le_bytes(), "one value: a head of width 0");
        assert_eq!(round_trip(&[5; 700]).len(), 3 * 4, "equal values: one head per block");
        for width in 0..=16u32 {
            for length in [1, 31, 32, 33, 255, 256, 257, 513, 30_848 / 5] {
                let top = ((1u32 << width) - 1) as u16;
                // Alternately a base and base + top: each block of two or
                // more values spans exactly `width` bits.
                let base = (u16::MAX - top).min(1000 + 37 * width as u16);
                let values: Vec<u16> = (0..length).map(|i| base + [0, top][i % 2]).collect();
                let encoded = round_trip(&values);
                let words_of = |n: usize| if n == 1 { 0 } else { (n * width as usize).div_ceil(32) };
                let expected: usize = values.chunks(BLOCK).map(|block| 4 + 4 * words_of(block.len())).sum();
                assert_eq!(encoded.len(), expected, "width {width}, {length} values");
            }
        }
        round_trip(&[0, u16::MAX, 0, u16::MAX, 1]);
        round_trip(&(0..=u16::MAX).collect::<Vec<_>>());
    }

    #[test]
    fn values_are_packed_lsb_first_from_each_block_head() {
        // Minimum 10, width 3: 0, 7, 1, ... (minus 10).
        let values = [10, 17, 11, 12, 13, 14, 15, 16, 10, 17, 10];
        let encoded = round_trip(&values);
        assert_eq!(u32::from_le_bytes(encoded[..4].try_into().unwrap()), 10 | 3 << 16);
        let word = u32::from_le_bytes(encoded[4..8].try_into().unwrap());
        let deltas: Vec<u32> = (0..10).map(|i| word >> (3 * i) & 7).collect();
        assert_eq!(deltas, [0, 7, 1, 2, 3, 4, 5, 6, 0, 7]);
        // The 11th value's 3 bits straddle the word: 2 in bit 30-31, 1 in the next.
        assert_eq!(encoded.len(), 12);
    }

    #[test]
    fn bad_bytes_are_errors_not_panics() {
        let mut out = [0u16; 300];
        assert!(matches!(decode(&[], &mut out), Err(CompactError::Truncated { block: 0, .. })));
        let head = (5u32 | 17 << 16).to_le_bytes();
        assert_eq!(decode(&head, &mut out), Err(CompactError::BadHead { block: 0, head: 5 | 17 << 16 }));
        let reserved = (5u32 | 1 << 24).to_le_bytes();
        assert!(matches!(decode(&reserved, &mut out), Err(CompactError::BadHead { .. })));
        let mut values = vec![9u16; 300];
        values[299] = 4000;
        let mut encoded = Vec::new();
        encode(&values, &mut encoded);
        for cut in [0, 3, 4, 5, encoded.len() - 1] {
            let error = decode(&encoded[..cut], &mut out).unwrap_err();
            assert!(matches!(error, CompactError::Truncated { .. }), "{error}");
        }
        // Minimum 65,535 with a non-zero value: over 16 bits.
        let overflowing = [u32::from(u16::MAX) | 1 << 16, 1].map(u32::to_le_bytes).concat();
        let error = decode(&overflowing, &mut out[..1]).unwrap_err();
        assert!(matches!(error, CompactError::Overflow { delta: 1, .. }), "{error}");
    }

    /// Not a timing test (it asserts nothing of time): prints the cost of
    /// encoding a board like the virtual skin's against a copy of it, for
    /// `cargo test --release -p skinware-viewer packing_cost -- --ignored --nocapture`.
    #[test]
    #[ignore = "a measurement; run it in a release build with --nocapture"]
    fn packing_cost_against_a_copy() {
        let board = virtual_like_board(30_848, 1);
        let mut out = Vec::with_capacity(max_encoded_bytes(board.len()));
        let mut copy = vec![0u16; board.len()];
        let rounds = 20_000;
        for _ in 0..5 {
            let started = std::time::Instant::now();
            for round in 0..rounds {
                out.clear();
                encode(std::hint::black_box(&board[..]), &mut out);
                std::hint::black_box(&out);
                std::hint::black_box(round);
            }
            let packing = started.elapsed().as_secs_f64() / f64::from(rounds) * 1e6;
            let started = std::time::Instant::now();
            for _ in 0..rounds {
                copy.copy_from_slice(std::hint::black_box(&board[..]));
                std::hint::black_box(&copy);
            }
            let copying = started.elapsed().as_secs_f64() / f64::from(rounds) * 1e6;
            println!(
                "{} values: {} bytes packed into {} ({:.1} %), {packing:.2} µs per board, a copy {copying:.2} µs",
                board.len(),
                2 * board.len(),
                out.len(),
                100.0 * out.len() as f64 / (2 * board.len()) as f64
            );
        }
    }

    /// Responses like the virtual skin's at rest: 1000 + 40 sin φ + noise of ±8.
    fn virtual_like_board(values: usize, seed: u64) -> Vec<u16> {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..values)
            .map(|i| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let noise = (state % 17) as f64 - 8.0;
                (1000.0 + 40.0 * (i as f64 * 0.013).sin() + noise) as u16
            })
            .collect()
    }
}
