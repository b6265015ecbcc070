//! Prints the REP-2016 type hash of every message type published to ROS
//! nodes and of every type they use, to compare with `ros2 topic info -v`.
fn main() {
    for t in skinware_ros2::type_hash::MESSAGE_TYPES {
        println!("{} {}", t.name, skinware_ros2::type_hash(t.name).unwrap_or_default());
    }
}
