//! The TOML configuration of `skin run`. See `examples/README.md` for the format.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Deserialize;

pub mod drivers;
mod emulators;
mod process;
mod regions;
mod services;
mod topology;

// What the rest of the crate names; the types nested deeper in a section
// (RtConfig, LayerConfig, InLayer, ...) are reached through their tables.
pub use drivers::{DriverConfig, pull_file, pull_file_in};
pub use emulators::{Emulation, EmulatorConfig};
pub use process::RestartConfig;
pub use regions::RegionConfig;
pub use services::{ServiceConfig, ServiceKind};

/// A whole configuration file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Skin name: the prefix of every channel.
    #[serde(default = "default_skin")]
    pub skin: String,
    /// Who may read the channels: `"owner"` (the default), `"group"` or `"everyone"`.
    #[serde(default)]
    pub access: AccessConfig,
    /// The older spelling of `access = "group"`.
    #[serde(default)]
    pub group_access: bool,
    /// Drivers, each run in its own process.
    #[serde(rename = "driver", default)]
    pub drivers: Vec<DriverConfig>,
    /// Emulated skin boards, started before the drivers.
    #[serde(rename = "emulator", default)]
    pub emulators: Vec<EmulatorConfig>,
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

/// Who may read the channels (see `docs/security.md`).
#[derive(Clone, Copy, Debug, Default, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum AccessConfig {
    /// Only the user that runs the skin.
    #[default]
    Owner,
    /// Also its group.
    Group,
    /// Every local user.
    Everyone,
}

fn default_skin() -> String {
    "default".into()
}

impl Config {
    /// Reads and checks a configuration file: syntax errors come with
    /// file:line:column, and every driver is built once to check its topology.
    pub fn load(path: &Path) -> Result<Config> {
        // A configuration is text a person writes: 16 MiB is far beyond one.
        let text = skinware::shm::read_named_text(path, 16 << 20)
            .with_context(|| format!("cannot read config {}", path.display()))?;
        Config::parse(&text, path)
    }

    /// Parses and checks the text of a configuration file, as [`Config::load`]
    /// does after reading it. `path` names the file in messages, and relative
    /// paths in the config start at its directory; nothing is read from it.
    pub fn parse(text: &str, path: &Path) -> Result<Config> {
        let mut config: Config = toml::from_str(text).map_err(|e| {
            let (line, column) = e.span().map(|span| line_column(text, span.start)).unwrap_or((1, 1));
            let message = crate::suggest::annotate_unknown_name(e.message()).unwrap_or_else(|| e.message().to_owned());
            anyhow::anyhow!("{}:{line}:{column}: {message}", path.display())
        })?;
        skinware::shm::validate_name("skin", &config.skin).with_context(|| format!("{}: `skin`", path.display()))?;
        if config.group_access && config.access == AccessConfig::Everyone {
            bail!("{}: `group_access = true` and `access = \"everyone\"` disagree; keep only `access`", path.display());
        }
        if config.drivers.is_empty() {
            bail!("{}: no [[driver]] table; add at least one driver (see examples/)", path.display());
        }
        let mut names = std::collections::HashSet::new();
        let mut channels: std::collections::HashSet<String> = std::collections::HashSet::new();
        let mut sensors = 0;
        let mut layers = Vec::new();
        for driver in &config.drivers {
            if !names.insert(&driver.name) {
                bail!("{}: driver name {:?} is used twice; driver names must be unique", path.display(), driver.name);
            }
            driver.check().with_context(|| format!("{}: driver {:?}", path.display(), driver.name))?;
            if driver.kind == drivers::DriverKind::Replay {
                // Its layers are in the recording, read when the skin starts: parsing reads no file.
                driver.check_replay().with_context(|| format!("{}: driver {:?}", path.display(), driver.name))?;
                continue;
            }
            let built =
                driver.build(&config.skin).with_context(|| format!("{}: driver {:?}", path.display(), driver.name))?;
            for spec in built.layers() {
                sensors += spec.topology.sensors.len();
                layers.push(spec.topology.name.clone());
                channels.insert(spec.topology.name);
            }
        }
        let mut emulators = std::collections::HashSet::new();
        for emulator in &config.emulators {
            if !emulators.insert(&emulator.name) {
                bail!(
                    "{}: emulator name {:?} is used twice; emulator names must be unique",
                    path.display(),
                    emulator.name
                );
            }
            emulator.check().with_context(|| format!("{}: emulator {:?}", path.display(), emulator.name))?;
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
        config.check_regions(path, sensors, &layers)?;
        config.base_dir = path.parent().map(Path::to_owned).unwrap_or_default();
        for driver in &mut config.drivers {
            if let Some(file) = &driver.file {
                driver.file = Some(config.base_dir.join(file));
            }
        }
        Ok(config)
    }

    /// Checks the regions against the skin's `sensors` and `layers`, which
    /// a replay driver's recording tells only when the skin starts.
    fn check_regions(&self, path: &Path, sensors: usize, layers: &[String]) -> Result<()> {
        let replayed = self.drivers.iter().any(|d| d.kind == drivers::DriverKind::Replay);
        for region in &self.regions {
            region.check(if replayed { usize::MAX } else { sensors }).with_context(|| format!("{}", path.display()))?;
            if !replayed {
                region.check_layers(layers).with_context(|| format!("{}", path.display()))?;
            }
        }
        Ok(())
    }

    /// Who may read the channels, as the library takes it.
    pub fn access(&self) -> skinware::Access {
        match (self.access, self.group_access) {
            (AccessConfig::Everyone, _) => skinware::Access::Everyone,
            (AccessConfig::Group, _) | (_, true) => skinware::Access::Group,
            (AccessConfig::Owner, false) => skinware::Access::Owner,
        }
    }

    /// The service called `name`.
    pub fn service(&self, name: &str) -> Result<&ServiceConfig> {
        self.services.iter().find(|s| s.name == name).with_context(|| format!("no service {name:?} in the config"))
    }

    /// The emulator called `name`.
    pub fn emulator(&self, name: &str) -> Result<&EmulatorConfig> {
        self.emulators.iter().find(|e| e.name == name).with_context(|| format!("no emulator {name:?} in the config"))
    }

    /// The driver called `name`.
    pub fn driver(&self, name: &str) -> Result<&DriverConfig> {
        self.drivers.iter().find(|d| d.name == name).with_context(|| format!("no driver {name:?} in the config"))
    }
}

fn line_column(text: &str, offset: usize) -> (usize, usize) {
    // An offset inside a character (which the parser should not give) counts
    // from that character's start.
    let mut end = offset.min(text.len());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let before = &text[..end];
    let line = before.matches('\n').count() + 1;
    let column = before.rfind('\n').map_or(before.len(), |nl| before.len() - nl - 1) + 1;
    (line, column)
}

#[cfg(test)]
mod tests;
