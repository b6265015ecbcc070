//! The skin's geometry from its config: every driver's layers and
//! calibration, and the config's regions.

use anyhow::{Context, Result};
use skinware::LayerTopology;
use skinware_geometry::{Calibration, GeometryError, RegionSpec, SkinGeometry};

use skin::config::Config;

/// The layers, the calibration (keyed by layer name) and the regions of `config`.
pub fn inputs(config: &Config) -> Result<(Vec<LayerTopology>, Calibration, Vec<RegionSpec>)> {
    let mut layers = Vec::new();
    let mut calibration = Calibration::new();
    for (index, driver) in config.drivers.iter().enumerate() {
        let built = driver.build(&config.skin)?;
        let own = match &driver.calibration {
            Some(path) => Calibration::load(&config.base_dir.join(path))
                .with_context(|| format!("driver {:?}: `calibration`", driver.name))?,
            None => built.calibration(index),
        };
        for spec in built.layers() {
            let topology = spec.topology;
            for sensor in &topology.sensors {
                let entry = own.get(&topology.name, &topology.sensor_type, sensor.uid).ok_or_else(|| {
                    GeometryError::Uncalibrated {
                        layer: topology.name.clone(),
                        sensor_type: topology.sensor_type.clone(),
                        uid: sensor.uid,
                    }
                })?;
                calibration.insert(&topology.name, sensor.uid, entry.clone()).map_err(anyhow::Error::msg)?;
            }
            layers.push(topology);
        }
    }
    let regions = config.regions.iter().map(|r| r.spec()).collect::<Result<Vec<_>>>()?;
    Ok((layers, calibration, regions))
}

/// The geometry of `config`, from the cache when its inputs have not changed.
/// The flag says whether it came from the cache.
pub fn load_or_build(config: &Config) -> Result<(SkinGeometry, bool)> {
    load_or_build_in(config, &skinware_geometry::cache_dir())
}

/// [`load_or_build`] with the cache in `cache`.
pub fn load_or_build_in(config: &Config, cache: &std::path::Path) -> Result<(SkinGeometry, bool)> {
    let (layers, calibration, regions) = inputs(config)?;
    Ok(SkinGeometry::load_or_build(cache, &config.skin, &layers, &calibration, &regions)?)
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::*;

    #[test]
    fn regions_resolve_against_the_skin_when_the_geometry_is_built() {
        let text = "[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 600\nlayers = 2\n[[region]]\nname = \"r\"\nlinks = [\"tail\"]\n";
        let config = Config::parse(text, Path::new("test.toml")).unwrap();
        let err = format!("{:#}", load_or_build_in(&config, &std::env::temp_dir()).unwrap_err());
        assert!(err.contains("region \"r\": no sensor is on link \"tail\""), "{err}");
    }

    #[test]
    fn a_skin_calib_calibration_is_imported() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/calibrated-hand.toml");
        let config = Config::load(&path).unwrap();
        let cache = std::env::temp_dir().join(format!("skin-calib-test-{}", std::process::id()));
        let (geometry, _) = load_or_build_in(&config, &cache).unwrap();
        let _ = std::fs::remove_dir_all(&cache);
        assert_eq!(geometry.sensor_count(), 24);
        // uid 8: row 1, column 1 of the 5 mm grid.
        assert!((geometry.positions[7][0] - 0.005).abs() < 1e-6 && (geometry.positions[7][1] - 0.005).abs() < 1e-6);
        assert!((geometry.radii[0] - 0.002).abs() < 1e-7);
        assert_eq!(geometry.region("palm").unwrap().len(), 12);
        assert_eq!(geometry.links, ["palm", "fingers"]);
        // A missing calibration file is named.
        let broken = config.drivers[0].clone();
        let mut config = config;
        config.drivers = vec![skin::config::DriverConfig { calibration: Some("missing.calib".into()), ..broken }];
        let err = format!("{:#}", load_or_build_in(&config, &std::env::temp_dir()).unwrap_err());
        assert!(err.contains("missing.calib") && err.contains("cannot read it"), "{err}");
    }
}
