//! CAN frames in UDP datagrams, as `cannelloni` (the SocketCAN-over-Ethernet
//! tunnel) sends them, format version 2:
//!
//! ```text
//! header   version = 2 (u8) | op code (u8: 0 data, 1 ack, 2 nack) | sequence (u8) | frame count (u16 BE)
//! frame    can_id (u32 BE, Linux flags: 0x8000_0000 extended, 0x4000_0000 remote, 0x2000_0000 error)
//!          | length (u8; 0x80 set means CAN FD, followed by a flags byte) | data (none for a remote frame)
//! ```

use embedded_can::{ExtendedId, Id, StandardId};

use super::CanFrame;

/// The format version this codec speaks.
pub const VERSION: u8 = 2;
/// The op code of a data packet.
pub const OP_DATA: u8 = 0;
const HEADER_BYTES: usize = 5;
const EXTENDED_FLAG: u32 = 0x8000_0000;
const REMOTE_FLAG: u32 = 0x4000_0000;
const ERROR_FLAG: u32 = 0x2000_0000;
const FD_FLAG: u8 = 0x80;
/// Frames in one datagram, at most: a 1500-byte Ethernet payload holds 100
/// classic frames, and cannelloni itself sends fewer.
pub const MAX_FRAMES_PER_PACKET: usize = 100;

/// A datagram that is not a cannelloni v2 data packet of classic frames.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "not a cannelloni v2 packet of classic CAN frames: {problem} (byte {offset} of {len}); is the peer cannelloni 1.x with classic CAN?"
)]
pub struct CannelloniError {
    /// What is wrong.
    pub problem: &'static str,
    /// Where.
    pub offset: usize,
    /// The datagram's length.
    pub len: usize,
}

/// A decoded data packet.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Packet {
    /// The sender's sequence number (wraps at 256): a gap means lost datagrams.
    pub sequence: u8,
    /// The frames, in order.
    pub frames: Vec<CanFrame>,
}

/// Encodes one data packet of up to [`MAX_FRAMES_PER_PACKET`] frames
/// (more are left out: callers send them in the next packet).
pub fn encode(sequence: u8, frames: &[CanFrame], out: &mut Vec<u8>) {
    let frames = &frames[..frames.len().min(MAX_FRAMES_PER_PACKET)];
    out.extend_from_slice(&[VERSION, OP_DATA, sequence]);
    out.extend_from_slice(&(frames.len() as u16).to_be_bytes());
    for frame in frames {
        let mut id = frame.raw_id();
        if frame.is_extended() {
            id |= EXTENDED_FLAG;
        }
        if frame.is_remote() {
            id |= REMOTE_FLAG;
        }
        out.extend_from_slice(&id.to_be_bytes());
        out.push(frame.dlc() as u8);
        out.extend_from_slice(frame.bytes());
    }
}

/// Decodes a datagram. Non-data packets (acks, nacks) have no frames.
pub fn decode(bytes: &[u8]) -> Result<Packet, CannelloniError> {
    let error = |problem, offset| CannelloniError { problem, offset, len: bytes.len() };
    let header = bytes.get(..HEADER_BYTES).ok_or(error("shorter than the 5-byte header", 0))?;
    if header[0] != VERSION {
        return Err(error("the version is not 2", 0));
    }
    let sequence = header[2];
    if header[1] != OP_DATA {
        return Ok(Packet { sequence, frames: Vec::new() });
    }
    let count = usize::from(u16::from_be_bytes([header[3], header[4]]));
    // Each frame takes at least 5 bytes: the count cannot claim more than the
    // datagram holds, so it never decides an allocation.
    if count > (bytes.len() - HEADER_BYTES) / 5 {
        return Err(error("the frame count is more than the datagram holds", 3));
    }
    let mut frames = Vec::with_capacity(count);
    let mut at = HEADER_BYTES;
    for _ in 0..count {
        let head = bytes.get(at..at + 5).ok_or(error("a frame is cut short", at))?;
        let raw = u32::from_be_bytes([head[0], head[1], head[2], head[3]]);
        let len = head[4];
        if len & FD_FLAG != 0 {
            return Err(error("CAN FD frames are not supported", at + 4));
        }
        if raw & ERROR_FLAG != 0 {
            return Err(error("error frames are not data", at));
        }
        let raw_id = raw & 0x1FFF_FFFF;
        let id = if raw & EXTENDED_FLAG != 0 {
            Id::Extended(ExtendedId::new(raw_id).ok_or(error("bad extended identifier", at))?)
        } else if raw_id <= 0x7FF {
            Id::Standard(StandardId::new(raw_id as u16).ok_or(error("bad standard identifier", at))?)
        } else {
            return Err(error("a standard identifier is at most 7FF", at));
        };
        let dlc = usize::from(len);
        if dlc > 8 {
            return Err(error("a classic frame has at most 8 bytes", at + 4));
        }
        at += 5;
        let frame = if raw & REMOTE_FLAG != 0 {
            CanFrame::remote(id, dlc)
        } else {
            let data = bytes.get(at..at + dlc).ok_or(error("the data is cut short", at))?;
            at += dlc;
            CanFrame::data(id, data)
        };
        frames.push(frame.ok_or(error("not a frame", at))?);
    }
    if at != bytes.len() {
        return Err(error("bytes follow the last frame", at));
    }
    Ok(Packet { sequence, frames })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::frame::any_frame;
    use proptest::prelude::*;

    #[test]
    fn golden_packet() {
        let frames = [
            CanFrame::standard(0x405, &[1, 2, 3, 4]).unwrap(),
            CanFrame::extended(0x1234_5678, &[]).unwrap(),
            CanFrame::remote(Id::Standard(StandardId::new(0x200).unwrap()), 2).unwrap(),
        ];
        let mut out = Vec::new();
        encode(7, &frames, &mut out);
        assert_eq!(
            out,
            [
                2, 0, 7, 0, 3, // header
                0, 0, 4, 5, 4, 1, 2, 3, 4, // 405#01020304
                0x92, 0x34, 0x56, 0x78, 0, // 12345678#
                0x40, 0, 2, 0, 2, // 200#R2
            ]
        );
        assert_eq!(decode(&out).unwrap(), Packet { sequence: 7, frames: frames.to_vec() });
    }

    #[test]
    fn bad_packets_say_what_is_wrong() {
        for (bytes, problem) in [
            (&[2u8, 0, 0][..], "header"),
            (&[1, 0, 0, 0, 0][..], "version"),
            (&[2, 0, 0, 0xFF, 0xFF, 0, 0, 0, 1, 0][..], "frame count"),
            (&[2, 0, 0, 0, 1, 0, 0, 0, 1, 0x88, 0][..], "CAN FD"),
            (&[2, 0, 0, 0, 1, 0, 0, 8, 0, 0][..], "at most 7FF"),
            (&[2, 0, 0, 0, 1, 0, 0, 0, 1, 2, 9][..], "cut short"),
            (&[2, 0, 0, 0, 1, 0, 0, 0, 1, 0, 9][..], "bytes follow"),
        ] {
            let err = decode(bytes).unwrap_err();
            assert!(err.problem.contains(problem), "{bytes:?}: {err}");
        }
        assert_eq!(decode(&[2, 1, 9, 0, 0]).unwrap().frames, []);
    }

    proptest! {
        #[test]
        fn packets_round_trip(sequence in any::<u8>(), frames in proptest::collection::vec(any_frame(), 0..MAX_FRAMES_PER_PACKET)) {
            let mut out = Vec::new();
            encode(sequence, &frames, &mut out);
            prop_assert_eq!(decode(&out).unwrap(), Packet { sequence, frames });
        }

        #[test]
        fn any_datagram_is_a_packet_or_an_error(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
            if let Ok(packet) = decode(&bytes) {
                prop_assert!(packet.frames.len() <= bytes.len() / 5);
            }
        }
    }
}
