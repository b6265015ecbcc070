//! The QoS of each topic, as ROS users expect it: sensor data best-effort
//! and keep-last (a late subscriber wants the newest frame, not a backlog),
//! status reliable, static data reliable and transient-local (a node that
//! starts later still gets `/tf_static`).
//!
//! A reliable writer never blocks the bridge: when its history is full the
//! write fails and is counted, as a best-effort topic's loss is.

use std::time::Duration;

use ros2_client::QosProfile;
use ros2_client::qos::{Durability, History, Reliability, WhenFull};

/// What kind of data a topic carries, which decides its QoS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TopicClass {
    /// Frames, clouds, contacts, the map: best-effort, volatile, keep last 5
    /// (ROS's `SensorDataQoS`).
    Sensor,
    /// `/diagnostics`: reliable, volatile, keep last 10 (ROS's default).
    Status,
    /// `/tf_static`: reliable, transient-local, keep last 1 (tf2's static
    /// broadcaster's durability; a subscriber's depth may be larger).
    Static,
}

impl TopicClass {
    /// Its QoS profile, for a publisher.
    pub fn profile(self) -> QosProfile {
        // Never wait for a slow reliable reader: fail and count it.
        let reliable = Reliability::Reliable { when_full: WhenFull::Fail };
        let base = QosProfile::subscription_default();
        match self {
            TopicClass::Sensor => {
                base.reliability(Reliability::BestEffort).history(History::KeepLast { depth: SENSOR_DEPTH })
            }
            TopicClass::Status => base.reliability(reliable).history(History::KeepLast { depth: 10 }),
            TopicClass::Static => base
                .reliability(reliable)
                .durability(Durability::TransientLocal)
                .history(History::KeepLast { depth: 1 }),
        }
    }

    /// How `skin bridge --stats` and the docs name it.
    pub fn as_str(self) -> &'static str {
        match self {
            TopicClass::Sensor => "best-effort, volatile, keep last 5",
            TopicClass::Status => "reliable, volatile, keep last 10",
            TopicClass::Static => "reliable, transient-local, keep last 1",
        }
    }
}

/// The history depth of a sensor topic (ROS's `SensorDataQoS`).
pub const SENSOR_DEPTH: usize = 5;

/// The QoS the `ros2` driver subscribes with: best-effort, keep last 5. A
/// best-effort subscriber matches reliable and best-effort publishers alike.
pub fn driver_subscription() -> QosProfile {
    QosProfile::subscription_default()
        .reliability(Reliability::BestEffort)
        .history(History::KeepLast { depth: SENSOR_DEPTH })
        .deadline(None)
        .lifespan(None::<Duration>)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_class_has_the_qos_ros_users_expect() {
        let sensor = TopicClass::Sensor.profile();
        assert_eq!(sensor.reliability, Reliability::BestEffort);
        assert_eq!(sensor.durability, Durability::Volatile);
        assert_eq!(sensor.history, History::KeepLast { depth: 5 });
        let status = TopicClass::Status.profile();
        assert!(matches!(status.reliability, Reliability::Reliable { when_full: WhenFull::Fail }));
        assert_eq!(status.durability, Durability::Volatile);
        let fixed = TopicClass::Static.profile();
        assert!(matches!(fixed.reliability, Reliability::Reliable { .. }));
        assert_eq!(fixed.durability, Durability::TransientLocal);
    }
}
