//! The ROS 2 messages skinware sends, as serde structs whose fields are in
//! the order of their `.msg` definitions: CDR has no field names, so that
//! order is the wire format.
//!
//! Standard messages (`builtin_interfaces`, `std_msgs`, `sensor_msgs`,
//! `geometry_msgs`) and the `tactile_msgs` of the ROS tactile stack are what
//! ROS nodes subscribe to; skinware's own `skinware_msgs` are what a
//! recording and a remote skinware reader carry (their `.msg` texts are in
//! [`schema`](crate::schema)).

use serde::{Deserialize, Serialize};

/// Full name of the frame message (a recording's frames, a remote reader's frames).
pub const SKIN_FRAME: &str = "skinware_msgs/msg/SkinFrame";
/// Full name of the message of frames a recorder missed.
pub const GAP: &str = "skinware_msgs/msg/Gap";
/// Full name of a recorded channel's statistics message.
pub const LAYER_STATS: &str = "skinware_msgs/msg/LayerStats";
/// Full name of the map image's message.
pub const IMAGE: &str = "sensor_msgs/msg/Image";
/// Full name of a layer's message for ROS nodes.
pub const TACTILE_STATE: &str = "tactile_msgs/msg/TactileState";
/// Full name of the contact service's message for ROS nodes.
pub const TACTILE_CONTACTS: &str = "tactile_msgs/msg/TactileContacts";

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

/// `std_msgs/Header`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// When the data was acquired (or the image drawn).
    pub stamp: Time,
    /// What the data is of: a layer, a region, the map.
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

/// A `skinware_msgs/SkinFrame` to encode, borrowing the frame's data.
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

/// A decoded `skinware_msgs/SkinFrame`.
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

/// A `skinware_msgs/Gap`.
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

/// A `skinware_msgs/LayerStats`.
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

/// `sensor_msgs/ChannelFloat32`: one named array of values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelFloat32 {
    /// The array's name.
    pub name: String,
    /// Its values.
    pub values: Vec<f32>,
}

/// `tactile_msgs/TactileState`: a header and named sensor arrays.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TactileState {
    /// Acquisition time; `frame_id` is the layer.
    pub header: Header,
    /// One array per patch, named `<layer>/patch<id>`.
    pub sensors: Vec<ChannelFloat32>,
}

/// `geometry_msgs/Point` and `geometry_msgs/Vector3`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/Wrench`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Wrench {
    /// Force.
    pub force: Vector3,
    /// Torque.
    pub torque: Vector3,
}

/// `tactile_msgs/TactileContact`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TactileContact {
    /// Acquisition time; `frame_id` is the region.
    pub header: Header,
    /// `<region>/<rank>`, rank 0 the largest.
    pub name: String,
    /// The contact's pressure-weighted centroid, metres.
    pub position: Vector3,
    /// Its mean outward normal.
    pub normal: Vector3,
    /// Into the skin along the normal, sized by the summed response above
    /// baseline (the skin is not calibrated in newtons); no torque.
    pub wrench: Wrench,
}

/// `tactile_msgs/TactileContacts`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TactileContacts {
    /// Every region's contacts.
    pub contacts: Vec<TactileContact>,
}
