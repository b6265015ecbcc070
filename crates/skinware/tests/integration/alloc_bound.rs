//! The allocation bound every decoder's property test checks (shared by the
//! test binaries of the crates that decode: skinware, skinware-geometry,
//! skinware-services). `allocation-counter` counts per thread, so tests
//! running beside each other do not disturb a measurement.

/// Bytes a decoder may allocate in all (not only at its peak), per byte of
/// input, plus a constant. What the topology decoder does per 4-byte uid
/// (the builder's list, the sensor, the uid index, their growth) is about
/// 25 bytes per input byte; the bound leaves room for that and little else.
pub const ALLOCATED_PER_INPUT_BYTE: u64 = 64;
/// The constant part of the allocation bound.
pub const ALLOCATED_BASE: u64 = 64 << 10;

/// Runs `decode` on `input` and checks its allocations against the bound.
pub fn within_allocation_bound<R>(input: &[u8], decode: impl FnOnce(&[u8]) -> R) -> R {
    let mut result = None;
    let info = allocation_counter::measure(|| result = Some(decode(input)));
    let bound = ALLOCATED_BASE + ALLOCATED_PER_INPUT_BYTE * input.len() as u64;
    assert!(
        info.bytes_total <= bound,
        "decoding {} bytes allocated {} bytes in all (bound {bound})",
        input.len(),
        info.bytes_total
    );
    result.expect("measure runs the closure")
}

/// The bound is not vacuous: a decoder that trusted a count would break it.
#[test]
#[should_panic(expected = "allocated")]
fn the_allocation_bound_catches_a_decoder_that_trusts_a_count() {
    let bytes = [0xff, 0xff, 0xff, 0x00];
    within_allocation_bound(&bytes, |b| {
        let count = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
        // Opaque to the optimiser, which would otherwise drop an allocation
        // nothing reads (so the test failed in release builds only).
        std::hint::black_box(Vec::<u32>::with_capacity(count))
    });
}
