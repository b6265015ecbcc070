//! The configurations the benches run the paper's virtual skin with: its
//! layers (and services) at another rate, and at another size.

#![forbid(unsafe_code)]

use anyhow::{Result, bail};

/// `examples/paper-virtual-skin.toml`, as the benches start from it.
pub const PAPER_SKIN: &str = include_str!("../../../examples/paper-virtual-skin.toml");
/// Taxels of the paper's skin.
pub const PAPER_TAXELS: usize = 30_848;
/// Layers of the paper's skin.
pub const PAPER_LAYERS: usize = 5;

/// Refuses a `--taxels` the paper's 5 layers cannot be given: at least one
/// taxel per layer, at most 1,000,000.
pub fn check_taxels(taxels: Option<usize>) -> Result<()> {
    if let Some(taxels) = taxels
        && !(PAPER_LAYERS..=1_000_000).contains(&taxels)
    {
        bail!("--taxels {taxels}: give from {PAPER_LAYERS} (one per layer) to 1,000,000");
    }
    Ok(())
}

/// How the paper's skin is changed for a bench.
#[derive(Clone, Debug)]
pub struct PaperSkin {
    /// Every layer's rate (and the services', if kept), Hz.
    pub rate_hz: f64,
    /// Taxels over the 5 layers; the paper's 30,848 if `None`.
    pub taxels: Option<usize>,
    /// Keep the contact and motion services (at `rate_hz`).
    pub services: bool,
    /// `reader_wake` of the layers' writers, as in `[driver.rt]`; the default if `None`.
    pub reader_wake: Option<&'static str>,
}

impl PaperSkin {
    /// The paper's skin at `rate_hz`, with its services.
    pub fn at(rate_hz: f64) -> PaperSkin {
        PaperSkin { rate_hz, taxels: None, services: true, reader_wake: None }
    }

    /// The configuration's text. Its frame buffers are left to `skin run`,
    /// which keeps 20 ms of frames at any rate (`skinware::slots_for_history`).
    pub fn config(&self) -> Result<String> {
        let layers_at = "rate_hz = { random = [30, 50] }";
        let sensors = format!("sensors = {PAPER_TAXELS}\n");
        let slots = "slots = 3\n";
        let rt = "[driver.rt]\n";
        for (needed, count) in [(layers_at, 1), (sensors.as_str(), 1), (slots, 1), (rt, 1), ("rate_hz = 50", 2)] {
            if PAPER_SKIN.matches(needed).count() != count {
                bail!("examples/paper-virtual-skin.toml no longer has {count} of {needed:?}; update skin_config.rs");
            }
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            bail!("a rate of {} Hz: give a positive number", self.rate_hz);
        }
        let rate = format!("rate_hz = {}", self.rate_hz);
        let mut text = PAPER_SKIN.replace(layers_at, &rate).replace(slots, "");
        if let Some(taxels) = self.taxels {
            text = text.replace(&sensors, &format!("sensors = {taxels}\n"));
        }
        if let Some(wake) = self.reader_wake {
            text = text.replace(rt, &format!("{rt}reader_wake = \"{wake}\"\n"));
        }
        Ok(match text.split_once("[[service]]") {
            Some((skin, services)) if self.services => {
                format!("{skin}[[service]]{}", services.replace("rate_hz = 50", &rate))
            }
            Some((skin, _)) => skin.to_owned(),
            None => bail!("examples/paper-virtual-skin.toml has no services; update skin_config.rs"),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paper_skin_changes_rate_size_and_services() {
        let text = PaperSkin { rate_hz: 1000.0, taxels: Some(100_000), services: true, reader_wake: Some("writer") }
            .config()
            .unwrap();
        assert_eq!(text.matches("rate_hz = 1000").count(), 3, "{text}");
        assert!(text.contains("sensors = 100000\n") && !text.contains("slots = 3"), "{text}");
        assert!(text.contains("[driver.rt]\nreader_wake = \"writer\"\n"), "{text}");
        let alone = PaperSkin { services: false, ..PaperSkin::at(500.0) }.config().unwrap();
        assert!(!alone.contains("[[service]]") && alone.contains("rate_hz = 500"), "{alone}");
        assert!(PaperSkin::at(f64::NAN).config().is_err());
    }
}
