//! REP-2016 type descriptions and their `RIHS01_` hashes, and the DDS names
//! of types: what a ROS 2 subscriber (on any RMW) checks before it accepts a
//! publisher's messages.
//!
//! Checked against the published hashes of `std_msgs/String` and
//! `sensor_msgs/Image`, and (in the tests of `skin bridge`) against those
//! Python's `rosbags` computes.

use sha2::{Digest, Sha256};

use crate::messages::{IMAGE, TACTILE_CONTACTS, TACTILE_STATE};
use crate::standard::{DIAGNOSTIC_ARRAY, MARKER_ARRAY, POINT_CLOUD2, TF_MESSAGE};

/// A field's type in a ROS 2 type description (`type_description_interfaces/FieldType`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldType {
    /// `int32`.
    Int32,
    /// `uint8`.
    Uint8,
    /// `uint32`.
    Uint32,
    /// `float32`.
    Float32,
    /// `float64`.
    Float64,
    /// `bool`.
    Bool,
    /// `byte` (an octet).
    Byte,
    /// `string` (unbounded).
    String,
    /// Another message type, by its full name (`std_msgs/msg/Header`).
    Nested(&'static str),
    /// An unbounded sequence of the inner type (`uint8[]`).
    Sequence(&'static FieldType),
}

impl FieldType {
    /// The `type_id` of REP-2016: the element's id, plus 144 for an unbounded sequence.
    fn type_id(self) -> u32 {
        match self {
            FieldType::Nested(_) => 1,
            FieldType::Uint8 => 3,
            FieldType::Int32 => 6,
            FieldType::Uint32 => 7,
            FieldType::Float32 => 10,
            FieldType::Float64 => 11,
            FieldType::Bool => 15,
            FieldType::Byte => 16,
            FieldType::String => 17,
            FieldType::Sequence(inner) => 144 + inner.type_id(),
        }
    }

    /// The type as a `.msg` file writes it (`uint8[]`, `std_msgs/Header`).
    pub fn msg_text(self) -> String {
        match self {
            FieldType::Int32 => "int32".into(),
            FieldType::Uint8 => "uint8".into(),
            FieldType::Uint32 => "uint32".into(),
            FieldType::Float32 => "float32".into(),
            FieldType::Float64 => "float64".into(),
            FieldType::Bool => "bool".into(),
            FieldType::Byte => "byte".into(),
            FieldType::String => "string".into(),
            FieldType::Nested(name) => name.replace("/msg/", "/"),
            FieldType::Sequence(inner) => format!("{}[]", inner.msg_text()),
        }
    }

    /// The message type this field is or holds, if any.
    pub fn nested(self) -> Option<&'static str> {
        Some(self.nested_name()).filter(|name| !name.is_empty())
    }

    fn nested_name(self) -> &'static str {
        match self {
            FieldType::Nested(name) => name,
            FieldType::Sequence(inner) => inner.nested_name(),
            _ => "",
        }
    }
}

/// One message type: its full name and its fields, in order.
#[derive(Clone, Copy, Debug)]
pub struct MessageType {
    /// `package/msg/Name`.
    pub name: &'static str,
    /// `(field name, type)`, in declaration order.
    pub fields: &'static [(&'static str, FieldType)],
}

const TIME_TYPE: MessageType = MessageType {
    name: "builtin_interfaces/msg/Time",
    fields: &[("sec", FieldType::Int32), ("nanosec", FieldType::Uint32)],
};
const HEADER_TYPE: MessageType = MessageType {
    name: "std_msgs/msg/Header",
    fields: &[("stamp", FieldType::Nested(TIME_TYPE.name)), ("frame_id", FieldType::String)],
};
const STRING_TYPE: MessageType = MessageType { name: "std_msgs/msg/String", fields: &[("data", FieldType::String)] };
const IMAGE_TYPE: MessageType = MessageType {
    name: IMAGE,
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("height", FieldType::Uint32),
        ("width", FieldType::Uint32),
        ("encoding", FieldType::String),
        ("is_bigendian", FieldType::Uint8),
        ("step", FieldType::Uint32),
        ("data", FieldType::Sequence(&FieldType::Uint8)),
    ],
};
const CHANNEL_FLOAT32_TYPE: MessageType = MessageType {
    name: "sensor_msgs/msg/ChannelFloat32",
    fields: &[("name", FieldType::String), ("values", FieldType::Sequence(&FieldType::Float32))],
};
const TACTILE_STATE_TYPE: MessageType = MessageType {
    name: TACTILE_STATE,
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("sensors", FieldType::Sequence(&FieldType::Nested(CHANNEL_FLOAT32_TYPE.name))),
    ],
};
const POINT_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/Point",
    fields: &[("x", FieldType::Float64), ("y", FieldType::Float64), ("z", FieldType::Float64)],
};
const VECTOR3_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/Vector3",
    fields: &[("x", FieldType::Float64), ("y", FieldType::Float64), ("z", FieldType::Float64)],
};
const WRENCH_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/Wrench",
    fields: &[("force", FieldType::Nested(VECTOR3_TYPE.name)), ("torque", FieldType::Nested(VECTOR3_TYPE.name))],
};
const TACTILE_CONTACT_TYPE: MessageType = MessageType {
    name: "tactile_msgs/msg/TactileContact",
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("name", FieldType::String),
        ("position", FieldType::Nested(POINT_TYPE.name)),
        ("normal", FieldType::Nested(VECTOR3_TYPE.name)),
        ("wrench", FieldType::Nested(WRENCH_TYPE.name)),
    ],
};
const TACTILE_CONTACTS_TYPE: MessageType = MessageType {
    name: TACTILE_CONTACTS,
    fields: &[("contacts", FieldType::Sequence(&FieldType::Nested(TACTILE_CONTACT_TYPE.name)))],
};

const POINT_FIELD_TYPE: MessageType = MessageType {
    name: "sensor_msgs/msg/PointField",
    fields: &[
        ("name", FieldType::String),
        ("offset", FieldType::Uint32),
        ("datatype", FieldType::Uint8),
        ("count", FieldType::Uint32),
    ],
};
const POINT_CLOUD2_TYPE: MessageType = MessageType {
    name: POINT_CLOUD2,
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("height", FieldType::Uint32),
        ("width", FieldType::Uint32),
        ("fields", FieldType::Sequence(&FieldType::Nested(POINT_FIELD_TYPE.name))),
        ("is_bigendian", FieldType::Bool),
        ("point_step", FieldType::Uint32),
        ("row_step", FieldType::Uint32),
        ("data", FieldType::Sequence(&FieldType::Uint8)),
        ("is_dense", FieldType::Bool),
    ],
};
const COLOR_RGBA_TYPE: MessageType = MessageType {
    name: "std_msgs/msg/ColorRGBA",
    fields: &[
        ("r", FieldType::Float32),
        ("g", FieldType::Float32),
        ("b", FieldType::Float32),
        ("a", FieldType::Float32),
    ],
};
const QUATERNION_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/Quaternion",
    fields: &[
        ("x", FieldType::Float64),
        ("y", FieldType::Float64),
        ("z", FieldType::Float64),
        ("w", FieldType::Float64),
    ],
};
const POSE_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/Pose",
    fields: &[
        ("position", FieldType::Nested(POINT_TYPE.name)),
        ("orientation", FieldType::Nested(QUATERNION_TYPE.name)),
    ],
};
const DURATION_TYPE: MessageType = MessageType {
    name: "builtin_interfaces/msg/Duration",
    fields: &[("sec", FieldType::Int32), ("nanosec", FieldType::Uint32)],
};
const COMPRESSED_IMAGE_TYPE: MessageType = MessageType {
    name: "sensor_msgs/msg/CompressedImage",
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("format", FieldType::String),
        ("data", FieldType::Sequence(&FieldType::Uint8)),
    ],
};
const UV_COORDINATE_TYPE: MessageType = MessageType {
    name: "visualization_msgs/msg/UVCoordinate",
    fields: &[("u", FieldType::Float32), ("v", FieldType::Float32)],
};
const MESH_FILE_TYPE: MessageType = MessageType {
    name: "visualization_msgs/msg/MeshFile",
    fields: &[("filename", FieldType::String), ("data", FieldType::Sequence(&FieldType::Uint8))],
};
const MARKER_TYPE: MessageType = MessageType {
    name: "visualization_msgs/msg/Marker",
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("ns", FieldType::String),
        ("id", FieldType::Int32),
        ("type", FieldType::Int32),
        ("action", FieldType::Int32),
        ("pose", FieldType::Nested(POSE_TYPE.name)),
        ("scale", FieldType::Nested(VECTOR3_TYPE.name)),
        ("color", FieldType::Nested(COLOR_RGBA_TYPE.name)),
        ("lifetime", FieldType::Nested(DURATION_TYPE.name)),
        ("frame_locked", FieldType::Bool),
        ("points", FieldType::Sequence(&FieldType::Nested(POINT_TYPE.name))),
        ("colors", FieldType::Sequence(&FieldType::Nested(COLOR_RGBA_TYPE.name))),
        ("texture_resource", FieldType::String),
        ("texture", FieldType::Nested(COMPRESSED_IMAGE_TYPE.name)),
        ("uv_coordinates", FieldType::Sequence(&FieldType::Nested(UV_COORDINATE_TYPE.name))),
        ("text", FieldType::String),
        ("mesh_resource", FieldType::String),
        ("mesh_file", FieldType::Nested(MESH_FILE_TYPE.name)),
        ("mesh_use_embedded_materials", FieldType::Bool),
    ],
};
const MARKER_ARRAY_TYPE: MessageType = MessageType {
    name: MARKER_ARRAY,
    fields: &[("markers", FieldType::Sequence(&FieldType::Nested(MARKER_TYPE.name)))],
};
const KEY_VALUE_TYPE: MessageType = MessageType {
    name: "diagnostic_msgs/msg/KeyValue",
    fields: &[("key", FieldType::String), ("value", FieldType::String)],
};
const DIAGNOSTIC_STATUS_TYPE: MessageType = MessageType {
    name: "diagnostic_msgs/msg/DiagnosticStatus",
    fields: &[
        ("level", FieldType::Byte),
        ("name", FieldType::String),
        ("message", FieldType::String),
        ("hardware_id", FieldType::String),
        ("values", FieldType::Sequence(&FieldType::Nested(KEY_VALUE_TYPE.name))),
    ],
};
const DIAGNOSTIC_ARRAY_TYPE: MessageType = MessageType {
    name: DIAGNOSTIC_ARRAY,
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("status", FieldType::Sequence(&FieldType::Nested(DIAGNOSTIC_STATUS_TYPE.name))),
    ],
};
const TRANSFORM_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/Transform",
    fields: &[
        ("translation", FieldType::Nested(VECTOR3_TYPE.name)),
        ("rotation", FieldType::Nested(QUATERNION_TYPE.name)),
    ],
};
const TRANSFORM_STAMPED_TYPE: MessageType = MessageType {
    name: "geometry_msgs/msg/TransformStamped",
    fields: &[
        ("header", FieldType::Nested(HEADER_TYPE.name)),
        ("child_frame_id", FieldType::String),
        ("transform", FieldType::Nested(TRANSFORM_TYPE.name)),
    ],
};
const TF_MESSAGE_TYPE: MessageType = MessageType {
    name: TF_MESSAGE,
    fields: &[("transforms", FieldType::Sequence(&FieldType::Nested(TRANSFORM_STAMPED_TYPE.name)))],
};

/// Every message type published to ROS nodes, and every type they use.
pub const MESSAGE_TYPES: &[MessageType] = &[
    TIME_TYPE,
    HEADER_TYPE,
    STRING_TYPE,
    IMAGE_TYPE,
    CHANNEL_FLOAT32_TYPE,
    TACTILE_STATE_TYPE,
    POINT_TYPE,
    VECTOR3_TYPE,
    WRENCH_TYPE,
    TACTILE_CONTACT_TYPE,
    TACTILE_CONTACTS_TYPE,
    POINT_FIELD_TYPE,
    POINT_CLOUD2_TYPE,
    COLOR_RGBA_TYPE,
    QUATERNION_TYPE,
    POSE_TYPE,
    DURATION_TYPE,
    COMPRESSED_IMAGE_TYPE,
    UV_COORDINATE_TYPE,
    MESH_FILE_TYPE,
    MARKER_TYPE,
    MARKER_ARRAY_TYPE,
    KEY_VALUE_TYPE,
    DIAGNOSTIC_STATUS_TYPE,
    DIAGNOSTIC_ARRAY_TYPE,
    TRANSFORM_TYPE,
    TRANSFORM_STAMPED_TYPE,
    TF_MESSAGE_TYPE,
];

/// The description of `name`, if it is one of [`MESSAGE_TYPES`].
pub fn message_type(name: &str) -> Option<&'static MessageType> {
    MESSAGE_TYPES.iter().find(|t| t.name == name)
}

/// The type description of `name` as REP-2016 hashes it: JSON with Python's
/// separators, keys in the IDL's order, no default values, and every type
/// it refers to (transitively) sorted by name.
pub fn hashed_type_description(name: &str) -> Option<String> {
    let root = message_type(name)?;
    let mut referenced = std::collections::BTreeSet::new();
    let mut queue: Vec<&str> = root.fields.iter().map(|(_, t)| t.nested_name()).filter(|n| !n.is_empty()).collect();
    while let Some(next) = queue.pop() {
        if referenced.insert(next) {
            let known = message_type(next)?;
            queue.extend(known.fields.iter().map(|(_, t)| t.nested_name()).filter(|n| !n.is_empty()));
        }
    }
    let describe = |t: &MessageType| {
        let fields: Vec<String> = t
            .fields
            .iter()
            .map(|(field, ty)| {
                format!(
                    "{{\"name\": \"{field}\", \"type\": {{\"type_id\": {}, \"capacity\": 0, \"string_capacity\": 0, \
                     \"nested_type_name\": \"{}\"}}}}",
                    ty.type_id(),
                    ty.nested_name()
                )
            })
            .collect();
        format!("{{\"type_name\": \"{}\", \"fields\": [{}]}}", t.name, fields.join(", "))
    };
    let references: Option<Vec<String>> = referenced.iter().map(|n| message_type(n).map(&describe)).collect();
    Some(format!(
        "{{\"type_description\": {}, \"referenced_type_descriptions\": [{}]}}",
        describe(root),
        references?.join(", ")
    ))
}

/// The REP-2016 type hash of `name` (`RIHS01_` and 64 hex digits), or `None`
/// for a type not in [`MESSAGE_TYPES`].
pub fn type_hash(name: &str) -> Option<String> {
    let description = hashed_type_description(name)?;
    let digest = Sha256::digest(description.as_bytes());
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    Some(format!("RIHS01_{hex}"))
}

/// The DDS name of a type, as the ROS 2 type support registers it (and
/// rmw_zenoh puts it in keys): `tactile_msgs/msg/TactileState` is
/// `tactile_msgs::msg::dds_::TactileState_`.
pub fn dds_type_name(name: &str) -> String {
    match name.rsplit_once('/') {
        Some((package, short)) => format!("{}::dds_::{short}_", package.replace('/', "::")),
        None => format!("{name}_"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hashes_match_the_published_vectors() {
        // From REP-2016 implementations and `ros2 topic info -v` (see
        // docs/remote.md, "ROS 2"); the tests of `skin bridge` also compare
        // every hash with the one `rosbags` computes.
        for (name, hash) in [
            ("std_msgs/msg/String", "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"),
            ("std_msgs/msg/Header", "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"),
            ("builtin_interfaces/msg/Time", "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"),
            ("sensor_msgs/msg/Image", "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"),
            // From the `share/<package>/msg/<Type>.json` of ROS 2 Kilted's
            // packages (the pip wheels of ros-python-wheels).
            (POINT_CLOUD2, "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5"),
            (MARKER_ARRAY, "RIHS01_86cb8800b6fb05b5eff1abd7a56f62a5641d3ae9a1c29e78e67e704f1d067dcf"),
            (DIAGNOSTIC_ARRAY, "RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e"),
        ] {
            assert_eq!(type_hash(name).as_deref(), Some(hash), "{name}");
        }
        assert_eq!(type_hash("pkg/msg/Unknown"), None);
    }

    #[test]
    fn every_published_type_has_a_hash() {
        for name in [IMAGE, TACTILE_STATE, TACTILE_CONTACTS] {
            assert!(type_hash(name).is_some_and(|hash| hash.len() == 7 + 64), "{name}");
        }
    }

    #[test]
    fn dds_names_are_what_the_type_support_registers() {
        assert_eq!(dds_type_name(TACTILE_STATE), "tactile_msgs::msg::dds_::TactileState_");
        assert_eq!(dds_type_name("std_msgs/msg/String"), "std_msgs::msg::dds_::String_");
    }
}
