//! What an rmw_zenoh node expects of a publisher, so that `ros2 topic echo`
//! on another machine receives it: the key expression, the REP-2016 type hash
//! in it, the attachment every sample carries, the GID and the liveliness
//! tokens of the ROS graph.
//!
//! Nothing here needs zenoh: it is strings and bytes, checked against the
//! published hashes of `std_msgs/String` and `sensor_msgs/Image`, and (in the
//! tests of `skin bridge`) against Python's `eclipse-zenoh` and `rosbags`.

use sha2::{Digest, Sha256};

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
            FieldType::String => 17,
            FieldType::Sequence(inner) => 144 + inner.type_id(),
        }
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

const TIME: MessageType = MessageType {
    name: "builtin_interfaces/msg/Time",
    fields: &[("sec", FieldType::Int32), ("nanosec", FieldType::Uint32)],
};
const HEADER: MessageType = MessageType {
    name: "std_msgs/msg/Header",
    fields: &[("stamp", FieldType::Nested(TIME.name)), ("frame_id", FieldType::String)],
};
const STRING: MessageType = MessageType { name: "std_msgs/msg/String", fields: &[("data", FieldType::String)] };
const IMAGE: MessageType = MessageType {
    name: "sensor_msgs/msg/Image",
    fields: &[
        ("header", FieldType::Nested(HEADER.name)),
        ("height", FieldType::Uint32),
        ("width", FieldType::Uint32),
        ("encoding", FieldType::String),
        ("is_bigendian", FieldType::Uint8),
        ("step", FieldType::Uint32),
        ("data", FieldType::Sequence(&FieldType::Uint8)),
    ],
};
const CHANNEL_FLOAT32: MessageType = MessageType {
    name: "sensor_msgs/msg/ChannelFloat32",
    fields: &[("name", FieldType::String), ("values", FieldType::Sequence(&FieldType::Float32))],
};
const TACTILE_STATE: MessageType = MessageType {
    name: "tactile_msgs/msg/TactileState",
    fields: &[
        ("header", FieldType::Nested(HEADER.name)),
        ("sensors", FieldType::Sequence(&FieldType::Nested(CHANNEL_FLOAT32.name))),
    ],
};
const POINT: MessageType = MessageType {
    name: "geometry_msgs/msg/Point",
    fields: &[("x", FieldType::Float64), ("y", FieldType::Float64), ("z", FieldType::Float64)],
};
const VECTOR3: MessageType = MessageType {
    name: "geometry_msgs/msg/Vector3",
    fields: &[("x", FieldType::Float64), ("y", FieldType::Float64), ("z", FieldType::Float64)],
};
const WRENCH: MessageType = MessageType {
    name: "geometry_msgs/msg/Wrench",
    fields: &[("force", FieldType::Nested(VECTOR3.name)), ("torque", FieldType::Nested(VECTOR3.name))],
};
const TACTILE_CONTACT: MessageType = MessageType {
    name: "tactile_msgs/msg/TactileContact",
    fields: &[
        ("header", FieldType::Nested(HEADER.name)),
        ("name", FieldType::String),
        ("position", FieldType::Nested(POINT.name)),
        ("normal", FieldType::Nested(VECTOR3.name)),
        ("wrench", FieldType::Nested(WRENCH.name)),
    ],
};
const TACTILE_CONTACTS: MessageType = MessageType {
    name: "tactile_msgs/msg/TactileContacts",
    fields: &[("contacts", FieldType::Sequence(&FieldType::Nested(TACTILE_CONTACT.name)))],
};

/// Every message type the bridge knows, the published ones and what they use.
pub const MESSAGE_TYPES: &[MessageType] = &[
    TIME,
    HEADER,
    STRING,
    IMAGE,
    CHANNEL_FLOAT32,
    TACTILE_STATE,
    POINT,
    VECTOR3,
    WRENCH,
    TACTILE_CONTACT,
    TACTILE_CONTACTS,
];

/// The full name of the layers' message.
pub const TACTILE_STATE_TYPE: &str = TACTILE_STATE.name;
/// The full name of the map's message.
pub const IMAGE_TYPE: &str = IMAGE.name;
/// The full name of the contacts' message.
pub const TACTILE_CONTACTS_TYPE: &str = TACTILE_CONTACTS.name;

fn message_type(name: &str) -> Option<&'static MessageType> {
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
/// for a type the bridge does not know.
pub fn type_hash(name: &str) -> Option<String> {
    let description = hashed_type_description(name)?;
    let digest = Sha256::digest(description.as_bytes());
    let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
    Some(format!("RIHS01_{hex}"))
}

/// The DDS name of a type, as rmw_zenoh puts it in keys:
/// `tactile_msgs/msg/TactileState` is `tactile_msgs::msg::dds_::TactileState_`.
pub fn dds_type_name(name: &str) -> String {
    match name.rsplit_once('/') {
        Some((package, short)) => format!("{}::dds_::{short}_", package.replace('/', "::")),
        None => format!("{name}_"),
    }
}

/// The data key of a topic: `<domain>/<topic without its outer slashes>/<dds type>/<hash>`.
/// A subscriber declares exactly this key, so every part must match.
pub fn topic_key(domain: u32, topic: &str, type_name: &str, hash: &str) -> String {
    format!("{domain}/{}/{}/{hash}", topic.trim_matches('/'), dds_type_name(type_name))
}

/// A name in a liveliness token: every `/` becomes `%`, and an empty name is `%`.
pub fn mangle(name: &str) -> String {
    if name.is_empty() { "%".to_owned() } else { name.replace('/', "%") }
}

/// The QoS the bridge offers, as rmw_zenoh writes it in a token: reliable,
/// volatile, keep last 10 (the ROS default, which every subscriber accepts),
/// each field left empty where it is the default.
pub const DEFAULT_QOS: &str = "::,10:,:,:,,";

/// The kind of a graph entity in its liveliness token.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EntityKind {
    /// A node (`NN`).
    Node,
    /// A publisher (`MP`).
    Publisher,
}

/// The liveliness token that announces an entity to the ROS graph:
/// `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/<namespace>/<node>`,
/// then for a publisher `/<topic>/<dds type>/<hash>/<qos>`.
#[derive(Clone, Debug)]
pub struct Liveliness<'a> {
    /// ROS domain id.
    pub domain: u32,
    /// The zenoh session id, in zenoh's own text form.
    pub zid: &'a str,
    /// The node's id within the session.
    pub node_id: u32,
    /// The entity's id within the session (the node's own for a node).
    pub entity_id: u32,
    /// Node or publisher.
    pub kind: EntityKind,
    /// The node's namespace (`/` for none).
    pub namespace: &'a str,
    /// The node's name.
    pub node: &'a str,
    /// For a publisher: topic, type and hash.
    pub topic: Option<(&'a str, &'a str, &'a str)>,
}

impl Liveliness<'_> {
    /// The token's key expression.
    pub fn key(&self) -> String {
        let kind = match self.kind {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
        };
        let mut key = format!(
            "@ros2_lv/{}/{}/{}/{}/{kind}/{}/{}/{}",
            self.domain,
            self.zid,
            self.node_id,
            self.entity_id,
            mangle(""),
            mangle(self.namespace.trim_end_matches('/')),
            mangle(self.node)
        );
        if let Some((topic, type_name, hash)) = self.topic {
            key.push_str(&format!(
                "/{}/{}/{hash}/{DEFAULT_QOS}",
                mangle(&format!("/{}", topic.trim_matches('/'))),
                dds_type_name(type_name)
            ));
        }
        key
    }
}

/// An entity's GID: the XXH3-128 hash of its liveliness key, low half first,
/// each half little-endian.
pub fn gid(liveliness_key: &str) -> [u8; 16] {
    xxhash_rust::xxh3::xxh3_128(liveliness_key.as_bytes()).to_le_bytes()
}

/// The attachment rmw_zenoh requires on every sample (it drops a sample
/// without one): the publisher's sequence number, the source time and the
/// publisher's GID, in zenoh-ext's serialization.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Attachment {
    /// Counts the publisher's samples from 1.
    pub sequence_number: i64,
    /// When the sample was published, ns since the Unix epoch.
    pub source_timestamp: i64,
    /// The publisher's GID.
    pub source_gid: [u8; 16],
}

/// The attachment's length: two `i64`s, the GID's length (a one-byte
/// varint) and the GID.
pub const ATTACHMENT_BYTES: usize = 8 + 8 + 1 + 16;

impl Attachment {
    /// The attachment's bytes.
    pub fn encode(&self) -> [u8; ATTACHMENT_BYTES] {
        let mut out = [0u8; ATTACHMENT_BYTES];
        out[0..8].copy_from_slice(&self.sequence_number.to_le_bytes());
        out[8..16].copy_from_slice(&self.source_timestamp.to_le_bytes());
        out[16] = 16;
        out[17..].copy_from_slice(&self.source_gid);
        out
    }

    /// Reads an attachment; says what is wrong with one that is not.
    pub fn decode(bytes: &[u8]) -> Result<Attachment, String> {
        let Ok(bytes) = <&[u8; ATTACHMENT_BYTES]>::try_from(bytes) else {
            return Err(format!("an rmw_zenoh attachment is {ATTACHMENT_BYTES} bytes, not {}", bytes.len()));
        };
        if bytes[16] != 16 {
            return Err(format!("the GID's length is {}, not 16", bytes[16]));
        }
        let i64_at = |at: usize| i64::from_le_bytes(bytes[at..at + 8].try_into().unwrap_or([0; 8]));
        let mut source_gid = [0u8; 16];
        source_gid.copy_from_slice(&bytes[17..]);
        Ok(Attachment { sequence_number: i64_at(0), source_timestamp: i64_at(8), source_gid })
    }
}

pub use skinware_record::ros_name;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hashes_match_the_published_vectors() {
        // From REP-2016 implementations and `ros2 topic info -v` (see
        // drivers-and-bridges.md §2); the tests of `skin bridge` also compare
        // every hash with the one `rosbags` computes.
        for (name, hash) in [
            ("std_msgs/msg/String", "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"),
            ("std_msgs/msg/Header", "RIHS01_f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01"),
            ("builtin_interfaces/msg/Time", "RIHS01_b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197"),
            ("sensor_msgs/msg/Image", "RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47"),
        ] {
            assert_eq!(type_hash(name).as_deref(), Some(hash), "{name}");
        }
        assert_eq!(type_hash("pkg/msg/Unknown"), None);
    }

    #[test]
    fn keys_are_what_rmw_zenoh_subscribes_to() {
        let hash = type_hash("std_msgs/msg/String").unwrap();
        assert_eq!(
            topic_key(0, "/chatter", "std_msgs/msg/String", &hash),
            format!("0/chatter/std_msgs::msg::dds_::String_/{hash}")
        );
        assert_eq!(dds_type_name(TACTILE_STATE_TYPE), "tactile_msgs::msg::dds_::TactileState_");
        let token = Liveliness {
            domain: 7,
            zid: "abc",
            node_id: 0,
            entity_id: 3,
            kind: EntityKind::Publisher,
            namespace: "/",
            node: "skin_bridge",
            topic: Some(("/skin/default/state", "std_msgs/msg/String", "RIHS01_x")),
        };
        assert_eq!(
            token.key(),
            "@ros2_lv/7/abc/0/3/MP/%/%/skin_bridge/%skin%default%state/std_msgs::msg::dds_::String_/RIHS01_x/::,10:,:,:,,"
        );
        let node = Liveliness { kind: EntityKind::Node, entity_id: 0, topic: None, ..token };
        assert_eq!(node.key(), "@ros2_lv/7/abc/0/0/NN/%/%/skin_bridge");
    }

    #[test]
    fn the_attachment_has_rmw_zenohs_layout() {
        let gid = gid("some/key");
        let attachment = Attachment { sequence_number: 5, source_timestamp: -2, source_gid: gid };
        let bytes = attachment.encode();
        assert_eq!(&bytes[..8], &5i64.to_le_bytes());
        assert_eq!(&bytes[8..16], &(-2i64).to_le_bytes());
        assert_eq!(bytes[16], 16);
        assert_eq!(&bytes[17..], &gid);
        assert_eq!(Attachment::decode(&bytes), Ok(attachment));
        assert!(Attachment::decode(&bytes[..32]).unwrap_err().contains("33 bytes"));
        let mut bad = bytes;
        bad[16] = 15;
        assert!(Attachment::decode(&bad).is_err());
        // Different keys, different GIDs; the same key, the same GID.
        assert_ne!(super::gid("a"), super::gid("b"));
        assert_eq!(super::gid("a"), super::gid("a"));
    }

    #[test]
    fn names_become_valid_ros_names() {
        assert_eq!(ros_name("virtual-0"), "virtual_0");
        assert_eq!(ros_name("2arms"), "_2arms");
        assert_eq!(ros_name(""), "_");
    }
}
