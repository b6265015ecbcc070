//! A calibration file (skinware's text format or skin.calib) from arbitrary text.
#![no_main]

use libfuzzer_sys::fuzz_target;
use skinware_geometry::Calibration;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(text) = std::str::from_utf8(bytes) {
        let _ = Calibration::parse(text, "fuzz.calib");
    }
});
