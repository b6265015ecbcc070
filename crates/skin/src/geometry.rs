//! The skin's geometry from its config: every driver's layers and
//! calibration, and the config's regions.

use anyhow::{Context, Result};
use skinware::LayerTopology;
use skinware_geometry::{Calibration, GeometryError, RegionSpec, SkinGeometry};

use crate::config::Config;

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
