//! Finds what this machine lacks for some of the tests (see
//! `build/test_probes.rs`): those tests are then built ignored, with why.

include!("../../build/test_probes.rs");

fn main() {
    // No CI machine of ours has a CAN interface (no AF_CAN in its kernel).
    test_probes::probe("skip_no_vcan0", std::path::Path::new("/sys/class/net/vcan0").exists(), false);
}
