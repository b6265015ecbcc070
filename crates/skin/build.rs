//! Finds what this machine lacks for some of the tests (see
//! `build/test_probes.rs`): those tests are then built ignored, with why.

include!("../../build/test_probes.rs");

fn main() {
    use test_probes::{is_root, probe, program, python_has};
    probe("skip_no_python_bindings", python_has(&["skinware", "pytest", "numpy"]), true);
    probe(
        "skip_no_chromium",
        program(&["chromedriver"]) && program(&["chromium", "chromium-browser", "google-chrome"]),
        true,
    );
    println!("cargo::rerun-if-changed=/usr/bin");
    probe("skip_not_root", is_root(), true);
}
