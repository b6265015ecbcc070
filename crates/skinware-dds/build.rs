//! Finds what this machine lacks for some of the tests (see
//! `build/test_probes.rs`): those tests are then built ignored, with why.

include!("../../build/test_probes.rs");

fn main() {
    test_probes::probe("skip_no_rclpy", rclpy_everywhere(), true);
}

/// Whether every Python of `SKINWARE_ROS2_PYTHONS` imports rclpy and the
/// message packages the tests use.
fn rclpy_everywhere() -> bool {
    println!("cargo::rerun-if-env-changed=SKINWARE_ROS2_PYTHONS");
    let list = std::env::var("SKINWARE_ROS2_PYTHONS").unwrap_or_default();
    let pythons: Vec<&str> = list.split(':').filter(|p| !p.is_empty()).collect();
    !pythons.is_empty()
        && pythons.iter().all(|python| {
            test_probes::imports(python, &["rclpy", "sensor_msgs.msg", "std_msgs.msg", "diagnostic_msgs.msg"])
        })
}
