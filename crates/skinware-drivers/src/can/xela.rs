//! XELA uSkin boards on raw CAN (older firmware; see `docs/drivers.md`). The
//! host asks for a sample by sending `[0x07, 0x00]` to `0x200 | board`; the
//! board answers with one frame per taxel, identifier `0x710 + taxel`, whose
//! bytes 1–6 are the X, Y and Z readings as u16 **big-endian**. A first byte
//! of 250 or more marks the taxel's reading invalid.
//!
//! A taxel measures three axes, so in skinware's model it is a module of
//! three sensors, X, Y and Z in that order (uids `taxel << 2 | axis`), and
//! publishes three responses; the board is a patch.

use super::CanFrame;

/// Identifier of taxel 0's answer.
pub const FIRST_TAXEL_ID: u16 = 0x710;
/// Axes per taxel.
pub const AXES: usize = 3;
/// The most taxels a board answers for (their identifiers stay below 0x800).
pub const MAX_TAXELS: usize = 0xF0;

/// One taxel's answer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TaxelReading {
    /// The taxel's index on the board.
    pub taxel: usize,
    /// X, Y, Z; `None` if the board marked the reading invalid.
    pub axes: Option<[u16; AXES]>,
}

/// The request for one sample from `board`.
pub fn request(board: u8) -> CanFrame {
    CanFrame::standard(0x200 | u16::from(board & 0xF), &[0x07, 0x00]).unwrap_or_else(|| unreachable!("an 11-bit id"))
}

/// Reads a taxel's answer; `None` for any other frame.
pub fn parse(frame: &CanFrame) -> Option<TaxelReading> {
    if frame.is_extended() || frame.is_remote() || frame.dlc() < 7 {
        return None;
    }
    let taxel = frame.raw_id().checked_sub(u32::from(FIRST_TAXEL_ID))? as usize;
    if taxel >= MAX_TAXELS {
        return None;
    }
    let data = frame.bytes();
    let axis = |i: usize| u16::from_be_bytes([data[1 + 2 * i], data[2 + 2 * i]]);
    let axes = (data[1] < 250).then(|| [axis(0), axis(1), axis(2)]);
    Some(TaxelReading { taxel, axes })
}

/// A taxel's answer (what an emulated board sends).
pub fn answer(taxel: usize, axes: [u16; AXES]) -> Option<CanFrame> {
    if taxel >= MAX_TAXELS {
        return None;
    }
    let mut data = [0u8; 8];
    for (i, value) in axes.iter().enumerate() {
        data[1 + 2 * i..3 + 2 * i].copy_from_slice(&value.to_be_bytes());
    }
    CanFrame::standard(FIRST_TAXEL_ID + taxel as u16, &data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn golden_frames() {
        assert_eq!(format!("{:?}", request(1)), "201#0700");
        let frame = answer(3, [0x0102, 0x0304, 0x0506]).unwrap();
        assert_eq!(format!("{frame:?}"), "713#0001020304050600");
        assert_eq!(parse(&frame), Some(TaxelReading { taxel: 3, axes: Some([0x0102, 0x0304, 0x0506]) }));
        let invalid = answer(0, [0xFA00, 0, 0]).unwrap();
        assert_eq!(parse(&invalid), Some(TaxelReading { taxel: 0, axes: None }));
        assert_eq!(parse(&request(1)), None);
    }

    proptest! {
        #[test]
        fn readings_round_trip(taxel in 0usize..MAX_TAXELS, axes in any::<[u16; AXES]>()) {
            let reading = parse(&answer(taxel, axes).unwrap()).unwrap();
            prop_assert_eq!(reading.taxel, taxel);
            prop_assert_eq!(reading.axes, (axes[0] >> 8 < 250).then_some(axes));
        }

        #[test]
        fn any_frame_is_a_reading_or_not(id in 0u16..0x800, data in proptest::collection::vec(any::<u8>(), 0..=8)) {
            if let Some(reading) = parse(&CanFrame::standard(id, &data).unwrap()) {
                prop_assert!(reading.taxel < MAX_TAXELS);
            }
        }
    }
}
