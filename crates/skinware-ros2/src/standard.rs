//! The standard ROS 2 messages that ROS tools draw without any package of
//! ours: `sensor_msgs/PointCloud2` (rviz2's and Foxglove's 3-D panels),
//! `visualization_msgs/MarkerArray` (contacts as arrows),
//! `diagnostic_msgs/DiagnosticArray` (`/diagnostics`, `rqt_robot_monitor`)
//! and `tf2_msgs/TFMessage` (the frames the clouds are drawn in).
//!
//! Fields are in the order of the Jazzy and Kilted `.msg` definitions, which
//! is their CDR layout. Humble's `Marker` lacks the texture and mesh-file
//! fields, so a Humble node cannot decode these `MarkerArray`s (the other
//! three are the same there).

use serde::{Deserialize, Serialize};

use crate::messages::{Header, Vector3};

/// Full name of a layer's point cloud message.
pub const POINT_CLOUD2: &str = "sensor_msgs/msg/PointCloud2";
/// Full name of the contacts' marker message.
pub const MARKER_ARRAY: &str = "visualization_msgs/msg/MarkerArray";
/// Full name of the health message published on `/diagnostics`.
pub const DIAGNOSTIC_ARRAY: &str = "diagnostic_msgs/msg/DiagnosticArray";
/// Full name of the transforms message of `/tf_static`.
pub const TF_MESSAGE: &str = "tf2_msgs/msg/TFMessage";

/// `sensor_msgs/PointField` datatype of a `float32`.
pub const POINT_FIELD_FLOAT32: u8 = 7;

/// `sensor_msgs/PointField`: one named field of every point.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointField {
    /// The field's name (`x`, `response`).
    pub name: String,
    /// Its byte offset in a point.
    pub offset: u32,
    /// Its type ([`POINT_FIELD_FLOAT32`], ...).
    pub datatype: u8,
    /// Elements per point.
    pub count: u32,
}

/// `sensor_msgs/PointCloud2`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointCloud2 {
    /// Acquisition time; `frame_id` is the frame the points are in.
    pub header: Header,
    /// 1: an unordered cloud.
    pub height: u32,
    /// Points.
    pub width: u32,
    /// The layout of a point.
    pub fields: Vec<PointField>,
    /// `false`: little-endian.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// The points.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
    /// `true`: no invalid (NaN) points.
    pub is_dense: bool,
}

/// `std_msgs/ColorRGBA`, each channel 0..1.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ColorRgba {
    /// Red.
    pub r: f32,
    /// Green.
    pub g: f32,
    /// Blue.
    pub b: f32,
    /// Opacity.
    pub a: f32,
}

/// `geometry_msgs/Quaternion`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Quaternion {
    /// No rotation.
    pub const IDENTITY: Quaternion = Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 };
}

/// `geometry_msgs/Pose`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// Position (`geometry_msgs/Point`).
    pub position: Vector3,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `builtin_interfaces/Duration`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Duration {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Duration {
    /// `d` as a ROS duration (saturating at `i32::MAX` seconds).
    pub fn from_std(d: std::time::Duration) -> Duration {
        Duration { sec: i32::try_from(d.as_secs()).unwrap_or(i32::MAX), nanosec: d.subsec_nanos() }
    }
}

/// `sensor_msgs/CompressedImage` (a marker's texture; empty here).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and frame.
    pub header: Header,
    /// `jpeg`, `png`, ...
    pub format: String,
    /// The image.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `visualization_msgs/UVCoordinate`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UvCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// `visualization_msgs/MeshFile` (a marker's mesh; empty here).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeshFile {
    /// The mesh's file name.
    pub filename: String,
    /// Its bytes.
    #[serde(with = "serde_bytes")]
    pub data: Vec<u8>,
}

/// `visualization_msgs/Marker` type of an arrow.
pub const MARKER_ARROW: i32 = 0;
/// `visualization_msgs/Marker` type of a sphere.
pub const MARKER_SPHERE: i32 = 2;
/// `visualization_msgs/Marker` action: add or modify.
pub const MARKER_ADD: i32 = 0;
/// `visualization_msgs/Marker` action: delete every marker (of the namespace).
pub const MARKER_DELETE_ALL: i32 = 3;

/// `visualization_msgs/Marker`, as Jazzy and Kilted define it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Marker {
    /// Stamp and the frame `pose` and `points` are in.
    pub header: Header,
    /// Namespace: with `id`, what a later marker replaces.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// Shape ([`MARKER_ARROW`], [`MARKER_SPHERE`], ...).
    #[serde(rename = "type")]
    pub kind: i32,
    /// [`MARKER_ADD`] or [`MARKER_DELETE_ALL`].
    pub action: i32,
    /// Where (unused by an arrow given by `points`).
    pub pose: Pose,
    /// Size; an arrow's shaft diameter, head diameter and head length.
    pub scale: Vector3,
    /// Colour.
    pub color: ColorRgba,
    /// How long the marker stays without an update (0: for ever).
    pub lifetime: Duration,
    /// Whether it moves with its frame.
    pub frame_locked: bool,
    /// An arrow's tail and head (`geometry_msgs/Point`).
    pub points: Vec<Vector3>,
    /// Per-point colours (none here).
    pub colors: Vec<ColorRgba>,
    /// Texture resource (none here).
    pub texture_resource: String,
    /// Texture (none here).
    pub texture: CompressedImage,
    /// Texture coordinates (none here).
    pub uv_coordinates: Vec<UvCoordinate>,
    /// A text marker's text.
    pub text: String,
    /// Mesh resource (none here).
    pub mesh_resource: String,
    /// Mesh (none here).
    pub mesh_file: MeshFile,
    /// Mesh materials (unused).
    pub mesh_use_embedded_materials: bool,
}

/// `visualization_msgs/MarkerArray`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MarkerArray {
    /// The markers, applied in order.
    pub markers: Vec<Marker>,
}

/// `diagnostic_msgs/KeyValue`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct KeyValue {
    /// What.
    pub key: String,
    /// Its value, as text.
    pub value: String,
}

/// `diagnostic_msgs/DiagnosticStatus` level: running as it should.
pub const DIAGNOSTIC_OK: u8 = 0;
/// `diagnostic_msgs/DiagnosticStatus` level: running, but not as it should.
pub const DIAGNOSTIC_WARN: u8 = 1;
/// `diagnostic_msgs/DiagnosticStatus` level: not running.
pub const DIAGNOSTIC_ERROR: u8 = 2;
/// `diagnostic_msgs/DiagnosticStatus` level: no news.
pub const DIAGNOSTIC_STALE: u8 = 3;

/// `diagnostic_msgs/DiagnosticStatus`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// [`DIAGNOSTIC_OK`], [`DIAGNOSTIC_WARN`], [`DIAGNOSTIC_ERROR`] or [`DIAGNOSTIC_STALE`].
    pub level: u8,
    /// `skin/<skin>/<channel>`: `rqt_robot_monitor` groups by its `/`s.
    pub name: String,
    /// One line on the state.
    pub message: String,
    /// Who writes the channel, as far as the publisher knows it.
    pub hardware_id: String,
    /// The figures.
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/DiagnosticArray`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// When the statuses were taken.
    pub header: Header,
    /// One per channel.
    pub status: Vec<DiagnosticStatus>,
}

/// `geometry_msgs/Transform`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Transform {
    /// Translation.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and the parent frame.
    pub header: Header,
    /// The frame it places.
    pub child_frame_id: String,
    /// The child's pose in the parent's frame.
    pub transform: Transform,
}

/// `tf2_msgs/TFMessage`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TfMessage {
    /// The transforms.
    pub transforms: Vec<TransformStamped>,
}

/// Full name of the raw-response array a `ros2` driver reads.
pub const UINT16_MULTI_ARRAY: &str = "std_msgs/msg/UInt16MultiArray";
/// Full name of the full-scale (0..1) array a `ros2` driver reads.
pub const FLOAT32_MULTI_ARRAY: &str = "std_msgs/msg/Float32MultiArray";

/// `std_msgs/MultiArrayDimension`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MultiArrayDimension {
    /// The dimension's name.
    pub label: String,
    /// Its length.
    pub size: u32,
    /// Elements spanned by one step of the dimension above.
    pub stride: u32,
}

/// `std_msgs/MultiArrayLayout`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct MultiArrayLayout {
    /// The dimensions, outermost first.
    pub dim: Vec<MultiArrayDimension>,
    /// Elements before the array's first.
    pub data_offset: u32,
}

/// `std_msgs/UInt16MultiArray`.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct UInt16MultiArray {
    /// The layout.
    pub layout: MultiArrayLayout,
    /// The elements.
    pub data: Vec<u16>,
}

/// `std_msgs/Float32MultiArray`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Float32MultiArray {
    /// The layout.
    pub layout: MultiArrayLayout,
    /// The elements.
    pub data: Vec<f32>,
}
