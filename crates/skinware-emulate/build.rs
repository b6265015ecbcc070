//! Finds what this machine lacks for some of the tests (see
//! `build/test_probes.rs`): those tests are then built ignored, with why.

include!("../../build/test_probes.rs");

fn main() {
    use test_probes::{probe, python_has};
    probe("skip_no_python_can", python_has(&["can", "serial"]), true);
}
