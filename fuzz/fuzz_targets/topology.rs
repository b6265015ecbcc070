//! A layer's topology from arbitrary description bytes: a value or a typed
//! error, never a panic or an allocation the input does not justify.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(topology) = skinware::LayerTopology::decode(bytes, "fuzz/layer") {
        // What decodes must encode back to the same bytes.
        assert_eq!(topology.encode(), bytes);
    }
});
