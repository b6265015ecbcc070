//! One-off probe for issue #20, goal 3: what it costs to bit-pack a whole
//! 30,848-taxel board per update (frame of reference per block of 256, then
//! the `bitpacking` crate's BitPacker8x), against what the bytes it saves cost
//! the kernel. Values like the virtual skin's: 1000 + 40 sin(phase) + noise of -8..=8.
use bitpacking::{BitPacker, BitPacker8x};
use std::time::Instant;
fn main() {
    let n = 30848usize;
    let mut s: u64 = 12345;
    let mut rnd = || { s ^= s << 13; s ^= s >> 7; s ^= s << 17; s };
    let v: Vec<u16> = (0..n)
        .map(|_| (1000.0 + 40.0 * ((rnd() % 6283) as f64 / 1000.0).sin()) as u16 + (rnd() % 17) as u16 - 8)
        .collect();
    let packer = BitPacker8x::new();
    let mut out = vec![0u8; n * 4 + 4096];
    let mut block = [0u32; 256];
    let reps = 20_000;
    let mut times = Vec::new();
    let mut bytes = 0;
    for _ in 0..5 {
        let started = Instant::now();
        for _ in 0..reps {
            let mut at = 0;
            for chunk in v.chunks(256) {
                let (min, max) = chunk.iter().fold((u16::MAX, 0), |(lo, hi), &x| (lo.min(x), hi.max(x)));
                let bits = (16 - (max - min).leading_zeros()) as u8;
                for (into, x) in block.iter_mut().zip(chunk) {
                    *into = u32::from(x.wrapping_sub(min));
                }
                out[at] = bits;
                out[at + 2..at + 4].copy_from_slice(&min.to_le_bytes());
                at += 4;
                at += packer.compress(&block, &mut out[at..], bits);
            }
            bytes = at;
            std::hint::black_box(&out);
        }
        times.push(started.elapsed().as_secs_f64() / reps as f64 * 1e6);
    }
    let mut copy = vec![0u16; n];
    let started = Instant::now();
    for _ in 0..reps {
        copy.copy_from_slice(std::hint::black_box(&v));
        std::hint::black_box(&copy);
    }
    let memcpy = started.elapsed().as_secs_f64() / reps as f64 * 1e6;
    println!("{n} values, {} bytes raw -> {bytes} bytes packed; encode us per board over 5 sets: {:.2?}; memcpy of the raw board {memcpy:.2} us", 2 * n, times);
}
