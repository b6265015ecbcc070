//! skinware-dds against a stock ROS 2 node: rclpy with Fast DDS (each ROS
//! distro's Python in `SKINWARE_ROS2_PYTHONS`, colon-separated; CI installs
//! Jazzy's and Kilted's from pip), in another process.

mod bridge;
mod driver;

use std::path::{Path, PathBuf};
use std::process::Command;

/// Each distro's Python with rclpy.
fn ros_pythons() -> Vec<String> {
    let list = std::env::var("SKINWARE_ROS2_PYTHONS").unwrap_or_default();
    list.split(':').filter(|p| !p.is_empty()).map(str::to_owned).collect()
}

/// The peer script.
fn peer() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/integration/rclpy_peer.py")
}

/// A DDS domain of this test run's own, so that parallel tests (and other
/// runs on the machine) do not hear each other: `slot` tells the tests of
/// one run apart.
fn domain(slot: u32) -> u16 {
    (10 + (std::process::id() % 40) * 5 + slot) as u16
}

/// `python` with `args` in `domain`, in its own process.
fn rclpy(python: &str, domain: u16) -> Command {
    let mut command = Command::new(python);
    command.arg(peer()).env("ROS_DOMAIN_ID", domain.to_string()).env("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp");
    command
}

/// A segment directory of the test's own, removed at the end.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("skinware-dds-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
