//! Where each of a skin's messages is published, the same in a recording and
//! on every transport: everything under `/skin/<skin>/`, with skinware names
//! made valid ROS names.
//!
//! | topic | message |
//! |---|---|
//! | `/skin/<skin>/<channel>` | `skinware_msgs/SkinFrame` (a recording) |
//! | `/skin/<skin>/<channel>/stats` | `skinware_msgs/LayerStats` (a recording) |
//! | `/skin/<skin>/gaps` | `skinware_msgs/Gap` (a recording) |
//! | `/skin/<skin>/<layer>/state` | `tactile_msgs/TactileState` |
//! | `/skin/<skin>/<service>/contacts` | `tactile_msgs/TactileContacts` |
//! | `/skin/<skin>/map` | `sensor_msgs/Image` |
//! | `/skin/<skin>/<layer>/cloud/<link>` | `sensor_msgs/PointCloud2` |
//! | `/skin/<skin>/<service>/markers` | `visualization_msgs/MarkerArray` |
//! | `/diagnostics` | `diagnostic_msgs/DiagnosticArray` |
//! | `/tf_static` | `tf2_msgs/TFMessage` |

/// ROS's topic of health reports (`rqt_robot_monitor` and the diagnostic
/// aggregator read it).
pub const DIAGNOSTICS_TOPIC: &str = "/diagnostics";
/// ROS's topic of transforms that never change.
pub const TF_STATIC_TOPIC: &str = "/tf_static";

/// A ROS 2 name token made from a skinware name: every character ROS forbids
/// becomes `_`, and a token may not be empty or start with a digit.
pub fn ros_name(name: &str) -> String {
    let mut out: String = name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' { c } else { '_' }).collect();
    // A ROS name token cannot start with a digit.
    if out.is_empty() || out.starts_with(|c: char| c.is_ascii_digit()) {
        out.insert(0, '_');
    }
    out
}

/// The topic of channel `channel` of skin `skin`: `/skin/<skin>/<channel>`,
/// with every character ROS 2 forbids in a name (such as `-`) made `_`.
pub fn frame_topic(skin: &str, channel: &str) -> String {
    format!("/skin/{}/{}", ros_name(skin), ros_name(channel))
}

/// The topic of the skin's map image.
pub fn map_topic(skin: &str) -> String {
    format!("/skin/{}/map", ros_name(skin))
}

/// The topic of a channel's statistics.
pub fn stats_topic(skin: &str, channel: &str) -> String {
    format!("{}/stats", frame_topic(skin, channel))
}

/// The topic of the frames the recorder missed.
pub fn gaps_topic(skin: &str) -> String {
    format!("/skin/{}/gaps", ros_name(skin))
}

/// The topic of a layer's `TactileState`s.
pub fn tactile_state_topic(skin: &str, layer: &str) -> String {
    format!("{}/state", frame_topic(skin, layer))
}

/// The topic of the contact service's `TactileContacts`.
pub fn contacts_topic(skin: &str, service: &str) -> String {
    format!("{}/contacts", frame_topic(skin, service))
}

/// The topic of the point cloud of a layer's taxels on link `link`.
pub fn cloud_topic(skin: &str, layer: &str, link: &str) -> String {
    format!("{}/cloud/{}", frame_topic(skin, layer), ros_name(link))
}

/// The topic of the contact service's markers.
pub fn markers_topic(skin: &str, service: &str) -> String {
    format!("{}/markers", frame_topic(skin, service))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_are_valid_ros_names() {
        assert_eq!(frame_topic("default", "virtual-0"), "/skin/default/virtual_0");
        assert_eq!(stats_topic("2arms", "contact"), "/skin/_2arms/contact/stats");
        assert_eq!(tactile_state_topic("default", "virtual-0"), "/skin/default/virtual_0/state");
        assert_eq!(contacts_topic("default", "contact"), "/skin/default/contact/contacts");
        assert_eq!(map_topic("a-b"), "/skin/a_b/map");
        assert_eq!(gaps_topic("default"), "/skin/default/gaps");
        assert_eq!(cloud_topic("default", "virtual-0", "left_forearm"), "/skin/default/virtual_0/cloud/left_forearm");
        assert_eq!(markers_topic("default", "contact"), "/skin/default/contact/markers");
    }

    #[test]
    fn names_become_valid_ros_names() {
        assert_eq!(ros_name("virtual-0"), "virtual_0");
        assert_eq!(ros_name("2arms"), "_2arms");
        assert_eq!(ros_name(""), "_");
    }
}
