//! skinware-ros2's integration tests: its messages decoded by ROS 2's own
//! type support, in other processes.

mod rclpy;
