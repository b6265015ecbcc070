//! The ROS 2 vocabulary of skinware: what its data is called and how it is
//! encoded once it leaves for ROS 2, whatever carries it.
//!
//! The recorder (`skinware-record`) writes these messages into MCAP files;
//! the bridge (`skinware-bridge`) publishes them on rmw_zenoh; a DDS
//! transport publishes the same bytes under the same names. This crate
//! knows none of MCAP, zenoh or DDS, so that each of them can use it alone:
//!
//! * [`messages`]: the message types ([`Time`], [`Header`], [`Image`],
//!   [`TactileState`], [`TactileContacts`], [`SkinFrame`], ...) and their
//!   full names ([`SKIN_FRAME`], [`TACTILE_STATE`], ...);
//! * [`cdr`]: [`encode`] and [`decode`], with typed errors ([`EncodeError`],
//!   [`DecodeError`]);
//! * [`schema`]: the `.msg` texts a recording embeds ([`schema_text`]);
//! * [`type_hash`](mod@type_hash): REP-2016 type descriptions, their `RIHS01_` hashes
//!   ([`type_hash()`]) and DDS type names ([`dds_type_name`]);
//! * [`topics`]: where each message goes ([`frame_topic`], [`map_topic`],
//!   [`ros_name`], ...);
//! * [`tactile`]: a layer's frame as a `TactileState`, the contact
//!   service's as `TactileContacts` ([`tactile_state`], [`tactile_contacts`]);
//! * [`heatmap`]: the skin's 2-D map as a `sensor_msgs/Image` ([`HeatMap`]);
//! * [`standard`]: the standard messages ROS tools draw
//!   ([`PointCloud2`](standard::PointCloud2), [`MarkerArray`](standard::MarkerArray),
//!   [`DiagnosticArray`](standard::DiagnosticArray), [`TfMessage`](standard::TfMessage)),
//!   made by [`cloud`] (a layer's taxels in 3-D, per link), [`markers`] (contacts
//!   as arrows) and [`diagnostics`] (every channel's health);
//! * [`qos`]: each kind of topic's QoS ([`qos::QosClass`]), also as a
//!   recording's `offered_qos_profiles`;
//! * [`rate`]: per-topic rate limits ([`rate::Every`]);
//! * [`view`]: the skin as standard ROS 2 topics for any transport
//!   ([`view::View`], over a [`view::Transport`]);
//! * [`clock`]: frames' CLOCK_MONOTONIC stamps as ROS time
//!   ([`clock_offset_ns`], [`ros_time`]).
//!
//! ```
//! use skinware::TopologyBuilder;
//! use skinware_ros2::{TACTILE_STATE, TactileState, Time, decode, tactile_state, tactile_state_topic, type_hash};
//!
//! let mut builder = TopologyBuilder::new("palm-0", "pressure", 50.0);
//! builder.patch(1).module(1, [10, 11, 12]);
//! let layer = builder.build()?;
//!
//! // What a transport sends: the topic, the type's hash, the CDR bytes.
//! assert_eq!(tactile_state_topic("default", &layer.name), "/skin/default/palm_0/state");
//! assert!(type_hash(TACTILE_STATE).is_some_and(|hash| hash.starts_with("RIHS01_")));
//! let bytes = tactile_state(&layer, &[0, 65535, 100], Time { sec: 1, nanosec: 0 })?;
//!
//! let back: TactileState = decode(&bytes, TACTILE_STATE)?;
//! assert_eq!(back.sensors[0].name, "palm-0/patch1");
//! assert_eq!(back.sensors[0].values[1], 1.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! No cargo features.

#![forbid(unsafe_code)]

pub mod cdr;
pub mod clock;
pub mod cloud;
pub mod diagnostics;
pub mod heatmap;
pub mod input;
pub mod markers;
pub mod messages;
pub mod qos;
pub mod rate;
pub mod schema;
pub mod standard;
pub mod tactile;
pub mod topics;
pub mod type_hash;
pub mod view;

pub use cdr::{DecodeError, EncodeError, decode, encode};
pub use clock::{clock_offset_ns, monotonic_ns, now_unix_ns, ros_time, unix_ns};
pub use heatmap::{HeatMap, LayerLook};
pub use messages::{
    ChannelFloat32, GAP, Gap, Header, IMAGE, Image, LAYER_STATS, LayerStats, SKIN_FRAME, SkinFrame, SkinFrameRef,
    TACTILE_CONTACTS, TACTILE_STATE, TactileContact, TactileContacts, TactileState, Time, Vector3, Wrench,
};
pub use schema::schema_text;
pub use tactile::{
    RESPONSE_FULL_SCALE, tactile_contacts, tactile_contacts_message, tactile_state, tactile_state_message,
};
pub use topics::{
    DIAGNOSTICS_TOPIC, TF_STATIC_TOPIC, cloud_topic, contacts_topic, frame_topic, gaps_topic, map_topic, markers_topic,
    ros_name, stats_topic, tactile_state_topic,
};
pub use type_hash::{dds_type_name, hashed_type_description, type_hash};
