//! Every decoder of the core, against arbitrary bytes: it returns a value or a
//! typed error, never panics, and allocates at most a fixed multiple of its
//! input; and encoding then decoding gives back what was encoded.

use proptest::prelude::*;
use skinware::wire::{Decoder, Encoder};
use skinware::{LayerTopology, TopologyBuilder};

use crate::alloc_bound::within_allocation_bound;

/// A topology of 1 to 4 patches of 1 to 5 modules of 1 to 12 sensors, with
/// unique ids and uids, any names and any finite rate.
fn topologies() -> impl Strategy<Value = LayerTopology> {
    let shape = prop::collection::vec(prop::collection::vec(1usize..=12, 1..=5), 1..=4);
    (shape, "\\PC{0,20}", "\\PC{0,20}", -1e6f64..1e6, any::<u32>(), any::<u32>()).prop_map(
        |(shape, name, sensor_type, rate, id_base, uid_base)| {
            let mut builder = TopologyBuilder::new(&name, &sensor_type, rate);
            let (mut module_id, mut uid) = (id_base, uid_base);
            for (p, modules) in shape.iter().enumerate() {
                builder.patch(id_base.wrapping_add(p as u32));
                for &sensors in modules {
                    module_id = module_id.wrapping_add(7);
                    let uids: Vec<u32> = (0..sensors)
                        .map(|_| {
                            uid = uid.wrapping_add(3);
                            uid
                        })
                        .collect();
                    builder.module(module_id, uids);
                }
            }
            builder.build().expect("unique by construction")
        },
    )
}

/// A valid encoding with a few bytes flipped, inserted or removed.
fn mutated(bytes: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let len = bytes.len();
    prop::collection::vec((0..len.max(1), any::<u8>(), 0u8..3), 1..6).prop_map(move |edits| {
        let mut out = bytes.clone();
        for (at, value, kind) in edits {
            let at = at.min(out.len());
            match kind {
                0 if at < out.len() => out[at] ^= value | 1,
                1 => out.insert(at, value),
                _ if at < out.len() => {
                    out.remove(at);
                }
                _ => out.push(value),
            }
        }
        out
    })
}

proptest! {
    #[test]
    fn topology_round_trips(topology in topologies()) {
        let bytes = topology.encode();
        let decoded = within_allocation_bound(&bytes, |b| LayerTopology::decode(b, "skin/layer"));
        prop_assert_eq!(decoded.unwrap(), topology);
    }

    #[test]
    fn topology_decoder_is_total_on_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..512)) {
        let _ = within_allocation_bound(&bytes, |b| LayerTopology::decode(b, "skin/layer"));
    }

    #[test]
    fn topology_decoder_is_total_past_the_magic(tail in prop::collection::vec(any::<u8>(), 0..512)) {
        let mut bytes = b"SKTOPO01".to_vec();
        bytes.extend_from_slice(&tail);
        let _ = within_allocation_bound(&bytes, |b| LayerTopology::decode(b, "skin/layer"));
    }

    #[test]
    fn topology_decoder_is_total_on_mutated_topologies(
        bytes in topologies().prop_flat_map(|t| mutated(t.encode()))
    ) {
        // Undecodable bytes name the channel; decodable but inconsistent ones
        // (a repeated uid, an empty module) name the offending ids.
        if let Err(e @ skinware::TopologyError::Malformed { .. }) =
            within_allocation_bound(&bytes, |b| LayerTopology::decode(b, "skin/layer"))
        {
            prop_assert!(e.to_string().contains("skin/layer"), "{}", e);
        }
    }

    #[test]
    fn wire_values_round_trip(
        words in prop::collection::vec(any::<u32>(), 0..40),
        text in "\\PC{0,40}",
        lists in prop::collection::vec(prop::collection::vec(any::<u32>(), 0..5), 0..5),
        real in any::<f64>().prop_filter("comparable", |r| !r.is_nan()),
    ) {
        let mut out = Encoder::new(b"PROPTEST");
        out.u32s(&words);
        out.str(&text);
        out.u32_lists(&lists);
        out.f64(real);
        let bytes = out.finish();
        let mut input = Decoder::new(&bytes, "test", b"PROPTEST").unwrap();
        prop_assert_eq!(input.u32s("words").unwrap(), words);
        prop_assert_eq!(input.str("text").unwrap(), text);
        prop_assert_eq!(input.u32_lists("lists").unwrap(), lists);
        prop_assert_eq!(input.f64("real").unwrap(), real);
        prop_assert!(input.finish().is_ok());
    }

    #[test]
    fn wire_counts_never_outrun_the_input(tail in prop::collection::vec(any::<u8>(), 0..64)) {
        let mut bytes = b"PROPTEST".to_vec();
        bytes.extend_from_slice(&tail);
        let _ = within_allocation_bound(&bytes, |b| {
            let mut input = Decoder::new(b, "test", b"PROPTEST").unwrap();
            (input.u32_lists("lists"), input.strs("names"), input.f32s("values"))
        });
    }
}
