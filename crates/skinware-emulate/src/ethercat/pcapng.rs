//! Captures of EtherCAT traffic in pcapng (what Wireshark opens): a writer
//! for what an emulated segment sees, and a reader for replaying it.
//!
//! Only what a capture of one Ethernet interface needs: a section header,
//! one interface description (link type 1, Ethernet; nanosecond time stamps)
//! and enhanced packet blocks, little-endian.

use std::io::{self, Write};

const SECTION_HEADER: u32 = 0x0A0D_0D0A;
const INTERFACE_DESCRIPTION: u32 = 0x0000_0001;
const ENHANCED_PACKET: u32 = 0x0000_0006;
const BYTE_ORDER_MAGIC: u32 = 0x1A2B_3C4D;
const LINKTYPE_ETHERNET: u16 = 1;
/// Option `if_tsresol`: time stamps in 10^-9 s.
const OPTION_TIMESTAMP_RESOLUTION: u16 = 9;

/// Writes a pcapng capture of one Ethernet interface.
pub struct PcapngWriter<W: Write> {
    out: W,
}

impl<W: Write> PcapngWriter<W> {
    /// Starts a capture: section header and interface description.
    pub fn new(mut out: W) -> io::Result<PcapngWriter<W>> {
        // Section header: magic, byte order, version 1.0, section length unknown (-1).
        let mut body = Vec::new();
        body.extend_from_slice(&BYTE_ORDER_MAGIC.to_le_bytes());
        body.extend_from_slice(&1u16.to_le_bytes());
        body.extend_from_slice(&0u16.to_le_bytes());
        body.extend_from_slice(&u64::MAX.to_le_bytes());
        write_block(&mut out, SECTION_HEADER, &body)?;
        // Interface: Ethernet, no snap length limit, nanosecond time stamps.
        let mut body = Vec::new();
        body.extend_from_slice(&LINKTYPE_ETHERNET.to_le_bytes());
        body.extend_from_slice(&0u16.to_le_bytes());
        body.extend_from_slice(&0u32.to_le_bytes());
        body.extend_from_slice(&OPTION_TIMESTAMP_RESOLUTION.to_le_bytes());
        body.extend_from_slice(&1u16.to_le_bytes());
        body.extend_from_slice(&[9, 0, 0, 0]);
        body.extend_from_slice(&[0, 0, 0, 0]); // opt_endofopt
        write_block(&mut out, INTERFACE_DESCRIPTION, &body)?;
        Ok(PcapngWriter { out })
    }

    /// Appends one frame seen at `timestamp_ns` (nanoseconds, any epoch).
    pub fn write_frame(&mut self, timestamp_ns: u64, frame: &[u8]) -> io::Result<()> {
        let mut body = Vec::with_capacity(20 + frame.len() + 3);
        body.extend_from_slice(&0u32.to_le_bytes());
        body.extend_from_slice(&((timestamp_ns >> 32) as u32).to_le_bytes());
        body.extend_from_slice(&(timestamp_ns as u32).to_le_bytes());
        body.extend_from_slice(&(frame.len() as u32).to_le_bytes());
        body.extend_from_slice(&(frame.len() as u32).to_le_bytes());
        body.extend_from_slice(frame);
        body.resize(body.len().next_multiple_of(4), 0);
        write_block(&mut self.out, ENHANCED_PACKET, &body)
    }

    /// Flushes and returns the output.
    pub fn finish(mut self) -> io::Result<W> {
        self.out.flush()?;
        Ok(self.out)
    }
}

fn write_block(out: &mut impl Write, kind: u32, body: &[u8]) -> io::Result<()> {
    let total = (12 + body.len()) as u32;
    out.write_all(&kind.to_le_bytes())?;
    out.write_all(&total.to_le_bytes())?;
    out.write_all(body)?;
    out.write_all(&total.to_le_bytes())
}

/// Why a capture cannot be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum PcapngError {
    /// It does not start with a little-endian section header.
    #[error("not a little-endian pcapng capture (it must start with a section header)")]
    NotPcapng,
    /// A block's length runs past the end, is too short, or its two copies differ.
    #[error("block at byte {offset} has a broken length")]
    BrokenBlock {
        /// Where the block starts.
        offset: usize,
    },
}

/// The frames of a pcapng capture (enhanced packet blocks), in order; other
/// blocks are skipped.
pub fn read_frames(capture: &[u8]) -> Result<Vec<Vec<u8>>, PcapngError> {
    let word = |at: usize| -> Option<u32> {
        capture.get(at..at.checked_add(4)?).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    };
    if word(0) != Some(SECTION_HEADER) || word(8) != Some(BYTE_ORDER_MAGIC) {
        return Err(PcapngError::NotPcapng);
    }
    let mut frames = Vec::new();
    let mut offset = 0;
    while offset < capture.len() {
        let broken = PcapngError::BrokenBlock { offset };
        let kind = word(offset).ok_or(broken.clone())?;
        let total = word(offset + 4).ok_or(broken.clone())? as usize;
        let end = offset.checked_add(total).ok_or(broken.clone())?;
        if total < 12 || !total.is_multiple_of(4) || end > capture.len() || word(end - 4) != Some(total as u32) {
            return Err(broken);
        }
        if kind == ENHANCED_PACKET {
            let captured = word(offset + 20).ok_or(broken.clone())? as usize;
            let data = offset + 28;
            let frame =
                data.checked_add(captured).and_then(|e| capture.get(data..e)).filter(|_| data + captured <= end - 4);
            frames.push(frame.ok_or(broken)?.to_vec());
        }
        offset = end;
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn frames_written_are_read_back() {
        let mut writer = PcapngWriter::new(Vec::new()).unwrap();
        let frames: Vec<Vec<u8>> = vec![vec![1, 2, 3], vec![], (0..=255).collect()];
        for (k, frame) in frames.iter().enumerate() {
            writer.write_frame(k as u64 * 1_000_000_007, frame).unwrap();
        }
        let capture = writer.finish().unwrap();
        assert_eq!(read_frames(&capture).unwrap(), frames);
        // The last block (256 bytes of frame, 28 of block) loses its last byte.
        let last = capture.len() - (28 + 256 + 4);
        assert_eq!(read_frames(&capture[..capture.len() - 1]), Err(PcapngError::BrokenBlock { offset: last }));
        assert_eq!(read_frames(b"not a capture"), Err(PcapngError::NotPcapng));
    }

    proptest! {
        /// A mutated capture is read or refused, never a panic.
        #[test]
        fn mutated_captures_never_panic(
            frames in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..80), 0..5),
            flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..6),
        ) {
            let mut writer = PcapngWriter::new(Vec::new()).unwrap();
            for frame in &frames {
                writer.write_frame(0, frame).unwrap();
            }
            let mut capture = writer.finish().unwrap();
            for (at, value) in flips {
                let at = at.index(capture.len());
                capture[at] = value;
            }
            let _ = read_frames(&capture);
        }
    }
}

/// Where a replay of a capture through a segment went different.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ReplayMismatch {
    /// The segment answered a request differently than the capture says.
    #[error("frame {index}: the answer differs from the capture's at byte {byte}")]
    Answer {
        /// The request's position in the capture.
        index: usize,
        /// The first byte that differs (or the shorter length).
        byte: usize,
    },
    /// The capture has an answer that the segment did not give, or the
    /// other way round.
    #[error("frame {index}: the capture {} an answer but the segment {}", if *.captured { "has" } else { "has no" }, if *.captured { "gave none" } else { "answered" })]
    Presence {
        /// The request's position in the capture.
        index: usize,
        /// Whether the capture holds an answer.
        captured: bool,
    },
}

/// Sends every request of a capture (frames from a MainDevice, each followed
/// by its answer if it had one, as [`super::serve_interface`] records them)
/// through `segment`, and checks that it answers exactly as captured.
/// Returns the requests replayed.
pub fn replay(frames: &[Vec<u8>], segment: &mut super::Segment) -> Result<usize, ReplayMismatch> {
    let is_answer = |frame: &[u8]| frame.get(6).is_some_and(|b| b & 0x02 != 0);
    let mut requests = 0;
    let mut index = 0;
    while index < frames.len() {
        let request = &frames[index];
        if is_answer(request) {
            // An answer without its request (the capture started late).
            index += 1;
            continue;
        }
        requests += 1;
        let captured = frames.get(index + 1).filter(|f| is_answer(f));
        let mut answer = request.clone();
        let answered = matches!(segment.process(&mut answer), Ok(super::Fate::Returned));
        match (captured, answered) {
            (Some(captured), true) => {
                if let Some(byte) = (0..captured.len().max(answer.len())).find(|&k| captured.get(k) != answer.get(k)) {
                    return Err(ReplayMismatch::Answer { index, byte });
                }
            }
            (None, false) => {}
            (captured, _) => return Err(ReplayMismatch::Presence { index, captured: captured.is_some() }),
        }
        index += if captured.is_some() { 2 } else { 1 };
    }
    Ok(requests)
}
