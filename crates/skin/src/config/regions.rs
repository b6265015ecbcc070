//! `[[region]]` tables: named sets of sensors, by id, link or distance.

use anyhow::{Result, bail};
use serde::Deserialize;
use skinware_geometry::{RegionSpec, Selector};

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
    /// The layer's name.
    pub layer: String,
    /// Sensors of the layer by uid.
    #[serde(default)]
    pub uids: Vec<u32>,
    /// Sensors of the layer by an inclusive range of uids.
    pub uid_range: Option<[u32; 2]>,
    /// Every sensor of these modules of the layer.
    #[serde(default)]
    pub modules: Vec<u32>,
    /// Every sensor of these patches of the layer.
    #[serde(default)]
    pub patches: Vec<u32>,
}

/// `near = { point = [x, y, z], radius = r }`, metres.
#[derive(Debug, Deserialize, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Near {
    /// Centre, metres.
    pub point: [f64; 3],
    /// Distance from the centre, metres.
    pub radius: f64,
}

/// One `[[region]]`: the union of everything it names.
#[derive(Debug, Deserialize, Clone, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RegionConfig {
    /// The region's name.
    pub name: String,
    /// Sensors by uid, in every layer.
    #[serde(default)]
    pub uids: Vec<u32>,
    /// Sensors by an inclusive range of uids, in every layer.
    pub uid_range: Option<[u32; 2]>,
    /// Every sensor of these modules, in every layer.
    #[serde(default)]
    pub modules: Vec<u32>,
    /// Every sensor of these patches, in every layer.
    #[serde(default)]
    pub patches: Vec<u32>,
    /// Every sensor on these robot links.
    #[serde(default)]
    pub links: Vec<String>,
    /// Every sensor near a point.
    pub near: Option<Near>,
    /// Sensors by id in one layer (`[[region.in_layer]]`).
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
    /// Checks that no `uid_range` spans more uids than the skin's `sensors`
    /// (every uid of a range must exist, and the range is expanded into a
    /// list of them), then that the region has a spec.
    /// Checks that every `[[region.in_layer]]` names one of `layers`, the
    /// config's (whose names are known before the skin runs).
    pub(super) fn check_layers(&self, layers: &[String]) -> Result<()> {
        for in_layer in &self.in_layers {
            if layers.contains(&in_layer.layer) {
                continue;
            }
            let hint = match crate::suggest::closest(&in_layer.layer, layers.iter().map(String::as_str)) {
                Some(name) => format!("did you mean {name:?}? "),
                None => String::new(),
            };
            bail!(
                "region {:?}: layer {:?} is not a layer of this config; {hint}its layers: {}",
                self.name,
                in_layer.layer,
                crate::suggest::list(layers, 20)
            );
        }
        Ok(())
    }

    pub(super) fn check(&self, sensors: usize) -> Result<()> {
        let ranges = std::iter::once(self.uid_range).chain(self.in_layers.iter().map(|l| l.uid_range));
        for [first, last] in ranges.flatten() {
            let span = u64::from(last.saturating_sub(first)) + 1;
            if first <= last && span > sensors as u64 {
                bail!(
                    "region {}: uid_range [{first}, {last}] spans {span} uids, more than the skin's {sensors} sensors",
                    self.name
                );
            }
        }
        self.spec()?;
        Ok(())
    }

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
