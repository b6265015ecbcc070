//! The soak's version of the user's config: every driver virtual and
//! publishing its verification pattern, relative paths made absolute, and
//! the contact and motion services added to a config that has none.
//!
//! The config is `skin run`'s, and so is its parser (`skin::config`), which
//! this crate cannot depend on: `skin` depends on this crate. The caller
//! lends it as a [`ConfigParser`]; this module only rewrites the TOML.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use super::LayerPlan;

/// `skin run`'s reading of a config, lent by the `skin` command line.
pub trait ConfigParser {
    /// Checks the config `text` (read from `path`) as `skin run` would, for
    /// its clear messages.
    fn check(&self, text: &str, path: &Path) -> Result<()>;

    /// What the config `text` (read from `path`) runs: its skin, its
    /// layers (their pull files in segment directory `dir`) and the
    /// channels of its periodic services.
    fn plan(&self, text: &str, path: &Path, dir: &Path) -> Result<SkinPlan>;
}

/// What a config runs, as the soak needs to know it.
#[derive(Clone, Debug)]
pub struct SkinPlan {
    /// The skin's name.
    pub skin: String,
    /// Every layer of its drivers, in order.
    pub layers: Vec<LayerPlan>,
    /// The channels of its periodic services (a contact service's taxel
    /// channel too).
    pub services: Vec<String>,
}

/// The soak's config, written, and what it runs.
#[derive(Debug)]
pub struct Prepared {
    /// Where it was written (absolute).
    pub path: PathBuf,
    /// What it runs.
    pub plan: SkinPlan,
}

/// The services added to a config that has none.
const SERVICES: &str = "[[service]]\nname = \"contact\"\nkind = \"contact\"\nrate_hz = 50\n\n\
                        [[service]]\nname = \"motion\"\nkind = \"motion\"\ninput = \"contact\"\nrate_hz = 50\n";

/// Writes the soak's version of `config` into `out` (see the module's
/// documentation); its layers' pull files are in segment directory `dir`.
pub fn prepare(config: &Path, dir: &Path, out: &Path, parser: &dyn ConfigParser) -> Result<Prepared> {
    let text = std::fs::read_to_string(config).with_context(|| format!("cannot read config {}", config.display()))?;
    // Checked as `skin run` would, first, for its clear messages.
    parser.check(&text, config)?;
    let value = soak_table(&text, config)?;
    let path = out.join("soak-config.toml");
    let text = format!(
        "# Written by `skin bench soak` from {}: its virtual drivers publish their\n# verification pattern.\n{}",
        config.display(),
        toml::to_string(&value)?
    );
    std::fs::write(&path, &text).with_context(|| format!("cannot write {}", path.display()))?;
    let plan = parser.plan(&text, &path, dir)?;
    if plan.layers.is_empty() {
        bail!("{}: no layers to soak", config.display());
    }
    Ok(Prepared { path: std::fs::canonicalize(&path)?, plan })
}

/// The config `text` (read from `config`) as the soak runs it.
fn soak_table(text: &str, config: &Path) -> Result<toml::Table> {
    let mut value: toml::Table = toml::from_str(text).with_context(|| format!("cannot parse {}", config.display()))?;
    let base = config.parent().map(Path::to_path_buf).unwrap_or_default();
    let base = std::fs::canonicalize(if base.as_os_str().is_empty() { Path::new(".") } else { &base })?;
    if value.get("emulator").is_some() {
        bail!(
            "{}: the soak runs virtual drivers only (its readers check the virtual skin's pattern); remove the [[emulator]] tables",
            config.display()
        );
    }
    let drivers =
        value.get_mut("driver").and_then(toml::Value::as_array_mut).context("the config has no [[driver]]")?;
    for driver in drivers.iter_mut() {
        let table = driver.as_table_mut().context("a [[driver]] that is not a table")?;
        let name = table.get("name").and_then(toml::Value::as_str).unwrap_or("?").to_owned();
        if table.get("kind").and_then(toml::Value::as_str) != Some("virtual") {
            bail!(
                "{}: driver {name} is not kind = \"virtual\": the soak's readers verify every frame against the virtual skin's pattern, which only virtual drivers publish",
                config.display()
            );
        }
        table.insert("verify_pattern".into(), toml::Value::Boolean(true));
        if let Some(calibration) = table.get("calibration").and_then(toml::Value::as_str) {
            let absolute = base.join(calibration).display().to_string();
            table.insert("calibration".into(), toml::Value::String(absolute));
        }
    }
    if value.get("service").is_none() {
        let services = toml::from_str::<toml::Table>(SERVICES)?.remove("service").context("the services")?;
        value.insert("service".into(), services);
    }
    Ok(value)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stand-in for `skin`'s parser: any TOML passes; a layer per
    /// driver, of its `sensors`.
    struct Tables;

    impl ConfigParser for Tables {
        fn check(&self, text: &str, _: &Path) -> Result<()> {
            toml::from_str::<toml::Table>(text)?;
            Ok(())
        }

        fn plan(&self, text: &str, _: &Path, dir: &Path) -> Result<SkinPlan> {
            let table: toml::Table = toml::from_str(text)?;
            let drivers = table.get("driver").and_then(toml::Value::as_array).cloned().unwrap_or_default();
            let layers = drivers
                .iter()
                .map(|driver| LayerPlan {
                    name: driver["name"].as_str().unwrap_or("?").to_owned(),
                    taxels: driver["sensors"].as_integer().unwrap_or(0) as usize,
                    pull_file: dir.join("pulled"),
                })
                .collect();
            Ok(SkinPlan { skin: table["skin"].as_str().unwrap_or("default").to_owned(), layers, services: Vec::new() })
        }
    }

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("skinware-soak-config-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn virtual_drivers_publish_their_pattern_and_get_the_services() {
        let out = scratch("virtual");
        let config = out.join("small.toml");
        let text =
            "skin = \"s\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 240\ncalibration = \"c.toml\"\n";
        std::fs::write(&config, text).unwrap();
        let prepared = prepare(&config, &out, &out, &Tables).unwrap();
        assert_eq!(prepared.plan.skin, "s");
        assert_eq!(prepared.plan.layers[0].taxels, 240);
        let written: toml::Table = toml::from_str(&std::fs::read_to_string(&prepared.path).unwrap()).unwrap();
        let driver = &written["driver"][0];
        assert_eq!(driver["verify_pattern"].as_bool(), Some(true));
        let calibration = driver["calibration"].as_str().unwrap();
        assert_eq!(Path::new(calibration), std::fs::canonicalize(&out).unwrap().join("c.toml"));
        let services: Vec<&str> =
            written["service"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
        assert_eq!(services, ["contact", "motion"]);
        let _ = std::fs::remove_dir_all(out);
    }

    #[test]
    fn other_drivers_and_emulators_are_refused_by_name() {
        let out = scratch("refused");
        let config = out.join("can.toml");
        std::fs::write(&config, "[[driver]]\nname = \"c\"\nkind = \"can\"\n").unwrap();
        let error = format!("{:#}", prepare(&config, &out, &out, &Tables).unwrap_err());
        assert!(error.contains("driver c is not kind = \"virtual\""), "{error}");
        std::fs::write(&config, "[[driver]]\nname = \"v\"\nkind = \"virtual\"\n[[emulator]]\nname = \"e\"\n").unwrap();
        let error = format!("{:#}", prepare(&config, &out, &out, &Tables).unwrap_err());
        assert!(error.contains("remove the [[emulator]] tables"), "{error}");
        let _ = std::fs::remove_dir_all(out);
    }
}
