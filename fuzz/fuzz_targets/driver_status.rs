//! A driver's status file (`skin ls` reads what another process wrote in
//! the segment directory) from arbitrary bytes: a status or an error, never a
//! panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use skin::driver_status::DriverStatus;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(status) = DriverStatus::decode(bytes) {
        let _ = status.is_live(skin::driver_status::now_ns());
    }
});
