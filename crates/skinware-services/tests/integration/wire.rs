//! The service description's decoder: encode then decode is the identity,
//! and arbitrary or mutated bytes give a value or a typed error, never a
//! panic, with allocation bounded by the input.

use proptest::prelude::*;
use skinware_services::ServiceInfo;

use crate::alloc_bound::within_allocation_bound;

fn words() -> impl Strategy<Value = Vec<String>> {
    prop::collection::vec("[a-z0-9_-]{1,12}", 0..8)
}

fn infos() -> impl Strategy<Value = ServiceInfo> {
    ("\\PC{0,32}", any::<u32>(), 1usize..4096, prop::option::of(0.001f64..1e6), words(), words()).prop_map(
        |(schema, version, record_bytes, rate_hz, inputs, labels)| ServiceInfo {
            schema: (schema, version),
            record_bytes,
            rate_hz,
            inputs,
            labels,
        },
    )
}

proptest! {
    #[test]
    fn service_description_round_trips(info in infos()) {
        let bytes = info.encode();
        prop_assert_eq!(within_allocation_bound(&bytes, ServiceInfo::decode).unwrap(), info);
    }

    #[test]
    fn service_description_decoder_is_total(tail in prop::collection::vec(any::<u8>(), 0..256), magic in any::<bool>()) {
        let mut bytes = if magic { b"SKSERV02".to_vec() } else { Vec::new() };
        bytes.extend_from_slice(&tail);
        let _ = within_allocation_bound(&bytes, ServiceInfo::decode);
    }

    #[test]
    fn service_description_decoder_is_total_on_mutations(
        (info, at, value) in (infos(), any::<prop::sample::Index>(), any::<u8>())
    ) {
        let mut bytes = info.encode();
        let at = at.index(bytes.len());
        bytes[at] ^= value | 1;
        let _ = within_allocation_bound(&bytes, ServiceInfo::decode);
    }
}
