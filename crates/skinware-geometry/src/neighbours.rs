//! The neighbour graph: which sensors are next to each other along the skin.
//!
//! Built with an R*-tree: each sensor's nearest few are candidates, and a
//! candidate is a neighbour when it is within 1.6 × the sensor's own
//! nearest-neighbour distance (so the graph adapts to the local pitch), its
//! normal is within 60° of the sensor's, and the segment between them lies
//! along the surface (at most 30° out of both tangent planes). The last two
//! tests are what keep the two sides of a limb, or two limbs facing each
//! other, apart. The graph is made symmetric by keeping an edge that either
//! end accepts.

#![forbid(unsafe_code)]

use rstar::RTree;
use rstar::primitives::GeomWithData;

/// How many nearest sensors are candidates.
const CANDIDATES: usize = 12;
/// A neighbour is at most this many times the sensor's nearest distance away.
const REACH: f64 = 1.6;
/// cos 60°: the most two neighbours' normals may differ.
const MIN_NORMAL_COS: f64 = 0.5;
/// sin 30°: the most the segment between neighbours may leave a tangent plane.
const MAX_NORMAL_COMPONENT: f64 = 0.5;

/// A symmetric graph in compressed rows: sensor `i`'s neighbours are
/// `list[offsets[i]..offsets[i + 1]]`, ascending.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct NeighbourGraph {
    /// Row starts, one per sensor plus one.
    pub offsets: Vec<u32>,
    /// Neighbour indices.
    pub list: Vec<u32>,
}

impl NeighbourGraph {
    /// The neighbours of sensor `i`.
    #[inline]
    pub fn of(&self, i: usize) -> &[u32] {
        &self.list[self.offsets[i] as usize..self.offsets[i + 1] as usize]
    }

    /// Number of sensors.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether the graph has no sensors.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Number of (undirected) edges.
    pub fn edge_count(&self) -> usize {
        self.list.len() / 2
    }

    /// Builds a graph from undirected edges over `n` sensors.
    pub fn from_edges(n: usize, edges: &[(u32, u32)]) -> NeighbourGraph {
        let mut directed: Vec<(u32, u32)> = edges.iter().flat_map(|&(a, b)| [(a, b), (b, a)]).collect();
        directed.sort_unstable();
        directed.dedup();
        let mut offsets = vec![0u32; n + 1];
        for &(a, _) in &directed {
            offsets[a as usize + 1] += 1;
        }
        for i in 0..n {
            offsets[i + 1] += offsets[i];
        }
        NeighbourGraph { offsets, list: directed.into_iter().map(|(_, b)| b).collect() }
    }
}

/// Each sensor's distance to its nearest other sensor (0 for a lone sensor).
pub(crate) fn nearest_distances(tree: &RTree<GeomWithData<[f64; 3], u32>>, positions: &[[f64; 3]]) -> Vec<f64> {
    positions
        .iter()
        .enumerate()
        .map(|(i, p)| {
            tree.nearest_neighbor_iter(p).find(|c| c.data as usize != i).map_or(0.0, |c| distance(p, c.geom()))
        })
        .collect()
}

/// An R*-tree of the positions, tagged with their indices.
pub(crate) fn spatial_index(positions: &[[f64; 3]]) -> RTree<GeomWithData<[f64; 3], u32>> {
    RTree::bulk_load(positions.iter().enumerate().map(|(i, p)| GeomWithData::new(*p, i as u32)).collect())
}

/// Builds the neighbour graph of sensors at `positions` with outward unit `normals`.
pub fn build(positions: &[[f64; 3]], normals: &[[f64; 3]]) -> NeighbourGraph {
    let tree = spatial_index(positions);
    let nearest = nearest_distances(&tree, positions);
    let mut edges = Vec::with_capacity(positions.len() * 4);
    for (i, p) in positions.iter().enumerate() {
        let reach = REACH * nearest[i];
        for candidate in tree.nearest_neighbor_iter(p).take(CANDIDATES + 1) {
            let j = candidate.data as usize;
            if j == i {
                continue;
            }
            let d = distance(p, candidate.geom());
            if d > reach {
                break;
            }
            if along_surface(p, &normals[i], &positions[j], &normals[j]) {
                edges.push((i.min(j) as u32, i.max(j) as u32));
            }
        }
    }
    NeighbourGraph::from_edges(positions.len(), &edges)
}

/// Whether two nearby sensors are on the same stretch of surface.
fn along_surface(pa: &[f64; 3], na: &[f64; 3], pb: &[f64; 3], nb: &[f64; 3]) -> bool {
    if dot(na, nb) < MIN_NORMAL_COS {
        return false;
    }
    let d = sub(pb, pa);
    let length = norm(&d);
    length == 0.0
        || (dot(&d, na).abs() <= MAX_NORMAL_COMPONENT * length && dot(&d, nb).abs() <= MAX_NORMAL_COMPONENT * length)
}

pub(crate) fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub(crate) fn dot(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub(crate) fn cross(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

pub(crate) fn norm(a: &[f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

pub(crate) fn distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    norm(&sub(a, b))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sensors around a thin tube: the two sides are close through the body
    /// but must not be neighbours.
    #[test]
    #[cfg_attr(miri, ignore = "no unsafe code here; too slow under Miri")]
    fn opposite_sides_of_a_thin_tube_are_not_neighbours() {
        let (mut positions, mut normals) = (Vec::new(), Vec::new());
        let radius = 0.01;
        for row in 0..20 {
            for column in 0..40 {
                let angle = column as f64 / 40.0 * std::f64::consts::TAU;
                let normal = [angle.cos(), angle.sin(), 0.0];
                positions.push([radius * normal[0], radius * normal[1], row as f64 * 0.0016]);
                normals.push(normal);
            }
        }
        let graph = build(&positions, &normals);
        for i in 0..graph.len() {
            assert!(graph.of(i).len() >= 3, "sensor {i} has {} neighbours", graph.of(i).len());
            for &j in graph.of(i) {
                assert!(graph.of(j as usize).contains(&(i as u32)), "not symmetric");
                assert!(dot(&normals[i], &normals[j as usize]) > 0.5);
            }
        }
    }
}
