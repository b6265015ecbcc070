//! skinware beyond one machine, on [zenoh](https://zenoh.io).
//!
//! Shared memory stops at the machine's edge. For what lies beyond, the
//! bridge (`skin bridge`) reads every layer and service as an ordinary reader
//! (so it cannot slow acquisition) and publishes them on zenoh twice:
//!
//! * for ROS 2 nodes on rmw_zenoh ([`rmw_zenoh`]): each layer as
//!   `tactile_msgs/TactileState`, the 2-D map as `sensor_msgs/Image`, the
//!   contact service as `tactile_msgs/TactileContacts` (messages, type
//!   hashes and topic names from `skinware-ros2`), with the key expressions,
//!   attachment and liveliness tokens rmw_zenoh expects;
//! * for remote skinware readers ([`protocol`]): the raw frames, each
//!   channel's description, state and the skin's geometry, enough to read a
//!   remote skin like a local one (`remote`, with feature `zenoh`).
//!
//! Without feature `zenoh` this crate is the wire formats alone, which build
//! in seconds; the engine takes minutes.

#![forbid(unsafe_code)]

#[cfg(feature = "zenoh")]
pub mod bridge;
#[cfg(feature = "zenoh")]
pub mod link;
pub mod protocol;
#[cfg(feature = "zenoh")]
pub mod remote;
pub mod rmw_zenoh;

/// What went wrong in the bridge or a remote reader.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// A message could not be encoded.
    #[error(transparent)]
    Encode(#[from] skinware_ros2::EncodeError),
    /// Bytes from the network that are not what they claim.
    #[error("malformed {what} from the network: {reason}")]
    Malformed {
        /// What was being decoded.
        what: String,
        /// Why it was refused.
        reason: String,
    },
    /// One of the bridge's or the mirror's threads could not be started.
    #[error("cannot start {thread}: {source}")]
    Thread {
        /// Which thread.
        thread: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// A layer's description that is not a layer topology.
    #[error("{channel}: its description is not a layer topology: {source}")]
    NotATopology {
        /// The layer.
        channel: String,
        /// Why (boxed, as [`BridgeError::Geometry`]'s).
        source: Box<skinware::TopologyError>,
    },
    /// The skin's geometry could not be read or published.
    #[error("{context}: {source}")]
    Geometry {
        /// What was being done.
        context: String,
        /// Why (boxed: it is large, and every result of the crate carries this enum).
        source: Box<skinware_geometry::GeometryError>,
    },
    /// A bad argument or name.
    #[error("{0}")]
    Invalid(String),
    /// The local exchange failed.
    #[error(transparent)]
    Skinware(#[from] skinware::Error),
    /// zenoh failed (opening a session, declaring, sending).
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// Nothing answered in time.
    #[error("{0}")]
    Timeout(String),
}
