//! The Lawicel (SLCAN) ASCII protocol that CANable, USBtin and similar USB
//! adapters speak over a serial line, host side. Written here because the
//! existing crates are abandoned (`slcan` 0.1 depends on the dead
//! `serial-core`) or immature.
//!
//! | host sends | meaning |
//! |---|---|
//! | `C\r`, `Sn\r`, `O\r` | close, set the bit rate (S0 = 10 kbit/s … S8 = 1 Mbit/s), open |
//! | `tIIILDD…\r` | a standard data frame: 3 hex digits of identifier, the length, the data |
//! | `TIIIIIIIILDD…\r` | an extended data frame |
//! | `rIIIL\r`, `RIIIIIIIIL\r` | remote frames |
//!
//! The adapter sends received frames the same way (with 4 hex digits of
//! millisecond timestamp appended when timestamps are on), `\r` to
//! acknowledge a command, `\x07` (BEL) to refuse one, and `z\r`/`Z\r` for a
//! transmitted frame.

use embedded_can::{ExtendedId, Id, StandardId};

use super::CanFrame;

/// Longest line an adapter sends: `T` + 8 + 1 + 16 + 4 (timestamp).
pub const MAX_LINE_BYTES: usize = 30;

/// The `Sn` command for a bit rate, if the protocol has one.
pub fn bitrate_command(bits_per_second: u32) -> Option<&'static [u8]> {
    Some(match bits_per_second {
        10_000 => b"S0\r",
        20_000 => b"S1\r",
        50_000 => b"S2\r",
        100_000 => b"S3\r",
        125_000 => b"S4\r",
        250_000 => b"S5\r",
        500_000 => b"S6\r",
        800_000 => b"S7\r",
        1_000_000 => b"S8\r",
        _ => return None,
    })
}

/// The bit rates [`bitrate_command`] knows, for error messages.
pub const BITRATES: &str = "10000, 20000, 50000, 100000, 125000, 250000, 500000, 800000, 1000000";

/// Appends the command that transmits `frame`.
pub fn encode(frame: &CanFrame, out: &mut Vec<u8>) {
    let kind = match (frame.is_extended(), frame.is_remote()) {
        (false, false) => 't',
        (true, false) => 'T',
        (false, true) => 'r',
        (true, true) => 'R',
    };
    let digits = if frame.is_extended() { 8 } else { 3 };
    let text = format!("{kind}{:0digits$X}{}", frame.raw_id(), frame.dlc());
    out.extend_from_slice(text.as_bytes());
    for byte in frame.bytes() {
        out.extend_from_slice(format!("{byte:02X}").as_bytes());
    }
    out.push(b'\r');
}

/// What an adapter said.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Event {
    /// A frame received from the bus, with the adapter's millisecond
    /// timestamp if it sends them.
    Frame(CanFrame, Option<u16>),
    /// A command was accepted (`\r`).
    Ok,
    /// A command was refused (BEL).
    Refused,
    /// A frame was transmitted (`z`/`Z`).
    Transmitted,
    /// A reply to another command (`V1013`, `F00`, …).
    Reply(String),
    /// A line that is none of these (noise on the line, a lost byte).
    Garbled {
        /// The line as received.
        line: String,
        /// Why it is not a frame.
        problem: &'static str,
    },
}

/// Turns the adapter's byte stream into [`Event`]s, keeping at most one
/// line of [`MAX_LINE_BYTES`]. Any byte sequence gives events or `Garbled`
/// lines; a too-long line is dropped up to its end.
#[derive(Debug, Default)]
pub struct Decoder {
    line: Vec<u8>,
    overlong: bool,
}

impl Decoder {
    /// A decoder at the start of a line.
    pub fn new() -> Decoder {
        Decoder::default()
    }

    /// Feeds bytes; calls `event` for each complete event.
    pub fn push(&mut self, bytes: &[u8], mut event: impl FnMut(Event)) {
        for &byte in bytes {
            match byte {
                b'\r' | b'\n' => {
                    if self.overlong {
                        self.overlong = false;
                        event(Event::Garbled { line: String::new(), problem: "a line longer than any frame" });
                    } else if !self.line.is_empty() {
                        event(parse_line(&self.line));
                    } else if byte == b'\r' {
                        event(Event::Ok);
                    }
                    self.line.clear();
                }
                0x07 => {
                    self.line.clear();
                    self.overlong = false;
                    event(Event::Refused);
                }
                _ if self.overlong => {}
                _ if self.line.len() >= MAX_LINE_BYTES => {
                    self.line.clear();
                    self.overlong = true;
                }
                _ => self.line.push(byte),
            }
        }
    }
}

fn hex(bytes: &[u8]) -> Option<u32> {
    if bytes.is_empty() || bytes.len() > 8 || !bytes.iter().all(u8::is_ascii_hexdigit) {
        return None;
    }
    u32::from_str_radix(std::str::from_utf8(bytes).ok()?, 16).ok()
}

/// Parses one line (without its `\r`).
pub fn parse_line(line: &[u8]) -> Event {
    let garbled = |problem| Event::Garbled { line: String::from_utf8_lossy(line).into_owned(), problem };
    let Some((&kind, rest)) = line.split_first() else {
        return Event::Ok;
    };
    let (extended, remote) = match kind {
        b't' => (false, false),
        b'T' => (true, false),
        b'r' => (false, true),
        b'R' => (true, true),
        b'z' | b'Z' if rest.is_empty() => return Event::Transmitted,
        _ => return Event::Reply(String::from_utf8_lossy(line).into_owned()),
    };
    let id_digits = if extended { 8 } else { 3 };
    let (Some(id_text), Some(&dlc)) = (rest.get(..id_digits), rest.get(id_digits)) else {
        return garbled("too short for a frame");
    };
    let Some(raw) = hex(id_text) else { return garbled("the identifier is not hexadecimal") };
    let id = if extended {
        match ExtendedId::new(raw) {
            Some(id) => Id::Extended(id),
            None => return garbled("an extended identifier is at most 1FFFFFFF"),
        }
    } else {
        match StandardId::new(raw as u16) {
            Some(id) => Id::Standard(id),
            None => return garbled("a standard identifier is at most 7FF"),
        }
    };
    if !(b'0'..=b'8').contains(&dlc) {
        return garbled("the length is not 0 to 8");
    }
    let dlc = usize::from(dlc - b'0');
    let body = &rest[id_digits + 1..];
    let data_digits = if remote { 0 } else { 2 * dlc };
    let (data_text, stamp_text) = match body.len() {
        n if n == data_digits => (body, None),
        n if n == data_digits + 4 => (&body[..data_digits], Some(&body[data_digits..])),
        _ => return garbled("the data does not match the length"),
    };
    let mut data = [0u8; 8];
    for (i, pair) in data_text.chunks_exact(2).enumerate() {
        match hex(pair) {
            Some(byte) => data[i] = byte as u8,
            None => return garbled("the data is not hexadecimal"),
        }
    }
    let stamp = match stamp_text.map(hex) {
        None => None,
        Some(Some(ms)) => Some(ms as u16),
        Some(None) => return garbled("the timestamp is not hexadecimal"),
    };
    let frame = if remote { CanFrame::remote(id, dlc) } else { CanFrame::data(id, &data[..dlc]) };
    match frame {
        Some(frame) => Event::Frame(frame, stamp),
        None => garbled("not a frame"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::frame::any_frame;
    use proptest::prelude::*;

    fn events(bytes: &[u8]) -> Vec<Event> {
        let mut decoder = Decoder::new();
        let mut found = Vec::new();
        decoder.push(bytes, |e| found.push(e));
        found
    }

    #[test]
    fn golden_commands() {
        let mut out = Vec::new();
        encode(&CanFrame::standard(0x20F, &[0x07, 0x00]).unwrap(), &mut out);
        encode(&CanFrame::extended(0x1234_5678, &[0xAB]).unwrap(), &mut out);
        encode(&CanFrame::remote(Id::Standard(StandardId::new(0x100).unwrap()), 2).unwrap(), &mut out);
        assert_eq!(out, b"t20F20700\rT123456781AB\rr1002\r");
        assert_eq!(bitrate_command(1_000_000), Some(&b"S8\r"[..]));
        assert_eq!(bitrate_command(42), None);
    }

    #[test]
    fn golden_adapter_output() {
        let found = events(b"\rt40F840F0F0F0F0F0F0F0\rt40F840F0F0F0F0F0F0F01A2B\r\x07z\rV1013\rt4\r");
        let frame = CanFrame::standard(0x40F, &[0x40, 0xF0, 0xF0, 0xF0, 0xF0, 0xF0, 0xF0, 0xF0]).unwrap();
        assert_eq!(found[0], Event::Ok);
        assert_eq!(found[1], Event::Frame(frame, None));
        assert_eq!(found[2], Event::Frame(frame, Some(0x1A2B)));
        assert_eq!(found[3], Event::Refused);
        assert_eq!(found[4], Event::Transmitted);
        assert_eq!(found[5], Event::Reply("V1013".into()));
        assert!(matches!(found[6], Event::Garbled { problem: "too short for a frame", .. }));
    }

    #[test]
    fn a_line_split_across_reads_is_one_frame() {
        let mut decoder = Decoder::new();
        let mut found = Vec::new();
        for chunk in b"t1232AB".chunks(1).chain([&b"CD\r"[..]]) {
            decoder.push(chunk, |e| found.push(e));
        }
        assert_eq!(found, [Event::Frame(CanFrame::standard(0x123, &[0xAB, 0xCD]).unwrap(), None)]);
    }

    #[test]
    fn an_endless_line_is_dropped_and_the_next_one_read() {
        let mut bytes = vec![b'7'; 10_000];
        bytes.extend_from_slice(b"\rt0011FF\r");
        let found = events(&bytes);
        assert!(matches!(found[0], Event::Garbled { .. }));
        assert_eq!(found[1], Event::Frame(CanFrame::standard(1, &[0xFF]).unwrap(), None));
    }

    proptest! {
        #[test]
        fn frames_round_trip_in_any_chunking(frames in proptest::collection::vec(any_frame(), 1..20), cut in 1usize..40) {
            let mut bytes = Vec::new();
            for frame in &frames {
                encode(frame, &mut bytes);
            }
            let mut decoder = Decoder::new();
            let mut found = Vec::new();
            for chunk in bytes.chunks(cut) {
                decoder.push(chunk, |e| found.push(e));
            }
            let expected: Vec<Event> = frames.iter().map(|f| Event::Frame(*f, None)).collect();
            prop_assert_eq!(found, expected);
        }

        #[test]
        fn any_bytes_decode_to_events(bytes in proptest::collection::vec(any::<u8>(), 0..2000)) {
            let mut count = 0;
            Decoder::new().push(&bytes, |_| count += 1);
            // At most one event per line end or BEL: nothing is invented.
            prop_assert!(count <= bytes.iter().filter(|&&b| b == b'\r' || b == b'\n' || b == 7).count());
        }
    }
}
