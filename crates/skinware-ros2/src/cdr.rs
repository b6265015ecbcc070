//! CDR, the encoding of every ROS 2 message on the wire and in a recording:
//! a 4-byte encapsulation header, then the fields in declaration order,
//! each aligned to its size (through `cdr-encoding`).

use serde::{Deserialize, Serialize};

/// The CDR encapsulation header for little-endian plain CDR.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A value that CDR cannot express.
#[derive(Debug, thiserror::Error)]
#[error("cannot encode a message: {source}")]
pub struct EncodeError {
    /// The encoder's complaint.
    #[from]
    pub source: cdr_encoding::Error,
}

/// Bytes that are not a CDR message of the type asked for.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    /// Too short to hold even the encapsulation header.
    #[error("a {what} message does not decode: {length} bytes, shorter than the 4-byte CDR header")]
    Short {
        /// The message type asked for.
        what: &'static str,
        /// The message's length.
        length: usize,
    },
    /// An encapsulation other than plain CDR (such as XCDR2).
    #[error("a {what} message does not decode: CDR header {header:02x?} is not plain CDR")]
    NotPlainCdr {
        /// The message type asked for.
        what: &'static str,
        /// The header found.
        header: [u8; 4],
    },
    /// A body that does not hold the type's fields.
    #[error("a {what} message does not decode: {source}")]
    Body {
        /// The message type asked for.
        what: &'static str,
        /// The decoder's complaint.
        source: cdr_encoding::Error,
    },
}

/// Encodes `value` as a CDR message: the encapsulation header, then the
/// body, little-endian. `size_hint` is the body's expected size, so that a
/// large message is allocated once.
pub fn encode<T: Serialize>(value: &T, size_hint: usize) -> Result<Vec<u8>, EncodeError> {
    let body = cdr_encoding::to_vec_with_size_hint::<T, byteorder::LittleEndian>(value, size_hint)?;
    let mut message = Vec::with_capacity(4 + body.len());
    message.extend_from_slice(&CDR_LE);
    message.extend_from_slice(&body);
    Ok(message)
}

/// Decodes a CDR message of type `what` (named in errors), in either byte
/// order: any bytes give a value or an error, never a panic.
pub fn decode<'de, T: Deserialize<'de>>(message: &'de [u8], what: &'static str) -> Result<T, DecodeError> {
    let Some((header, body)) = message.split_first_chunk::<4>() else {
        return Err(DecodeError::Short { what, length: message.len() });
    };
    let value = match header {
        [0x00, 0x01, _, _] => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body),
        [0x00, 0x00, _, _] => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body),
        _ => return Err(DecodeError::NotPlainCdr { what, header: *header }),
    };
    value.map(|(value, _)| value).map_err(|source| DecodeError::Body { what, source })
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;
    use crate::messages::{Image, SkinFrame, SkinFrameRef, Time};

    #[test]
    fn a_skin_frame_has_the_cdr_layout_ros_expects() {
        let frame = SkinFrameRef {
            stamp: Time { sec: 1, nanosec: 2 },
            published: Time { sec: 3, nanosec: 4 },
            seq: 5,
            status: 6,
            skipped: 7,
            responses: &[0x0102, 0x0304, 0x0506],
            payload: &[],
        };
        let bytes = encode(&frame, 0).unwrap();
        let mut expected = vec![0, 1, 0, 0];
        expected.extend([1, 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 4, 0, 0, 0]);
        // seq at offset 16 of the body: already 8-aligned.
        expected.extend(5u64.to_le_bytes());
        expected.extend(6u64.to_le_bytes());
        expected.extend(7u64.to_le_bytes());
        expected.extend([3, 0, 0, 0, 2, 1, 4, 3, 6, 5]);
        // The payload's length is 4-aligned: two bytes of padding first.
        expected.extend([0, 0, 0, 0, 0, 0]);
        assert_eq!(bytes, expected);
        let back: SkinFrame = decode(&bytes, "SkinFrame").unwrap();
        assert_eq!(back.responses, [0x0102, 0x0304, 0x0506]);
        assert_eq!((back.seq, back.status, back.skipped), (5, 6, 7));
    }

    #[test]
    fn short_or_foreign_messages_are_errors_not_panics() {
        assert!(matches!(decode::<SkinFrame>(&[0, 1], "SkinFrame"), Err(DecodeError::Short { length: 2, .. })));
        assert!(matches!(
            decode::<SkinFrame>(&[0, 7, 0, 0, 1], "SkinFrame"),
            Err(DecodeError::NotPlainCdr { header: [0, 7, 0, 0], .. })
        ));
        // A length far beyond the message.
        let mut huge = vec![0, 1, 0, 0];
        huge.extend([0u8; 40]);
        huge.extend(u32::MAX.to_le_bytes());
        let error = decode::<SkinFrame>(&huge, "SkinFrame").unwrap_err();
        assert!(matches!(error, DecodeError::Body { what: "SkinFrame", .. }), "{error}");
        assert!(error.to_string().starts_with("a SkinFrame message does not decode: "), "{error}");
    }

    proptest! {
        #[test]
        fn frames_round_trip(seq: u64, status: u64, skipped: u64, sec in 0i32.., nanosec in 0u32..1_000_000_000,
                             responses in proptest::collection::vec(any::<u16>(), 0..300),
                             payload in proptest::collection::vec(any::<u8>(), 0..300)) {
            let stamp = Time { sec, nanosec };
            let frame = SkinFrameRef { stamp, published: stamp, seq, status, skipped, responses: &responses, payload: &payload };
            let back: SkinFrame = decode(&encode(&frame, 0).unwrap(), "SkinFrame").unwrap();
            prop_assert_eq!(back, SkinFrame { stamp, published: stamp, seq, status, skipped, responses, payload });
        }

        #[test]
        fn any_bytes_decode_to_a_frame_or_an_error(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = decode::<SkinFrame>(&bytes, "SkinFrame");
            let _ = decode::<Image>(&bytes, "Image");
        }
    }
}
