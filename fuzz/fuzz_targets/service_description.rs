//! A service channel's description from arbitrary bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use skinware_services::ServiceInfo;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(info) = ServiceInfo::decode(bytes) {
        if info.rate_hz.is_none_or(|hz| !hz.is_nan()) {
            assert_eq!(ServiceInfo::decode(&info.encode()).as_ref(), Ok(&info));
        }
    }
});
