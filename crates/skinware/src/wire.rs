//! The one binary encoding of what skinware stores or hands between
//! processes outside frames: a layer's topology (in its channel's
//! description), a service's description, and the published geometry file.
//!
//! * Every encoding starts with an 8-byte magic that names it and its version
//!   (`SKTOPO01`).
//! * Integers and floats are little-endian and fixed-width.
//! * Strings, byte strings and arrays are a `u32` count followed by their
//!   elements; strings are UTF-8.
//!
//! [`Decoder`] reads it and never trusts a count: before it allocates for
//! `n` elements it checks that the input still holds `n` of them, so a
//! decoder allocates at most a small multiple of its input, and any input,
//! however hostile, ends in a value or a [`DecodeError`] that says what was
//! being read, at which byte, and why; never a panic.
//!
//! ```
//! use skinware::wire::{Decoder, Encoder};
//!
//! let mut out = Encoder::new(b"EXAMPLE1");
//! out.str("palm");
//! out.u32s(&[3, 4, 5]);
//! let bytes = out.finish();
//!
//! let mut input = Decoder::new(&bytes, "example", b"EXAMPLE1")?;
//! assert_eq!(input.str("region name")?, "palm");
//! assert_eq!(input.u32s("sensors")?, [3, 4, 5]);
//! input.finish()?;
//! # Ok::<(), skinware::wire::DecodeError>(())
//! ```

#![forbid(unsafe_code)]

/// Why bytes could not be decoded, and where.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{what}: {field} at byte {offset}: {problem}")]
pub struct DecodeError {
    /// What was being decoded ("topology", "geometry file", ...).
    pub what: &'static str,
    /// The field being read when it failed.
    pub field: &'static str,
    /// Its byte offset in the input.
    pub offset: usize,
    /// What was wrong.
    pub problem: Problem,
}

/// What was wrong with the bytes.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Problem {
    /// The input does not start with the expected magic.
    #[error("it starts with {found:?}, not {expected:?}; it is not this kind of data, or another version of it")]
    BadMagic {
        /// The magic expected.
        expected: String,
        /// The first bytes found (lossily as text).
        found: String,
    },
    /// The input ends inside a value.
    #[error("the input ends there; {needed} more bytes were needed (truncated?)")]
    Truncated {
        /// Bytes missing.
        needed: usize,
    },
    /// A count larger than what is left of the input could hold.
    #[error("a count of {count} needs at least {needed} bytes, but only {remaining} remain")]
    CountTooLarge {
        /// The count read.
        count: u64,
        /// Bytes it needs at the least.
        needed: u64,
        /// Bytes left.
        remaining: usize,
    },
    /// A string that is not UTF-8.
    #[error("the text is not UTF-8")]
    NotUtf8,
    /// Bytes left over after the value.
    #[error("{0} bytes are left over after the end")]
    Trailing(usize),
    /// A value that decodes but cannot be right.
    #[error("{0}")]
    Invalid(String),
}

/// Writes the encoding. Counts above `u32::MAX` cannot occur in a skin (the
/// exchange caps descriptions at 64 MiB); they are written as `u32::MAX`, which
/// a decoder then refuses.
#[derive(Clone, Debug)]
pub struct Encoder {
    bytes: Vec<u8>,
}

impl Encoder {
    /// Starts an encoding with its magic.
    pub fn new(magic: &[u8; 8]) -> Encoder {
        Encoder::with_capacity(magic, 64)
    }

    /// Starts an encoding with room for `capacity` bytes.
    pub fn with_capacity(magic: &[u8; 8], capacity: usize) -> Encoder {
        let mut bytes = Vec::with_capacity(capacity.max(8));
        bytes.extend_from_slice(magic);
        Encoder { bytes }
    }

    /// A `u32`.
    pub fn u32(&mut self, value: u32) {
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    /// A `u64`.
    pub fn u64(&mut self, value: u64) {
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    /// An `f64`.
    pub fn f64(&mut self, value: f64) {
        self.bytes.extend_from_slice(&value.to_le_bytes());
    }

    /// A count of what follows.
    pub fn count(&mut self, count: usize) {
        self.u32(u32::try_from(count).unwrap_or(u32::MAX));
    }

    /// A byte string.
    pub fn bytes(&mut self, value: &[u8]) {
        self.count(value.len());
        self.bytes.extend_from_slice(value);
    }

    /// A string.
    pub fn str(&mut self, value: &str) {
        self.bytes(value.as_bytes());
    }

    /// A list of strings.
    pub fn strs<S: AsRef<str>>(&mut self, values: &[S]) {
        self.count(values.len());
        for value in values {
            self.str(value.as_ref());
        }
    }

    /// An array of `u32`.
    pub fn u32s(&mut self, values: &[u32]) {
        self.count(values.len());
        for &value in values {
            self.u32(value);
        }
    }

    /// An array of `f32`.
    pub fn f32s(&mut self, values: impl ExactSizeIterator<Item = f32>) {
        self.count(values.len());
        for value in values {
            self.bytes.extend_from_slice(&value.to_le_bytes());
        }
    }

    /// An array of arrays of `u32`.
    pub fn u32_lists(&mut self, lists: &[Vec<u32>]) {
        self.count(lists.len());
        for list in lists {
            self.u32s(list);
        }
    }

    /// The bytes written so far (after the magic too).
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The encoding.
    pub fn finish(self) -> Vec<u8> {
        self.bytes
    }
}

/// Reads the encoding, checking every length against the input.
#[derive(Clone, Debug)]
pub struct Decoder<'a> {
    bytes: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Decoder<'a> {
    /// Starts decoding `bytes` as `what`, which must begin with `magic`.
    pub fn new(bytes: &'a [u8], what: &'static str, magic: &[u8; 8]) -> Result<Decoder<'a>, DecodeError> {
        let mut decoder = Decoder { bytes, at: 0, what };
        let found = decoder.take("magic", 8)?;
        if found != magic {
            return Err(DecodeError {
                what,
                field: "magic",
                offset: 0,
                problem: Problem::BadMagic {
                    expected: String::from_utf8_lossy(magic).into_owned(),
                    found: String::from_utf8_lossy(found).into_owned(),
                },
            });
        }
        Ok(decoder)
    }

    /// Byte offset of the next value.
    pub fn offset(&self) -> usize {
        self.at
    }

    /// Bytes not read yet.
    pub fn remaining(&self) -> usize {
        self.bytes.len() - self.at
    }

    /// An error about `field` at the current offset.
    pub fn error(&self, field: &'static str, problem: Problem) -> DecodeError {
        DecodeError { what: self.what, field, offset: self.at, problem }
    }

    /// An error about a value of `field` that decoded but cannot be right.
    pub fn invalid(&self, field: &'static str, reason: impl Into<String>) -> DecodeError {
        self.error(field, Problem::Invalid(reason.into()))
    }

    fn take(&mut self, field: &'static str, n: usize) -> Result<&'a [u8], DecodeError> {
        if n > self.remaining() {
            return Err(self.error(field, Problem::Truncated { needed: n - self.remaining() }));
        }
        let slice = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(slice)
    }

    fn array<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], DecodeError> {
        let mut out = [0; N];
        out.copy_from_slice(self.take(field, N)?);
        Ok(out)
    }

    /// A `u32`.
    pub fn u32(&mut self, field: &'static str) -> Result<u32, DecodeError> {
        self.array(field).map(u32::from_le_bytes)
    }

    /// A `u64`.
    pub fn u64(&mut self, field: &'static str) -> Result<u64, DecodeError> {
        self.array(field).map(u64::from_le_bytes)
    }

    /// An `f64`.
    pub fn f64(&mut self, field: &'static str) -> Result<f64, DecodeError> {
        self.array(field).map(f64::from_le_bytes)
    }

    /// A count of elements that each take at least `min_element_bytes` (at
    /// least 1 is assumed), checked against what is left of the input.
    pub fn count(&mut self, field: &'static str, min_element_bytes: usize) -> Result<usize, DecodeError> {
        let start = self.at;
        let count = self.u32(field)?;
        let needed = u64::from(count) * min_element_bytes.max(1) as u64;
        if needed > self.remaining() as u64 {
            return Err(DecodeError {
                what: self.what,
                field,
                offset: start,
                problem: Problem::CountTooLarge { count: u64::from(count), needed, remaining: self.remaining() },
            });
        }
        Ok(count as usize)
    }

    /// A byte string, borrowed from the input.
    pub fn bytes(&mut self, field: &'static str) -> Result<&'a [u8], DecodeError> {
        let len = self.count(field, 1)?;
        self.take(field, len)
    }

    /// A string.
    pub fn str(&mut self, field: &'static str) -> Result<String, DecodeError> {
        let start = self.at;
        let bytes = self.bytes(field)?;
        String::from_utf8(bytes.to_vec()).map_err(|_| DecodeError {
            what: self.what,
            field,
            offset: start,
            problem: Problem::NotUtf8,
        })
    }

    /// A list of strings.
    pub fn strs(&mut self, field: &'static str) -> Result<Vec<String>, DecodeError> {
        let count = self.count(field, 4)?;
        (0..count).map(|_| self.str(field)).collect()
    }

    /// An array of `u32`.
    pub fn u32s(&mut self, field: &'static str) -> Result<Vec<u32>, DecodeError> {
        let count = self.count(field, 4)?;
        let bytes = self.take(field, count * 4)?;
        Ok(bytes.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
    }

    /// An array of `f32`.
    pub fn f32s(&mut self, field: &'static str) -> Result<Vec<f32>, DecodeError> {
        let count = self.count(field, 4)?;
        let bytes = self.take(field, count * 4)?;
        Ok(bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect())
    }

    /// An array of arrays of `u32`.
    pub fn u32_lists(&mut self, field: &'static str) -> Result<Vec<Vec<u32>>, DecodeError> {
        let count = self.count(field, 4)?;
        (0..count).map(|_| self.u32s(field)).collect()
    }

    /// Ends decoding: every byte must have been read.
    pub fn finish(self) -> Result<(), DecodeError> {
        match self.remaining() {
            0 => Ok(()),
            left => Err(self.error("end", Problem::Trailing(left))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_of_value_round_trips() {
        let mut out = Encoder::new(b"TESTWIRE");
        out.u32(7);
        out.u64(u64::MAX - 1);
        out.f64(-2.5);
        out.bytes(b"\x00\xff");
        out.str("sensor");
        out.strs(&["a", "bc"]);
        out.u32s(&[1, 2, 3]);
        out.f32s([0.5f32, -1.0].into_iter());
        out.u32_lists(&[vec![], vec![9, 8]]);
        let bytes = out.finish();
        let mut input = Decoder::new(&bytes, "test", b"TESTWIRE").unwrap();
        assert_eq!(input.u32("a").unwrap(), 7);
        assert_eq!(input.u64("b").unwrap(), u64::MAX - 1);
        assert_eq!(input.f64("c").unwrap(), -2.5);
        assert_eq!(input.bytes("d").unwrap(), b"\x00\xff");
        assert_eq!(input.str("e").unwrap(), "sensor");
        assert_eq!(input.strs("f").unwrap(), ["a", "bc"]);
        assert_eq!(input.u32s("g").unwrap(), [1, 2, 3]);
        assert_eq!(input.f32s("h").unwrap(), [0.5, -1.0]);
        assert_eq!(input.u32_lists("i").unwrap(), [vec![], vec![9, 8]]);
        input.finish().unwrap();
    }

    #[test]
    fn errors_say_what_where_and_why() {
        let err = Decoder::new(b"SKTOPO01", "geometry file", b"SKGEOM02").unwrap_err();
        assert!(matches!(err.problem, Problem::BadMagic { .. }), "{err}");
        assert!(err.to_string().starts_with("geometry file: magic at byte 0:"), "{err}");

        let mut bytes = Encoder::new(b"TESTWIRE").finish();
        bytes.extend_from_slice(&u32::MAX.to_le_bytes());
        let mut input = Decoder::new(&bytes, "test", b"TESTWIRE").unwrap();
        let err = input.u32s("sensors").unwrap_err();
        assert_eq!((err.field, err.offset), ("sensors", 8));
        assert!(matches!(err.problem, Problem::CountTooLarge { count: 0xffff_ffff, remaining: 0, .. }), "{err}");

        let mut input = Decoder::new(b"TESTWIRE\x01\x00", "test", b"TESTWIRE").unwrap();
        let err = input.u32("rate").unwrap_err();
        assert_eq!(err.problem, Problem::Truncated { needed: 2 });

        let mut out = Encoder::new(b"TESTWIRE");
        out.bytes(&[0xff, 0xfe]);
        out.u32(1);
        let bytes = out.finish();
        let mut input = Decoder::new(&bytes, "test", b"TESTWIRE").unwrap();
        assert_eq!(input.str("name").unwrap_err().problem, Problem::NotUtf8);
        assert_eq!(input.finish().unwrap_err().problem, Problem::Trailing(4));
    }
}
