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

pub use skinware_ros2::qos::{QosClass, SENSOR_DEPTH};

/// The DDS profile of a publisher of `class`.
pub fn profile(class: QosClass) -> QosProfile {
    // Never wait for a slow reliable reader: fail and count it.
    let reliability =
        if class.reliable() { Reliability::Reliable { when_full: WhenFull::Fail } } else { Reliability::BestEffort };
    let durability = if class.transient_local() { Durability::TransientLocal } else { Durability::Volatile };
    QosProfile::subscription_default()
        .reliability(reliability)
        .durability(durability)
        .history(History::KeepLast { depth: class.depth() })
}

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
        let sensor = profile(QosClass::Sensor);
        assert_eq!(sensor.reliability, Reliability::BestEffort);
        assert_eq!(sensor.durability, Durability::Volatile);
        assert_eq!(sensor.history, History::KeepLast { depth: 5 });
        let status = profile(QosClass::Status);
        assert!(matches!(status.reliability, Reliability::Reliable { when_full: WhenFull::Fail }));
        assert_eq!(status.durability, Durability::Volatile);
        let fixed = profile(QosClass::Static);
        assert!(matches!(fixed.reliability, Reliability::Reliable { .. }));
        assert_eq!(fixed.durability, Durability::TransientLocal);
    }
}
