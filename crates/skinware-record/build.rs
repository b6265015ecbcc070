//! Finds what this machine lacks for some of the tests (see
//! `build/test_probes.rs`): those tests are then built ignored, with why.

include!("../../build/test_probes.rs");

fn main() {
    test_probes::probe("skip_not_root", test_probes::is_root(), true);
}
