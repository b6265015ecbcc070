//! CySkin CPM patches on CAN (the successor of the paper's skin), in the
//! layout a user reverse-engineered from the CPM-Finger (see
//! `docs/drivers.md`): one sample is four frames at `base`, `base + 2`,
//! `base + 4` and `base + 6` (0x405, 0x407, 0x409, 0x40B for the default
//! base), each 4 × u16 little-endian, 16 raw 16-bit capacitance values in all;
//! the sample is complete with the last frame.
//!
//! The values arrive in wire order; taxel `PERMUTATION[p]` of the patch is
//! the value at wire position `p` (our reading of the published table).
//! skinware publishes the raw values unchanged (pressure raises them).

use super::CanFrame;

/// Taxels per CPM patch.
pub const TAXELS: usize = 16;
/// Frames per sample.
pub const FRAMES: usize = 4;
/// The default identifier of a patch's first frame.
pub const DEFAULT_BASE_ID: u16 = 0x405;
/// Which taxel each wire position holds.
pub const PERMUTATION: [usize; TAXELS] = [11, 15, 14, 12, 9, 13, 8, 10, 6, 7, 4, 5, 2, 0, 3, 1];

/// A frame of a CPM patch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Quarter {
    /// Which of the four frames (0 to 3); the sample is complete at 3.
    pub index: usize,
    /// Its four values, in wire order.
    pub values: [u16; 4],
}

/// Reads a frame of the patch whose first frame has identifier `base_id`;
/// `None` for any other frame (other patches, other devices, bad lengths).
pub fn parse(frame: &CanFrame, base_id: u16) -> Option<Quarter> {
    if frame.is_extended() || frame.is_remote() || frame.dlc() != 8 {
        return None;
    }
    let offset = frame.raw_id().checked_sub(u32::from(base_id))?;
    if offset % 2 != 0 || offset / 2 >= FRAMES as u32 {
        return None;
    }
    let data = frame.bytes();
    let value = |i: usize| u16::from_le_bytes([data[2 * i], data[2 * i + 1]]);
    Some(Quarter { index: (offset / 2) as usize, values: [value(0), value(1), value(2), value(3)] })
}

/// Stores a frame's values into the patch's `taxels` (in taxel order).
pub fn place(quarter: &Quarter, taxels: &mut [u16; TAXELS]) {
    for (i, &value) in quarter.values.iter().enumerate() {
        taxels[PERMUTATION[4 * quarter.index + i]] = value;
    }
}

/// The four frames of one sample of `taxels` (what an emulated patch sends).
pub fn sample_frames(base_id: u16, taxels: &[u16; TAXELS]) -> [CanFrame; FRAMES] {
    let mut wire = [0u16; TAXELS];
    for (position, &taxel) in PERMUTATION.iter().enumerate() {
        wire[position] = taxels[taxel];
    }
    std::array::from_fn(|index| {
        let mut data = [0u8; 8];
        for i in 0..4 {
            data[2 * i..2 * i + 2].copy_from_slice(&wire[4 * index + i].to_le_bytes());
        }
        let id = (base_id + 2 * index as u16) & 0x7FF;
        CanFrame::standard(id, &data).unwrap_or_else(|| unreachable!("an 11-bit id and 8 bytes"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn golden_sample() {
        let taxels: [u16; TAXELS] = std::array::from_fn(|t| 1000 + t as u16);
        let frames = sample_frames(DEFAULT_BASE_ID, &taxels);
        assert_eq!(format!("{:?}", frames[0]), "405#F303F703F603F403");
        assert_eq!(format!("{:?}", frames[3]), "40B#EA03E803EB03E903");
        let mut read = [0u16; TAXELS];
        for frame in &frames {
            place(&parse(frame, DEFAULT_BASE_ID).unwrap(), &mut read);
        }
        assert_eq!(read, taxels);
        assert_eq!(parse(&frames[0], 0x500), None);
        assert_eq!(parse(&CanFrame::standard(0x406, &[0; 8]).unwrap(), DEFAULT_BASE_ID), None);
    }

    #[test]
    fn the_permutation_is_one() {
        let mut seen = PERMUTATION.to_vec();
        seen.sort();
        assert_eq!(seen, (0..TAXELS).collect::<Vec<_>>());
    }

    proptest! {
        #[test]
        fn samples_round_trip(base in 0u16..0x7F0, taxels in any::<[u16; TAXELS]>()) {
            let mut read = [0u16; TAXELS];
            for frame in sample_frames(base, &taxels) {
                place(&parse(&frame, base).unwrap(), &mut read);
            }
            prop_assert_eq!(read, taxels);
        }

        #[test]
        fn any_frame_is_a_quarter_or_not(id in 0u16..0x800, data in proptest::collection::vec(any::<u8>(), 0..=8)) {
            if let Some(quarter) = parse(&CanFrame::standard(id, &data).unwrap(), DEFAULT_BASE_ID) {
                prop_assert!(quarter.index < FRAMES);
            }
        }
    }
}
