//! The binary encoding of a [`SkinGeometry`] (cache and published file), in
//! skinware's one [`wire`](skinware::wire) encoding, and the hash that keys
//! the cache. Every read is bounds-checked and every index checked before
//! use: a truncated, foreign or hostile file is a [`DecodeError`] saying
//! where and why, never a panic.
//!
//! Layout: `SKGEOM02`, the geometry version (u32), the input hash (u64), the
//! skin name, then the sensors (layers' topologies, positions, normals,
//! radii), the links, the sensor types, the regions, the neighbour graph, the
//! 2-D map and the build times, and last an FNV-1a checksum (u64) of
//! everything before it.

#![forbid(unsafe_code)]

use skinware::LayerTopology;
use skinware::wire::{DecodeError, Decoder, Encoder, Problem};

use super::{BuildTimes, MapQuality, NeighbourGraph, NeighbourStats, RegionIndex, SkinGeometry, SkinMap};

const MAGIC: &[u8; 8] = b"SKGEOM02";
/// What decode errors call the input.
const WHAT: &str = "geometry file";

/// 64-bit FNV-1a.
pub(crate) struct Fnv(u64);

impl Fnv {
    pub(crate) fn new() -> Fnv {
        Fnv(0xcbf2_9ce4_8422_2325)
    }
    pub(crate) fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
        // Separates consecutive fields.
        self.0 = (self.0 ^ 0xff).wrapping_mul(0x0100_0000_01b3);
    }
    pub(crate) fn finish(&self) -> u64 {
        self.0
    }
}

fn flat<const N: usize>(values: &[[f32; N]]) -> impl ExactSizeIterator<Item = f32> + '_ {
    values.as_flattened().iter().copied()
}

/// `values` cut into groups of `N`, exactly `count` of them.
fn groups<const N: usize>(
    input: &Decoder<'_>,
    field: &'static str,
    values: Vec<f32>,
    count: usize,
) -> Result<Vec<[f32; N]>, DecodeError> {
    if values.len() != N * count {
        return Err(input.invalid(field, format!("{} values where {count} × {N} were expected", values.len())));
    }
    Ok(values.chunks_exact(N).map(|c| std::array::from_fn(|i| c[i])).collect())
}

impl SkinGeometry {
    /// The binary encoding.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Encoder::with_capacity(MAGIC, 64 * self.sensor_count() + 4096);
        out.u32(super::GEOMETRY_VERSION);
        out.u64(self.input_hash);
        out.str(&self.skin);
        self.encode_sensors(&mut out);
        self.encode_indices(&mut out);
        self.encode_map_and_times(&mut out);
        let mut checksum = Fnv::new();
        checksum.write(out.as_bytes());
        out.u64(checksum.finish());
        out.finish()
    }

    fn encode_sensors(&self, out: &mut Encoder) {
        out.count(self.layers.len());
        for layer in &self.layers {
            out.bytes(&layer.encode());
        }
        out.u32s(&self.layer_starts.iter().map(|&s| s as u32).collect::<Vec<_>>());
        out.f32s(flat(&self.positions));
        out.f32s(flat(&self.normals));
        out.f32s(self.radii.iter().copied());
    }

    fn encode_indices(&self, out: &mut Encoder) {
        out.strs(&self.links);
        out.u32s(&self.link_of.iter().map(|&l| u32::from(l)).collect::<Vec<_>>());
        out.u32_lists(&self.by_link);
        out.count(self.by_type.len());
        for (name, sensors) in &self.by_type {
            out.str(name);
            out.u32s(sensors);
        }
        let r = &self.regions;
        out.strs(&r.names);
        out.u32_lists(&r.sensors);
        out.u32_lists(&r.subregions_of);
        out.u32_lists(&r.subregion_sensors);
        out.u32_lists(&r.regions_of);
        out.u32s(&self.neighbours.offsets);
        out.u32s(&self.neighbours.list);
        let s = &self.neighbour_stats;
        for v in [s.edges, s.min_degree, s.max_degree, s.isolated] {
            out.u64(v as u64);
        }
        for v in [s.mean_degree, s.mean_edge_m, s.max_edge_m] {
            out.f64(v);
        }
    }

    fn encode_map_and_times(&self, out: &mut Encoder) {
        let m = &self.map;
        out.f32s(flat(&m.positions));
        out.u32s(&m.piece_of);
        out.f32s(flat(&m.piece_bounds));
        let q = &m.quality;
        for v in
            [q.mean_relative_error, q.p95_relative_error, q.seam_edge_fraction, q.flipped_fraction, q.stacked_fraction]
        {
            out.f64(v);
        }
        for v in [q.triangles, usize::from(q.pieces_overlap), q.pieces] {
            out.u64(v as u64);
        }
        let t = &self.build_times;
        for v in [t.indices_ms, t.regions_ms, t.neighbours_ms, t.map_ms, t.total_ms] {
            out.f64(v);
        }
    }

    /// Decodes [`SkinGeometry::encode`]'s output, checking every length and index.
    pub fn decode(bytes: &[u8]) -> Result<SkinGeometry, DecodeError> {
        let body = checked_body(bytes)?;
        let mut input = Decoder::new(body, WHAT, MAGIC)?;
        let version = input.u32("geometry version")?;
        if version != super::GEOMETRY_VERSION {
            return Err(input.invalid(
                "geometry version",
                format!("version {version}, this program reads {}", super::GEOMETRY_VERSION),
            ));
        }
        let input_hash = input.u64("input hash")?;
        let skin = input.str("skin name")?;
        let sensors = decode_sensors(&mut input)?;
        let total = sensors.positions.len();
        let (links, link_of, by_link, by_type) = decode_links_and_types(&mut input)?;
        let regions = decode_regions(&mut input)?;
        let (neighbours, neighbour_stats) = decode_neighbours(&mut input)?;
        let map = decode_map(&mut input, total)?;
        let build_times = decode_build_times(&mut input)?;
        input.finish()?;
        let geometry = SkinGeometry {
            skin,
            input_hash,
            layers: sensors.layers,
            layer_starts: sensors.layer_starts,
            positions: sensors.positions,
            normals: sensors.normals,
            radii: sensors.radii,
            links,
            link_of,
            by_link,
            by_type,
            regions,
            neighbours,
            neighbour_stats,
            map,
            build_times,
        };
        geometry.check().map_err(|reason| DecodeError { what: WHAT, field: "indices", offset: 0, problem: reason })?;
        Ok(geometry)
    }

    /// Every index in range, so that users can index without checks.
    fn check(&self) -> Result<(), Problem> {
        let n = self.sensor_count();
        let in_range = |list: &[u32], bound: usize| list.iter().all(|&i| (i as usize) < bound);
        let ok = self.radii.len() == n
            && self.link_of.len() == n
            && self.link_of.iter().all(|&l| (l as usize) < self.links.len())
            && self.by_link.len() == self.links.len()
            && self.by_link.iter().all(|l| in_range(l, n))
            && self.by_type.iter().all(|(_, l)| in_range(l, n))
            && self.regions.sensors.len() == self.regions.names.len()
            && self.regions.subregions_of.len() == self.regions.names.len()
            && self.regions.sensors.iter().all(|l| in_range(l, n))
            && self.regions.subregions_of.iter().all(|l| in_range(l, self.regions.subregion_sensors.len()))
            && self.regions.subregion_sensors.iter().all(|l| in_range(l, n))
            && self.regions.regions_of.len() == self.regions.subregion_sensors.len()
            && self.regions.regions_of.iter().all(|l| in_range(l, self.regions.names.len()))
            && self.neighbours.offsets.len() == n + 1
            && self.neighbours.offsets.windows(2).all(|w| w[0] <= w[1])
            && self.neighbours.offsets.last().is_some_and(|&e| e as usize == self.neighbours.list.len())
            && in_range(&self.neighbours.list, n)
            && self.map.positions.len() == n
            && self.map.piece_of.len() == n
            && in_range(&self.map.piece_of, self.map.piece_bounds.len());
        if ok { Ok(()) } else { Err(Problem::Invalid("an index is out of range".into())) }
    }
}

/// The bytes before the trailing checksum, once the checksum matches them.
fn checked_body(bytes: &[u8]) -> Result<&[u8], DecodeError> {
    let at_end = |problem| DecodeError { what: WHAT, field: "checksum", offset: bytes.len(), problem };
    let Some(body_len) = bytes.len().checked_sub(8).filter(|&l| l >= 8) else {
        // Too short even for magic and checksum: report it as the magic would.
        Decoder::new(bytes, WHAT, MAGIC)?;
        return Err(at_end(Problem::Truncated { needed: 16 - bytes.len() }));
    };
    let (body, stored) = bytes.split_at(body_len);
    let mut checksum = Fnv::new();
    checksum.write(body);
    if checksum.finish().to_le_bytes() != stored {
        Decoder::new(body, WHAT, MAGIC)?;
        return Err(at_end(Problem::Invalid("the checksum does not match (truncated or corrupted)".into())));
    }
    Ok(body)
}

/// The per-sensor part of a geometry file.
struct Sensors {
    layers: Vec<LayerTopology>,
    layer_starts: Vec<usize>,
    positions: Vec<[f32; 3]>,
    normals: Vec<[f32; 3]>,
    radii: Vec<f32>,
}

fn decode_sensors(input: &mut Decoder<'_>) -> Result<Sensors, DecodeError> {
    let layer_count = input.count("layers", 4)?;
    let mut layers = Vec::with_capacity(layer_count);
    for _ in 0..layer_count {
        let at = input.offset();
        let bytes = input.bytes("layer topology")?;
        let layer = LayerTopology::decode(bytes, "geometry").map_err(|e| DecodeError {
            what: WHAT,
            field: "layer topology",
            offset: at,
            problem: Problem::Invalid(e.to_string()),
        })?;
        layers.push(layer);
    }
    let layer_starts: Vec<usize> = input.u32s("layer starts")?.into_iter().map(|s| s as usize).collect();
    let expected_starts: Vec<usize> = std::iter::once(0)
        .chain(layers.iter().scan(0, |sum, l| {
            *sum += l.sensors.len();
            Some(*sum)
        }))
        .collect();
    if layer_starts != expected_starts {
        return Err(input.invalid("layer starts", "the layer offsets do not match the layers"));
    }
    let total = expected_starts.last().copied().unwrap_or(0);
    let values = input.f32s("positions")?;
    let positions = groups(input, "positions", values, total)?;
    let values = input.f32s("normals")?;
    let normals = groups(input, "normals", values, total)?;
    let radii = input.f32s("radii")?;
    Ok(Sensors { layers, layer_starts, positions, normals, radii })
}

/// Links, each sensor's link, sensors by link, and sensors by type.
type LinksAndTypes = (Vec<String>, Vec<u16>, Vec<Vec<u32>>, Vec<(String, Vec<u32>)>);

fn decode_links_and_types(input: &mut Decoder<'_>) -> Result<LinksAndTypes, DecodeError> {
    let links = input.strs("links")?;
    let link_of = input
        .u32s("sensor links")?
        .into_iter()
        .map(u16::try_from)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|_| input.invalid("sensor links", "a link number above 65535"))?;
    let by_link = input.u32_lists("sensors by link")?;
    let type_count = input.count("sensor types", 8)?;
    let mut by_type = Vec::with_capacity(type_count);
    for _ in 0..type_count {
        by_type.push((input.str("sensor type")?, input.u32s("sensors of a type")?));
    }
    Ok((links, link_of, by_link, by_type))
}

fn decode_regions(input: &mut Decoder<'_>) -> Result<RegionIndex, DecodeError> {
    Ok(RegionIndex {
        names: input.strs("region names")?,
        sensors: input.u32_lists("region sensors")?,
        subregions_of: input.u32_lists("sub-regions of regions")?,
        subregion_sensors: input.u32_lists("sub-region sensors")?,
        regions_of: input.u32_lists("regions of sub-regions")?,
    })
}

fn decode_neighbours(input: &mut Decoder<'_>) -> Result<(NeighbourGraph, NeighbourStats), DecodeError> {
    let graph = NeighbourGraph { offsets: input.u32s("neighbour offsets")?, list: input.u32s("neighbour list")? };
    let mut counts = [0usize; 4];
    for c in &mut counts {
        *c = usize::try_from(input.u64("neighbour statistics")?).unwrap_or(usize::MAX);
    }
    let mut reals = [0.0f64; 3];
    for r in &mut reals {
        *r = input.f64("neighbour statistics")?;
    }
    let stats = NeighbourStats {
        edges: counts[0],
        min_degree: counts[1],
        max_degree: counts[2],
        isolated: counts[3],
        mean_degree: reals[0],
        mean_edge_m: reals[1],
        max_edge_m: reals[2],
    };
    Ok((graph, stats))
}

fn decode_map(input: &mut Decoder<'_>, sensors: usize) -> Result<SkinMap, DecodeError> {
    let values = input.f32s("map positions")?;
    let positions = groups(input, "map positions", values, sensors)?;
    let piece_of = input.u32s("map pieces")?;
    let values = input.f32s("map piece bounds")?;
    let pieces = values.len() / 4;
    let piece_bounds = groups(input, "map piece bounds", values, pieces)?;
    let mut q = [0.0f64; 5];
    for v in &mut q {
        *v = input.f64("map quality")?;
    }
    let mut counts = [0u64; 3];
    for v in &mut counts {
        *v = input.u64("map quality")?;
    }
    let count = |v: u64| usize::try_from(v).unwrap_or(usize::MAX);
    Ok(SkinMap {
        positions,
        piece_of,
        piece_bounds,
        quality: MapQuality {
            mean_relative_error: q[0],
            p95_relative_error: q[1],
            seam_edge_fraction: q[2],
            flipped_fraction: q[3],
            stacked_fraction: q[4],
            triangles: count(counts[0]),
            pieces_overlap: counts[1] != 0,
            pieces: count(counts[2]),
        },
    })
}

fn decode_build_times(input: &mut Decoder<'_>) -> Result<BuildTimes, DecodeError> {
    let mut t = [0.0f64; 5];
    for v in &mut t {
        *v = input.f64("build times")?;
    }
    Ok(BuildTimes { indices_ms: t[0], regions_ms: t[1], neighbours_ms: t[2], map_ms: t[3], total_ms: t[4] })
}
