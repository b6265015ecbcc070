//! ROS 2 over DDS, the default middleware of ROS 2 robots (Fast DDS on
//! Humble, Jazzy and Kilted), with no ROS installation on skinware's side.
//!
//! * [`DdsBridge`]: every layer and service of a skin as the standard ROS 2
//!   topics (`skin bridge --ros2 dds`), the view of `skinware_ros2::view`
//!   over [`DdsTransport`]: a `sensor_msgs/PointCloud2` per layer
//!   and link, contacts as a `visualization_msgs/MarkerArray`, every
//!   channel's health on `/diagnostics`, the links on `/tf_static`, the 2-D
//!   map as a `sensor_msgs/Image`, and the ROS tactile stack's
//!   `TactileState` and `TactileContacts`; each with the QoS ROS users
//!   expect ([`qos`]) and its own rate limit;
//! * [`driver`]: the `ros2` driver kind's subscriber: a `PointCloud2` with a
//!   response field, or a `UInt16MultiArray`/`Float32MultiArray`, decoded
//!   into a layer's frame ([`driver::decode`], for any bytes).
//!
//! The messages, their names and their encodings are `skinware-ros2`'s,
//! shared with the recorder and the rmw_zenoh bridge. The DDS participant is
//! `ros2-client` (Atostek, on RustDDS): pure Rust, it builds with cargo
//! alone where a Fast DDS binding needs a C++ toolchain and a ROS
//! installation, and its nodes appear in `rclpy`'s graph with their topics
//! and types. Its limits, measured, are in `docs/ros2.md`: it sends large
//! messages as many small datagrams (so the large topics are phased apart,
//! and a subscriber of clouds faster than the defaults wants the larger
//! socket buffer of `docs/ros2/fastdds-large.xml`), it announces no
//! REP-2016 type hash (matching does not need it), and it reassembles a
//! fragmented message into a buffer of the announced size, up to 4 GiB.

#![forbid(unsafe_code)]

mod bridge;
pub mod driver;
pub mod qos;

pub use bridge::{DEFAULT_MAP_WIDTH, DdsBridge, DdsOptions, DdsTransport, Rates, TopicReport};

/// What went wrong in skinware's DDS side, with what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum DdsError {
    /// The DDS participant, node, topic, publisher or subscription could not be made.
    #[error("DDS: {0}")]
    Dds(String),
    /// Options or a configuration that name what cannot be.
    #[error("{0}")]
    Invalid(String),
    /// A skinware channel could not be read.
    #[error(transparent)]
    Skinware(#[from] skinware::Error),
    /// The skin's topics could not be set up.
    #[error(transparent)]
    View(#[from] skinware_ros2::view::ViewError),
    /// A `ros2` layer's message or field that cannot be read.
    #[error(transparent)]
    Input(#[from] skinware_ros2::input::UnknownInput),
    /// A thread could not be started.
    #[error("cannot start {thread}: {source}")]
    Thread {
        /// Which thread.
        thread: String,
        /// The OS's complaint.
        source: std::io::Error,
    },
}

/// `package/msg/Name` as ros2-client names a type (`package`, `Name`).
fn type_name(full: &str) -> ros2_client::MessageTypeName {
    let (package, name) = full.split_once("/msg/").unwrap_or(("", full));
    ros2_client::MessageTypeName::new(package, name)
}

/// The ROS domain of `ROS_DOMAIN_ID`, as ROS 2 nodes read it (0 if unset);
/// an error names a value that is not a domain.
pub fn domain_from_env() -> Result<u16, DdsError> {
    match std::env::var("ROS_DOMAIN_ID") {
        Err(_) => Ok(0),
        Ok(value) if value.trim().is_empty() => Ok(0),
        Ok(value) => check_domain(value.trim().parse().map_err(|_| {
            DdsError::Invalid(format!("ROS_DOMAIN_ID={value:?} is not a domain id; set it to 0..=232, or unset it"))
        })?),
    }
}

/// `domain` if DDS can use it (RTPS's port arithmetic allows 0..=232).
pub fn check_domain(domain: u32) -> Result<u16, DdsError> {
    u16::try_from(domain).ok().filter(|d| *d <= 232).ok_or_else(|| {
        DdsError::Invalid(format!("ROS domain {domain}: DDS domains are 0..=232 (ROS_DOMAIN_ID, --domain)"))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn types_are_named_as_ros2_client_names_them() {
        let name = type_name("sensor_msgs/msg/PointCloud2");
        assert_eq!(name.dds_msg_type(), "sensor_msgs::msg::dds_::PointCloud2_");
    }

    #[test]
    fn domains_beyond_rtps_ports_are_refused() {
        assert_eq!(check_domain(0).unwrap(), 0);
        assert_eq!(check_domain(232).unwrap(), 232);
        assert!(check_domain(233).unwrap_err().to_string().contains("0..=232"));
    }
}
