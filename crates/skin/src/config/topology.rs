//! `[[driver.layer]]` tables: layers with an explicit topology (patches,
//! modules and the uids of their sensors).

use anyhow::{Context, Result, bail};
use serde::Deserialize;

use super::process::RtConfig;

/// One `[[driver.layer]]`: a layer with an explicit topology.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct LayerConfig {
    /// The layer's channel name.
    pub name: String,
    /// The kind of its sensors.
    #[serde(default = "default_sensor_type")]
    pub sensor_type: String,
    /// Rate of this layer; the driver's `rate_hz` if absent.
    pub rate_hz: Option<f64>,
    /// The number of sensors the layer must have (a check on the modules below).
    pub sensors: Option<usize>,
    /// Real-time settings of this layer's writer thread; the driver's if absent.
    pub rt: Option<RtConfig>,
    /// Its patches (`[[driver.layer.patch]]`).
    #[serde(rename = "patch")]
    pub patches: Vec<PatchConfig>,
}

fn default_sensor_type() -> String {
    "pressure".into()
}

/// One `[[driver.layer.patch]]`.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct PatchConfig {
    /// Unique in the layer.
    pub id: u32,
    /// Its modules (`[[driver.layer.patch.module]]`).
    #[serde(rename = "module", default)]
    pub modules: Vec<ModuleConfig>,
}

/// One `[[driver.layer.patch.module]]`: its sensors' uids as a list or an inclusive range.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct ModuleConfig {
    /// Unique in the layer.
    pub id: u32,
    /// Its sensors' uids, in frame order.
    pub uids: Option<Vec<u32>>,
    /// Its sensors' uids as an inclusive range.
    pub uid_range: Option<[u32; 2]>,
}

impl LayerConfig {
    /// Builds and checks the topology: unique uids and ids, no empty module or
    /// patch, and the declared sensor count. `budget` is how many more sensors
    /// the driver may have; it is checked before a `uid_range` is expanded.
    pub(super) fn topology(&self, default_rate: f64, budget: &mut usize) -> Result<skinware::LayerTopology> {
        skinware::shm::validate_name("layer", &self.name)?;
        if let Some(rate) = self.rate_hz
            && !(rate.is_finite() && rate > 0.0 && rate <= 100_000.0)
        {
            bail!("layer {}: rate_hz {rate} must be above 0 and at most 100000", self.name);
        }
        let mut builder =
            skinware::TopologyBuilder::new(&self.name, &self.sensor_type, self.rate_hz.unwrap_or(default_rate));
        for patch in &self.patches {
            builder.patch(patch.id);
            for module in &patch.modules {
                let count = match (&module.uids, module.uid_range) {
                    (Some(uids), None) => uids.len(),
                    (None, Some([first, last])) => (last as usize).saturating_sub(first as usize) + 1,
                    _ => 0,
                };
                *budget = budget.checked_sub(count).with_context(|| {
                    format!(
                        "layer {}: module {}: the driver's layers hold more than {} sensors",
                        self.name,
                        module.id,
                        skinware_drivers::MAX_SENSORS
                    )
                })?;
                let uids: Vec<u32> = match (&module.uids, module.uid_range) {
                    (Some(uids), None) => uids.clone(),
                    (None, Some([first, last])) if first <= last => (first..=last).collect(),
                    (None, Some([first, last])) => {
                        bail!("layer {}: module {}: uid_range [{first}, {last}] is backwards", self.name, module.id)
                    }
                    _ => bail!("layer {}: module {} needs exactly one of `uids` or `uid_range`", self.name, module.id),
                };
                builder.module(module.id, uids);
            }
        }
        let topology = builder.build()?;
        if let Some(declared) = self.sensors
            && declared != topology.sensors.len()
        {
            bail!(
                "layer {}: declares {declared} sensors but its modules hold {}; the sensor counts do not add up",
                self.name,
                topology.sensors.len()
            );
        }
        Ok(topology)
    }
}
