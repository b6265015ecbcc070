//! The verification pattern of the virtual skin (`verify_pattern = true`):
//! responses that are a function of the frame's sequence number and the
//! sensor's index, so that a reader can check every frame it gets on its own,
//! without trusting the exchange's seqlock. A frame whose words came from two
//! different frames (a torn read) fails the check at almost every word, and
//! a frame labelled with the wrong sequence number fails it too.
//!
//! The responses stay within 32 counts of [`PATTERN_BASE`], near an
//! untouched taxel's baseline, so that the contact service, running on a
//! patterned skin, sees noise below its touch threshold rather than contacts
//! everywhere.

/// The lowest response of the pattern: about an untouched taxel's baseline.
pub const PATTERN_BASE: u16 = 984;

/// The pattern's responses span `PATTERN_BASE .. PATTERN_BASE + PATTERN_SPAN`.
const PATTERN_SPAN: u64 = 32;

/// Response `index` of frame `seq` (every response but a frame's last, which
/// is the [`pattern_checksum`] of the others).
pub fn pattern_response(seq: u64, index: usize) -> u16 {
    // A multiply-xorshift mix, so that frames one apart differ at about 31
    // of every 32 sensors (a linear pattern would differ everywhere or nowhere).
    let mut x = seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (index as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 31;
    x = x.wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^= x >> 29;
    PATTERN_BASE + (x % PATTERN_SPAN) as u16
}

/// The checksum response over `responses` (FNV-1a, folded into the pattern's
/// span): a reader that does not know [`pattern_response`] can still check
/// that a frame is whole.
pub fn pattern_checksum(responses: &[u16]) -> u16 {
    let hash =
        responses.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &r| (h ^ u64::from(r)).wrapping_mul(0x0100_0000_01b3));
    PATTERN_BASE + ((hash ^ (hash >> 32)) % PATTERN_SPAN) as u16
}

/// Fills `out` with frame `seq`'s pattern: its last response is the checksum.
pub fn fill_pattern(seq: u64, out: &mut [u16]) {
    let Some((last, rest)) = out.split_last_mut() else { return };
    for (index, response) in rest.iter_mut().enumerate() {
        *response = pattern_response(seq, index);
    }
    *last = pattern_checksum(rest);
}

/// Where frame `seq`'s `responses` differ from its pattern: `None` if the
/// frame is whole, else the first index that does not match (the last index
/// for a wrong checksum).
pub fn pattern_mismatch(seq: u64, responses: &[u16]) -> Option<usize> {
    let (last, rest) = responses.split_last()?;
    if let Some(index) = rest.iter().enumerate().position(|(index, &r)| r != pattern_response(seq, index)) {
        return Some(index);
    }
    (*last != pattern_checksum(rest)).then_some(rest.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_filled_frame_checks_and_a_mixed_one_does_not() {
        let mut frame = vec![0u16; 6_170];
        fill_pattern(41, &mut frame);
        assert_eq!(pattern_mismatch(41, &frame), None);
        assert!(frame.iter().all(|&r| (PATTERN_BASE..PATTERN_BASE + 32).contains(&r)));
        // Labelled with the wrong sequence number.
        assert!(pattern_mismatch(42, &frame).is_some());
        // Torn: the second half from the next frame.
        let mut next = vec![0u16; 6_170];
        fill_pattern(42, &mut next);
        let mut torn = frame.clone();
        torn[3_000..].copy_from_slice(&next[3_000..]);
        let at = pattern_mismatch(41, &torn).expect("a torn frame is caught");
        assert!((3_000..3_040).contains(&at), "caught at {at}");
        // One word off, only in the checksum.
        let mut bad_sum = frame.clone();
        *bad_sum.last_mut().unwrap() ^= 1;
        assert_eq!(pattern_mismatch(41, &bad_sum), Some(6_169));
    }
}
