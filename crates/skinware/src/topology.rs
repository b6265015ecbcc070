//! The skin model of one layer: patches, modules and sensors, published in the
//! layer channel's description area so that any reader gets a typed view.
//!
//! A sensor's index in the layer is its index in every frame of the layer.

#![forbid(unsafe_code)]

use std::collections::HashMap;
use std::ops::Range;

use crate::wire::{DecodeError, Decoder, Encoder};

/// One sensor (taxel).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sensor {
    /// Stable hardware id, unique within the layer.
    pub uid: u32,
    /// Index of its module in [`LayerTopology::modules`].
    pub module: usize,
}

/// A few sensors physically together (e.g. one triangular PCB).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Module {
    /// Hardware id, unique within the layer.
    pub id: u32,
    /// Index of its patch in [`LayerTopology::patches`].
    pub patch: usize,
    /// Its sensors, as indices into [`LayerTopology::sensors`] (and frames).
    pub sensors: Range<usize>,
}

/// A network of modules handled by one microcontroller.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Patch {
    /// Hardware id, unique within the layer.
    pub id: u32,
    /// Its modules, as indices into [`LayerTopology::modules`].
    pub modules: Range<usize>,
}

/// The topology of one layer.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerTopology {
    /// Layer (channel) name.
    pub name: String,
    /// Sensor type, e.g. "pressure".
    pub sensor_type: String,
    /// Nominal acquisition rate, Hz (0 for sporadic).
    pub rate_hz: f64,
    /// Patches in order.
    pub patches: Vec<Patch>,
    /// Modules in order; each patch's modules are contiguous.
    pub modules: Vec<Module>,
    /// Sensors in frame order; each module's sensors are contiguous.
    pub sensors: Vec<Sensor>,
    by_uid: HashMap<u32, usize>,
}

/// A topology that cannot be right, naming the offending ids.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TopologyError {
    /// Two sensors share a uid.
    #[error(
        "layer {layer}: sensor uid {uid} appears more than once (modules {first_module} and {second_module}); uids must be unique within a layer"
    )]
    DuplicateUid {
        /// Layer name.
        layer: String,
        /// The repeated uid.
        uid: u32,
        /// Module id of the first occurrence.
        first_module: u32,
        /// Module id of the second.
        second_module: u32,
    },
    /// Two modules (or patches) share an id.
    #[error("layer {layer}: {what} id {id} appears more than once; ids must be unique within a layer")]
    DuplicateId {
        /// Layer name.
        layer: String,
        /// "module" or "patch".
        what: &'static str,
        /// The repeated id.
        id: u32,
    },
    /// A module without sensors or a patch without modules.
    #[error("layer {layer}: {what} {id} is empty; every patch needs a module and every module a sensor")]
    Empty {
        /// Layer name.
        layer: String,
        /// "module" or "patch".
        what: &'static str,
        /// Its id.
        id: u32,
    },
    /// A layer with no sensors at all.
    #[error("layer {layer} has no sensors")]
    NoSensors {
        /// Layer name.
        layer: String,
    },
    /// The description bytes are not a topology of this version.
    #[error("the topology published in channel {channel} cannot be decoded: {source}")]
    Malformed {
        /// Channel label.
        channel: String,
        /// What was wrong, and where.
        #[source]
        source: DecodeError,
    },
}

/// A patch being built: its id and its modules (id, sensor uids).
type PatchDraft = (u32, Vec<(u32, Vec<u32>)>);

/// A topology under construction: patches of modules of sensor uids.
#[derive(Clone, Debug, Default)]
pub struct TopologyBuilder {
    name: String,
    sensor_type: String,
    rate_hz: f64,
    patches: Vec<PatchDraft>,
}

impl TopologyBuilder {
    /// Starts a layer.
    pub fn new(name: &str, sensor_type: &str, rate_hz: f64) -> TopologyBuilder {
        TopologyBuilder { name: name.to_owned(), sensor_type: sensor_type.to_owned(), rate_hz, patches: Vec::new() }
    }

    /// Adds a patch with id `id`.
    pub fn patch(&mut self, id: u32) -> &mut Self {
        self.patches.push((id, Vec::new()));
        self
    }

    /// Adds a module to the last patch (starting a patch 0 if there is none).
    pub fn module(&mut self, id: u32, uids: impl IntoIterator<Item = u32>) -> &mut Self {
        if self.patches.is_empty() {
            self.patch(0);
        }
        if let Some((_, modules)) = self.patches.last_mut() {
            modules.push((id, uids.into_iter().collect()));
        }
        self
    }

    /// Validates and builds the topology.
    pub fn build(&self) -> Result<LayerTopology, TopologyError> {
        let layer = || self.name.clone();
        let mut topology = LayerTopology {
            name: self.name.clone(),
            sensor_type: self.sensor_type.clone(),
            rate_hz: self.rate_hz,
            patches: Vec::with_capacity(self.patches.len()),
            modules: Vec::new(),
            sensors: Vec::new(),
            by_uid: HashMap::new(),
        };
        let mut patch_ids = HashMap::new();
        let mut module_ids = HashMap::new();
        for (patch_id, modules) in &self.patches {
            if patch_ids.insert(*patch_id, ()).is_some() {
                return Err(TopologyError::DuplicateId { layer: layer(), what: "patch", id: *patch_id });
            }
            if modules.is_empty() {
                return Err(TopologyError::Empty { layer: layer(), what: "patch", id: *patch_id });
            }
            let patch_index = topology.patches.len();
            let first_module = topology.modules.len();
            for (module_id, uids) in modules {
                if module_ids.insert(*module_id, ()).is_some() {
                    return Err(TopologyError::DuplicateId { layer: layer(), what: "module", id: *module_id });
                }
                if uids.is_empty() {
                    return Err(TopologyError::Empty { layer: layer(), what: "module", id: *module_id });
                }
                let module_index = topology.modules.len();
                let first_sensor = topology.sensors.len();
                for &uid in uids {
                    if let Some(&previous) = topology.by_uid.get(&uid) {
                        // The first occurrence may be in this very module, not
                        // pushed yet.
                        let first_module = topology.modules.get(topology.sensors[previous].module);
                        return Err(TopologyError::DuplicateUid {
                            layer: layer(),
                            uid,
                            first_module: first_module.map_or(*module_id, |m| m.id),
                            second_module: *module_id,
                        });
                    }
                    topology.by_uid.insert(uid, topology.sensors.len());
                    topology.sensors.push(Sensor { uid, module: module_index });
                }
                topology.modules.push(Module {
                    id: *module_id,
                    patch: patch_index,
                    sensors: first_sensor..topology.sensors.len(),
                });
            }
            topology.patches.push(Patch { id: *patch_id, modules: first_module..topology.modules.len() });
        }
        if topology.sensors.is_empty() {
            return Err(TopologyError::NoSensors { layer: layer() });
        }
        Ok(topology)
    }
}

const TOPOLOGY_MAGIC: &[u8; 8] = b"SKTOPO01";

impl LayerTopology {
    /// Index (in frames) of the sensor with hardware id `uid`.
    pub fn sensor_by_uid(&self, uid: u32) -> Option<usize> {
        self.by_uid.get(&uid).copied()
    }

    /// The module a sensor belongs to.
    pub fn module_of(&self, sensor: usize) -> Option<&Module> {
        self.sensors.get(sensor).map(|s| &self.modules[s.module])
    }

    /// The patch a sensor belongs to.
    pub fn patch_of(&self, sensor: usize) -> Option<&Patch> {
        self.module_of(sensor).map(|m| &self.patches[m.patch])
    }

    /// Frame payload size of this layer: one `u16` per sensor.
    pub fn frame_bytes(&self) -> usize {
        self.sensors.len() * 2
    }

    /// Serialises the topology for a channel's description area, in the
    /// [`wire`](crate::wire) encoding:
    /// `SKTOPO01`, name, sensor type, rate (f64), then the patches, each with
    /// its id and its modules, each with its id and its sensors' uids.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Encoder::with_capacity(TOPOLOGY_MAGIC, 64 + self.sensors.len() * 4 + self.modules.len() * 12);
        out.str(&self.name);
        out.str(&self.sensor_type);
        out.f64(self.rate_hz);
        out.count(self.patches.len());
        let uids: Vec<u32> = self.sensors.iter().map(|s| s.uid).collect();
        for patch in &self.patches {
            out.u32(patch.id);
            out.count(patch.modules.len());
            for module in &self.modules[patch.modules.clone()] {
                out.u32(module.id);
                out.u32s(&uids[module.sensors.clone()]);
            }
        }
        out.finish()
    }

    /// Reads a topology from a channel's description area; `channel` names it in errors.
    pub fn decode(bytes: &[u8], channel: &str) -> Result<LayerTopology, TopologyError> {
        let malformed = |source| TopologyError::Malformed { channel: channel.to_owned(), source };
        let mut input = Decoder::new(bytes, "topology", TOPOLOGY_MAGIC).map_err(malformed)?;
        let name = input.str("layer name").map_err(malformed)?;
        let sensor_type = input.str("sensor type").map_err(malformed)?;
        let rate_hz = input.f64("rate").map_err(malformed)?;
        let mut builder = TopologyBuilder::new(&name, &sensor_type, rate_hz);
        // A patch is at least its id and module count; a module its id and sensor count.
        let patches = input.count("patches", 8).map_err(malformed)?;
        for _ in 0..patches {
            builder.patch(input.u32("patch id").map_err(malformed)?);
            let modules = input.count("modules", 8).map_err(malformed)?;
            for _ in 0..modules {
                let id = input.u32("module id").map_err(malformed)?;
                builder.module(id, input.u32s("sensor uids").map_err(malformed)?);
            }
        }
        input.finish().map_err(malformed)?;
        builder.build()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> LayerTopology {
        let mut builder = TopologyBuilder::new("arm", "pressure", 40.0);
        builder.patch(7).module(1, [100, 101, 102]).module(2, [103]);
        builder.patch(8).module(3, [200, 201]);
        builder.build().unwrap()
    }

    #[test]
    fn hierarchy_both_ways_and_uid_lookup() {
        let topology = sample();
        assert_eq!(topology.sensors.len(), 6);
        let sensor = topology.sensor_by_uid(201).unwrap();
        assert_eq!(sensor, 5);
        assert_eq!(topology.module_of(sensor).unwrap().id, 3);
        assert_eq!(topology.patch_of(sensor).unwrap().id, 8);
        assert_eq!(topology.patches[0].modules, 0..2);
        assert_eq!(topology.modules[1].sensors, 3..4);
        assert_eq!(topology.sensor_by_uid(999), None);
    }

    #[test]
    fn encoding_round_trips() {
        let topology = sample();
        assert_eq!(LayerTopology::decode(&topology.encode(), "s/arm").unwrap(), topology);
    }

    #[test]
    fn malformed_descriptions_are_errors_not_panics() {
        let bytes = sample().encode();
        for cut in 0..bytes.len() {
            assert!(LayerTopology::decode(&bytes[..cut], "s/arm").is_err(), "cut at {cut}");
        }
        assert!(matches!(LayerTopology::decode(b"stress", "s/x"), Err(TopologyError::Malformed { .. })));
        let mut trailing = bytes.clone();
        trailing.push(0);
        let err = LayerTopology::decode(&trailing, "s/arm").unwrap_err();
        assert!(err.to_string().contains(&format!("at byte {}", bytes.len())), "{err}");
    }

    #[test]
    fn inconsistent_topologies_name_the_offending_ids() {
        let mut dup = TopologyBuilder::new("l", "p", 1.0);
        dup.patch(1).module(1, [5, 6]).module(2, [6]);
        assert_eq!(
            dup.build().unwrap_err(),
            TopologyError::DuplicateUid { layer: "l".into(), uid: 6, first_module: 1, second_module: 2 }
        );
        // A uid repeated inside one module (it used to index past the modules).
        let mut within = TopologyBuilder::new("l", "p", 1.0);
        within.patch(1).module(3, [7, 8, 7]);
        assert_eq!(
            within.build().unwrap_err(),
            TopologyError::DuplicateUid { layer: "l".into(), uid: 7, first_module: 3, second_module: 3 }
        );
        let mut empty = TopologyBuilder::new("l", "p", 1.0);
        empty.patch(1).module(9, []);
        assert_eq!(empty.build().unwrap_err(), TopologyError::Empty { layer: "l".into(), what: "module", id: 9 });
        let mut modules = TopologyBuilder::new("l", "p", 1.0);
        modules.patch(1).module(4, [1]).patch(2).module(4, [2]);
        assert!(matches!(modules.build(), Err(TopologyError::DuplicateId { what: "module", id: 4, .. })));
    }
}
