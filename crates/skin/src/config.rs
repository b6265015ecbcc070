//! The TOML configuration of `skin run`. See `examples/README.md` for the format.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use skinware_drivers::{CablePull, Rate, ScriptedContact, VirtualSkin, VirtualSkinConfig};
use skinware_geometry::{RegionSpec, Selector};

/// A whole configuration file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Skin name: the prefix of every channel.
    #[serde(default = "default_skin")]
    pub skin: String,
    /// Create channels readable by the group too.
    #[serde(default)]
    pub group_access: bool,
    /// Drivers, each run in its own process.
    #[serde(rename = "driver", default)]
    pub drivers: Vec<DriverConfig>,
    /// Named regions of the skin.
    #[serde(rename = "region", default)]
    pub regions: Vec<RegionConfig>,
    /// Services, each run in its own supervised process.
    #[serde(rename = "service", default)]
    pub services: Vec<ServiceConfig>,
    /// The directory of the config file: relative paths in it start there.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// The kinds of service.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum ServiceKind {
    /// Contact detection (`skinware_services::contact`).
    Contact,
    /// Motion detection (`skinware_services::motion`), on a contact service.
    Motion,
}

/// One `[[service]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct ServiceConfig {
    pub name: String,
    pub kind: ServiceKind,
    /// Publishing rate; absent for a sporadic service (one frame per request).
    pub rate_hz: Option<f64>,
    /// Motion: the contact service it reads.
    pub input: Option<String>,
    /// Contact: touch threshold in noise standard deviations.
    pub threshold_sigma: Option<f32>,
    /// Contact: minimum touch threshold, response units.
    pub min_threshold: Option<f32>,
    /// Contact: time constant of the baseline (drift compensation), seconds.
    pub baseline_tau_s: Option<f32>,
    /// Motion: slower than this (m/s) is not sliding.
    pub min_speed: Option<f64>,
    /// Motion: velocity fitting window, seconds.
    pub window_s: Option<f64>,
    #[serde(default)]
    pub restart: RestartConfig,
}

impl ServiceConfig {
    /// Periodic at `rate_hz`, or sporadic.
    pub fn mode(&self) -> skinware_services::framework::ServiceMode {
        match self.rate_hz {
            Some(hz) => skinware_services::framework::ServiceMode::Periodic { hz },
            None => skinware_services::framework::ServiceMode::Sporadic,
        }
    }

    /// The contact service's settings.
    pub fn contact(&self) -> skinware_services::ContactServiceConfig {
        let defaults = skinware_services::ContactParams::default();
        skinware_services::ContactServiceConfig {
            name: self.name.clone(),
            mode: self.mode(),
            params: skinware_services::ContactParams {
                threshold_sigma: self.threshold_sigma.unwrap_or(defaults.threshold_sigma),
                min_threshold: self.min_threshold.unwrap_or(defaults.min_threshold),
                baseline_tau_s: self.baseline_tau_s.unwrap_or(defaults.baseline_tau_s),
                ..defaults
            },
        }
    }

    /// The motion service's settings.
    pub fn motion(&self) -> skinware_services::MotionServiceConfig {
        let defaults = skinware_services::MotionParams::default();
        skinware_services::MotionServiceConfig {
            name: self.name.clone(),
            mode: self.mode(),
            input: self.input.clone().unwrap_or_else(|| "contact".into()),
            params: skinware_services::MotionParams {
                min_speed: self.min_speed.unwrap_or(defaults.min_speed),
                window_s: self.window_s.unwrap_or(defaults.window_s),
                ..defaults
            },
        }
    }

    fn check(&self, services: &[ServiceConfig]) -> Result<()> {
        skinware::shm::validate_name("service", &self.name)?;
        self.restart.check()?;
        if let Some(hz) = self.rate_hz {
            if !(hz.is_finite() && (0.001..=10_000.0).contains(&hz)) {
                bail!("rate_hz {hz} must be from 0.001 to 10000 (or absent for a sporadic service)");
            }
        }
        let positive = |what: &str, v: Option<f64>| -> Result<()> {
            match v {
                Some(v) if !(v.is_finite() && v > 0.0) => bail!("{what} {v} must be above 0"),
                _ => Ok(()),
            }
        };
        positive("threshold_sigma", self.threshold_sigma.map(f64::from))?;
        positive("min_threshold", self.min_threshold.map(f64::from))?;
        positive("baseline_tau_s", self.baseline_tau_s.map(f64::from))?;
        positive("min_speed", self.min_speed)?;
        positive("window_s", self.window_s)?;
        let contact_only = [
            ("threshold_sigma", self.threshold_sigma.is_some()),
            ("min_threshold", self.min_threshold.is_some()),
            ("baseline_tau_s", self.baseline_tau_s.is_some()),
        ];
        let motion_only = [
            ("input", self.input.is_some()),
            ("min_speed", self.min_speed.is_some()),
            ("window_s", self.window_s.is_some()),
        ];
        let (foreign, kind) = match self.kind {
            ServiceKind::Contact => (&motion_only, "contact"),
            ServiceKind::Motion => (&contact_only, "motion"),
        };
        if let Some((key, _)) = foreign.iter().find(|(_, set)| *set) {
            bail!("`{key}` does not apply to a {kind} service");
        }
        if self.kind == ServiceKind::Motion {
            let input = self.input.as_deref().unwrap_or("contact");
            match services.iter().find(|s| s.name == input && s.kind == ServiceKind::Contact) {
                None => bail!("its input {input:?} is not a contact service of this config; add one or set `input`"),
                Some(contact) if contact.rate_hz.is_none() => {
                    bail!("its input {input:?} is sporadic; give the contact service a rate_hz to track motion on it")
                }
                Some(_) => {}
            }
        }
        Ok(())
    }
}

/// Sensors chosen by id, in one layer (`[[region.in_layer]]`) or in all of them.
struct IdSelection<'a> {
    uids: &'a [u32],
    uid_range: Option<[u32; 2]>,
    modules: &'a [u32],
    patches: &'a [u32],
}

/// `[[region.in_layer]]`: ids of one layer. Its id fields repeat
/// [`RegionConfig`]'s on purpose: serde's `flatten` would lose
/// `deny_unknown_fields` and the line:column of errors.
#[derive(Debug, Deserialize, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InLayer {
    pub layer: String,
    #[serde(default)]
    pub uids: Vec<u32>,
    pub uid_range: Option<[u32; 2]>,
    #[serde(default)]
    pub modules: Vec<u32>,
    #[serde(default)]
    pub patches: Vec<u32>,
}

/// `near = { point = [x, y, z], radius = r }`, metres.
#[derive(Debug, Deserialize, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Near {
    pub point: [f64; 3],
    pub radius: f64,
}

/// One `[[region]]`: the union of everything it names.
#[derive(Debug, Deserialize, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RegionConfig {
    pub name: String,
    #[serde(default)]
    pub uids: Vec<u32>,
    pub uid_range: Option<[u32; 2]>,
    #[serde(default)]
    pub modules: Vec<u32>,
    #[serde(default)]
    pub patches: Vec<u32>,
    #[serde(default)]
    pub links: Vec<String>,
    pub near: Option<Near>,
    #[serde(default, rename = "in_layer")]
    pub in_layers: Vec<InLayer>,
}

impl IdSelection<'_> {
    fn selectors(&self, layer: Option<&str>, region: &str, out: &mut Vec<Selector>) -> Result<()> {
        let layer = layer.map(str::to_owned);
        let mut uids = self.uids.to_vec();
        if let Some([first, last]) = self.uid_range {
            if first > last {
                bail!("region {region}: uid_range [{first}, {last}] is backwards");
            }
            if last - first >= 1_000_000 {
                bail!(
                    "region {region}: uid_range [{first}, {last}] spans more than a million uids; split it or use modules/patches"
                );
            }
            uids.extend(first..=last);
        }
        if !uids.is_empty() {
            out.push(Selector::Uids { layer: layer.clone(), uids });
        }
        if !self.modules.is_empty() {
            out.push(Selector::Modules { layer: layer.clone(), ids: self.modules.to_vec() });
        }
        if !self.patches.is_empty() {
            out.push(Selector::Patches { layer, ids: self.patches.to_vec() });
        }
        Ok(())
    }
}

impl RegionConfig {
    /// The library's form of this region.
    pub fn spec(&self) -> Result<RegionSpec> {
        let mut selectors = Vec::new();
        let ids =
            IdSelection { uids: &self.uids, uid_range: self.uid_range, modules: &self.modules, patches: &self.patches };
        ids.selectors(None, &self.name, &mut selectors)?;
        for link in &self.links {
            selectors.push(Selector::Link(link.clone()));
        }
        if let Some(near) = &self.near {
            selectors.push(Selector::Near { point: near.point, radius: near.radius });
        }
        for in_layer in &self.in_layers {
            let ids = IdSelection {
                uids: &in_layer.uids,
                uid_range: in_layer.uid_range,
                modules: &in_layer.modules,
                patches: &in_layer.patches,
            };
            ids.selectors(Some(&in_layer.layer), &self.name, &mut selectors)?;
        }
        Ok(RegionSpec { name: self.name.clone(), selectors })
    }
}

fn default_skin() -> String {
    "default".into()
}

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

/// The file whose existence pulls the cable of `layer` (see `skin pull`).
pub fn pull_file(skin: &str, layer: &str) -> PathBuf {
    skinware::shm::segment_dir().join(format!("skinware-ctl.{skin}.{layer}.pulled"))
}

impl Config {
    /// Reads and checks a configuration file: syntax errors come with
    /// file:line:column, and every driver is built once to check its topology.
    pub fn load(path: &Path) -> Result<Config> {
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read config {}", path.display()))?;
        let mut config: Config = toml::from_str(&text).map_err(|e| {
            let (line, column) = e.span().map(|span| line_column(&text, span.start)).unwrap_or((1, 1));
            anyhow::anyhow!("{}:{line}:{column}: {}", path.display(), e.message())
        })?;
        skinware::shm::validate_name("skin", &config.skin).with_context(|| format!("{}: `skin`", path.display()))?;
        if config.drivers.is_empty() {
            bail!("{}: no [[driver]] table; add at least one driver (see examples/)", path.display());
        }
        let mut names = std::collections::HashSet::new();
        for driver in &config.drivers {
            if !names.insert(&driver.name) {
                bail!("{}: driver name {:?} is used twice; driver names must be unique", path.display(), driver.name);
            }
            driver.restart.check().with_context(|| format!("{}: driver {:?}", path.display(), driver.name))?;
            driver.build(&config.skin).with_context(|| format!("{}: driver {:?}", path.display(), driver.name))?;
        }
        let mut channels: std::collections::HashSet<String> = std::collections::HashSet::new();
        for driver in &config.drivers {
            for spec in skinware::Driver::layers(&driver.build(&config.skin)?) {
                channels.insert(spec.topology.name);
            }
        }
        for service in &config.services {
            service
                .check(&config.services)
                .with_context(|| format!("{}: service {:?}", path.display(), service.name))?;
            for channel in [service.name.clone(), skinware_services::taxel_channel(&service.name)] {
                if !channels.insert(channel.clone()) {
                    bail!(
                        "{}: channel name {channel:?} is used twice (layers and services share names)",
                        path.display()
                    );
                }
            }
        }
        for region in &config.regions {
            region.spec().with_context(|| format!("{}", path.display()))?;
        }
        config.base_dir = path.parent().map(Path::to_owned).unwrap_or_default();
        Ok(config)
    }

    /// The service called `name`.
    pub fn service(&self, name: &str) -> Result<&ServiceConfig> {
        self.services.iter().find(|s| s.name == name).with_context(|| format!("no service {name:?} in the config"))
    }

    /// The driver called `name`.
    pub fn driver(&self, name: &str) -> Result<&DriverConfig> {
        self.drivers.iter().find(|d| d.name == name).with_context(|| format!("no driver {name:?} in the config"))
    }
}

fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rfind('\n').map_or(before.len(), |nl| before.len() - nl - 1) + 1;
    (line, column)
}

impl RestartConfig {
    fn check(&self) -> Result<()> {
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

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str) -> Result<Config> {
        let path = std::env::temp_dir().join(format!("skin-config-test-{}-{}.toml", std::process::id(), text.len()));
        std::fs::write(&path, text).unwrap();
        let result = Config::load(&path);
        let _ = std::fs::remove_file(&path);
        result
    }

    #[test]
    fn syntax_errors_name_line_and_column() {
        let err = load("skin = \"a\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nlayers = \"two\"\n").unwrap_err();
        let message = format!("{err:#}");
        assert!(message.contains(":5:10:"), "{message}");
        assert!(message.contains("invalid type"), "{message}");
    }

    #[test]
    fn unknown_keys_are_rejected() {
        let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nlayerz = 2\n").unwrap_err();
        let message = format!("{err:#}");
        assert!(message.contains(":4:1:") && message.contains("unknown field `layerz`"), "{message}");
    }

    #[test]
    fn inconsistent_parameters_are_rejected() {
        let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 3\nlayers = 5\n").unwrap_err();
        assert!(format!("{err:#}").contains("3 sensors cannot be split over 5 layers"), "{err:#}");
        let err = load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\n[[driver.cable_pull]]\nlayer = \"v-9\"\nat_s = 1\nduration_s = 1\n")
            .unwrap_err();
        assert!(format!("{err:#}").contains("v-9"), "{err:#}");
    }

    const EXPLICIT: &str = "[[driver]]\nname = \"v\"\nkind = \"virtual\"\nrate_hz = 50\n[[driver.layer]]\nname = \"palm\"\nsensors = SENSORS\n[[driver.layer.patch]]\nid = 1\n[[driver.layer.patch.module]]\nid = 1\nuid_range = [1, 12]\n[[driver.layer.patch.module]]\nid = 2\nuids = [UIDS]\n";

    fn explicit(sensors: &str, uids: &str) -> Result<Config> {
        load(&EXPLICIT.replace("SENSORS", sensors).replace("UIDS", uids))
    }

    #[test]
    fn explicit_topology_is_checked() {
        let config = explicit("15", "13, 14, 15").unwrap();
        let driver = config.drivers[0].build("s").unwrap();
        let layers = skinware::Driver::layers(&driver);
        assert_eq!(layers[0].topology.sensors.len(), 15);
        assert_eq!(layers[0].topology.rate_hz, 50.0);

        let err = format!("{:#}", explicit("15", "12, 14, 15").unwrap_err());
        assert!(err.contains("uid 12 appears more than once (modules 1 and 2)"), "{err}");
        let err = format!("{:#}", explicit("15", "").unwrap_err());
        assert!(err.contains("module 2 is empty"), "{err}");
        let err = format!(
            "{:#}",
            load("[[driver]]\nname = \"v\"\nkind = \"virtual\"\nrestart = { min_backoff_s = -1, max_backoff_s = 1 }\n")
                .unwrap_err()
        );
        assert!(err.contains("restart backoff"), "{err}");
        let err = format!("{:#}", explicit("20", "13, 14, 15").unwrap_err());
        assert!(err.contains("declares 20 sensors but its modules hold 15"), "{err}");
    }

    const DRIVER: &str = "[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 600\nlayers = 2\n";

    fn with(extra: &str) -> Result<Config> {
        load(&format!("{DRIVER}{extra}"))
    }

    #[test]
    fn services_are_checked() {
        let ok = with("[[service]]\nname = \"contact\"\nkind = \"contact\"\nrate_hz = 50\n[[service]]\nname = \"motion\"\nkind = \"motion\"\n").unwrap();
        assert_eq!(ok.services.len(), 2);
        assert_eq!(ok.services[1].mode(), skinware_services::framework::ServiceMode::Sporadic);
        let err = format!("{:#}", with("[[service]]\nname = \"m\"\nkind = \"motion\"\nrate_hz = 50\n").unwrap_err());
        assert!(err.contains("service \"m\"") && err.contains("input \"contact\" is not a contact service"), "{err}");
        let err = format!("{:#}", with("[[service]]\nname = \"c\"\nkind = \"contact\"\nmin_speed = 1\n").unwrap_err());
        assert!(err.contains("`min_speed` does not apply to a contact service"), "{err}");
        let err = format!("{:#}", with("[[service]]\nname = \"c\"\nkind = \"contact\"\nrate_hz = -5\n").unwrap_err());
        assert!(err.contains("rate_hz -5 must be from 0.001 to 10000"), "{err}");
        let err = format!("{:#}", with("[[service]]\nname = \"v-1\"\nkind = \"contact\"\n").unwrap_err());
        assert!(err.contains("channel name \"v-1\" is used twice"), "{err}");
        let err = format!("{:#}", with("[[service]]\nname = \"c\"\nkind = \"vision\"\n").unwrap_err());
        assert!(err.contains(":8:8:") && err.contains("unknown variant `vision`"), "{err}");
    }

    #[test]
    fn regions_are_checked() {
        let ok = with("[[region]]\nname = \"arms\"\nlinks = [\"left_forearm\"]\nmodules = [1]\nnear = { point = [0, 0, 1], radius = 0.1 }\n[[region.in_layer]]\nlayer = \"v-1\"\nuid_range = [400, 410]\n").unwrap();
        let spec = ok.regions[0].spec().unwrap();
        assert_eq!(spec.selectors.len(), 4);
        let err = format!("{:#}", with("[[region]]\nname = \"r\"\nuid_range = [9, 3]\n").unwrap_err());
        assert!(err.contains("uid_range [9, 3] is backwards"), "{err}");
        let err = format!("{:#}", with("[[region]]\nname = \"r\"\nlink = \"torso\"\n").unwrap_err());
        assert!(err.contains("unknown field `link`"), "{err}");
        // Resolving against the skin happens when the geometry is built.
        let config = with("[[region]]\nname = \"r\"\nlinks = [\"tail\"]\n").unwrap();
        let err = format!("{:#}", crate::geometry::load_or_build_in(&config, &std::env::temp_dir()).unwrap_err());
        assert!(err.contains("region \"r\": no sensor is on link \"tail\""), "{err}");
    }

    #[test]
    fn a_skin_calib_calibration_is_imported() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/calibrated-hand.toml");
        let config = Config::load(&path).unwrap();
        let cache = std::env::temp_dir().join(format!("skin-calib-test-{}", std::process::id()));
        let (geometry, _) = crate::geometry::load_or_build_in(&config, &cache).unwrap();
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
        config.drivers = vec![crate::config::DriverConfig { calibration: Some("missing.calib".into()), ..broken }];
        let err = format!("{:#}", crate::geometry::load_or_build_in(&config, &std::env::temp_dir()).unwrap_err());
        assert!(err.contains("missing.calib") && err.contains("cannot read it"), "{err}");
    }

    #[test]
    fn example_configs_load() {
        let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
        let mut loaded = 0;
        for entry in std::fs::read_dir(&examples).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                Config::load(&path).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
                loaded += 1;
            }
        }
        assert!(loaded >= 2);
    }
}
