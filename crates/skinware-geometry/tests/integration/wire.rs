//! The geometry file's decoder against arbitrary and mutated files (with
//! their checksum made right, so that the decoder reads past it): a value or
//! a typed error, never a panic, and allocation bounded by the input; and
//! encode then decode is the identity on geometries built from random skins.

use proptest::prelude::*;
use skinware::TopologyBuilder;
use skinware_geometry::{Calibration, RegionSpec, Selector, SensorCalibration, SkinGeometry};

use crate::alloc_bound::within_allocation_bound;

/// The file's checksum, FNV-1a 64 over the bytes and then one 0xff byte,
/// computed here independently of the crate's own.
fn checksum(bytes: &[u8]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes.iter().chain(&[0xff]) {
        hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    hash
}

fn with_checksum(mut body: Vec<u8>) -> Vec<u8> {
    let sum = checksum(&body);
    body.extend_from_slice(&sum.to_le_bytes());
    body
}

/// A grid of `columns × rows` sensors in one or two layers, on two links,
/// with regions cut by uid ranges and by link.
fn geometries() -> impl Strategy<Value = SkinGeometry> {
    (1u32..8, 1u32..6, 0.002f64..0.02, any::<bool>(), 0u32..4).prop_map(
        |(columns, rows, pitch, two_layers, regions)| {
            let count = columns * rows;
            let split = if two_layers { count / 2 } else { count };
            let mut layers = Vec::new();
            for (name, uids) in [("front", 1..=split), ("back", split + 1..=count)] {
                if uids.is_empty() {
                    continue;
                }
                let mut builder = TopologyBuilder::new(name, "pressure", 50.0);
                builder.patch(1).module(10, uids);
                layers.push(builder.build().unwrap());
            }
            let mut calibration = Calibration::new();
            for uid in 1..=count {
                let (row, column) = ((uid - 1) / columns, (uid - 1) % columns);
                let sensor = SensorCalibration {
                    position: [f64::from(column) * pitch, f64::from(row) * pitch, 0.0],
                    normal: [0.0, 0.0, 1.0],
                    radius: pitch / 3.0,
                    link: if column <= columns / 2 { "palm".into() } else { "finger".into() },
                };
                calibration.insert("pressure", uid, sensor).unwrap();
            }
            let specs: Vec<RegionSpec> = (0..regions)
                .map(|r| RegionSpec {
                    name: format!("region{r}"),
                    selectors: vec![if r % 2 == 0 {
                        Selector::Uids { layer: None, uids: (1..=count).step_by(r as usize + 1).collect() }
                    } else {
                        Selector::Link("palm".into())
                    }],
                })
                .collect();
            SkinGeometry::build("s", &layers, &calibration, &specs).unwrap()
        },
    )
}

fn decode(bytes: &[u8]) -> Result<SkinGeometry, skinware::wire::DecodeError> {
    within_allocation_bound(bytes, SkinGeometry::decode)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn geometry_round_trips(geometry in geometries()) {
        prop_assert_eq!(decode(&geometry.encode()).unwrap(), geometry);
    }

    #[test]
    fn geometry_decoder_is_total_on_arbitrary_bytes(body in prop::collection::vec(any::<u8>(), 0..512)) {
        let _ = decode(&body);
        let mut with_magic = b"SKGEOM02\x02\x00\x00\x00".to_vec();
        with_magic.extend_from_slice(&body);
        let _ = decode(&with_checksum(with_magic));
    }

    #[test]
    fn geometry_decoder_is_total_on_mutated_files(
        (geometry, edits) in (geometries(), prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6))
    ) {
        let file = geometry.encode();
        let mut body = file[..file.len() - 8].to_vec();
        for (at, value) in edits {
            let at = at.index(body.len());
            body[at] ^= value | 1;
        }
        // Fixed checksum: the decoder must catch the damage by itself.
        if let Ok(decoded) = decode(&with_checksum(body)) {
            // Damage only to values (a coordinate, a build time) may decode;
            // every index in it is then still in range.
            for s in 0..decoded.sensor_count() {
                let _ = decoded.neighbours_of(s);
            }
        }
    }
}
