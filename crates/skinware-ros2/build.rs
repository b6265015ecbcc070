//! Finds what this machine lacks for some of the tests (see
//! `build/test_probes.rs`): those tests are then built ignored, with why.

include!("../../build/test_probes.rs");

fn main() {
    // Every distro's rclpy, with the message packages the tests use.
    let rclpy = test_probes::ros2_pythons_import(&[
        "rclpy",
        "sensor_msgs.msg",
        "visualization_msgs.msg",
        "diagnostic_msgs.msg",
    ]);
    test_probes::probe("skip_no_rclpy", rclpy, true);
}
