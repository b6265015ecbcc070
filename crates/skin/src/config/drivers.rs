//! `[[driver]]` tables: the drivers `skin run` starts, their layers, real-time
//! settings and restart backoff.

use std::path::PathBuf;

use anyhow::{Result, bail};
use serde::Deserialize;
use skinware_drivers::{CablePull, Rate, ScriptedContact, VirtualSkin, VirtualSkinConfig};

use super::pull_file;

/// The kinds of driver.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DriverKind {
    /// The virtual skin.
    Virtual,
}

/// Real-time settings of a driver's writer threads.
#[derive(Debug, Deserialize, Default, Clone)]
#[serde(deny_unknown_fields)]
pub struct RtConfig {
    pub fifo_priority: Option<u8>,
    #[serde(default)]
    pub lock_memory: bool,
    #[serde(default)]
    pub cpus: Vec<usize>,
}

impl RtConfig {
    fn options(&self) -> skinware::RtOptions {
        skinware::RtOptions {
            fifo_priority: self.fifo_priority,
            lock_memory: self.lock_memory,
            cpus: self.cpus.clone(),
        }
    }
}

/// Restart policy of a driver process.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct RestartConfig {
    pub min_backoff_s: f64,
    pub max_backoff_s: f64,
}

impl Default for RestartConfig {
    fn default() -> Self {
        RestartConfig { min_backoff_s: 0.2, max_backoff_s: 5.0 }
    }
}

/// One `[[driver]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct DriverConfig {
    pub name: String,
    pub kind: DriverKind,
    #[serde(default)]
    pub rt: RtConfig,
    #[serde(default)]
    pub restart: RestartConfig,
    /// Frame buffers per layer channel.
    #[serde(default = "default_slots")]
    pub slots: usize,
    // Virtual skin parameters.
    pub sensors: Option<usize>,
    pub layers: Option<usize>,
    pub sensors_per_module: Option<usize>,
    pub modules_per_patch: Option<[usize; 2]>,
    pub rate_hz: Option<Rate>,
    pub seed: Option<u64>,
    #[serde(default, rename = "cable_pull")]
    pub cable_pulls: Vec<CablePull>,
    /// Scripted contacts (`[[driver.contact]]`).
    #[serde(default, rename = "contact")]
    pub contacts: Vec<ScriptedContact>,
    /// Whether random contacts press and slide all over the body (default true).
    pub random_contacts: Option<bool>,
    /// Uids of simulated dead taxels (their response never changes).
    #[serde(default)]
    pub dead_taxels: Vec<u32>,
    /// Uids of simulated stuck (saturated) taxels.
    #[serde(default)]
    pub stuck_taxels: Vec<u32>,
    /// A calibration file (skinware or skin.calib format); the virtual skin
    /// calibrates itself when absent.
    pub calibration: Option<PathBuf>,
    /// Layers with an explicit topology (instead of generated ones).
    #[serde(default, rename = "layer")]
    pub explicit_layers: Vec<LayerConfig>,
}

/// One `[[driver.layer]]`: a layer with an explicit topology.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct LayerConfig {
    pub name: String,
    #[serde(default = "default_sensor_type")]
    pub sensor_type: String,
    /// Rate of this layer; the driver's `rate_hz` if absent.
    pub rate_hz: Option<f64>,
    /// The number of sensors the layer must have (a check on the modules below).
    pub sensors: Option<usize>,
    /// Real-time settings of this layer's writer thread; the driver's if absent.
    pub rt: Option<RtConfig>,
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
    pub id: u32,
    #[serde(rename = "module", default)]
    pub modules: Vec<ModuleConfig>,
}

/// One `[[driver.layer.patch.module]]`: its sensors' uids as a list or an inclusive range.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct ModuleConfig {
    pub id: u32,
    pub uids: Option<Vec<u32>>,
    pub uid_range: Option<[u32; 2]>,
}

impl LayerConfig {
    /// Builds and checks the topology: unique uids and ids, no empty module or
    /// patch, and the declared sensor count.
    fn topology(&self, default_rate: f64) -> Result<skinware::LayerTopology> {
        skinware::shm::validate_name("layer", &self.name)?;
        if let Some(rate) = self.rate_hz {
            if !(rate.is_finite() && rate > 0.0 && rate <= 100_000.0) {
                bail!("layer {}: rate_hz {rate} must be above 0 and at most 100000", self.name);
            }
        }
        let mut builder =
            skinware::TopologyBuilder::new(&self.name, &self.sensor_type, self.rate_hz.unwrap_or(default_rate));
        for patch in &self.patches {
            builder.patch(patch.id);
            for module in &patch.modules {
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
        if let Some(declared) = self.sensors {
            if declared != topology.sensors.len() {
                bail!(
                    "layer {}: declares {declared} sensors but its modules hold {}; the sensor counts do not add up",
                    self.name,
                    topology.sensors.len()
                );
            }
        }
        Ok(topology)
    }
}

fn default_slots() -> usize {
    skinware::DEFAULT_SLOTS
}

impl RestartConfig {
    pub(super) fn check(&self) -> Result<()> {
        let RestartConfig { min_backoff_s: min, max_backoff_s: max } = *self;
        if !(min.is_finite() && max.is_finite() && min > 0.0 && min <= max && max <= 3600.0) {
            bail!("restart backoff [{min}, {max}] s must satisfy 0 < min_backoff_s <= max_backoff_s <= 3600");
        }
        Ok(())
    }
}

impl DriverConfig {
    /// Builds the driver this table describes.
    pub fn build(&self, skin: &str) -> Result<VirtualSkin> {
        skinware::shm::validate_name("driver", &self.name)?;
        match self.kind {
            DriverKind::Virtual => {
                let defaults = VirtualSkinConfig::default();
                let layers = self.layers.unwrap_or(defaults.layers);
                let mut config = VirtualSkinConfig {
                    name: self.name.clone(),
                    sensors: self.sensors.unwrap_or(defaults.sensors),
                    layers,
                    sensors_per_module: self.sensors_per_module.unwrap_or(defaults.sensors_per_module),
                    modules_per_patch: self
                        .modules_per_patch
                        .map(|[a, b]| (a, b))
                        .unwrap_or(defaults.modules_per_patch),
                    rate: self.rate_hz.clone().unwrap_or(defaults.rate),
                    seed: self.seed.unwrap_or(defaults.seed),
                    cable_pulls: self.cable_pulls.clone(),
                    pull_files: None,
                    rt: self.rt.options(),
                    explicit_layers: None,
                    contacts: self.contacts.clone(),
                    random_contacts: self.random_contacts.unwrap_or(true),
                    dead_taxels: self.dead_taxels.clone(),
                    stuck_taxels: self.stuck_taxels.clone(),
                };
                if !self.explicit_layers.is_empty() {
                    if self.sensors.is_some() || self.layers.is_some() {
                        bail!("give either `sensors`/`layers` (a generated skin) or [[driver.layer]] tables, not both");
                    }
                    let default_rate = match &config.rate {
                        Rate::Fixed(hz) => *hz,
                        Rate::Random { random: [lo, _] } => *lo,
                    };
                    let mut layers = Vec::new();
                    for layer in &self.explicit_layers {
                        let rt = layer.rt.as_ref().unwrap_or(&self.rt).options();
                        layers.push(skinware::LayerSpec { topology: layer.topology(default_rate)?, rt });
                    }
                    config.explicit_layers = Some(layers);
                }
                config.pull_files = Some(config.layer_names().iter().map(|layer| pull_file(skin, layer)).collect());
                VirtualSkin::new(config).map_err(|e| anyhow::anyhow!(e))
            }
        }
    }
}
