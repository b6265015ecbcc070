//! The `.msg` texts of the messages a recording holds, with the definitions
//! they depend on appended the way `ros2 bag` embeds them, so that Foxglove,
//! the ROS 2 tools and Python's `mcap-ros2-support` decode a recording
//! without any package of ours.

use crate::messages::{GAP, IMAGE, LAYER_STATS, SKIN_FRAME};
use crate::standard::{DIAGNOSTIC_ARRAY, MARKER_ARRAY, POINT_CLOUD2, TF_MESSAGE};
use crate::type_hash::{MessageType, message_type};

/// The separator between a `.msg` text and the definitions it depends on.
const SEPARATOR: &str = "================================================================================";

/// `builtin_interfaces/Time`, as a dependency section.
const TIME_DEPENDENCY: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";

/// The `.msg` text of `name` (one of [`SKIN_FRAME`], [`GAP`], [`LAYER_STATS`],
/// [`IMAGE`], [`POINT_CLOUD2`], [`MARKER_ARRAY`], [`DIAGNOSTIC_ARRAY`],
/// [`TF_MESSAGE`]) with its dependencies, or `None` for another type.
pub fn schema_text(name: &str) -> Option<String> {
    if [POINT_CLOUD2, MARKER_ARRAY, DIAGNOSTIC_ARRAY, TF_MESSAGE].contains(&name) {
        return standard_schema_text(message_type(name)?);
    }
    let own = match name {
        SKIN_FRAME => concat!(
            "# One frame of a skinware channel (a layer or a service), as the recorder read it.\n",
            "builtin_interfaces/Time stamp      # when it was acquired (wall clock)\n",
            "builtin_interfaces/Time published  # when its writer published it (wall clock)\n",
            "uint64 seq                         # the writer's sequence number\n",
            "uint64 status                      # bits: 1 fault, 2 partial, 4 input faulted\n",
            "uint64 skipped                     # frames the recorder missed just before this one\n",
            "uint16[] responses                 # a layer: one response per sensor, in topology order\n",
            "uint8[] payload                    # a service: its frame's bytes\n",
        ),
        GAP => concat!(
            "# Frames of a channel that the recorder did not get (it was too slow, or stopped).\n",
            "builtin_interfaces/Time stamp  # when the frame after the gap was acquired\n",
            "string channel                 # the skinware channel\n",
            "uint64 first_seq               # the first sequence number missing\n",
            "uint64 count                   # how many are missing\n",
        ),
        LAYER_STATS => concat!(
            "# A channel's statistics over the last interval of the recording.\n",
            "builtin_interfaces/Time stamp\n",
            "string channel\n",
            "string state            # the writer's: running, paused, faulted or gone\n",
            "uint64 frames           # frames recorded since the start\n",
            "uint64 lost             # frames missed since the start\n",
            "uint64 faulted          # frames with a fault status since the start\n",
            "float64 rate_hz         # frames recorded per second over the interval\n",
            "float64 latency_ms      # mean publish time minus acquisition time over the interval\n",
            "uint16 min_response     # over the newest frame of a layer (0 for a service)\n",
            "uint16 max_response\n",
            "float64 mean_response\n",
        ),
        IMAGE => {
            return Some(format!(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n\
                 uint8[] data\n{SEPARATOR}\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n\
                 {SEPARATOR}\n{TIME_DEPENDENCY}"
            ));
        }
        _ => return None,
    };
    Some(format!("{own}{SEPARATOR}\n{TIME_DEPENDENCY}"))
}

/// A standard type's `.msg` text (fields only: constants do not change the
/// encoding), then every type it uses, each once, in the order first met.
fn standard_schema_text(root: &MessageType) -> Option<String> {
    let fields = |t: &MessageType| -> String {
        t.fields.iter().map(|(name, ty)| format!("{} {name}\n", ty.msg_text())).collect()
    };
    let mut text = fields(root);
    let mut seen: Vec<&str> = Vec::new();
    let mut queue: Vec<&str> = root.fields.iter().filter_map(|(_, ty)| ty.nested()).collect();
    while !queue.is_empty() {
        let next = queue.remove(0);
        if seen.contains(&next) {
            continue;
        }
        seen.push(next);
        let used = message_type(next)?;
        text.push_str(&format!("{SEPARATOR}\nMSG: {}\n{}", next.replace("/msg/", "/"), fields(used)));
        queue.extend(used.fields.iter().filter_map(|(_, ty)| ty.nested()));
    }
    Some(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_schema_names_its_dependencies() {
        for name in [SKIN_FRAME, GAP, LAYER_STATS, IMAGE] {
            let text = schema_text(name).unwrap();
            assert!(text.contains("MSG: builtin_interfaces/Time"), "{name}");
        }
        assert!(schema_text(IMAGE).unwrap().contains("MSG: std_msgs/Header"));
        assert!(schema_text("pkg/msg/Other").is_none());
    }

    #[test]
    fn standard_schemas_carry_every_type_they_use() {
        let cloud = schema_text(POINT_CLOUD2).unwrap();
        assert!(cloud.starts_with("std_msgs/Header header\nuint32 height\n"), "{cloud}");
        assert!(cloud.contains("sensor_msgs/PointField[] fields\n"));
        assert!(
            cloud.contains("MSG: sensor_msgs/PointField\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n")
        );
        assert!(cloud.contains("MSG: builtin_interfaces/Time\n"));
        let markers = schema_text(MARKER_ARRAY).unwrap();
        for used in
            ["visualization_msgs/Marker", "geometry_msgs/Pose", "std_msgs/ColorRGBA", "visualization_msgs/MeshFile"]
        {
            assert_eq!(markers.matches(&format!("MSG: {used}\n")).count(), 1, "{used}");
        }
        assert!(schema_text(DIAGNOSTIC_ARRAY).unwrap().contains("MSG: diagnostic_msgs/DiagnosticStatus\nbyte level\n"));
        assert!(schema_text(TF_MESSAGE).unwrap().contains("MSG: geometry_msgs/TransformStamped\n"));
    }
}
