//! The bridge in the ROS graph, as rmw_zenoh declares a node's entities:
//! its node, a publisher per topic (with its liveliness token, GID and
//! attachment), and what each channel's frames become for ROS nodes.

use std::sync::atomic::{AtomicI64, Ordering};

use skinware::{ChannelKind, LayerTopology};
use skinware_ros2::{TACTILE_CONTACTS, TACTILE_STATE};
use skinware_services::{RegionContacts, ServiceInfo};
use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::{Session, Wait};

use super::Shared;
use super::channel::Channel;
use crate::BridgeError;
use crate::rmw_zenoh::{self, Attachment, EntityKind, Liveliness};

/// Announces the bridge's node `node_name` to the ROS graph of `domain`.
pub(super) fn declare_node(session: &Session, domain: u32, node_name: &str) -> Result<LivelinessToken, BridgeError> {
    let zid = session.zid().to_string();
    let key = Liveliness {
        domain,
        zid: &zid,
        node_id: 0,
        entity_id: 0,
        kind: EntityKind::Node,
        namespace: "/",
        node: node_name,
        topic: None,
    }
    .key();
    session
        .liveliness()
        .declare_token(key)
        .wait()
        .map_err(|e| BridgeError::Zenoh(format!("cannot announce the ROS 2 node: {e}")))
}

/// A ROS publisher: its key, GID, sequence numbers and graph token.
pub(super) struct RosPublisher {
    publisher: Publisher<'static>,
    gid: [u8; 16],
    sequence: AtomicI64,
    _token: LivelinessToken,
}

impl RosPublisher {
    pub(super) fn declare(shared: &Shared, topic: &str, type_name: &str) -> Result<RosPublisher, BridgeError> {
        let hash = skinware_ros2::type_hash(type_name)
            .ok_or_else(|| BridgeError::Invalid(format!("no type description for {type_name}")))?;
        let key = rmw_zenoh::topic_key(shared.options.domain, topic, type_name, &hash);
        let zid = shared.session.zid().to_string();
        let token_key = Liveliness {
            domain: shared.options.domain,
            zid: &zid,
            node_id: 0,
            entity_id: shared.next_entity.fetch_add(1, Ordering::Relaxed),
            kind: EntityKind::Publisher,
            namespace: "/",
            node: &shared.node_name,
            topic: Some((topic, type_name, &hash)),
        }
        .key();
        let zenoh = |e: zenoh::Error| BridgeError::Zenoh(format!("cannot declare the ROS 2 topic {topic}: {e}"));
        // As rmw_zenoh publishes a keep-last topic: drop rather than block.
        let publisher = shared
            .session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::Data)
            .wait()
            .map_err(zenoh)?;
        let token = shared.session.liveliness().declare_token(token_key.clone()).wait().map_err(zenoh)?;
        Ok(RosPublisher { publisher, gid: rmw_zenoh::gid(&token_key), sequence: AtomicI64::new(0), _token: token })
    }

    /// Whether any subscriber listens (the message need not be built otherwise).
    pub(super) fn wanted(&self) -> bool {
        self.publisher.matching_status().wait().map(|m| m.matching()).unwrap_or(true)
    }

    pub(super) fn put(&self, payload: Vec<u8>, now_wall_ns: i64) -> Result<(), BridgeError> {
        let attachment = Attachment {
            sequence_number: self.sequence.fetch_add(1, Ordering::Relaxed) + 1,
            source_timestamp: now_wall_ns,
            source_gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(ZBytes::from(attachment.encode().to_vec()))
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot publish on {}: {e}", self.publisher.key_expr())))
    }
}

/// What a channel's frames become for ROS nodes: a layer's a
/// `TactileState`, the contact service's `TactileContacts`; other services
/// none.
pub(super) struct ChannelRos {
    /// `None` without ROS, or for a service ROS has no message for.
    publisher: Option<RosPublisher>,
    /// A layer's topology (a service's is `None`).
    layer: Option<LayerTopology>,
    /// The contact service's region names, one per record.
    regions: Vec<String>,
}

impl ChannelRos {
    /// Declares the channel's ROS topic, if it has one.
    pub(super) fn declare(shared: &Shared, channel: &Channel) -> Result<ChannelRos, BridgeError> {
        let skin = &shared.options.skin;
        let name = &channel.info.name;
        let publisher = if !shared.options.ros {
            None
        } else if channel.info.kind == ChannelKind::Layer {
            let topic = skinware_ros2::tactile_state_topic(skin, name);
            Some(RosPublisher::declare(shared, &topic, TACTILE_STATE)?)
        } else if channel.info.schema.0 == <RegionContacts as skinware_services::ServicePayload>::SCHEMA {
            let topic = skinware_ros2::contacts_topic(skin, name);
            Some(RosPublisher::declare(shared, &topic, TACTILE_CONTACTS)?)
        } else {
            None
        };
        let layer = match channel.info.kind {
            ChannelKind::Layer => Some(
                LayerTopology::decode(&channel.info.description, name)
                    .map_err(|source| BridgeError::NotATopology { channel: name.clone(), source: Box::new(source) })?,
            ),
            ChannelKind::Service => None,
        };
        let regions = ServiceInfo::parse(&channel.info.description).map(|info| info.labels).unwrap_or_default();
        Ok(ChannelRos { publisher, layer, regions })
    }

    /// Publishes `frame` for ROS nodes, if any listens.
    pub(super) fn send(&self, shared: &Shared, channel: &Channel, frame: &skinware::Frame<'_>) {
        let Some(publisher) = self.publisher.as_ref().filter(|p| p.wanted()) else { return };
        let stamp = skinware_ros2::ros_time(frame.acquired_ns(), shared.clock_offset_ns);
        let message = match &self.layer {
            Some(layer) => skinware_ros2::tactile_state(layer, frame.responses(), stamp),
            None => skinware_ros2::tactile_contacts(&self.regions, &frame.records::<RegionContacts>(), stamp),
        };
        match message.map_err(BridgeError::from).and_then(|bytes| publisher.put(bytes, shared.wall_now_ns())) {
            Ok(()) => {
                channel.counters.ros_sent.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => channel.counters.error(format!("ROS 2 message of {}: {e}", channel.info.name)),
        }
    }
}
