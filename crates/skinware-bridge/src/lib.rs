//! skinware beyond one machine, on [zenoh](https://zenoh.io).
//!
//! Shared memory stops at the machine's edge. For what lies beyond, the
//! bridge (`skin bridge`) reads every layer and service as an ordinary reader
//! (so it cannot slow acquisition) and publishes them on zenoh twice:
//!
//! * for ROS 2 nodes on rmw_zenoh ([`ros2`], [`messages`]): each layer as
//!   `tactile_msgs/TactileState`, the 2-D map as `sensor_msgs/Image`, the
//!   contact service as `tactile_msgs/TactileContacts`, with the key
//!   expressions, type hashes, attachment and liveliness tokens rmw_zenoh
//!   expects;
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
pub mod messages;
pub mod protocol;
#[cfg(feature = "zenoh")]
pub mod remote;
pub mod ros2;

/// What went wrong in the bridge or a remote reader.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// A message could not be encoded.
    #[error("cannot encode a message: {0}")]
    Encode(String),
    /// Bytes from the network that are not what they claim.
    #[error("malformed {what} from the network: {reason}")]
    Malformed {
        /// What was being decoded.
        what: String,
        /// Why it was refused.
        reason: String,
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
