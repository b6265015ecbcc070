//! `skin run`'s config parser, lent to `skin bench soak`: the soak
//! (`skinware-bench`) rewrites the config, but cannot read one itself, as
//! `skin` depends on it.

use std::path::Path;

use anyhow::Result;
use skin::config::{Config, ServiceKind};
use skinware_bench::soak::LayerPlan;
use skinware_bench::soak::config::{ConfigParser, SkinPlan};

/// `skin run`'s reading of a config ([`Config`]).
pub struct SkinConfigs;

impl ConfigParser for SkinConfigs {
    fn check(&self, text: &str, path: &Path) -> Result<()> {
        Config::parse(text, path).map(drop)
    }

    fn plan(&self, text: &str, path: &Path, dir: &Path) -> Result<SkinPlan> {
        let parsed = Config::parse(text, path)?;
        let mut layers = Vec::new();
        for driver in &parsed.drivers {
            let built = driver.build(&parsed.skin)?;
            for spec in built.layers() {
                let name = spec.topology.name.clone();
                layers.push(LayerPlan {
                    pull_file: skin::config::pull_file_in(dir, &parsed.skin, &name),
                    taxels: spec.topology.sensors.len(),
                    name,
                });
            }
        }
        let mut services = Vec::new();
        for service in parsed.services.iter().filter(|s| s.rate_hz.is_some()) {
            services.push(service.name.clone());
            if service.kind == ServiceKind::Contact {
                services.push(skinware_services::taxel_channel(&service.name));
            }
        }
        Ok(SkinPlan { skin: parsed.skin, layers, services })
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use skinware_bench::soak::config::prepare;

    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("skin-soak-test-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn the_papers_skin_becomes_a_patterned_skin_with_its_services() {
        let out = scratch("paper");
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/paper-virtual-skin.toml");
        let prepared = prepare(&config, Path::new("/dev/shm/soak-test"), &out, &SkinConfigs).unwrap();
        let plan = &prepared.plan;
        assert_eq!(plan.layers.len(), 5);
        assert_eq!(plan.layers.iter().map(|l| l.taxels).sum::<usize>(), 30_848);
        assert_eq!(plan.layers[2].pull_file, Path::new("/dev/shm/soak-test/skinware-ctl.default.virtual-2.pulled"));
        assert_eq!(plan.services, ["contact", "contact-taxels", "motion"]);
        let written = Config::load(&prepared.path).unwrap();
        assert!(written.drivers.iter().all(|d| d.verify_pattern));
        let _ = std::fs::remove_dir_all(out);
    }

    #[test]
    fn services_are_added_and_other_drivers_refused() {
        let out = scratch("small");
        let config = out.join("small.toml");
        std::fs::write(
            &config,
            "skin = \"s\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 240\nlayers = 2\n",
        )
        .unwrap();
        let prepared = prepare(&config, &out, &out, &SkinConfigs).unwrap();
        assert_eq!(prepared.plan.skin, "s");
        assert_eq!(prepared.plan.services, ["contact", "contact-taxels", "motion"]);
        std::fs::write(
            &config,
            "[[driver]]\nname = \"c\"\nkind = \"can\"\ninterface = \"candump:///x\"\nprotocol = \"icub-mtb\"\n",
        )
        .unwrap();
        let error = format!("{:#}", prepare(&config, &out, &out, &SkinConfigs).err().unwrap());
        assert!(error.contains("virtual") || error.contains("board"), "{error}");
        let _ = std::fs::remove_dir_all(out);
    }
}
