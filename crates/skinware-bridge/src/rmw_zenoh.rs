//! What an rmw_zenoh node expects of a publisher, so that `ros2 topic echo`
//! on another machine receives it: the key expression (with the REP-2016
//! type hash `skinware-ros2` computes), the attachment every sample carries,
//! the GID and the liveliness tokens of the ROS graph.
//!
//! Nothing here needs zenoh: it is strings and bytes, checked here and (in
//! the tests of `skin bridge`) against Python's `eclipse-zenoh` and `rosbags`.

use skinware_ros2::dds_type_name;

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

/// Bytes that are not an rmw_zenoh attachment.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum AttachmentError {
    /// Not the attachment's length.
    #[error("an rmw_zenoh attachment is {ATTACHMENT_BYTES} bytes, not {found}")]
    Length {
        /// The length found.
        found: usize,
    },
    /// A GID length other than 16.
    #[error("the GID's length is {found}, not 16")]
    GidLength {
        /// The length found.
        found: u8,
    },
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
    pub fn decode(bytes: &[u8]) -> Result<Attachment, AttachmentError> {
        let Ok(bytes) = <&[u8; ATTACHMENT_BYTES]>::try_from(bytes) else {
            return Err(AttachmentError::Length { found: bytes.len() });
        };
        if bytes[16] != 16 {
            return Err(AttachmentError::GidLength { found: bytes[16] });
        }
        let i64_at = |at: usize| i64::from_le_bytes(bytes[at..at + 8].try_into().unwrap_or([0; 8]));
        let mut source_gid = [0u8; 16];
        source_gid.copy_from_slice(&bytes[17..]);
        Ok(Attachment { sequence_number: i64_at(0), source_timestamp: i64_at(8), source_gid })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_are_what_rmw_zenoh_subscribes_to() {
        let hash = skinware_ros2::type_hash("std_msgs/msg/String").unwrap();
        assert_eq!(
            topic_key(0, "/chatter", "std_msgs/msg/String", &hash),
            format!("0/chatter/std_msgs::msg::dds_::String_/{hash}")
        );
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
        assert_eq!(Attachment::decode(&bytes[..32]), Err(AttachmentError::Length { found: 32 }));
        assert!(AttachmentError::Length { found: 32 }.to_string().contains("33 bytes, not 32"));
        let mut bad = bytes;
        bad[16] = 15;
        assert_eq!(Attachment::decode(&bad), Err(AttachmentError::GidLength { found: 15 }));
        // Different keys, different GIDs; the same key, the same GID.
        assert_ne!(super::gid("a"), super::gid("b"));
        assert_eq!(super::gid("a"), super::gid("a"));
    }
}
