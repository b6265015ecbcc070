//! Regions: named, possibly overlapping sets of sensors, and the sub-regions
//! (disjoint pieces) they cut the skin into.

#![forbid(unsafe_code)]

use std::collections::HashMap;

use super::GeometryError;

/// One way of choosing sensors. A region is the union of its selectors.
#[derive(Clone, Debug, PartialEq)]
pub enum Selector {
    /// Sensors by uid, in one layer or (without `layer`) in every layer.
    Uids {
        /// Restrict to this layer.
        layer: Option<String>,
        /// The uids.
        uids: Vec<u32>,
    },
    /// Every sensor of these modules.
    Modules {
        /// Restrict to this layer.
        layer: Option<String>,
        /// Module ids.
        ids: Vec<u32>,
    },
    /// Every sensor of these patches.
    Patches {
        /// Restrict to this layer.
        layer: Option<String>,
        /// Patch ids.
        ids: Vec<u32>,
    },
    /// Every sensor on a robot link.
    Link(String),
    /// Every sensor within `radius` metres of `point`.
    Near {
        /// Centre, metres.
        point: [f64; 3],
        /// Distance, metres.
        radius: f64,
    },
}

/// A region as the user defines it.
#[derive(Clone, Debug, PartialEq)]
pub struct RegionSpec {
    /// Its name, unique.
    pub name: String,
    /// The union of these.
    pub selectors: Vec<Selector>,
}

/// What the selectors need to know of each sensor.
pub(crate) struct SensorFacts<'a> {
    pub layer: &'a str,
    pub uid: u32,
    pub module_id: u32,
    pub patch_id: u32,
    pub link: &'a str,
    pub position: [f64; 3],
}

/// Regions resolved to sensors, and their sub-regions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RegionIndex {
    /// Region names.
    pub names: Vec<String>,
    /// Each region's sensors (global indices, ascending).
    pub sensors: Vec<Vec<u32>>,
    /// Each region's sub-regions.
    pub subregions_of: Vec<Vec<u32>>,
    /// Each sub-region's sensors (ascending); sub-regions are disjoint.
    pub subregion_sensors: Vec<Vec<u32>>,
    /// Each sub-region's regions.
    pub regions_of: Vec<Vec<u32>>,
}

impl RegionIndex {
    /// Resolves `specs` against the sensors.
    pub(crate) fn build(specs: &[RegionSpec], facts: &[SensorFacts<'_>]) -> Result<RegionIndex, GeometryError> {
        let error = |region: &str, message: String| GeometryError::Region { region: region.to_owned(), message };
        let mut sensors = Vec::with_capacity(specs.len());
        let mut seen = HashMap::new();
        for spec in specs {
            if seen.insert(spec.name.as_str(), ()).is_some() {
                return Err(error(&spec.name, "is defined twice; region names must be unique".into()));
            }
            if spec.name.is_empty() || spec.name.chars().any(|c| c.is_whitespace() || c.is_control()) {
                return Err(error(&spec.name, "a region name must be one word".into()));
            }
            if spec.selectors.is_empty() {
                return Err(error(
                    &spec.name,
                    "has no selector; give uids, modules, patches, a link or a point".into(),
                ));
            }
            let mut chosen = vec![false; facts.len()];
            for selector in &spec.selectors {
                select(selector, facts, &mut chosen).map_err(|m| error(&spec.name, m))?;
            }
            let list: Vec<u32> = (0..facts.len() as u32).filter(|&i| chosen[i as usize]).collect();
            if list.is_empty() {
                return Err(error(&spec.name, "selects no sensor".into()));
            }
            sensors.push(list);
        }
        Ok(RegionIndex::from_sets(specs.iter().map(|s| s.name.clone()).collect(), sensors, facts.len()))
    }

    /// Computes sub-regions from resolved region sets over `sensor_count` sensors.
    pub fn from_sets(names: Vec<String>, sensors: Vec<Vec<u32>>, sensor_count: usize) -> RegionIndex {
        // Each sensor's signature: the ascending list of regions holding it.
        let mut signature: Vec<Vec<u32>> = vec![Vec::new(); sensor_count];
        for (region, list) in sensors.iter().enumerate() {
            for &s in list {
                if signature[s as usize].last() != Some(&(region as u32)) {
                    signature[s as usize].push(region as u32);
                }
            }
        }
        let mut ids: HashMap<&[u32], u32> = HashMap::new();
        let mut subregion_sensors: Vec<Vec<u32>> = Vec::new();
        let mut regions_of: Vec<Vec<u32>> = Vec::new();
        for (s, sig) in signature.iter().enumerate() {
            if sig.is_empty() {
                continue;
            }
            let id = *ids.entry(sig.as_slice()).or_insert_with(|| {
                subregion_sensors.push(Vec::new());
                regions_of.push(sig.clone());
                (subregion_sensors.len() - 1) as u32
            });
            subregion_sensors[id as usize].push(s as u32);
        }
        let mut subregions_of = vec![Vec::new(); names.len()];
        for (sub, regions) in regions_of.iter().enumerate() {
            for &r in regions {
                subregions_of[r as usize].push(sub as u32);
            }
        }
        RegionIndex { names, sensors, subregions_of, subregion_sensors, regions_of }
    }

    /// The index of region `name`.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }
}

fn select(selector: &Selector, facts: &[SensorFacts<'_>], chosen: &mut [bool]) -> Result<(), String> {
    let in_layer = |layer: &Option<String>, f: &SensorFacts<'_>| layer.as_deref().is_none_or(|l| l == f.layer);
    if let Selector::Uids { layer: Some(l), .. }
    | Selector::Modules { layer: Some(l), .. }
    | Selector::Patches { layer: Some(l), .. } = selector
        && !facts.iter().any(|f| f.layer == l)
    {
        return Err(format!("layer {l:?} does not exist; `skin ls` lists the layers"));
    }
    let mut pick = |what: &str, ids: &[u32], key: &dyn Fn(&SensorFacts<'_>) -> Option<u32>| {
        let wanted: HashMap<u32, bool> = ids.iter().map(|&i| (i, false)).collect();
        let mut wanted = wanted;
        for (k, f) in facts.iter().enumerate() {
            if let Some(id) = key(f)
                && let Some(found) = wanted.get_mut(&id)
            {
                *found = true;
                chosen[k] = true;
            }
        }
        let mut missing: Vec<u32> = wanted.into_iter().filter(|(_, f)| !f).map(|(i, _)| i).collect();
        missing.sort_unstable();
        if let Some(first) = missing.first() {
            return Err(format!(
                "{what} {first} does not exist ({} missing in all); check the ids with `skin ls --modules`",
                missing.len()
            ));
        }
        Ok(())
    };
    match selector {
        Selector::Uids { layer, uids } => pick("sensor uid", uids, &|f| in_layer(layer, f).then_some(f.uid)),
        Selector::Modules { layer, ids } => pick("module", ids, &|f| in_layer(layer, f).then_some(f.module_id)),
        Selector::Patches { layer, ids } => pick("patch", ids, &|f| in_layer(layer, f).then_some(f.patch_id)),
        Selector::Link(link) => {
            let mut any = false;
            for (k, f) in facts.iter().enumerate() {
                if f.link == link {
                    chosen[k] = true;
                    any = true;
                }
            }
            if !any {
                let mut links: Vec<&str> = facts.iter().map(|f| f.link).collect();
                links.sort_unstable();
                links.dedup();
                return Err(format!("no sensor is on link {link:?}; the links are {}", links.join(", ")));
            }
            Ok(())
        }
        Selector::Near { point, radius } => {
            if !(point.iter().all(|v| v.is_finite()) && radius.is_finite() && *radius > 0.0) {
                return Err(format!("point {point:?} and radius {radius} must be finite, radius above 0"));
            }
            for (k, f) in facts.iter().enumerate() {
                let d2: f64 = (0..3).map(|a| (f.position[a] - point[a]).powi(2)).sum();
                if d2 <= radius * radius {
                    chosen[k] = true;
                }
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// Sub-regions are disjoint, cover exactly the union of the regions,
        /// every region is the union of its sub-regions, and the two indices
        /// agree.
        #[test]
    #[cfg_attr(miri, ignore = "no unsafe code here; too slow under Miri")]
        fn subregions_partition_the_regions(
            sensor_count in 1usize..200,
            raw in proptest::collection::vec(proptest::collection::vec(0u32..200, 0..60), 0..8),
        ) {
            let sets: Vec<Vec<u32>> = raw
                .into_iter()
                .map(|mut s| {
                    s.retain(|&i| (i as usize) < sensor_count);
                    s.sort_unstable();
                    s.dedup();
                    s
                })
                .collect();
            let names = (0..sets.len()).map(|k| format!("r{k}")).collect();
            let index = RegionIndex::from_sets(names, sets.clone(), sensor_count);
            let mut owner = vec![None; sensor_count];
            for (sub, sensors) in index.subregion_sensors.iter().enumerate() {
                prop_assert!(!sensors.is_empty());
                for &s in sensors {
                    prop_assert!(owner[s as usize].is_none(), "sensor {} in two sub-regions", s);
                    owner[s as usize] = Some(sub);
                }
            }
            for (s, owned) in owner.iter().enumerate() {
                let in_a_region = sets.iter().any(|set| set.contains(&(s as u32)));
                prop_assert_eq!(owned.is_some(), in_a_region);
            }
            for (r, set) in sets.iter().enumerate() {
                let mut union: Vec<u32> =
                    index.subregions_of[r].iter().flat_map(|&sub| index.subregion_sensors[sub as usize].clone()).collect();
                union.sort_unstable();
                prop_assert_eq!(&union, set);
                for &sub in &index.subregions_of[r] {
                    prop_assert!(index.regions_of[sub as usize].contains(&(r as u32)));
                }
            }
            // Two sensors share a sub-region exactly when the same regions hold them.
            for sub in &index.subregion_sensors {
                let first = sub[0];
                for &s in sub {
                    for set in &sets {
                        prop_assert_eq!(set.contains(&s), set.contains(&first));
                    }
                }
            }
        }
    }
}
