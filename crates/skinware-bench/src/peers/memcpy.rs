//! The `memcpy` floors of `skin bench peers`: one frame copied hot, just
//! written by another core, and by a real-time reader woken for it.

use std::time::Duration;

use skinware::{Stop, Ticker};

use super::setup::{FRAME_BYTES, RATE_HZ};
use crate::measure::Percentiles;

/// Median time of copying one frame between two buffers.
pub(super) fn measure_memcpy() -> u64 {
    let source = vec![0x5au8; FRAME_BYTES];
    let mut target = vec![0u8; FRAME_BYTES];
    let mut samples: Vec<u64> = (0..2000)
        .map(|_| {
            let started = skinware::os::monotonic_ns();
            target.copy_from_slice(std::hint::black_box(&source));
            std::hint::black_box(&mut target);
            skinware::os::monotonic_ns() - started
        })
        .collect();
    Percentiles::of(&mut samples).p50
}

/// Median time of a `memcpy` of one frame that a thread on another CPU has
/// just written (both threads pinned, taking turns; the lock is not timed).
pub(super) fn measure_memcpy_cross_core() -> u64 {
    let source = std::sync::Mutex::new(vec![0u8; FRAME_BYTES]);
    let turn = std::sync::Barrier::new(2);
    let rounds = 500u32;
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[0]);
            for round in 0..rounds {
                skinware::lock(&source).fill(round as u8);
                turn.wait();
                turn.wait();
            }
        });
        let reader = scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[1]);
            let mut target = vec![0u8; FRAME_BYTES];
            let mut samples = Vec::with_capacity(rounds as usize);
            for _ in 0..rounds {
                turn.wait();
                let frame = skinware::lock(&source);
                let started = skinware::os::monotonic_ns();
                target.copy_from_slice(std::hint::black_box(&frame));
                std::hint::black_box(&mut target);
                samples.push(skinware::os::monotonic_ns() - started);
                drop(frame);
                turn.wait();
            }
            Percentiles::of(&mut samples).p50
        });
        reader.join().unwrap_or(0)
    })
}

/// Median time of a plain `memcpy` of a frame that another CPU has just
/// written, by a real-time thread that slept until it was published: exactly
/// the state of a waiting reader (its CPU idle for 5 ms, the frame in the
/// writer's cache, its own buffer possibly evicted), with the library taken
/// out. The wake and the lock are not timed.
pub(super) fn measure_memcpy_woken(rounds: u32) -> u64 {
    let shared = std::sync::Mutex::new((0u32, vec![0u8; FRAME_BYTES]));
    let published = std::sync::Condvar::new();
    let stop = Stop::new();
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[0]);
            let _ = skinware::os::set_fifo_priority(80);
            let mut ticker = Ticker::new(Duration::from_secs_f64(1.0 / RATE_HZ));
            for round in 1..=rounds {
                if ticker.wait(&stop).is_none() {
                    break;
                }
                let mut frame = skinware::lock(&shared);
                frame.1.fill(round as u8);
                frame.0 = round;
                drop(frame);
                published.notify_one();
            }
        });
        let reader = scope.spawn(|| {
            let _ = skinware::os::pin_to_cpus(&[1]);
            let _ = skinware::os::set_fifo_priority(70);
            let mut target = vec![0u8; FRAME_BYTES];
            let mut samples = Vec::with_capacity(rounds as usize);
            let mut last = 0;
            while last < rounds {
                let guard = skinware::lock(&shared);
                let (frame, timed_out) = published
                    .wait_timeout_while(guard, Duration::from_secs(1), |frame| frame.0 == last)
                    .unwrap_or_else(|p| p.into_inner());
                if timed_out.timed_out() {
                    break;
                }
                let started = skinware::os::monotonic_ns();
                target.copy_from_slice(std::hint::black_box(&frame.1));
                std::hint::black_box(&mut target);
                samples.push(skinware::os::monotonic_ns() - started);
                last = frame.0;
            }
            samples
        });
        let mut samples = reader.join().unwrap_or_default();
        stop.stop();
        if samples.is_empty() { 0 } else { Percentiles::of(&mut samples).p50 }
    })
}
