//! The geometry pipeline on the virtual humanoid: 30,848 sensors on curved
//! body parts, split over five layers.

use skinware::Driver;
use skinware_drivers::{VirtualSkin, VirtualSkinConfig};
use skinware_geometry::{RegionSpec, Selector, SkinGeometry};

fn humanoid() -> (Vec<skinware::LayerTopology>, skinware_geometry::Calibration) {
    let skin = VirtualSkin::new(VirtualSkinConfig { layers: 5, ..VirtualSkinConfig::default() }).unwrap();
    let layers = skin.layers().into_iter().map(|l| l.topology).collect();
    (layers, skin.calibration())
}

#[test]
fn humanoid_geometry_is_local_symmetric_and_flattens_with_little_distortion() {
    let (layers, calibration) = humanoid();
    let regions = vec![
        RegionSpec {
            name: "left_arm".into(),
            selectors: vec![Selector::Link("left_forearm".into()), Selector::Link("left_upper_arm".into())],
        },
        RegionSpec {
            name: "left_elbow".into(),
            selectors: vec![Selector::Near { point: [0.24, 0.0, 1.14], radius: 0.08 }],
        },
    ];
    let geometry = SkinGeometry::build("humanoid", &layers, &calibration, &regions).unwrap();
    let n = geometry.sensor_count();
    assert_eq!(n, 30_848);
    let stats = &geometry.neighbour_stats;
    let quality = &geometry.map.quality;
    eprintln!("neighbours: {stats:?}");
    eprintln!("map: {quality:?}");
    eprintln!("build: {:?}", geometry.build_times);

    // Symmetric, and local: no edge between sensors facing away from each other
    // (the two sides of a limb) and no edge longer than a few pitches.
    for i in 0..n {
        for &j in geometry.neighbours_of(i) {
            let j = j as usize;
            assert!(geometry.neighbours_of(j).contains(&(i as u32)), "edge {i}-{j} is one-way");
            let (a, b) = (geometry.normals[i], geometry.normals[j]);
            let cos = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            assert!(cos > 0.5, "edge {i}-{j} joins sensors whose normals are {cos} apart");
            assert_eq!(geometry.link_of[i], geometry.link_of[j], "edge {i}-{j} jumps between body parts");
        }
    }
    assert!(stats.mean_edge_m > 0.0 && stats.max_edge_m < 3.0 * stats.mean_edge_m, "{stats:?}");
    assert!(stats.min_degree >= 3 && stats.isolated == 0, "{stats:?}");
    // One surface piece per body part.
    assert_eq!(quality.pieces, 9, "{quality:?}");
    assert!(quality.mean_relative_error < 0.15, "{quality:?}");
    assert!(quality.flipped_fraction < 0.01, "{quality:?}");
    assert_eq!(quality.stacked_fraction, 0.0, "{quality:?}");
    assert!(!quality.pieces_overlap, "{quality:?}");
    // Up on the robot is up on the map: neighbours that climb in 3-D climb on the map.
    let (mut climbing, mut agreeing) = (0, 0);
    for i in 0..n {
        for &j in geometry.neighbours_of(i) {
            let rise = geometry.positions[j as usize][2] - geometry.positions[i][2];
            if rise.abs() > 0.5 * stats.mean_edge_m as f32 {
                climbing += 1;
                let map_rise = geometry.map.positions[j as usize][1] - geometry.map.positions[i][1];
                agreeing += usize::from(map_rise * rise > 0.0);
            }
        }
    }
    assert!(agreeing as f64 > 0.99 * climbing as f64, "{agreeing} of {climbing} climbing edges climb on the map");
    // A tube is cut once, along a seam: a small share of the edges.
    assert!(quality.seam_edge_fraction < 0.02, "{quality:?}");
}
