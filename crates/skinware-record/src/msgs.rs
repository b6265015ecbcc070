//! The messages of a recording: their ROS 2 `.msg` definitions (embedded in
//! the file as `ros2msg` schemas, so that Foxglove and the ROS 2 tools need
//! no package of ours) and their CDR encoding, through `cdr-encoding`.

use serde::{Deserialize, Serialize};

use crate::RecordError;

/// Schema encoding of every schema in a recording.
pub const SCHEMA_ENCODING: &str = "ros2msg";
/// Message encoding of every channel in a recording.
pub const MESSAGE_ENCODING: &str = "cdr";

/// The separator between a `.msg` text and the definitions it depends on.
const SEPARATOR: &str = "================================================================================";

/// `builtin_interfaces/Time`, as a dependency section.
const TIME_DEPENDENCY: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";

/// Name of the frame message.
pub const SKIN_FRAME: &str = "skinware_msgs/msg/SkinFrame";
/// Name of the gap message.
pub const GAP: &str = "skinware_msgs/msg/Gap";
/// Name of the statistics message.
pub const LAYER_STATS: &str = "skinware_msgs/msg/LayerStats";
/// Name of the image message.
pub const IMAGE: &str = "sensor_msgs/msg/Image";

/// The schema text of `name` (one of the names above).
pub fn schema_text(name: &str) -> Option<String> {
    let own = match name {
        SKIN_FRAME => concat!(
            "# One frame of a skinware channel (a layer or a service), as the recorder read it.\n",
            "builtin_interfaces/Time stamp      # when it was acquired (wall clock)\n",
            "builtin_interfaces/Time published  # when its writer published it (wall clock)\n",
            "uint64 seq                         # the writer's sequence number\n",
            "uint64 status                      # bits: 1 fault, 2 partial, 4 input faulted\n",
            "uint64 skipped                     # frames the recorder missed just before this one\n",
            "uint16[] responses                 # a layer: one response per sensor, in topology order\n",
            "uint8[] payload                    # a service: its frame's bytes\n",
        ),
        GAP => concat!(
            "# Frames of a channel that the recorder did not get (it was too slow, or stopped).\n",
            "builtin_interfaces/Time stamp  # when the frame after the gap was acquired\n",
            "string channel                 # the skinware channel\n",
            "uint64 first_seq               # the first sequence number missing\n",
            "uint64 count                   # how many are missing\n",
        ),
        LAYER_STATS => concat!(
            "# A channel's statistics over the last interval of the recording.\n",
            "builtin_interfaces/Time stamp\n",
            "string channel\n",
            "string state            # the writer's: running, paused, faulted or gone\n",
            "uint64 frames           # frames recorded since the start\n",
            "uint64 lost             # frames missed since the start\n",
            "uint64 faulted          # frames with a fault status since the start\n",
            "float64 rate_hz         # frames recorded per second over the interval\n",
            "float64 latency_ms      # mean publish time minus acquisition time over the interval\n",
            "uint16 min_response     # over the newest frame of a layer (0 for a service)\n",
            "uint16 max_response\n",
            "float64 mean_response\n",
        ),
        IMAGE => {
            return Some(format!(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n\
                 uint8[] data\n{SEPARATOR}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\
                 {SEPARATOR}\n{TIME_DEPENDENCY}"
            ));
        }
        _ => return None,
    };
    Some(format!("{own}{SEPARATOR}\n{TIME_DEPENDENCY}"))
}

/// `builtin_interfaces/Time`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the Unix epoch.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// The time `ns` nanoseconds after the epoch (saturating in 2038, as ROS 2 does).
    pub fn from_ns(ns: u64) -> Time {
        let sec = (ns / 1_000_000_000).min(i32::MAX as u64) as i32;
        Time { sec, nanosec: (ns % 1_000_000_000) as u32 }
    }

    /// Nanoseconds since the epoch (0 for a time before it).
    pub fn to_ns(self) -> u64 {
        u64::try_from(self.sec).unwrap_or(0) * 1_000_000_000 + u64::from(self.nanosec)
    }
}

/// A `SkinFrame` to encode, borrowing the frame's data.
#[derive(Serialize)]
pub struct SkinFrameRef<'a> {
    /// Acquisition time.
    pub stamp: Time,
    /// Publication time.
    pub published: Time,
    /// Sequence number.
    pub seq: u64,
    /// Status bits.
    pub status: u64,
    /// Frames missed before this one.
    pub skipped: u64,
    /// A layer's responses.
    pub responses: &'a [u16],
    /// A service's bytes.
    #[serde(with = "serde_bytes")]
    pub payload: &'a [u8],
}

/// A decoded `SkinFrame`.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
pub struct SkinFrame {
    /// Acquisition time.
    pub stamp: Time,
    /// Publication time.
    pub published: Time,
    /// Sequence number.
    pub seq: u64,
    /// Status bits.
    pub status: u64,
    /// Frames missed before this one.
    pub skipped: u64,
    /// A layer's responses.
    pub responses: Vec<u16>,
    /// A service's bytes.
    #[serde(with = "serde_bytes")]
    pub payload: Vec<u8>,
}

impl SkinFrame {
    /// The frame's payload as the channel carried it: a layer's responses as
    /// little-endian bytes (the exchange's own layout on this machine), or a
    /// service's bytes.
    pub fn channel_bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::new();
        self.channel_bytes_into(&mut bytes);
        bytes
    }

    /// [`SkinFrame::channel_bytes`] into `out` (cleared first), reusing its allocation.
    pub fn channel_bytes_into(&self, out: &mut Vec<u8>) {
        out.clear();
        if self.payload.is_empty() {
            out.extend(self.responses.iter().flat_map(|r| r.to_ne_bytes()));
        } else {
            out.extend_from_slice(&self.payload);
        }
    }
}

/// A `Gap`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Gap {
    /// When the frame after the gap was acquired.
    pub stamp: Time,
    /// The channel.
    pub channel: String,
    /// The first missing sequence number.
    pub first_seq: u64,
    /// How many are missing.
    pub count: u64,
}

/// A `LayerStats`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LayerStats {
    /// When the interval ended.
    pub stamp: Time,
    /// The channel.
    pub channel: String,
    /// The writer's state.
    pub state: String,
    /// Frames recorded since the start.
    pub frames: u64,
    /// Frames missed since the start.
    pub lost: u64,
    /// Frames with a fault status since the start.
    pub faulted: u64,
    /// Frames per second over the interval.
    pub rate_hz: f64,
    /// Mean publication latency over the interval, ms.
    pub latency_ms: f64,
    /// Smallest response of the newest frame.
    pub min_response: u16,
    /// Largest response of the newest frame.
    pub max_response: u16,
    /// Mean response of the newest frame.
    pub mean_response: f64,
}

/// `std_msgs/Header`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// Time of the image.
    pub stamp: Time,
    /// Its frame id.
    pub frame_id: String,
}

/// A `sensor_msgs/Image`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Image {
    /// Stamp and frame.
    pub header: Header,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding (`rgb8`).
    pub encoding: String,
    /// 0: little-endian.
    pub is_bigendian: u8,
    /// Bytes per row.
    pub step: u32,
    /// The pixels.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// The CDR encapsulation header for little-endian plain CDR.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Encodes `value` as a CDR message: the encapsulation header, then the body.
pub fn encode<T: Serialize>(value: &T, size_hint: usize) -> Result<Vec<u8>, RecordError> {
    let body = cdr_encoding::to_vec_with_size_hint::<T, byteorder::LittleEndian>(value, size_hint)
        .map_err(|e| RecordError::Encode(e.to_string()))?;
    let mut message = Vec::with_capacity(4 + body.len());
    message.extend_from_slice(&CDR_LE);
    message.extend_from_slice(&body);
    Ok(message)
}

/// Decodes a CDR message of type `what` (named in errors).
pub fn decode<'de, T: Deserialize<'de>>(message: &'de [u8], what: &str) -> Result<T, RecordError> {
    let bad = |reason: String| RecordError::BadMessage { what: what.to_owned(), reason };
    let Some((header, body)) = message.split_first_chunk::<4>() else {
        return Err(bad(format!("{} bytes, shorter than the 4-byte CDR header", message.len())));
    };
    let value = match header {
        [0x00, 0x01, _, _] => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body),
        [0x00, 0x00, _, _] => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body),
        _ => return Err(bad(format!("CDR header {header:02x?} is not plain CDR"))),
    };
    value.map(|(value, _)| value).map_err(|e| bad(e.to_string()))
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

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
    fn every_schema_names_its_dependencies() {
        for name in [SKIN_FRAME, GAP, LAYER_STATS, IMAGE] {
            let text = schema_text(name).unwrap();
            assert!(text.contains("MSG: builtin_interfaces/Time"), "{name}");
        }
        assert!(schema_text(IMAGE).unwrap().contains("MSG: std_msgs/Header"));
        assert!(schema_text("pkg/msg/Other").is_none());
    }

    #[test]
    fn short_or_foreign_messages_are_errors_not_panics() {
        assert!(decode::<SkinFrame>(&[0, 1], "SkinFrame").is_err());
        assert!(decode::<SkinFrame>(&[0, 7, 0, 0, 1], "SkinFrame").is_err());
        // A length far beyond the message.
        let mut huge = vec![0, 1, 0, 0];
        huge.extend([0u8; 40]);
        huge.extend(u32::MAX.to_le_bytes());
        assert!(decode::<SkinFrame>(&huge, "SkinFrame").is_err());
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
