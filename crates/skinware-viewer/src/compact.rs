//! The compact encoding of a layer's responses in an update (protocol 3,
//! `docs/viewer.md`): per block of [`BLOCK`] taxels, the block's first
//! value and a bit width, then the difference of each value from the one
//! before it (zigzag: 0, -1, 1, -2, ... as 0, 1, 2, 3, ...) in that many
//! bits, packed LSB-first into little-endian 32-bit words.
//!
//! Differences, not each value minus the block's minimum (the first
//! design, as in the probe of `docs/bench/viewer.md`): on 96 layer frames
//! of `skin demo` taken from the browser test, a block's minimum and width
//! packed them into 48–50 % of their raw bytes, because a contact is a
//! smooth bump over many taxels (14 % of the blocks were 9 to 16 bits
//! wide), not a few outliers, so smaller blocks did not help either (49.5 %
//! at 32 taxels); the differences between neighbouring taxels (one module's
//! taxels are next to each other) packed the same frames into 43 %, and
//! choosing the better of the two per block gained nothing more. Of
//! those frames' 2,400 blocks, 1,923 needed 6 bits per taxel (the virtual
//! skin's noise is ±8: at rest), 104 5 bits, and those under a contact 7
//! to 16, mostly 12 to 14.
//!
//! Everything is a 32-bit word, so that the page reads a layer's responses
//! with one `Uint32Array` over the message (every array of the protocol
//! starts aligned to its element size):
//!
//! - a block's head: bits 0–15 its first value, bits 16–23 the width (0
//!   to 16), bits 24–31 zero;
//! - then the block's `n` differences (256, fewer in a layer's last block;
//!   the first is from the first value to itself, 0), `width` bits each,
//!   in 4 lanes: difference `i` is in lane `i % 4`, at position `i / 4`;
//!   each lane's differences are packed LSB-first into its own words (a
//!   position's bits start at bit `position × width` of the lane's words
//!   and may run on into its next word), and the lanes' words are
//!   interleaved: word `k` of lane `l` is the block's word `4k + l`, so
//!   `4 × ceil(ceil(n / 4) × width / 32)` words. Value `i` is value
//!   `i - 1` plus difference `i`, modulo 2^16. Width 0: every value equals
//!   the first, no words follow. Width 16 holds any block (4 bytes more
//!   than its raw values), which is what a block that does not pack gets:
//!   no separate raw form.
//!
//! Our own packer, not the `bitpacking` crate's (whose lanes hold
//! 32-bit values and whose layouts take more undoing in JavaScript): the
//! page decodes a value with one shift, mask and add, at the lane's word
//! `4 × (bit >> 5) + lane`. The lanes are for the encoder: it packs 128
//! values at a time, the four lanes at once with vector instructions, with
//! the width a constant (one function per width, unrolled): 6–10 µs per
//! board of the paper's skin, against 15–23 µs for one lane and 45 µs for
//! its first, rolled-up loop (`packing_cost_against_a_copy`).

#![forbid(unsafe_code)]

/// Taxels per block: each block has its own first value and width.
pub const BLOCK: usize = 256;
/// Bytes of a block's head (one word).
pub const BLOCK_HEAD_BYTES: usize = 4;
/// The widest a value gets: a response is a `u16`.
pub const MAX_WIDTH: u32 = 16;

/// Bytes of the encoding of `values` at most (every block 16 bits wide),
/// for a buffer reserved once.
pub fn max_encoded_bytes(values: usize) -> usize {
    let block_bytes = |values: usize| BLOCK_HEAD_BYTES + 4 * block_words(values, MAX_WIDTH as usize);
    values / BLOCK * block_bytes(BLOCK) + if values.is_multiple_of(BLOCK) { 0 } else { block_bytes(values % BLOCK) }
}

/// A difference of two responses as a small unsigned number: 0, -1, 1, -2,
/// 2, ... become 0, 1, 2, 3, 4, ...
fn zigzag(difference: u16) -> u16 {
    let difference = difference as i16;
    ((difference << 1) ^ (difference >> 15)) as u16
}

/// The difference [`zigzag`] made `bits` of.
fn unzigzag(bits: u16) -> u16 {
    (bits >> 1) ^ (bits & 1).wrapping_neg()
}

/// Appends the encoding of `values` to `out` (which keeps whatever it
/// held). Two passes per block: the differences and the width they need
/// (an OR of them all), then the packing, into a block's worth of words on
/// the stack, appended at once. Allocates only if `out` lacks
/// [`max_encoded_bytes`] of spare capacity.
pub fn encode(values: &[u16], out: &mut Vec<u8>) {
    let mut differences = [0u16; BLOCK];
    // A block's head and its differences at 16 bits.
    let mut words = [0u32; 1 + BLOCK * MAX_WIDTH as usize / 32];
    for block in values.chunks(BLOCK) {
        let first = block[0];
        let differences = &mut differences[..block.len()];
        differences[0] = 0;
        for (difference, pair) in differences[1..].iter_mut().zip(block.windows(2)) {
            *difference = zigzag(pair[1].wrapping_sub(pair[0]));
        }
        let all_bits = differences.iter().fold(0, |bits, &difference| bits | difference);
        let width = MAX_WIDTH - all_bits.leading_zeros();
        words[0] = u32::from(first) | width << 16;
        let packed = &mut words[1..];
        let used = 1 + match width {
            0 => 0,
            1 => pack_block::<1>(differences, packed),
            2 => pack_block::<2>(differences, packed),
            3 => pack_block::<3>(differences, packed),
            4 => pack_block::<4>(differences, packed),
            5 => pack_block::<5>(differences, packed),
            6 => pack_block::<6>(differences, packed),
            7 => pack_block::<7>(differences, packed),
            8 => pack_block::<8>(differences, packed),
            9 => pack_block::<9>(differences, packed),
            10 => pack_block::<10>(differences, packed),
            11 => pack_block::<11>(differences, packed),
            12 => pack_block::<12>(differences, packed),
            13 => pack_block::<13>(differences, packed),
            14 => pack_block::<14>(differences, packed),
            15 => pack_block::<15>(differences, packed),
            _ => pack_block::<16>(differences, packed),
        };
        let words = &mut words[..used];
        // Little-endian on the wire (nothing to do on a little-endian machine).
        for word in words.iter_mut() {
            *word = word.to_le();
        }
        out.extend_from_slice(bytemuck::cast_slice(words));
    }
}

/// Lanes of the packing: value `i` of a block is in lane `i % LANES`.
pub const LANES: usize = 4;
/// Values of one group: 32 per lane.
const GROUP: usize = 32 * LANES;

/// The words a block of `values` values of `width` bits takes after its head.
pub fn block_words(values: usize, width: usize) -> usize {
    LANES * (values.div_ceil(LANES) * width).div_ceil(32)
}

/// Packs one block's `bits` (each under 2^W) into `words` in groups of
/// 128 (4·W words each); a last group of fewer is padded with zeros and cut
/// to the words its values need. Returns the words written.
fn pack_block<const W: usize>(bits: &[u16], words: &mut [u32]) -> usize {
    let mut groups = bits.chunks_exact(GROUP);
    let mut at = 0;
    for group in &mut groups {
        let group: &[u16; GROUP] = group.try_into().unwrap_or(&[0; GROUP]);
        let packed: [[u32; LANES]; W] = pack_group::<W>(group);
        words[at..at + LANES * W].copy_from_slice(packed.as_flattened());
        at += LANES * W;
    }
    let rest = groups.remainder();
    if !rest.is_empty() {
        let mut group = [0; GROUP];
        group[..rest.len()].copy_from_slice(rest);
        let used = block_words(rest.len(), W);
        let packed: [[u32; LANES]; W] = pack_group::<W>(&group);
        words[at..at + used].copy_from_slice(&packed.as_flattened()[..used]);
        at += used;
    }
    at
}

/// 128 values of W bits in 4·W words: value `i` in lane `i % 4`, each
/// lane's 32 values LSB-first in its W words, which are interleaved (word
/// `k` of lane `l` at `4k + l`), so that the four lanes are packed at once
/// with vector instructions. One statement per lane position, each with
/// constant word indices and shifts once W is known.
#[inline(always)]
fn pack_group<const W: usize>(group: &[u16; GROUP]) -> [[u32; LANES]; W] {
    let mut words = [[0u32; LANES]; W];
    macro_rules! pack {
        ($($position:literal)*) => {$({
            let (word, shift) = ($position * W / 32, $position * W % 32);
            for lane in 0..LANES {
                let bits = u32::from(group[LANES * $position + lane]);
                words[word][lane] |= bits << shift;
                // A value that runs on into the lane's next word (shift > 16
                // then, so the shift below is by less than 16).
                if shift + W > 32 {
                    words[word + 1][lane] |= bits >> (32 - shift);
                }
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
    #[error("compact responses: block {block}'s head {head:#010x} is not a first value and a width of 0 to 16")]
    BadHead {
        /// The block (from 0).
        block: usize,
        /// Its head word.
        head: u32,
    },
}

/// Decodes `out.len()` values from the start of `bytes` into `out`, and
/// returns how many bytes they took (where the next layer's start). Any
/// bits decode (modulo 2^16, as they were encoded); only a head that is not
/// one or bytes cut short are errors. The
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
        let (first, width) = (head as u16, head >> 16);
        if width > MAX_WIDTH {
            return Err(CompactError::BadHead { block, head });
        }
        let words = block_words(values.len(), width as usize);
        let needed = BLOCK_HEAD_BYTES + 4 * words;
        if bytes.len() - at < needed {
            return Err(truncated(needed));
        }
        let packed = &bytes[at + BLOCK_HEAD_BYTES..at + needed];
        let word = |index: usize| u32::from_le_bytes(packed[4 * index..4 * index + 4].try_into().unwrap_or([0; 4]));
        let mask = ((1u64 << width) - 1) as u32;
        let mut previous = first;
        for (index, value) in values.iter_mut().enumerate() {
            let (lane, bit) = (index % LANES, index / LANES * width as usize);
            let (at_word, shift) = (LANES * (bit / 32) + lane, bit % 32);
            let mut bits = if width == 0 { 0 } else { word(at_word) >> shift };
            if shift + width as usize > 32 {
                bits |= word(at_word + LANES) << (32 - shift);
            }
            // Masked to at most 16 bits.
            previous = previous.wrapping_add(unzigzag((bits & mask) as u16));
            *value = previous;
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

    /// The width a block needs, from the definition: the zigzag
    /// differences computed in wider integers.
    fn width_of(block: &[u16]) -> usize {
        let zigzags = block.windows(2).map(|pair| {
            let difference = i32::from(pair[1].wrapping_sub(pair[0]) as i16);
            if difference >= 0 { 2 * difference } else { -2 * difference - 1 }
        });
        zigzags.map(|z| 32 - z.leading_zeros() as usize).max().unwrap_or(0)
    }

    #[test]
    fn lengths_widths_and_the_full_range_come_back_in_the_documented_bytes() {
        assert!(round_trip(&[]).is_empty());
        assert_eq!(round_trip(&[7]), 7u32.to_le_bytes(), "one value: a head of width 0");
        assert_eq!(round_trip(&[5; 700]).len(), 3 * 4, "equal values: one head per block");
        // Steps of 2^(w-2) make differences of width w (zigzag doubles
        // them), u16::MAX (-1) width 1; then a few others.
        let steps = (0..15).map(|k| 1u16 << k).chain([0, u16::MAX, 3, 100, 1000, 20_000, 32_767, 32_768, 40_000]);
        let mut widths = std::collections::BTreeSet::new();
        for step in steps {
            for length in [1, 2, 31, 32, 33, 255, 256, 257, 513, 6_170] {
                // Up and down by `step`, and a ramp: widths from 0 to 16.
                let zigzag: Vec<u16> = (0..length).map(|i| 1000u16.wrapping_add([0, step][i % 2])).collect();
                let ramp: Vec<u16> = (0..length).map(|i| (i as u16).wrapping_mul(step)).collect();
                for values in [zigzag, ramp] {
                    let encoded = round_trip(&values);
                    widths.extend(values.chunks(BLOCK).map(width_of));
                    // Per block a head, then 4 lanes of ceil(n / 4) values, each lane in whole words.
                    let expected: usize = values
                        .chunks(BLOCK)
                        .map(|block| 4 + 4 * 4 * (block.len().div_ceil(4) * width_of(block)).div_ceil(32))
                        .sum();
                    assert_eq!(encoded.len(), expected, "step {step}, {length} values");
                }
            }
        }
        assert_eq!(widths.len(), 17, "the cases above reach every width: {widths:?}");
        round_trip(&[0, u16::MAX, 0, u16::MAX, 1]);
        round_trip(&(0..=u16::MAX).collect::<Vec<_>>());
        round_trip(&(0..=u16::MAX).rev().step_by(7).collect::<Vec<_>>());
    }

    fn words(encoded: &[u8]) -> Vec<u32> {
        encoded.chunks(4).map(|word| u32::from_le_bytes(word.try_into().unwrap())).collect()
    }

    #[test]
    fn differences_are_packed_lsb_first_in_four_lanes_after_each_block_head() {
        // Differences 0, 1, -2, 3, 0, 1, 0, 1, -4, 0, 3: zigzag 0, 2, 3, 6,
        // 0, 2, 0, 2, 7, 0, 6, which need 3 bits. Lane l holds values l,
        // l + 4, l + 8: lane 0 0, 0, 7; lane 1 2, 2, 0; lane 2 3, 0, 6;
        // lane 3 6, 2; one word each.
        let values = [10, 11, 9, 12, 12, 13, 13, 14, 10, 10, 13];
        let encoded = words(&round_trip(&values));
        assert_eq!(encoded, [10 | 3 << 16, 7 << 6, 2 | 2 << 3, 3 | 6 << 6, 6 | 2 << 3]);
        // Steps of 2 (zigzag 4, 3 bits): a lane's 11th value (values 40
        // and 41) runs on from bits 30-31 of the lane's first word (00)
        // into bit 0 of its second (1), 4 words on.
        let ramp: Vec<u16> = (0..44).map(|i| 2 * i).collect();
        let encoded = words(&round_trip(&ramp));
        assert_eq!(encoded.len(), 1 + 8);
        assert_eq!(encoded[1], (1..10).fold(0, |word, position| word | 4 << (3 * position)), "lane 0: 0, then 4s");
        assert_eq!(encoded[2], (0..10).fold(0, |word, position| word | 4 << (3 * position)), "lane 1: 4s");
        assert_eq!((encoded[1] >> 30, encoded[5], encoded[6]), (0, 1, 1));
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
    }

    /// Not a timing test (it asserts nothing of time): prints the cost of
    /// encoding a board like the virtual skin's against a copy of it, for
    /// `cargo test --release -p skinware-viewer packing_cost -- --ignored --nocapture`.
    #[test]
    #[ignore = "a measurement; run it in a release build with --nocapture"]
    fn packing_cost_against_a_copy() {
        for contacts in [0, 4] {
            let board = virtual_like_board(30_848, 1, contacts);
            let mut out = Vec::with_capacity(max_encoded_bytes(board.len()));
            let mut copy = vec![0u16; board.len()];
            let rounds = 20_000;
            for _ in 0..3 {
                let started = std::time::Instant::now();
                for _ in 0..rounds {
                    out.clear();
                    encode(std::hint::black_box(&board[..]), &mut out);
                    std::hint::black_box(&out);
                }
                let packing = started.elapsed().as_secs_f64() / f64::from(rounds) * 1e6;
                let started = std::time::Instant::now();
                for _ in 0..rounds {
                    copy.copy_from_slice(std::hint::black_box(&board[..]));
                    std::hint::black_box(&copy);
                }
                let copying = started.elapsed().as_secs_f64() / f64::from(rounds) * 1e6;
                println!(
                    "{} values, {contacts} contacts: {} bytes packed into {} ({:.1} %), {packing:.2} µs per board, a copy {copying:.2} µs",
                    board.len(),
                    2 * board.len(),
                    out.len(),
                    100.0 * out.len() as f64 / (2 * board.len()) as f64
                );
            }
        }
    }

    /// Responses like the virtual skin's: 1000 + 40 sin φ + noise of ±8 at
    /// rest, and `contacts` bumps 15,000 to 40,000 high over about 40
    /// taxels each.
    fn virtual_like_board(values: usize, seed: u64, contacts: usize) -> Vec<u16> {
        let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        let centres: Vec<f64> = (1..=contacts).map(|c| (c * values / (contacts + 1)) as f64).collect();
        (0..values)
            .map(|i| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let noise = (state % 17) as f64 - 8.0;
                let bumps: f64 = centres
                    .iter()
                    .enumerate()
                    .map(|(c, centre)| (15_000.0 + 8_000.0 * c as f64) * (-((i as f64 - centre) / 12.0).powi(2)).exp())
                    .sum();
                (1000.0 + 40.0 * (i as f64 * 0.013).sin() + noise + bumps).min(65_535.0) as u16
            })
            .collect()
    }
}
