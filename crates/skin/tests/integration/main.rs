//! The integration tests of `skin`, in one test binary (as ripgrep does):
//! one link instead of one per file, and one place for what they share.
//!
//! - [`e2e`]: `skin run` with a SIGKILLed driver and a pulled cable;
//! - [`cli_e2e`]: what the commands refuse (`skin pull` of what has no
//!   simulated cable, `--skin` of a skin that is not there), `skin ls`'s
//!   listing and rates, `skin view` started before its skin;
//! - [`ethercat_e2e`]: `skin run` of an EtherCAT skin on a veth pair in a
//!   network namespace, a reader outside it, `skin ls` showing SubDevices;
//! - [`services_e2e`]: services, regions and geometry through the CLI;
//! - [`c_api`]: the C API and the C++ wrapper, from C and C++ test programs
//!   (also under AddressSanitizer and Valgrind);
//! - [`record_e2e`]: `skin record`, `replay`, `info` and `--recover` on the
//!   paper's skin, with Python's `mcap` as the independent reader;
//! - [`browser`]: `skin demo` and `skin view` of the iCub example in
//!   headless Chromium (skipped without it, except under `CI=true`);
//! - [`python`]: the Python bindings' pytest suite, against this build's
//!   `skin` (skipped without the package, except under `CI=true`);
//! - [`docs`]: every command of the docs' shell blocks runs (or a marker
//!   says why it cannot here), and the docs' tables list what is in the tree.
//!
//! - [`bridge_e2e`] (feature `zenoh`): `skin bridge` between two network
//!   namespaces, and a ROS 2 subscriber made of Python's `eclipse-zenoh` and
//!   `rosbags`;
//! - [`ros2_e2e`] (feature `dds`): a ROS 2 sensor on one network namespace
//!   is a `ros2` layer of `skin run` on another, whose `skin bridge --ros2
//!   dds` cloud comes back to an rclpy subscriber.
//!
//! Run one file's tests with `cargo test -p skin --test integration e2e::`.

#[cfg(feature = "zenoh")]
mod bridge_e2e;
mod browser;
mod c_api;
mod can_e2e;
mod cli_e2e;
mod docs;
mod e2e;
mod ethercat_e2e;
mod python;
mod record_e2e;
#[cfg(feature = "dds")]
mod ros2_e2e;
mod services_e2e;
mod util;
