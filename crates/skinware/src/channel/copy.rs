//! Wide copies between private memory and a ring's shared payload words.
//!
//! The seqlock lets a reader copy a slot while the writer may be rewriting it
//! (the reader then discards the copy), so every access to payload words must
//! be atomic: a plain `memcpy` racing with the writer would be a data race,
//! which Rust makes undefined behaviour. Relaxed `AtomicU64` loads are sound
//! but cannot be vectorised, and they copy a 60 KB frame at about a third of
//! `memcpy`'s speed.
//!
//! On x86-64 these functions therefore move the words with SSE2 loads and
//! stores (part of the x86-64 baseline, so no runtime detection) in inline
//! assembly. An `asm!` block may do anything the equivalent Rust operations
//! could do; here that is a sequence of relaxed 8-byte atomic loads or stores,
//! one per word, in some order within the block:
//!
//! * the words are 8-byte aligned, so no word of a 16-byte SSE access is
//!   split across a cache line, and on every x86-64 implementation each such
//!   word is read or written as a unit. The architecture manuals only promise
//!   that accesses wider than 8 bytes "may be implemented as multiple
//!   accesses", so the protocol does not rest on it: a word torn by a racing
//!   writer was written after the writer's odd stamp, so the reader's stamp
//!   check discards the copy exactly as it would a stale word;
//! * the order of the words within one copy does not matter to the protocol:
//!   the reader validates the whole copy afterwards, and the writer publishes
//!   the whole frame afterwards;
//! * the ordering the protocol needs around the copy comes from x86-64's total
//!   store order (loads are not reordered with later loads, stores not with
//!   later stores) plus the caller's fences, which the block cannot be moved
//!   across since it is not marked `nomem`.
//!
//! Everywhere else (other architectures, Miri, loom) the same functions are
//! plain loops of relaxed atomic accesses, which the model checkers can see.

use crate::sync::{AtomicU64, Ordering};

/// Words moved per iteration of the assembly loops: eight 16-byte registers.
#[cfg(all(target_arch = "x86_64", not(miri), not(loom)))]
const BLOCK_WORDS: usize = 16;

/// Copies `src` into `dst` (up to the shorter of the two) with relaxed atomic
/// loads. The writer may be storing into `src` meanwhile: the copy may then be
/// torn, and the caller must detect that (the seqlock stamp) and discard it.
pub(crate) fn load_words(dst: &mut [u64], src: &[AtomicU64]) {
    load_bytes(bytemuck::cast_slice_mut(dst), src);
}

/// Copies `src` into `dst` as bytes in native order, up to whichever ends
/// first (a ragged last word copies only the bytes `dst` has room for), with
/// relaxed atomic loads and the same tearing caveat as [`load_words`]. `dst`
/// need not be aligned: it is a caller's buffer (the C API's reads copy a
/// frame straight into it, once).
pub(crate) fn load_bytes(dst: &mut [u8], src: &[AtomicU64]) {
    let len = dst.len().min(src.len() * 8);
    let whole = len / 8;
    let done = load_blocks(&mut dst[..whole * 8], &src[..whole]);
    for (to, from) in dst[done * 8..whole * 8].chunks_exact_mut(8).zip(&src[done..whole]) {
        to.copy_from_slice(&from.load(Ordering::Relaxed).to_ne_bytes());
    }
    if len > whole * 8 {
        let word = src[whole].load(Ordering::Relaxed).to_ne_bytes();
        dst[whole * 8..len].copy_from_slice(&word[..len - whole * 8]);
    }
}

/// Stores the whole words of `src` (bytes in native order, any alignment) into
/// `dst`, up to whichever ends first, with relaxed atomic stores; returns how
/// many words it stored. Only the single writer calls this, on the slot it owns.
pub(crate) fn store_words(dst: &[AtomicU64], src: &[u8]) -> usize {
    let len = dst.len().min(src.len() / 8);
    let (dst, src) = (&dst[..len], &src[..len * 8]);
    let done = store_blocks(dst, src);
    for (to, from) in dst[done..].iter().zip(src[done * 8..].chunks_exact(8)) {
        to.store(
            u64::from_ne_bytes([from[0], from[1], from[2], from[3], from[4], from[5], from[6], from[7]]),
            Ordering::Relaxed,
        );
    }
    len
}

/// Copies whole blocks of `src` into `dst` (`src.len() * 8` bytes, any
/// alignment); returns how many words it copied.
#[cfg(all(target_arch = "x86_64", not(miri), not(loom)))]
fn load_blocks(dst: &mut [u8], src: &[AtomicU64]) -> usize {
    debug_assert_eq!(dst.len(), src.len() * 8);
    let blocks = src.len() / BLOCK_WORDS;
    if blocks == 0 {
        return 0;
    }
    // SAFETY: `src` is valid for reads and `dst` for writes of
    // `blocks * BLOCK_WORDS * 8` bytes (both slices are at least that long), and
    // they cannot overlap: `dst` is a unique borrow. The unaligned `movdqu`
    // needs no alignment beyond the slices' own. Concurrent stores into `src`
    // by the writer are atomic 8-byte stores, and the loads here are, word by
    // word, atomic 8-byte loads (see the module comment), so this is the racy
    // but defined relaxed atomic copy the seqlock expects. The block clobbers
    // only the registers it declares and touches no stack.
    unsafe {
        std::arch::asm!(
            "2:",
            "movdqu {x0}, xmmword ptr [{src}]",
            "movdqu {x1}, xmmword ptr [{src} + 16]",
            "movdqu {x2}, xmmword ptr [{src} + 32]",
            "movdqu {x3}, xmmword ptr [{src} + 48]",
            "movdqu {x4}, xmmword ptr [{src} + 64]",
            "movdqu {x5}, xmmword ptr [{src} + 80]",
            "movdqu {x6}, xmmword ptr [{src} + 96]",
            "movdqu {x7}, xmmword ptr [{src} + 112]",
            "movdqu xmmword ptr [{dst}], {x0}",
            "movdqu xmmword ptr [{dst} + 16], {x1}",
            "movdqu xmmword ptr [{dst} + 32], {x2}",
            "movdqu xmmword ptr [{dst} + 48], {x3}",
            "movdqu xmmword ptr [{dst} + 64], {x4}",
            "movdqu xmmword ptr [{dst} + 80], {x5}",
            "movdqu xmmword ptr [{dst} + 96], {x6}",
            "movdqu xmmword ptr [{dst} + 112], {x7}",
            "add {src}, 128",
            "add {dst}, 128",
            "dec {blocks}",
            "jnz 2b",
            src = inout(reg) src.as_ptr() => _,
            dst = inout(reg) dst.as_mut_ptr() => _,
            blocks = inout(reg) blocks => _,
            x0 = out(xmm_reg) _, x1 = out(xmm_reg) _, x2 = out(xmm_reg) _, x3 = out(xmm_reg) _,
            x4 = out(xmm_reg) _, x5 = out(xmm_reg) _, x6 = out(xmm_reg) _, x7 = out(xmm_reg) _,
            options(nostack),
        );
    }
    blocks * BLOCK_WORDS
}

/// Stores whole blocks; returns how many words it stored.
#[cfg(all(target_arch = "x86_64", not(miri), not(loom)))]
fn store_blocks(dst: &[AtomicU64], src: &[u8]) -> usize {
    debug_assert_eq!(dst.len() * 8, src.len());
    let blocks = dst.len() / BLOCK_WORDS;
    if blocks == 0 {
        return 0;
    }
    // SAFETY: `src` is valid for reads and `dst` for writes of
    // `blocks * BLOCK_WORDS * 8` bytes, and `movdqu` needs no alignment; `dst`
    // is atomics, which may be written through a shared reference, and `src`
    // is private memory, so they do not overlap. Only the single writer
    // stores into `dst`, and readers load it atomically, so these stores are,
    // word by word, the relaxed atomic stores the seqlock expects (see the
    // module comment).
    unsafe {
        std::arch::asm!(
            "2:",
            "movdqu {x0}, xmmword ptr [{src}]",
            "movdqu {x1}, xmmword ptr [{src} + 16]",
            "movdqu {x2}, xmmword ptr [{src} + 32]",
            "movdqu {x3}, xmmword ptr [{src} + 48]",
            "movdqu {x4}, xmmword ptr [{src} + 64]",
            "movdqu {x5}, xmmword ptr [{src} + 80]",
            "movdqu {x6}, xmmword ptr [{src} + 96]",
            "movdqu {x7}, xmmword ptr [{src} + 112]",
            "movdqu xmmword ptr [{dst}], {x0}",
            "movdqu xmmword ptr [{dst} + 16], {x1}",
            "movdqu xmmword ptr [{dst} + 32], {x2}",
            "movdqu xmmword ptr [{dst} + 48], {x3}",
            "movdqu xmmword ptr [{dst} + 64], {x4}",
            "movdqu xmmword ptr [{dst} + 80], {x5}",
            "movdqu xmmword ptr [{dst} + 96], {x6}",
            "movdqu xmmword ptr [{dst} + 112], {x7}",
            "add {src}, 128",
            "add {dst}, 128",
            "dec {blocks}",
            "jnz 2b",
            src = inout(reg) src.as_ptr() => _,
            dst = inout(reg) dst.as_ptr() => _,
            blocks = inout(reg) blocks => _,
            x0 = out(xmm_reg) _, x1 = out(xmm_reg) _, x2 = out(xmm_reg) _, x3 = out(xmm_reg) _,
            x4 = out(xmm_reg) _, x5 = out(xmm_reg) _, x6 = out(xmm_reg) _, x7 = out(xmm_reg) _,
            options(nostack),
        );
    }
    blocks * BLOCK_WORDS
}

#[cfg(not(all(target_arch = "x86_64", not(miri), not(loom))))]
fn load_blocks(_dst: &mut [u8], _src: &[AtomicU64]) -> usize {
    0
}

#[cfg(not(all(target_arch = "x86_64", not(miri), not(loom))))]
fn store_blocks(_dst: &[AtomicU64], _src: &[u8]) -> usize {
    0
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    fn pattern(i: usize) -> u64 {
        (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x0123_4567_89ab_cdef
    }

    #[test]
    fn loads_copy_every_word_for_every_length_and_start() {
        let shared: Vec<AtomicU64> = (0..200).map(|i| AtomicU64::new(pattern(i))).collect();
        for start in 0..3 {
            for len in 0..(shared.len() - start) {
                let mut out = vec![0u64; len + 1];
                out[len] = 7;
                load_words(&mut out[..len], &shared[start..start + len]);
                for (i, &word) in out[..len].iter().enumerate() {
                    assert_eq!(word, pattern(start + i), "start {start}, len {len}, word {i}");
                }
                assert_eq!(out[len], 7, "wrote past the end (start {start}, len {len})");
            }
        }
    }

    #[test]
    fn byte_loads_copy_every_byte_for_every_length_and_alignment() {
        let shared: Vec<AtomicU64> = (0..40).map(|i| AtomicU64::new(pattern(i))).collect();
        let expected: Vec<u8> = (0..40).flat_map(|i| pattern(i).to_ne_bytes()).collect();
        // Unaligned starts in the destination, and lengths that end mid-word.
        // Under Miri (slow), the lengths around every boundary: a word, a
        // 16-word block, the end of the source, and past it.
        let lengths: Vec<usize> = if cfg!(miri) {
            vec![0, 1, 7, 8, 9, 127, 128, 129, 136, 255, 256, 257, 319, 320, 321, 325]
        } else {
            (0..=(shared.len() * 8 + 5)).collect()
        };
        for start in [0, 1, 3, 8] {
            for &len in &lengths {
                let mut out = vec![0xAAu8; start + len + 1];
                load_bytes(&mut out[start..start + len], &shared);
                let copied = len.min(expected.len());
                assert_eq!(&out[start..start + copied], &expected[..copied], "start {start}, len {len}");
                assert!(out[..start].iter().all(|&b| b == 0xAA), "wrote before the start ({start}, {len})");
                assert!(out[start + copied..].iter().all(|&b| b == 0xAA), "wrote past the end ({start}, {len})");
            }
        }
    }

    #[test]
    fn stores_copy_every_word_for_every_length_and_start() {
        let source: Vec<u8> = (0..200).flat_map(|i| pattern(i).to_ne_bytes()).collect();
        // Starts that are not multiples of 8 bytes: the source need not be aligned.
        for start in [0, 1, 8, 13] {
            for len in 0..(source.len() - start) / 8 {
                let shared: Vec<AtomicU64> = (0..=len).map(|_| AtomicU64::new(7)).collect();
                // A ragged tail of source bytes is not a whole word and is left alone.
                assert_eq!(store_words(&shared[..len], &source[start..start + len * 8 + 3]), len);
                for (i, word) in shared[..len].iter().enumerate() {
                    let expected = u64::from_ne_bytes(source[start + 8 * i..start + 8 * i + 8].try_into().unwrap());
                    assert_eq!(word.load(Ordering::Relaxed), expected, "start {start}, len {len}, word {i}");
                }
                assert_eq!(shared[len].load(Ordering::Relaxed), 7, "wrote past the end (start {start}, len {len})");
            }
        }
    }

    #[test]
    fn mismatched_lengths_copy_the_shorter() {
        let shared: Vec<AtomicU64> = (0..40).map(|i| AtomicU64::new(pattern(i))).collect();
        let mut out = vec![0u64; 100];
        load_words(&mut out, &shared);
        assert!(out[..40].iter().enumerate().all(|(i, &w)| w == pattern(i)));
        assert!(out[40..].iter().all(|&w| w == 0));
        assert_eq!(store_words(&shared[..5], &[1; 400]), 5);
        assert!(shared[..5].iter().all(|w| w.load(Ordering::Relaxed) == 0x0101_0101_0101_0101));
        assert_eq!(shared[5].load(Ordering::Relaxed), pattern(5));
    }
}
