//! `[[driver]]` tables: the virtual skin's parameters, and the driver they build.

use std::path::PathBuf;

use anyhow::{Result, bail};
use serde::Deserialize;
use skinware_drivers::{CablePull, Rate, ScriptedContact, VirtualSkin, VirtualSkinConfig};

use super::process::{RestartConfig, RtConfig};
use super::topology::LayerConfig;

/// The kinds of driver.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DriverKind {
    /// The virtual skin.
    Virtual,
}

/// One `[[driver]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct DriverConfig {
    /// Unique among the drivers; generated layers are `NAME-0`, `NAME-1`, ...
    pub name: String,
    /// Which driver.
    pub kind: DriverKind,
    /// Real-time settings of its writer threads (`[driver.rt]`).
    #[serde(default)]
    pub rt: RtConfig,
    /// How its process is restarted (`[driver.restart]`).
    #[serde(default)]
    pub restart: RestartConfig,
    /// Frame buffers per layer channel.
    #[serde(default = "default_slots")]
    pub slots: usize,
    /// Generated skin: total sensors, split equally over `layers`.
    pub sensors: Option<usize>,
    /// Generated skin: number of layers.
    pub layers: Option<usize>,
    /// Generated skin: sensors per module (a layer's last module may have fewer).
    pub sensors_per_module: Option<usize>,
    /// Generated skin: `[min, max]` modules per patch, drawn per patch.
    pub modules_per_patch: Option<[usize; 2]>,
    /// Acquisition rate of each layer, drawn once per layer.
    pub rate_hz: Option<Rate>,
    /// Seed of every random choice (rates, patch sizes, contacts, noise).
    pub seed: Option<u64>,
    /// Scheduled disconnections (`[[driver.cable_pull]]`).
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

fn default_slots() -> usize {
    skinware::DEFAULT_SLOTS
}

/// The file whose existence pulls the cable of `layer` (see `skin pull`).
pub fn pull_file(skin: &str, layer: &str) -> PathBuf {
    skinware::shm::segment_dir().join(format!("skinware-ctl.{skin}.{layer}.pulled"))
}

impl DriverConfig {
    /// Checks what building the driver does not: its restart policy and slots.
    pub(super) fn check(&self) -> Result<()> {
        self.restart.check()?;
        if !(skinware::MIN_SLOTS..=skinware::MAX_SLOTS).contains(&self.slots) {
            bail!("slots = {} must be from {} to {}", self.slots, skinware::MIN_SLOTS, skinware::MAX_SLOTS);
        }
        Ok(())
    }

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
                    let mut budget = skinware_drivers::MAX_SENSORS;
                    for layer in &self.explicit_layers {
                        let rt = layer.rt.as_ref().unwrap_or(&self.rt).options();
                        layers.push(skinware::LayerSpec { topology: layer.topology(default_rate, &mut budget)?, rt });
                    }
                    config.explicit_layers = Some(layers);
                }
                // Before the layers are named: their number is checked there.
                config.validate()?;
                config.pull_files = Some(config.layer_names().iter().map(|layer| pull_file(skin, layer)).collect());
                VirtualSkin::new(config).map_err(|e| anyhow::anyhow!(e))
            }
        }
    }
}
