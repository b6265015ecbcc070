//! Malformed calibrations, regions and geometry files get errors that name
//! the file, the line and the fix; the cache follows its inputs.

use skinware::TopologyBuilder;
use skinware_geometry::{Calibration, GeometryError, RegionSpec, Selector, SkinGeometry};

fn calibration_error(text: &str) -> String {
    match Calibration::parse(text, "skin.calib") {
        Ok(c) => panic!("accepted {text:?}: {c:?}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn empty_calibration() {
    let e = calibration_error("\n# nothing\n");
    assert!(e.contains("skin.calib, line 1") && e.contains("empty"), "{e}");
}

#[test]
fn unknown_calibration_format() {
    let e = calibration_error("hello world\n");
    assert!(e.contains("unknown format") && e.contains("skinware-calibration 1"), "{e}");
}

#[test]
fn unsupported_calibration_version() {
    let e = calibration_error("skinware-calibration 7\n");
    assert!(e.contains("unsupported version"), "{e}");
}

#[test]
fn wrong_number_of_fields() {
    let e = calibration_error("skinware-calibration 1\nlayer 1 0 0 0 0 0 1 0.001\n");
    assert!(e.contains("line 2") && e.contains("expected 10 fields") && e.contains("found 9"), "{e}");
}

#[test]
fn a_coordinate_that_is_not_a_number() {
    let e = calibration_error("skinware-calibration 1\nlayer 1 0 zero 0 0 0 1 0.001 arm\n");
    assert!(e.contains("line 2") && e.contains("y \"zero\""), "{e}");
}

#[test]
fn a_zero_normal() {
    let e = calibration_error("skinware-calibration 1\nlayer 1 0 0 0 0 0 0 0.001 arm\n");
    assert!(e.contains("line 2") && e.contains("normal is zero"), "{e}");
}

#[test]
fn a_sensor_calibrated_twice() {
    let e = calibration_error("skinware-calibration 1\nl 1 0 0 0 0 0 1 0.001 arm\nl 1 0 0 0 0 0 1 0.001 arm\n");
    assert!(e.contains("line 3") && e.contains("calibrated twice"), "{e}");
}

#[test]
fn skin_calib_with_fewer_sensors_than_announced() {
    let e = calibration_error("3\n0 1 0 0 0 0 0 1 1000 1\n0 2 0 0 0 0 0 1 1000 1\n");
    assert!(e.contains("announces 3 sensors but the file holds 2"), "{e}");
}

#[test]
fn skin_calib_with_more_sensors_than_announced() {
    let e = calibration_error("1\n0 1 0 0 0 0 0 1 1000 1\n0 2 0 0 0 0 0 1 1000 1\n");
    assert!(e.contains("line 3") && e.contains("more sensors than the 1 announced"), "{e}");
}

#[test]
fn skin_calib_positions_must_be_integer_nanometres() {
    let e = calibration_error("1\n0 1 0.5 0 0 0 0 1 1000 1\n");
    assert!(e.contains("px (integer nanometres) \"0.5\""), "{e}");
}

#[test]
fn missing_calibration_file() {
    let e = Calibration::load(std::path::Path::new("/nonexistent/skin.calib")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/skin.calib") && e.contains("cannot read it"), "{e}");
}

fn strip() -> (Vec<skinware::LayerTopology>, Calibration) {
    let mut builder = TopologyBuilder::new("strip", "pressure", 50.0);
    builder.patch(1).module(10, 1..=6).module(11, 7..=12);
    let topology = builder.build().unwrap();
    let mut calibration = Calibration::new();
    for uid in 1..=12u32 {
        let (row, column) = ((uid - 1) / 6, (uid - 1) % 6);
        let sensor = skinware_geometry::SensorCalibration {
            position: [column as f64 * 0.005, row as f64 * 0.005, 0.0],
            normal: [0.0, 0.0, 1.0],
            radius: 0.002,
            link: if column < 3 { "palm".into() } else { "finger".into() },
        };
        calibration.insert("pressure", uid, sensor).unwrap();
    }
    (vec![topology], calibration)
}

fn region_error(selectors: Vec<Selector>) -> String {
    let (layers, calibration) = strip();
    let regions = [RegionSpec { name: "bad".into(), selectors }];
    SkinGeometry::build("s", &layers, &calibration, &regions).unwrap_err().to_string()
}

#[test]
fn uncalibrated_sensor() {
    let (layers, mut calibration) = strip();
    calibration = Calibration::parse(&calibration.to_native_text().replace("pressure 12 ", "other 12 "), "x").unwrap();
    let e = SkinGeometry::build("s", &layers, &calibration, &[]).unwrap_err().to_string();
    assert!(e.contains("layer strip: sensor uid 12 has no calibration"), "{e}");
}

#[test]
fn region_with_an_unknown_module() {
    let e = region_error(vec![Selector::Modules { layer: None, ids: vec![10, 99] }]);
    assert!(e.contains("region \"bad\"") && e.contains("module 99 does not exist"), "{e}");
}

#[test]
fn region_with_an_unknown_link() {
    let e = region_error(vec![Selector::Link("elbow".into())]);
    assert!(e.contains("no sensor is on link \"elbow\"") && e.contains("finger, palm"), "{e}");
}

#[test]
fn region_in_an_unknown_layer() {
    let e = region_error(vec![Selector::Uids { layer: Some("nope".into()), uids: vec![1] }]);
    assert!(e.contains("layer \"nope\" does not exist"), "{e}");
}

#[test]
fn region_that_selects_nothing() {
    let e = region_error(vec![Selector::Near { point: [5.0, 5.0, 5.0], radius: 0.01 }]);
    assert!(e.contains("selects no sensor"), "{e}");
}

#[test]
fn region_with_a_negative_radius() {
    let e = region_error(vec![Selector::Near { point: [0.0, 0.0, 0.0], radius: -1.0 }]);
    assert!(e.contains("radius above 0"), "{e}");
}

#[test]
fn region_defined_twice() {
    let (layers, calibration) = strip();
    let region = RegionSpec { name: "palm".into(), selectors: vec![Selector::Link("palm".into())] };
    let e = SkinGeometry::build("s", &layers, &calibration, &[region.clone(), region]).unwrap_err().to_string();
    assert!(e.contains("defined twice"), "{e}");
}

#[test]
fn regions_and_indices_on_a_strip() {
    let (layers, calibration) = strip();
    let regions = [
        RegionSpec { name: "palm".into(), selectors: vec![Selector::Link("palm".into())] },
        RegionSpec {
            name: "module11".into(),
            selectors: vec![Selector::Modules { layer: Some("strip".into()), ids: vec![11] }],
        },
    ];
    let g = SkinGeometry::build("s", &layers, &calibration, &regions).unwrap();
    assert_eq!(g.region("palm").unwrap(), &[0, 1, 2, 6, 7, 8]);
    assert_eq!(g.region("module11").unwrap(), &[6, 7, 8, 9, 10, 11]);
    // palm only, both, module11 only.
    assert_eq!(g.regions.subregion_sensors.len(), 3);
    assert_eq!(g.link("finger").unwrap(), &[3, 4, 5, 9, 10, 11]);
    assert_eq!(g.of_type("pressure").unwrap().len(), 12);
    let located = g.locate(7).unwrap();
    assert_eq!((located.uid, located.module_id, located.patch_id), (8, 11, 1));
    // Grid neighbours: a corner has its row and column neighbours.
    assert!(g.neighbours_of(0).contains(&1) && g.neighbours_of(0).contains(&6), "{:?}", g.neighbours_of(0));
    assert!(!g.neighbours_of(0).contains(&2));
}

#[test]
fn truncated_and_foreign_geometry_files() {
    let dir = std::env::temp_dir().join(format!("skinware-geometry-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let e = SkinGeometry::open_in(&dir, "s").unwrap_err();
    assert!(matches!(e, GeometryError::Missing { .. }) && e.to_string().contains("skin run"), "{e}");

    let (layers, calibration) = strip();
    let g = SkinGeometry::build("s", &layers, &calibration, &[]).unwrap();
    let path = g.publish(&dir).unwrap();
    assert_eq!(SkinGeometry::open_in(&dir, "s").unwrap(), g);
    let bytes = std::fs::read(&path).unwrap();
    for cut in [0, 7, 8, 40, bytes.len() / 2, bytes.len() - 1] {
        std::fs::write(&path, &bytes[..cut]).unwrap();
        let e = SkinGeometry::open_in(&dir, "s").unwrap_err().to_string();
        assert!(e.contains("unreadable") && (e.contains("truncated") || e.contains("magic")), "cut at {cut}: {e}");
    }
    std::fs::write(&path, b"#!/bin/sh\necho not a geometry\n").unwrap();
    let e = SkinGeometry::open_in(&dir, "s").unwrap_err().to_string();
    assert!(e.contains("magic at byte 0") && e.contains("not \"SKGEOM02\""), "{e}");
    // Flipped bits anywhere are caught by the checksum, not trusted.
    for at in [9, 100, bytes.len() / 2, bytes.len() - 9] {
        let mut corrupt = bytes.clone();
        corrupt[at] ^= 0x40;
        std::fs::write(&path, &corrupt).unwrap();
        let e = SkinGeometry::open_in(&dir, "s").unwrap_err().to_string();
        assert!(e.contains("checksum"), "byte {at}: {e}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_cache_follows_the_calibration() {
    let cache = std::env::temp_dir().join(format!("skinware-geometry-cache-{}", std::process::id()));
    let (layers, calibration) = strip();
    let (first, cached) = SkinGeometry::load_or_build(&cache, "s", &layers, &calibration, &[]).unwrap();
    assert!(!cached);
    let (second, cached) = SkinGeometry::load_or_build(&cache, "s", &layers, &calibration, &[]).unwrap();
    assert!(cached);
    assert_eq!(first, second);
    let moved =
        Calibration::parse(&calibration.to_native_text().replace("pressure 1 0 0", "pressure 1 0.001 0"), "x").unwrap();
    let (third, cached) = SkinGeometry::load_or_build(&cache, "s", &layers, &moved, &[]).unwrap();
    assert!(!cached, "a changed calibration must be recomputed");
    assert_ne!(third.positions[0], first.positions[0]);
    std::fs::remove_dir_all(&cache).unwrap();
}
