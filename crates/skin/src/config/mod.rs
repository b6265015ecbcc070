//! The TOML configuration of `skin run`. See `examples/README.md` for the format.
//!
//! [`Config`] is the file; each kind of table has its own module: drivers,
//! services, regions.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Deserialize;

mod drivers;
mod regions;
mod services;

pub use drivers::{DriverConfig, RestartConfig};
pub use regions::RegionConfig;
pub use services::{ServiceConfig, ServiceKind};

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

fn default_skin() -> String {
    "default".into()
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Loads a config from `text` (written to a temporary file).
    pub(crate) fn load(text: &str) -> Result<Config> {
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

    /// Loads a config of one virtual driver plus `extra`.
    pub(crate) fn with(extra: &str) -> Result<Config> {
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
