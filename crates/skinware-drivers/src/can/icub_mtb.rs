//! The iCub skin's MTB boards on CAN (robotology's public protocol, read from
//! its host driver and firmware headers; see `docs/drivers.md`).
//!
//! * Identifiers are 11-bit: `class << 8 | board << 4 | triangle`. Boards
//!   stream class 4 (`PERIODIC_SKIN`) once configured; commands go to class
//!   2, `0x200 | board`.
//! * Each 12-taxel triangle sends two frames per period: a **head**
//!   (`d[0] = 0x40`, taxels 0–6 in `d[1..8]`) and a **tail** (`d[0] = 0xC0`,
//!   taxels 7–11 in `d[1..6]`, an out-of-range mask in `d[6]` and the high
//!   nibble of `d[7]`, an error code in the low nibble of `d[7]`).
//! * Values are 8-bit and **inverted**: an untouched taxel reads about the
//!   board's no-load value (240 by default) and pressure lowers it. skinware
//!   publishes `response = 255 − raw`, so pressure raises the response: an
//!   untouched taxel reads about 15, a fully pressed one up to 255.
//!
//! In skinware's model a board is a patch (id = its address) and a triangle
//! a module (id = its index on the board); taxel `k` of triangle `t` on board
//! `b` has uid `b << 8 | t << 4 | k`.

use super::CanFrame;

/// Taxels per triangle.
pub const TAXELS_PER_TRIANGLE: usize = 12;
/// The class of streamed skin frames.
pub const CLASS_PERIODIC_SKIN: u16 = 4;
/// The class of host commands.
pub const CLASS_COMMAND: u16 = 2;
/// `SET_BRD_CFG`: skin type, period in ms, no-load value.
pub const SET_BOARD_CONFIG: u8 = 0x4D;
/// `SET_TRIANG_CFG`: first and last triangle, shift, enabled, CDC offset.
pub const SET_TRIANGLE_CONFIG: u8 = 0x50;
/// `SET_TXMODE`: 0 starts streaming, 1 stops it.
pub const SET_TX_MODE: u8 = 0x07;

/// The default no-load value the host configures.
pub const DEFAULT_NO_LOAD: u8 = 0xF0;
/// The default CDC offset the host configures.
pub const DEFAULT_CDC_OFFSET: u16 = 0x2200;

/// The response skinware publishes for a raw 8-bit MTB value.
pub fn response(raw: u8) -> u16 {
    u16::from(255 - raw)
}

/// One MTB board on the bus.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Board {
    /// Its address, 1 to 15.
    pub address: u8,
    /// Its triangles (0 to 15) in the order they appear in the layer.
    pub triangles: Vec<u8>,
}

/// How the host configures the boards at start-up.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BoardSettings {
    /// Streaming period, ms (1 to 255).
    pub period_ms: u8,
    /// The value an untouched taxel reads.
    pub no_load: u8,
    /// Skin type (0 for the standard triangles).
    pub skin_type: u8,
    /// Right shift applied to capacitance changes (sensitivity).
    pub shift: u8,
    /// The CDC offset.
    pub cdc_offset: u16,
}

impl Default for BoardSettings {
    fn default() -> Self {
        BoardSettings {
            period_ms: 20,
            no_load: DEFAULT_NO_LOAD,
            skin_type: 0,
            shift: 0,
            cdc_offset: DEFAULT_CDC_OFFSET,
        }
    }
}

/// A frame of the MTB protocol, as the host reads it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message {
    /// Taxels 0–6 of a triangle.
    Head {
        /// Board address.
        board: u8,
        /// Triangle index.
        triangle: u8,
        /// Raw values.
        raw: [u8; 7],
    },
    /// Taxels 7–11 of a triangle, with its diagnostics.
    Tail {
        /// Board address.
        board: u8,
        /// Triangle index.
        triangle: u8,
        /// Raw values.
        raw: [u8; 5],
        /// One bit per taxel (bit 11 = taxel 11) out of range.
        out_of_range: u16,
        /// 0 ok, 1 I2C no-acknowledge, 2 triangle not connected.
        error: u8,
    },
    /// A command to a board (what a host sends; an emulated board obeys it).
    Command {
        /// The addressed board.
        board: u8,
        /// The command byte and its arguments.
        bytes: [u8; 8],
        /// How many of `bytes` were sent.
        len: usize,
    },
    /// Anything else on the bus (debug frames, other classes).
    Other,
}

/// Reads one frame. Total: any frame is a message or `Other`.
pub fn parse(frame: &CanFrame) -> Message {
    if frame.is_extended() || frame.is_remote() {
        return Message::Other;
    }
    let id = frame.raw_id() as u16;
    let (class, board, triangle) = (id >> 8, ((id >> 4) & 0xF) as u8, (id & 0xF) as u8);
    let data = frame.bytes();
    if class == CLASS_COMMAND && !data.is_empty() {
        let mut bytes = [0u8; 8];
        bytes[..data.len()].copy_from_slice(data);
        return Message::Command { board: (id & 0xF) as u8, bytes, len: data.len() };
    }
    if class != CLASS_PERIODIC_SKIN || data.len() != 8 {
        return Message::Other;
    }
    if data[0] & 0x80 == 0 {
        let mut raw = [0u8; 7];
        raw.copy_from_slice(&data[1..8]);
        Message::Head { board, triangle, raw }
    } else {
        let mut raw = [0u8; 5];
        raw.copy_from_slice(&data[1..6]);
        let out_of_range = (u16::from(data[6]) << 4) | u16::from(data[7] >> 4);
        Message::Tail { board, triangle, raw, out_of_range, error: data[7] & 0x0F }
    }
}

/// The two frames a board sends for one triangle (what an emulated board
/// sends; also the golden frames of the tests).
pub fn triangle_frames(board: u8, triangle: u8, raw: &[u8; 12], out_of_range: u16, error: u8) -> [CanFrame; 2] {
    let id = (CLASS_PERIODIC_SKIN << 8) | (u16::from(board & 0xF) << 4) | u16::from(triangle & 0xF);
    let mut head = [0x40u8; 8];
    head[1..8].copy_from_slice(&raw[..7]);
    let mut tail = [0u8; 8];
    tail[0] = 0xC0;
    tail[1..6].copy_from_slice(&raw[7..]);
    tail[6] = (out_of_range >> 4) as u8;
    tail[7] = ((out_of_range as u8 & 0xF) << 4) | (error & 0xF);
    // Both identifiers are below 0x800 and both payloads 8 bytes: always frames.
    let frame = |data: &[u8; 8]| CanFrame::standard(id, data).unwrap_or_else(|| unreachable!("a valid MTB frame"));
    [frame(&head), frame(&tail)]
}

fn command(board: u8, bytes: &[u8]) -> CanFrame {
    let id = (CLASS_COMMAND << 8) | u16::from(board & 0xF);
    CanFrame::standard(id, bytes).unwrap_or_else(|| unreachable!("commands are at most 7 bytes"))
}

/// What the host sends at start-up: each board's configuration, its
/// triangles' configuration, then the start command.
pub fn start_commands(boards: &[Board], settings: &BoardSettings) -> Vec<CanFrame> {
    let mut frames = Vec::new();
    for board in boards {
        let address = board.address;
        frames.push(command(
            address,
            &[SET_BOARD_CONFIG, settings.skin_type & 0xF, settings.period_ms, settings.no_load],
        ));
        let first = board.triangles.iter().copied().min().unwrap_or(0);
        let last = board.triangles.iter().copied().max().unwrap_or(0);
        let [cdc_lo, cdc_hi] = settings.cdc_offset.to_le_bytes();
        frames.push(command(address, &[SET_TRIANGLE_CONFIG, first, last, settings.shift, 1, cdc_lo, cdc_hi]));
        frames.push(command(address, &[SET_TX_MODE, 0]));
    }
    frames
}

/// What the host sends to stop the boards streaming.
pub fn stop_commands(boards: &[Board]) -> Vec<CanFrame> {
    boards.iter().map(|board| command(board.address, &[SET_TX_MODE, 1])).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn golden_triangle_frames() {
        let raw = [240, 239, 238, 237, 236, 235, 234, 233, 232, 231, 230, 229];
        let [head, tail] = triangle_frames(3, 10, &raw, 0b1000_0000_0001, 2);
        assert_eq!(format!("{head:?}"), "43A#40F0EFEEEDECEBEA");
        assert_eq!(format!("{tail:?}"), "43A#C0E9E8E7E6E58012");
        assert_eq!(parse(&head), Message::Head { board: 3, triangle: 10, raw: [240, 239, 238, 237, 236, 235, 234] });
        assert_eq!(
            parse(&tail),
            Message::Tail { board: 3, triangle: 10, raw: [233, 232, 231, 230, 229], out_of_range: 0x801, error: 2 }
        );
        assert_eq!(response(240), 15);
        assert_eq!(response(0), 255);
    }

    #[test]
    fn golden_start_and_stop() {
        let boards = [Board { address: 1, triangles: (0..16).collect() }];
        let frames: Vec<String> =
            start_commands(&boards, &BoardSettings::default()).iter().map(|f| format!("{f:?}")).collect();
        assert_eq!(frames, ["201#4D0014F0", "201#50000F00010022", "201#0700"]);
        assert_eq!(format!("{:?}", stop_commands(&boards)[0]), "201#0701");
        assert!(matches!(
            parse(&start_commands(&boards, &BoardSettings::default())[0]),
            Message::Command { board: 1, len: 4, .. }
        ));
    }

    proptest! {
        #[test]
        fn triangles_round_trip(board in 1u8..16, triangle in 0u8..16, raw in any::<[u8; 12]>(), mask in 0u16..0x1000, error in 0u8..16) {
            let [head, tail] = triangle_frames(board, triangle, &raw, mask, error);
            let Message::Head { raw: first, .. } = parse(&head) else { panic!("not a head") };
            let Message::Tail { raw: rest, out_of_range, error: e, board: b, triangle: t } = parse(&tail) else { panic!("not a tail") };
            prop_assert_eq!((b, t, out_of_range, e), (board, triangle, mask, error));
            prop_assert_eq!([&first[..], &rest[..]].concat(), raw.to_vec());
        }

        #[test]
        fn any_frame_parses(id in 0u16..0x800, data in proptest::collection::vec(any::<u8>(), 0..=8)) {
            let _ = parse(&CanFrame::standard(id, &data).unwrap());
        }
    }
}
