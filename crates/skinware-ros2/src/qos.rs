//! The QoS of each kind of topic, as ROS users expect it, for every
//! transport and for recordings: sensor data best-effort and keep-last (a
//! late subscriber wants the newest frame, not a backlog), status reliable,
//! static data reliable and transient-local (a node that starts later still
//! gets `/tf_static`).

/// What kind of data a topic carries, which decides its QoS.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum QosClass {
    /// Frames, clouds, contacts, the map: best-effort, volatile, keep last
    /// [`SENSOR_DEPTH`] (ROS's `SensorDataQoS`).
    Sensor,
    /// `/diagnostics`: reliable, volatile, keep last 10 (ROS's default).
    Status,
    /// `/tf_static`: reliable, transient-local, keep last 1.
    Static,
}

/// The history depth of a sensor topic (ROS's `SensorDataQoS`).
pub const SENSOR_DEPTH: usize = 5;

impl QosClass {
    /// Whether it is reliable (else best-effort).
    pub fn reliable(self) -> bool {
        self != QosClass::Sensor
    }

    /// Whether it is transient-local (else volatile).
    pub fn transient_local(self) -> bool {
        self == QosClass::Static
    }

    /// Its keep-last depth.
    pub fn depth(self) -> usize {
        match self {
            QosClass::Sensor => SENSOR_DEPTH,
            QosClass::Status => 10,
            QosClass::Static => 1,
        }
    }

    /// How `skin bridge --stats` and the docs name it.
    pub fn as_str(self) -> &'static str {
        match self {
            QosClass::Sensor => "best-effort, volatile, keep last 5",
            QosClass::Status => "reliable, volatile, keep last 10",
            QosClass::Static => "reliable, transient-local, keep last 1",
        }
    }

    /// The QoS a recording's channel says it was offered with, as rosbag2
    /// writes its `offered_qos_profiles` metadata (YAML, the names Jazzy's
    /// and Kilted's rosbag2 write; durations 0: the default): `ros2 bag play`
    /// offers it again, so `/tf_static` is transient-local on replay too.
    pub fn offered_qos_profiles(self) -> String {
        let time = |name: &str| format!("  {name}:\n    sec: 0\n    nsec: 0\n");
        format!(
            "- history: keep_last\n  depth: {}\n  reliability: {}\n  durability: {}\n{}{}  liveliness: automatic\n{}  avoid_ros_namespace_conventions: false",
            self.depth(),
            if self.reliable() { "reliable" } else { "best_effort" },
            if self.transient_local() { "transient_local" } else { "volatile" },
            time("deadline"),
            time("lifespan"),
            time("liveliness_lease_duration"),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_class_is_offered_as_rosbag2_writes_it() {
        let yaml = QosClass::Static.offered_qos_profiles();
        assert!(yaml.starts_with("- history: keep_last\n  depth: 1\n  reliability: reliable\n"), "{yaml}");
        assert!(yaml.contains("  durability: transient_local\n"), "{yaml}");
        assert!(yaml.contains("  deadline:\n    sec: 0\n    nsec: 0\n"), "{yaml}");
        assert!(yaml.ends_with("avoid_ros_namespace_conventions: false"), "{yaml}");
        let sensor = QosClass::Sensor.offered_qos_profiles();
        assert!(sensor.contains("reliability: best_effort") && sensor.contains("durability: volatile"));
    }
}
