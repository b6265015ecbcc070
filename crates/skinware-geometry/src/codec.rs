//! The binary encoding of a [`SkinGeometry`] (cache and published file), and
//! the hash that keys the cache. Every read is bounds-checked: a truncated or
//! foreign file is an error, never a panic.

#![forbid(unsafe_code)]

use super::{BuildTimes, MapQuality, NeighbourGraph, NeighbourStats, RegionIndex, SkinGeometry, SkinMap};
use skinware::LayerTopology;

const MAGIC: &[u8; 8] = b"SKGEOM01";

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

#[derive(Default)]
struct Out(Vec<u8>);

impl Out {
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn bytes(&mut self, v: &[u8]) {
        self.u64(v.len() as u64);
        self.0.extend_from_slice(v);
    }
    fn str(&mut self, v: &str) {
        self.bytes(v.as_bytes());
    }
    fn u32s(&mut self, v: &[u32]) {
        self.u64(v.len() as u64);
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn f32s(&mut self, v: impl ExactSizeIterator<Item = f32>) {
        self.u64(v.len() as u64);
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    fn lists(&mut self, v: &[Vec<u32>]) {
        self.u64(v.len() as u64);
        for l in v {
            self.u32s(l);
        }
    }
}

struct In<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> In<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len()).ok_or("the file is truncated")?;
        let slice = &self.bytes[self.at..end];
        self.at = end;
        Ok(slice)
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    fn len(&mut self, item: usize) -> Result<usize, String> {
        let n = self.u64()? as usize;
        if n.checked_mul(item).is_none_or(|b| b > self.bytes.len() - self.at) {
            return Err(format!("a length of {n} runs past the end of the file"));
        }
        Ok(n)
    }
    fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().expect("8 bytes")))
    }
    fn bytes(&mut self) -> Result<&'a [u8], String> {
        let n = self.len(1)?;
        self.take(n)
    }
    fn str(&mut self) -> Result<String, String> {
        String::from_utf8(self.bytes()?.to_vec()).map_err(|_| "a name is not UTF-8".to_owned())
    }
    fn u32s(&mut self) -> Result<Vec<u32>, String> {
        let n = self.len(4)?;
        Ok(self.take(n * 4)?.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes"))).collect())
    }
    fn f32s(&mut self) -> Result<Vec<f32>, String> {
        let n = self.len(4)?;
        Ok(self.take(n * 4)?.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes"))).collect())
    }
    fn lists(&mut self) -> Result<Vec<Vec<u32>>, String> {
        let n = self.len(8)?;
        (0..n).map(|_| self.u32s()).collect()
    }
}

fn triples(flat: Vec<f32>, what: &str, n: usize) -> Result<Vec<[f32; 3]>, String> {
    if flat.len() != 3 * n {
        return Err(format!("{what}: {} values for {n} sensors", flat.len()));
    }
    Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

impl SkinGeometry {
    /// The binary encoding.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Out::default();
        out.0.extend_from_slice(MAGIC);
        out.u64(u64::from(super::GEOMETRY_VERSION));
        out.u64(self.input_hash);
        out.str(&self.skin);
        out.u64(self.layers.len() as u64);
        for layer in &self.layers {
            out.bytes(&layer.encode());
        }
        out.u32s(&self.layer_starts.iter().map(|&s| s as u32).collect::<Vec<_>>());
        out.f32s(self.positions.iter().flatten().copied().collect::<Vec<_>>().into_iter());
        out.f32s(self.normals.iter().flatten().copied().collect::<Vec<_>>().into_iter());
        out.f32s(self.radii.iter().copied());
        out.u64(self.links.len() as u64);
        for link in &self.links {
            out.str(link);
        }
        out.u32s(&self.link_of.iter().map(|&l| u32::from(l)).collect::<Vec<_>>());
        out.lists(&self.by_link);
        out.u64(self.by_type.len() as u64);
        for (name, sensors) in &self.by_type {
            out.str(name);
            out.u32s(sensors);
        }
        let r = &self.regions;
        out.u64(r.names.len() as u64);
        for name in &r.names {
            out.str(name);
        }
        out.lists(&r.sensors);
        out.lists(&r.subregions_of);
        out.lists(&r.subregion_sensors);
        out.lists(&r.regions_of);
        out.u32s(&self.neighbours.offsets);
        out.u32s(&self.neighbours.list);
        let s = &self.neighbour_stats;
        for v in [s.edges, s.min_degree, s.max_degree, s.isolated] {
            out.u64(v as u64);
        }
        for v in [s.mean_degree, s.mean_edge_m, s.max_edge_m] {
            out.f64(v);
        }
        let m = &self.map;
        out.f32s(m.positions.iter().flatten().copied().collect::<Vec<_>>().into_iter());
        out.u32s(&m.piece_of);
        out.f32s(m.piece_bounds.iter().flatten().copied().collect::<Vec<_>>().into_iter());
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
        let mut checksum = Fnv::new();
        checksum.write(&out.0);
        out.u64(checksum.finish());
        out.0
    }

    /// Decodes [`SkinGeometry::encode`]'s output, checking every length and index.
    pub fn decode(bytes: &[u8]) -> Result<SkinGeometry, String> {
        if bytes.get(..8) != Some(MAGIC.as_slice()) {
            return Err("it is not a skinware geometry file (bad magic)".into());
        }
        let Some(body_len) = bytes.len().checked_sub(8).filter(|&l| l >= 8) else {
            return Err("the file is truncated".into());
        };
        let (body, stored) = bytes.split_at(body_len);
        let mut checksum = Fnv::new();
        checksum.write(body);
        if checksum.finish().to_le_bytes() != stored {
            return Err("its checksum does not match (truncated or corrupted)".into());
        }
        let mut input = In { bytes: body, at: 8 };
        let version = input.u64()?;
        if version != u64::from(super::GEOMETRY_VERSION) {
            return Err(format!("it has geometry version {version}, this program reads {}", super::GEOMETRY_VERSION));
        }
        let input_hash = input.u64()?;
        let skin = input.str()?;
        let layer_count = input.len(8)?;
        let mut layers = Vec::with_capacity(layer_count);
        for _ in 0..layer_count {
            layers.push(LayerTopology::decode(input.bytes()?, "geometry").map_err(|e| e.to_string())?);
        }
        let layer_starts: Vec<usize> = input.u32s()?.into_iter().map(|s| s as usize).collect();
        let total: usize = layers.iter().map(|l| l.sensors.len()).sum();
        let expected_starts: Vec<usize> = std::iter::once(0)
            .chain(layers.iter().scan(0, |sum, l| {
                *sum += l.sensors.len();
                Some(*sum)
            }))
            .collect();
        if layer_starts != expected_starts {
            return Err("the layer offsets do not match the layers".into());
        }
        let positions = triples(input.f32s()?, "positions", total)?;
        let normals = triples(input.f32s()?, "normals", total)?;
        let radii = input.f32s()?;
        let link_count = input.len(8)?;
        let links = (0..link_count).map(|_| input.str()).collect::<Result<Vec<_>, _>>()?;
        let link_of: Vec<u16> = input.u32s()?.into_iter().map(|l| l as u16).collect();
        let by_link = input.lists()?;
        let type_count = input.len(16)?;
        let mut by_type = Vec::with_capacity(type_count);
        for _ in 0..type_count {
            by_type.push((input.str()?, input.u32s()?));
        }
        let region_count = input.len(8)?;
        let names = (0..region_count).map(|_| input.str()).collect::<Result<Vec<_>, _>>()?;
        let regions = RegionIndex {
            names,
            sensors: input.lists()?,
            subregions_of: input.lists()?,
            subregion_sensors: input.lists()?,
            regions_of: input.lists()?,
        };
        let neighbours = NeighbourGraph { offsets: input.u32s()?, list: input.u32s()? };
        let mut counts = [0usize; 4];
        for c in &mut counts {
            *c = input.u64()? as usize;
        }
        let mut reals = [0.0f64; 3];
        for r in &mut reals {
            *r = input.f64()?;
        }
        let neighbour_stats = NeighbourStats {
            edges: counts[0],
            min_degree: counts[1],
            max_degree: counts[2],
            isolated: counts[3],
            mean_degree: reals[0],
            mean_edge_m: reals[1],
            max_edge_m: reals[2],
        };
        let map_positions: Vec<[f32; 2]> = input.f32s()?.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let piece_of = input.u32s()?;
        let piece_bounds: Vec<[f32; 4]> = input.f32s()?.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect();
        let mut q = [0.0f64; 5];
        for v in &mut q {
            *v = input.f64()?;
        }
        let mut qc = [0u64; 3];
        for v in &mut qc {
            *v = input.u64()?;
        }
        let mut t = [0.0f64; 5];
        for v in &mut t {
            *v = input.f64()?;
        }
        let geometry = SkinGeometry {
            skin,
            input_hash,
            layers,
            layer_starts,
            positions,
            normals,
            radii,
            links,
            link_of,
            by_link,
            by_type,
            regions,
            neighbours,
            neighbour_stats,
            map: SkinMap {
                positions: map_positions,
                piece_of,
                piece_bounds,
                quality: MapQuality {
                    mean_relative_error: q[0],
                    p95_relative_error: q[1],
                    seam_edge_fraction: q[2],
                    flipped_fraction: q[3],
                    stacked_fraction: q[4],
                    triangles: qc[0] as usize,
                    pieces_overlap: qc[1] != 0,
                    pieces: qc[2] as usize,
                },
            },
            build_times: BuildTimes {
                indices_ms: t[0],
                regions_ms: t[1],
                neighbours_ms: t[2],
                map_ms: t[3],
                total_ms: t[4],
            },
        };
        geometry.check()?;
        Ok(geometry)
    }

    /// Every index in range, so that users can index without checks.
    fn check(&self) -> Result<(), String> {
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
        if ok { Ok(()) } else { Err("an index is out of range".into()) }
    }
}
