//! Geometry and indices of a whole skin: calibration, regions and
//! sub-regions, the neighbour graph and the 2-D map.
//!
//! [`SkinGeometry::build`] computes everything once from the layers'
//! topologies, a [`Calibration`] and the [`RegionSpec`]s. The result is
//! cached on disk, keyed by a hash of its inputs ([`SkinGeometry::load_or_build`]),
//! and published next to the skin's channels ([`SkinGeometry::publish`]) so
//! that any process gets it with [`SkinGeometry::open`].
//!
//! Sensors are numbered globally: layer after layer, in each layer's frame
//! order. [`SkinGeometry::global`] and [`SkinGeometry::locate`] convert.

#![forbid(unsafe_code)]

mod calibration;
mod codec;
pub mod map2d;
pub mod neighbours;
mod regions;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use calibration::{Calibration, SensorCalibration};
pub use map2d::{MapQuality, SkinMap};
pub use neighbours::NeighbourGraph;
pub use regions::{RegionIndex, RegionSpec, Selector};

use skinware::LayerTopology;

/// Bumped whenever the computation or the encoding changes, so that caches
/// made by another version are recomputed. 3: the map packs each link's
/// pieces together.
pub const GEOMETRY_VERSION: u32 = 3;

/// Errors of calibration, regions and the published geometry.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GeometryError {
    /// A calibration file that cannot be read.
    #[error("calibration {source_name}, line {line}: {message}")]
    Calibration {
        /// File name.
        source_name: String,
        /// 1-based line (0: the whole file).
        line: usize,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A sensor calibration that cannot be used (not finite, no normal, ...).
    #[error("{key} uid {uid}: {reason}")]
    Sensor {
        /// The layer name or sensor type it was given under.
        key: String,
        /// The sensor's uid.
        uid: u32,
        /// What is wrong and how to fix it.
        reason: String,
    },
    /// A sensor without calibration.
    #[error(
        "layer {layer}: sensor uid {uid} has no calibration (looked for key {layer:?} and sensor type {sensor_type:?}); add a line for it to the calibration file"
    )]
    Uncalibrated {
        /// Layer name.
        layer: String,
        /// Its sensor type.
        sensor_type: String,
        /// The uid.
        uid: u32,
    },
    /// A region that cannot be resolved.
    #[error("region {region:?}: {message}")]
    Region {
        /// Region name.
        region: String,
        /// What is wrong.
        message: String,
    },
    /// No published geometry for this skin.
    #[error(
        "no geometry is published for skin {skin} ({path}); `skin run CONFIG`, `skin replay FILE.mcap` and `skin demo` publish it when they start the skin"
    )]
    Missing {
        /// Skin name.
        skin: String,
        /// Where it was looked for.
        path: PathBuf,
    },
    /// A published or cached geometry that cannot be decoded.
    #[error("geometry file {path} is unreadable ({source}); remove it (it is recomputed) or rerun `skin run`")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What was wrong, and where.
        #[source]
        source: skinware::wire::DecodeError,
    },
    /// An I/O failure writing or reading a geometry file.
    #[error("{op} {path}: {source}")]
    Io {
        /// What was being done.
        op: &'static str,
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
}

/// Where one sensor sits in the hierarchy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SensorRef {
    /// Layer index in [`SkinGeometry::layers`].
    pub layer: usize,
    /// Index in the layer (and its frames).
    pub sensor: usize,
    /// The sensor's uid.
    pub uid: u32,
    /// Its module's id.
    pub module_id: u32,
    /// Its patch's id.
    pub patch_id: u32,
}

/// Neighbour graph statistics.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NeighbourStats {
    /// Undirected edges.
    pub edges: usize,
    /// Fewest neighbours of a sensor.
    pub min_degree: usize,
    /// Mean neighbours per sensor.
    pub mean_degree: f64,
    /// Most neighbours of a sensor.
    pub max_degree: usize,
    /// Sensors without a neighbour.
    pub isolated: usize,
    /// Mean edge length, metres.
    pub mean_edge_m: f64,
    /// Longest edge, metres.
    pub max_edge_m: f64,
}

/// How long each stage of [`SkinGeometry::build`] took, milliseconds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BuildTimes {
    /// Calibration lookup, hierarchy and type/link indices.
    pub indices_ms: f64,
    /// Regions and sub-regions.
    pub regions_ms: f64,
    /// The neighbour graph.
    pub neighbours_ms: f64,
    /// The 2-D map and its distortion figures.
    pub map_ms: f64,
    /// Everything.
    pub total_ms: f64,
}

/// The geometry and indices of a skin. Every sensor list holds global indices.
#[derive(Clone, Debug, PartialEq)]
pub struct SkinGeometry {
    /// Skin name.
    pub skin: String,
    /// Hash of the inputs this was computed from.
    pub input_hash: u64,
    /// The layers, in global order.
    pub layers: Vec<LayerTopology>,
    /// Global index of each layer's first sensor, plus the total at the end.
    pub layer_starts: Vec<usize>,
    /// Each sensor's position, metres.
    pub positions: Vec<[f32; 3]>,
    /// Each sensor's outward unit normal.
    pub normals: Vec<[f32; 3]>,
    /// Each sensor's radius, metres.
    pub radii: Vec<f32>,
    /// Robot link names.
    pub links: Vec<String>,
    /// Each sensor's link, an index into `links`.
    pub link_of: Vec<u16>,
    /// The sensors on each link.
    pub by_link: Vec<Vec<u32>>,
    /// Sensor types and their sensors.
    pub by_type: Vec<(String, Vec<u32>)>,
    /// Regions and sub-regions.
    pub regions: RegionIndex,
    /// Each sensor's neighbours.
    pub neighbours: NeighbourGraph,
    /// Statistics of the neighbour graph.
    pub neighbour_stats: NeighbourStats,
    /// The 2-D map.
    pub map: SkinMap,
    /// What the build cost (of the build that made this, even if it came from the cache).
    pub build_times: BuildTimes,
}

impl SkinGeometry {
    /// Computes the geometry of the skin made of `layers`.
    pub fn build(
        skin: &str,
        layers: &[LayerTopology],
        calibration: &Calibration,
        regions: &[RegionSpec],
    ) -> Result<SkinGeometry, GeometryError> {
        let started = Instant::now();
        let input_hash = input_hash(skin, layers, calibration, regions);
        let placed = place_sensors(layers, calibration)?;
        let (links, by_link) = link_index(&placed.link_names, &placed.link_of);
        let by_type = type_index(layers, &placed.layer_starts);
        let indices_ms = ms(started);

        let stage = Instant::now();
        let facts = region_facts(layers, &placed);
        let region_index = RegionIndex::build(regions, &facts)?;
        let regions_ms = ms(stage);

        let Placed { layer_starts, positions, normals, radii, link_of, .. } = placed;
        let stage = Instant::now();
        let graph = neighbours::build(&positions, &normals);
        let neighbour_stats = neighbour_stats(&positions, &graph);
        let neighbours_ms = ms(stage);

        let stage = Instant::now();
        let map = map2d::build(&positions, &normals, &graph, &link_of);
        let map_ms = ms(stage);

        Ok(SkinGeometry {
            skin: skin.to_owned(),
            input_hash,
            layers: layers.to_vec(),
            layer_starts,
            positions: positions.iter().map(|p| p.map(|v| v as f32)).collect(),
            normals: normals.iter().map(|p| p.map(|v| v as f32)).collect(),
            radii,
            links,
            link_of,
            by_link,
            by_type,
            regions: region_index,
            neighbours: graph,
            neighbour_stats,
            map,
            build_times: BuildTimes { indices_ms, regions_ms, neighbours_ms, map_ms, total_ms: ms(started) },
        })
    }

    /// Number of sensors in the whole skin.
    pub fn sensor_count(&self) -> usize {
        self.positions.len()
    }

    /// The global index of sensor `sensor` of layer `layer`.
    pub fn global(&self, layer: usize, sensor: usize) -> Option<usize> {
        let start = *self.layer_starts.get(layer)?;
        (start + sensor < *self.layer_starts.get(layer + 1)?).then_some(start + sensor)
    }

    /// The layer index of the layer called `name`.
    pub fn layer_index(&self, name: &str) -> Option<usize> {
        self.layers.iter().position(|l| l.name == name)
    }

    /// Where global sensor `global` sits: layer, index in it, uid, module and patch.
    pub fn locate(&self, global: usize) -> Option<SensorRef> {
        if global >= self.sensor_count() {
            return None;
        }
        let layer = self.layer_starts.partition_point(|&s| s <= global) - 1;
        let topology = &self.layers[layer];
        let sensor = global - self.layer_starts[layer];
        let s = topology.sensors[sensor];
        let module = &topology.modules[s.module];
        Some(SensorRef { layer, sensor, uid: s.uid, module_id: module.id, patch_id: topology.patches[module.patch].id })
    }

    /// The sensors of region `name`.
    pub fn region(&self, name: &str) -> Option<&[u32]> {
        self.regions.find(name).map(|r| self.regions.sensors[r].as_slice())
    }

    /// The sensors on robot link `name`.
    pub fn link(&self, name: &str) -> Option<&[u32]> {
        self.links.iter().position(|l| l == name).map(|l| self.by_link[l].as_slice())
    }

    /// The sensors of type `sensor_type`.
    pub fn of_type(&self, sensor_type: &str) -> Option<&[u32]> {
        self.by_type.iter().find(|(t, _)| t == sensor_type).map(|(_, s)| s.as_slice())
    }

    /// The neighbours of global sensor `global`.
    // Inline across crates: the contact service's component search calls it
    // for every touched taxel, and the call cost more than the lookup.
    #[inline]
    pub fn neighbours_of(&self, global: usize) -> &[u32] {
        self.neighbours.of(global)
    }

    /// The published geometry file of `skin` in `dir`.
    pub fn published_path(dir: &Path, skin: &str) -> PathBuf {
        dir.join(format!("skinware-geometry.{skin}"))
    }

    /// Publishes the geometry for readers of this skin: written to a temporary
    /// file and renamed, so readers see the old file or the new one, whole.
    pub fn publish(&self, dir: &Path) -> Result<PathBuf, GeometryError> {
        let path = SkinGeometry::published_path(dir, &self.skin);
        write_atomically(&path, &self.encode())?;
        Ok(path)
    }

    /// The largest published geometry file read (1 GiB): the file is in a
    /// world-writable directory, so its size is anyone's number. A 300,000
    /// taxel skin's geometry is tens of megabytes.
    pub const MAX_PUBLISHED_BYTES: u64 = 1 << 30;

    /// The geometry published for `skin` in the segment directory.
    pub fn open(skin: &str) -> Result<SkinGeometry, GeometryError> {
        SkinGeometry::open_in(&skinware::shm::segment_dir(), skin)
    }

    /// The geometry published for `skin` in `dir`.
    pub fn open_in(dir: &Path, skin: &str) -> Result<SkinGeometry, GeometryError> {
        let path = SkinGeometry::published_path(dir, skin);
        let bytes = match skinware::shm::read_regular(&path, SkinGeometry::MAX_PUBLISHED_BYTES) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                return Err(GeometryError::Missing { skin: skin.to_owned(), path });
            }
            Err(source) => return Err(GeometryError::Io { op: "read", path, source }),
        };
        SkinGeometry::decode(&bytes).map_err(|source| GeometryError::Corrupt { path, source })
    }

    /// The geometry from the cache in `cache_dir` if one was computed from the
    /// same inputs, else computed now and cached. The flag says whether it
    /// came from the cache.
    pub fn load_or_build(
        cache_dir: &Path,
        skin: &str,
        layers: &[LayerTopology],
        calibration: &Calibration,
        regions: &[RegionSpec],
    ) -> Result<(SkinGeometry, bool), GeometryError> {
        let hash = input_hash(skin, layers, calibration, regions);
        let path = cache_dir.join(format!("geometry-{hash:016x}.bin"));
        if let Ok(bytes) = skinware::shm::read_named_file(&path, SkinGeometry::MAX_PUBLISHED_BYTES) {
            match SkinGeometry::decode(&bytes) {
                Ok(geometry) if geometry.input_hash == hash => return Ok((geometry, true)),
                Ok(_) => {
                    tracing::warn!(path = %path.display(), "cached geometry was made from other inputs; recomputing")
                }
                Err(reason) => {
                    tracing::warn!(path = %path.display(), %reason, "cached geometry unreadable; recomputing")
                }
            }
        }
        let geometry = SkinGeometry::build(skin, layers, calibration, regions)?;
        std::fs::create_dir_all(cache_dir).map_err(|source| GeometryError::Io {
            op: "create cache directory",
            path: cache_dir.to_owned(),
            source,
        })?;
        write_atomically(&path, &geometry.encode())?;
        Ok((geometry, false))
    }
}

/// Every sensor's calibrated place and link, in global order.
struct Placed<'a> {
    /// Global index of each layer's first sensor, plus the total at the end.
    layer_starts: Vec<usize>,
    positions: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
    radii: Vec<f32>,
    /// Link names and their indices, numbered by first appearance.
    link_names: BTreeMap<String, usize>,
    /// Each sensor's link, an index into `link_names`.
    link_of: Vec<u16>,
    /// Each sensor's link name, as the calibration spells it.
    sensor_links: Vec<&'a str>,
}

/// Looks every sensor of `layers` up in `calibration`, layer after layer.
fn place_sensors<'a>(layers: &[LayerTopology], calibration: &'a Calibration) -> Result<Placed<'a>, GeometryError> {
    let mut layer_starts = vec![0];
    let (mut positions, mut normals, mut radii) = (Vec::new(), Vec::new(), Vec::new());
    let mut link_names: BTreeMap<String, usize> = BTreeMap::new();
    let mut link_of = Vec::new();
    let mut sensor_links: Vec<&str> = Vec::new();
    for layer in layers {
        for sensor in &layer.sensors {
            let c = calibration.get(&layer.name, &layer.sensor_type, sensor.uid).ok_or_else(|| {
                GeometryError::Uncalibrated {
                    layer: layer.name.clone(),
                    sensor_type: layer.sensor_type.clone(),
                    uid: sensor.uid,
                }
            })?;
            positions.push(c.position);
            normals.push(c.normal);
            radii.push(c.radius as f32);
            sensor_links.push(&c.link);
            let next = link_names.len();
            let link = *link_names.entry(c.link.clone()).or_insert(next);
            link_of.push(u16::try_from(link).map_err(|_| GeometryError::Calibration {
                source_name: format!("layer {}", layer.name),
                line: 0,
                message: format!("more than {} robot links; links are meant to be body parts", u16::MAX),
            })?);
        }
        layer_starts.push(positions.len());
    }
    Ok(Placed { layer_starts, positions, normals, radii, link_names, link_of, sensor_links })
}

/// The link names in index order, and the sensors on each link.
fn link_index(link_names: &BTreeMap<String, usize>, link_of: &[u16]) -> (Vec<String>, Vec<Vec<u32>>) {
    // Links are numbered by first appearance; list them in that order.
    let mut links = vec![String::new(); link_names.len()];
    for (name, &index) in link_names {
        links[index] = name.clone();
    }
    let mut by_link = vec![Vec::new(); links.len()];
    for (s, &l) in link_of.iter().enumerate() {
        by_link[l as usize].push(s as u32);
    }
    (links, by_link)
}

/// The sensor types, in name order, and their sensors.
fn type_index(layers: &[LayerTopology], layer_starts: &[usize]) -> Vec<(String, Vec<u32>)> {
    let mut types: BTreeMap<&str, Vec<u32>> = BTreeMap::new();
    for (l, layer) in layers.iter().enumerate() {
        types.entry(&layer.sensor_type).or_default().extend(layer_starts[l] as u32..layer_starts[l + 1] as u32);
    }
    types.into_iter().map(|(t, s)| (t.to_owned(), s)).collect()
}

/// What region selectors look at, per sensor in global order.
fn region_facts<'a>(layers: &'a [LayerTopology], placed: &Placed<'a>) -> Vec<regions::SensorFacts<'a>> {
    let mut facts = Vec::with_capacity(placed.positions.len());
    for (l, layer) in layers.iter().enumerate() {
        for (k, sensor) in layer.sensors.iter().enumerate() {
            let module = &layer.modules[sensor.module];
            let g = placed.layer_starts[l] + k;
            facts.push(regions::SensorFacts {
                layer: &layer.name,
                uid: sensor.uid,
                module_id: module.id,
                patch_id: layer.patches[module.patch].id,
                link: placed.sensor_links[g],
                position: placed.positions[g],
            });
        }
    }
    facts
}

/// The directory where geometry caches live: `$SKINWARE_CACHE_DIR`, else
/// `$XDG_CACHE_HOME/skinware`, else `~/.cache/skinware`.
pub fn cache_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("SKINWARE_CACHE_DIR") {
        return PathBuf::from(dir);
    }
    if let Some(dir) = std::env::var_os("XDG_CACHE_HOME") {
        return PathBuf::from(dir).join("skinware");
    }
    match std::env::var_os("HOME") {
        Some(home) => PathBuf::from(home).join(".cache/skinware"),
        None => std::env::temp_dir().join("skinware-cache"),
    }
}

fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), GeometryError> {
    // A new hidden file beside it (never a link or FIFO someone left at a
    // guessable name; `skin clean` removes one its dead writer left),
    // renamed over the published one.
    skinware::shm::replace_file(path, bytes, 0o644).map_err(|source| GeometryError::Io {
        op: "write",
        path: path.to_owned(),
        source,
    })
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

fn neighbour_stats(positions: &[[f64; 3]], graph: &NeighbourGraph) -> NeighbourStats {
    let n = graph.len();
    if n == 0 {
        return NeighbourStats::default();
    }
    let degrees: Vec<usize> = (0..n).map(|i| graph.of(i).len()).collect();
    let (mut sum, mut longest, mut count) = (0.0, 0.0f64, 0usize);
    for i in 0..n {
        for &j in graph.of(i) {
            if (j as usize) > i {
                let d = neighbours::distance(&positions[i], &positions[j as usize]);
                sum += d;
                longest = longest.max(d);
                count += 1;
            }
        }
    }
    NeighbourStats {
        edges: graph.edge_count(),
        min_degree: degrees.iter().copied().min().unwrap_or(0),
        mean_degree: degrees.iter().sum::<usize>() as f64 / n as f64,
        max_degree: degrees.iter().copied().max().unwrap_or(0),
        isolated: degrees.iter().filter(|&&d| d == 0).count(),
        mean_edge_m: if count == 0 { 0.0 } else { sum / count as f64 },
        max_edge_m: longest,
    }
}

/// FNV-1a over a canonical encoding of everything the geometry depends on.
fn input_hash(skin: &str, layers: &[LayerTopology], calibration: &Calibration, regions: &[RegionSpec]) -> u64 {
    let mut hasher = codec::Fnv::new();
    hasher.write(&GEOMETRY_VERSION.to_le_bytes());
    hasher.write(skin.as_bytes());
    for layer in layers {
        hasher.write(&layer.encode());
    }
    for layer in layers {
        for sensor in &layer.sensors {
            if let Some(c) = calibration.get(&layer.name, &layer.sensor_type, sensor.uid) {
                for v in c.position.iter().chain(&c.normal).chain([&c.radius]) {
                    hasher.write(&v.to_le_bytes());
                }
                hasher.write(c.link.as_bytes());
            } else {
                hasher.write(b"uncalibrated");
            }
        }
    }
    hasher.write(format!("{regions:?}").as_bytes());
    hasher.finish()
}
