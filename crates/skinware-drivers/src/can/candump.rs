//! The log format of `candump -l` (can-utils): one frame per line,
//!
//! ```text
//! (1436509052.249713) can0 405#0A0B0C0D0E0F1011
//! (1436509052.249902) can0 12345678#01
//! (1436509052.250117) can0 200#R2
//! ```
//!
//! a timestamp in seconds and microseconds, the interface, and the frame:
//! 3 hex digits of a standard identifier or 8 of an extended one, `#`, and the
//! data in hex (or `R` and an optional length digit for a remote frame). CAN FD
//! lines (`##`) are refused with a clear error: no skin here uses CAN FD.

use embedded_can::{ExtendedId, Id, StandardId};

use super::CanFrame;

/// The longest line accepted; a `candump -l` line is at most about 60 bytes.
pub const MAX_LINE_BYTES: usize = 256;

/// One frame of a log, with when and where it was seen.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LogRecord {
    /// Microseconds since the Unix epoch (`candump` uses the wall clock).
    pub time_us: u64,
    /// The interface it was seen on (`can0`).
    pub interface: String,
    /// The frame.
    pub frame: CanFrame,
}

/// A line that is not a `candump -l` record.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error(
    "not a candump log line ({problem}): {line:?}; logs are written by `candump -l`, one `(seconds.micros) interface ID#DATA` per line"
)]
pub struct CandumpError {
    /// The line (shortened if long).
    pub line: String,
    /// What is wrong with it.
    pub problem: &'static str,
}

/// Parses one line. Blank lines give `Ok(None)`.
pub fn parse_line(line: &str) -> Result<Option<LogRecord>, CandumpError> {
    let error = |problem| CandumpError { line: line.chars().take(80).collect(), problem };
    if line.len() > MAX_LINE_BYTES {
        return Err(error("the line is too long"));
    }
    let line_trimmed = line.trim();
    if line_trimmed.is_empty() {
        return Ok(None);
    }
    let mut fields = line_trimmed.split_ascii_whitespace();
    let (Some(stamp), Some(interface), Some(frame), None) =
        (fields.next(), fields.next(), fields.next(), fields.next())
    else {
        return Err(error("it does not have three fields"));
    };
    let stamp = stamp.strip_prefix('(').and_then(|s| s.strip_suffix(')')).ok_or_else(|| error("no (timestamp)"))?;
    let (seconds, micros) = stamp.split_once('.').ok_or_else(|| error("the timestamp has no '.'"))?;
    if micros.len() != 6 {
        return Err(error("the timestamp needs six digits of microseconds"));
    }
    let seconds: u64 = parse_decimal(seconds).ok_or_else(|| error("bad seconds in the timestamp"))?;
    let micros: u64 = parse_decimal(micros).ok_or_else(|| error("bad microseconds in the timestamp"))?;
    let time_us = seconds
        .checked_mul(1_000_000)
        .and_then(|us| us.checked_add(micros))
        .ok_or_else(|| error("the timestamp is too large"))?;
    let frame = parse_frame(frame).map_err(error)?;
    Ok(Some(LogRecord { time_us, interface: interface.to_owned(), frame }))
}

fn parse_decimal(text: &str) -> Option<u64> {
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    text.parse().ok()
}

/// Parses `ID#DATA` (the `cansend` notation, also used in logs).
pub fn parse_frame(text: &str) -> Result<CanFrame, &'static str> {
    let (id_text, rest) = text.split_once('#').ok_or("no '#' between identifier and data")?;
    if rest.starts_with('#') {
        return Err("CAN FD frames (##) are not supported");
    }
    if id_text.is_empty() || !id_text.bytes().all(|b| b.is_ascii_hexdigit()) {
        return Err("the identifier is not hexadecimal");
    }
    let raw = u32::from_str_radix(id_text, 16).map_err(|_| "the identifier is too long")?;
    let id = match id_text.len() {
        1..=3 => Id::Standard(StandardId::new(raw as u16).ok_or("a standard identifier is at most 7FF")?),
        8 => {
            if raw & 0x2000_0000 != 0 {
                return Err("error frames are not data");
            }
            Id::Extended(ExtendedId::new(raw).ok_or("an extended identifier is at most 1FFFFFFF")?)
        }
        _ => return Err("an identifier has 3 (standard) or 8 (extended) hex digits"),
    };
    if let Some(length) = rest.strip_prefix('R') {
        let dlc = match length.as_bytes() {
            [] => 0,
            [digit] if digit.is_ascii_digit() => usize::from(digit - b'0'),
            _ => return Err("a remote frame's length is one digit"),
        };
        return CanFrame::remote(id, dlc).ok_or("a remote frame asks for at most 8 bytes");
    }
    if rest.len() % 2 != 0 || rest.len() > 16 {
        return Err("the data must be 0 to 8 bytes, two hex digits each");
    }
    let mut data = [0u8; 8];
    for (i, pair) in rest.as_bytes().chunks_exact(2).enumerate() {
        let text = std::str::from_utf8(pair).map_err(|_| "the data is not hexadecimal")?;
        if !text.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err("the data is not hexadecimal");
        }
        data[i] = u8::from_str_radix(text, 16).map_err(|_| "the data is not hexadecimal")?;
    }
    CanFrame::data(id, &data[..rest.len() / 2]).ok_or("more than 8 data bytes")
}

/// The `cansend` notation of a frame: `405#0A0B`, `12345678#`, `200#R2`.
pub fn frame_text(frame: &CanFrame) -> String {
    frame.cansend_text()
}

/// One log line for `record`, without the line end.
pub fn format_line(record: &LogRecord) -> String {
    format!(
        "({}.{:06}) {} {}",
        record.time_us / 1_000_000,
        record.time_us % 1_000_000,
        record.interface,
        frame_text(&record.frame)
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::can::frame::any_frame;
    use proptest::prelude::*;

    #[test]
    fn golden_lines() {
        let record = parse_line("(1436509052.249713) can0 405#0A0B0C0D0E0F1011\n").unwrap().unwrap();
        assert_eq!(record.time_us, 1_436_509_052_249_713);
        assert_eq!(record.interface, "can0");
        assert_eq!((record.frame.raw_id(), record.frame.bytes()), (0x405, &[10u8, 11, 12, 13, 14, 15, 16, 17][..]));
        let extended = parse_line("(0000000001.000001) slcan0 12345678#01").unwrap().unwrap();
        assert!(extended.frame.is_extended() && extended.frame.raw_id() == 0x1234_5678);
        let remote = parse_line("(1.000000) can0 200#R2").unwrap().unwrap();
        assert!(remote.frame.is_remote() && remote.frame.dlc() == 2);
        assert_eq!(parse_line("   ").unwrap(), None);
        assert_eq!(format_line(&record), "(1436509052.249713) can0 405#0A0B0C0D0E0F1011");
        assert_eq!(format_line(&remote), "(1.000000) can0 200#R2");
    }

    #[test]
    fn bad_lines_say_what_is_wrong() {
        for (line, problem) in [
            ("can0 405#00", "three fields"),
            ("(1.5) can0 405#00", "six digits"),
            ("(1.000000) can0 405##100", "CAN FD"),
            ("(1.000000) can0 800#00", "at most 7FF"),
            ("(1.000000) can0 4051#00", "3 (standard) or 8"),
            ("(1.000000) can0 405#0", "two hex digits"),
            ("(1.000000) can0 405#000102030405060708", "0 to 8 bytes"),
            ("(1.000000) can0 405#zz", "not hexadecimal"),
            ("(1.000000) can0 20000080#0000", "error frames"),
        ] {
            let err = parse_line(line).unwrap_err();
            assert!(err.problem.contains(problem), "{line}: {err}");
            assert!(err.to_string().contains("candump -l"), "{err}");
        }
    }

    proptest! {
        #[test]
        fn lines_round_trip(frame in any_frame(), time_us in any::<u64>()) {
            let record = LogRecord { time_us: time_us / 2, interface: "can0".into(), frame };
            prop_assert_eq!(parse_line(&format_line(&record)).unwrap(), Some(record));
        }

        #[test]
        fn any_text_is_a_record_or_an_error(line in "\\PC{0,300}") {
            let _ = parse_line(&line);
        }

        #[test]
        fn near_misses_are_a_record_or_an_error(line in "\\([0-9]{1,12}\\.[0-9]{5,7}\\) [a-z0-9]{1,6} [0-9A-Fa-f]{1,9}#{1,2}R?[0-9A-Fa-f]{0,18}") {
            let _ = parse_line(&line);
        }
    }
}
