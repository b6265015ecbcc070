//! The 2-D "somatosensory" map: the skin's surface flattened into the plane.
//!
//! Method: a discrete exponential map (DEXP; Schmidt, Grimm and Wyvill,
//! "Interactive decal compositing with discrete exponential maps", SIGGRAPH
//! 2006) per connected surface piece, computed on the neighbour graph.
//!
//! * Each piece gets a root near its geodesic centre (the middle of a
//!   double-sweep diameter path).
//! * Sensors are visited in Dijkstra order of geodesic distance from the root.
//!   A sensor's 2-D position is its already-placed neighbours' positions plus
//!   the 3-D step to it, expressed in a tangent frame carried along the
//!   shortest-path tree by minimal rotations (a discrete parallel transport).
//!   The step is projected onto the plane normal to the two sensors' mean
//!   normal and keeps its 3-D length.
//! * On a developable surface (a cylinder, a cone, a plane) this is an
//!   isometry up to discretisation. A closed tube is cut along its cut locus,
//!   the line opposite the root that the shortest paths reach from both sides:
//!   the only edges whose length the map does not keep. They are counted as
//!   *seam* edges, not as distortion.
//! * Each piece is turned so that the robot's up is up on the map (or, for a
//!   piece that does not climb, to its principal axes), and the pieces are
//!   shelf-packed without overlap, a few pitches apart: the pieces of one
//!   link (most of whose sensors are on it) together in a block of their
//!   own, so that a body part cut into many pieces (an iCub patch's
//!   triangles, which touch no other) stays in one place on the map.
//!
//! The map measures itself ([`MapQuality`]): neighbour-distance error, seam
//! edges, triangles of the neighbour graph whose orientation the map flips,
//! and sensors that the map stacks onto another.

#![forbid(unsafe_code)]

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rstar::RTree;
use rstar::primitives::GeomWithData;

use super::neighbours::{NeighbourGraph, cross, distance, dot, norm, sub};

/// A map edge longer than this many times its 3-D length is a seam.
const SEAM_RATIO: f64 = 3.0;
/// Two sensors closer on the map than this fraction of their 3-D nearest
/// distance are stacked onto each other.
const STACKED_FRACTION: f64 = 0.3;

/// How faithful the map is.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MapQuality {
    /// Mean of |map length − 3-D length| / 3-D length over neighbour edges (seams excluded).
    pub mean_relative_error: f64,
    /// 95th percentile of the same.
    pub p95_relative_error: f64,
    /// Fraction of neighbour edges that lie across a seam.
    pub seam_edge_fraction: f64,
    /// Triangles of the neighbour graph (3-cliques, seams excluded).
    pub triangles: usize,
    /// Fraction of those whose orientation on the map is the reverse of the 3-D one.
    pub flipped_fraction: f64,
    /// Fraction of sensors the map puts onto another sensor.
    pub stacked_fraction: f64,
    /// Whether any two pieces' bounding boxes overlap (they must not).
    pub pieces_overlap: bool,
    /// Number of pieces.
    pub pieces: usize,
}

/// The flattened skin.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SkinMap {
    /// Each sensor's map position, metres.
    pub positions: Vec<[f32; 2]>,
    /// Each sensor's piece.
    pub piece_of: Vec<u32>,
    /// Each piece's bounding box on the map: `[min_x, min_y, max_x, max_y]`.
    pub piece_bounds: Vec<[f32; 4]>,
    /// The map's own distortion figures.
    pub quality: MapQuality,
}

#[derive(PartialEq)]
struct Visit(f64, u32);
impl Eq for Visit {}
impl PartialOrd for Visit {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Visit {
    fn cmp(&self, other: &Self) -> Ordering {
        other.0.total_cmp(&self.0).then_with(|| other.1.cmp(&self.1))
    }
}

/// Flattens the surface given by `positions`, unit `normals` and the
/// neighbour `graph`; the pieces of each link (`link_of`, by sensor) are
/// packed together.
pub fn build(positions: &[[f64; 3]], normals: &[[f64; 3]], graph: &NeighbourGraph, link_of: &[u16]) -> SkinMap {
    let n = positions.len();
    let pieces = components(graph);
    let mut piece_of = vec![0u32; n];
    let mut scratch = Dijkstra::new(n);
    let surface = Surface { positions, normals, graph };
    let mut placement = Placement { uv: vec![[0.0; 2]; n], frame: vec![[0.0; 3]; n], placed: vec![false; n] };
    for (p, members) in pieces.iter().enumerate() {
        for &m in members {
            piece_of[m as usize] = p as u32;
        }
        let root = centre(members, positions, graph, &mut scratch);
        surface.exponential_map(root, &mut scratch, &mut placement);
        surface.orient_up(members, &mut placement.uv);
    }
    let mut uv = placement.uv;
    let pitch = median_edge(positions, graph).max(1e-6);
    let link_of_piece: Vec<u16> = pieces.iter().map(|members| main_link(members, link_of)).collect();
    let piece_bounds = pack(&pieces, &link_of_piece, &mut uv, 3.0 * pitch);
    let quality = measure(positions, normals, graph, &uv, &piece_bounds);
    SkinMap {
        positions: uv.iter().map(|p| [p[0] as f32, p[1] as f32]).collect(),
        piece_of,
        piece_bounds: piece_bounds.iter().map(|b| b.map(|v| v as f32)).collect(),
        quality,
    }
}

/// Connected components, each ascending, largest first.
fn components(graph: &NeighbourGraph) -> Vec<Vec<u32>> {
    let n = graph.len();
    let mut seen = vec![false; n];
    let mut pieces = Vec::new();
    for start in 0..n {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut members = vec![start as u32];
        let mut k = 0;
        while k < members.len() {
            for &j in graph.of(members[k] as usize) {
                if !seen[j as usize] {
                    seen[j as usize] = true;
                    members.push(j);
                }
            }
            k += 1;
        }
        members.sort_unstable();
        pieces.push(members);
    }
    pieces.sort_by_key(|m| std::cmp::Reverse(m.len()));
    pieces
}

/// Dijkstra's scratch space, reused across pieces.
struct Dijkstra {
    dist: Vec<f64>,
    parent: Vec<u32>,
    order: Vec<u32>,
    touched: Vec<u32>,
}

impl Dijkstra {
    fn new(n: usize) -> Dijkstra {
        Dijkstra { dist: vec![f64::INFINITY; n], parent: vec![u32::MAX; n], order: Vec::new(), touched: Vec::new() }
    }

    /// Geodesic distances over the graph from `root`; `order` is the visiting order.
    fn run(&mut self, root: u32, positions: &[[f64; 3]], graph: &NeighbourGraph) {
        for &t in &self.touched {
            self.dist[t as usize] = f64::INFINITY;
            self.parent[t as usize] = u32::MAX;
        }
        self.touched.clear();
        self.order.clear();
        let mut heap = BinaryHeap::new();
        self.dist[root as usize] = 0.0;
        self.touched.push(root);
        heap.push(Visit(0.0, root));
        while let Some(Visit(d, i)) = heap.pop() {
            if d > self.dist[i as usize] {
                continue;
            }
            self.order.push(i);
            for &j in graph.of(i as usize) {
                let candidate = d + distance(&positions[i as usize], &positions[j as usize]);
                if candidate < self.dist[j as usize] {
                    if self.dist[j as usize].is_infinite() {
                        self.touched.push(j);
                    }
                    self.dist[j as usize] = candidate;
                    self.parent[j as usize] = i;
                    heap.push(Visit(candidate, j));
                }
            }
        }
    }

    fn farthest(&self) -> u32 {
        *self.order.last().expect("a piece has a sensor")
    }
}

/// A sensor near the piece's geodesic centre: the middle of the path between
/// two far-apart sensors found by a double sweep.
fn centre(members: &[u32], positions: &[[f64; 3]], graph: &NeighbourGraph, scratch: &mut Dijkstra) -> u32 {
    scratch.run(members[0], positions, graph);
    let a = scratch.farthest();
    scratch.run(a, positions, graph);
    let b = scratch.farthest();
    let half = scratch.dist[b as usize] / 2.0;
    let mut at = b;
    while scratch.dist[at as usize] > half && scratch.parent[at as usize] != u32::MAX {
        at = scratch.parent[at as usize];
    }
    at
}

/// The rotation-minimising transport of tangent vector `v` from normal `from` to normal `to`.
fn transport(v: &[f64; 3], from: &[f64; 3], to: &[f64; 3]) -> [f64; 3] {
    let axis = cross(from, to);
    let sin = norm(&axis);
    let cos = dot(from, to);
    if sin < 1e-12 {
        return *v;
    }
    let k = axis.map(|a| a / sin);
    // Rodrigues' rotation formula.
    let kxv = cross(&k, v);
    let kdv = dot(&k, v);
    [0, 1, 2].map(|a| v[a] * cos + kxv[a] * sin + k[a] * kdv * (1.0 - cos))
}

fn normalized(v: [f64; 3]) -> [f64; 3] {
    let l = norm(&v);
    if l < 1e-15 { v } else { v.map(|x| x / l) }
}

/// The surface being flattened.
struct Surface<'a> {
    positions: &'a [[f64; 3]],
    normals: &'a [[f64; 3]],
    graph: &'a NeighbourGraph,
}

/// The map under construction: positions, each placed sensor's tangent frame
/// (its first axis; the second is normal × first) and which are placed.
struct Placement {
    uv: Vec<[f64; 2]>,
    frame: Vec<[f64; 3]>,
    placed: Vec<bool>,
}

impl Surface<'_> {
    /// Where `j` lands seen from placed sensor `i`: `i`'s map position plus
    /// the 3-D step, projected onto the plane normal to the two sensors' mean
    /// normal, keeping its length, in `i`'s frame carried to that plane.
    fn step(&self, i: usize, j: usize, placement: &Placement) -> [f64; 2] {
        let (pi, ni, nj) = (&self.positions[i], &self.normals[i], &self.normals[j]);
        let mid = normalized([ni[0] + nj[0], ni[1] + nj[1], ni[2] + nj[2]]);
        let e1 = transport(&placement.frame[i], ni, &mid);
        let e2 = cross(&mid, &e1);
        let d = sub(&self.positions[j], pi);
        let t = sub(&d, &mid.map(|x| x * dot(&d, &mid)));
        let scale = if norm(&t) > 1e-15 { norm(&d) / norm(&t) } else { 0.0 };
        let base = placement.uv[i];
        [base[0] + dot(&t, &e1) * scale, base[1] + dot(&t, &e2) * scale]
    }

    /// The discrete exponential map of the piece around `root`.
    fn exponential_map(&self, root: u32, scratch: &mut Dijkstra, placement: &mut Placement) {
        scratch.run(root, self.positions, self.graph);
        let r = root as usize;
        let n = &self.normals[r];
        let helper = if n[0].abs() < 0.9 { [1.0, 0.0, 0.0] } else { [0.0, 1.0, 0.0] };
        placement.frame[r] = normalized(sub(&helper, &n.map(|x| x * dot(&helper, n))));
        placement.uv[r] = [0.0, 0.0];
        placement.placed[r] = true;
        for k in 1..scratch.order.len() {
            let j = scratch.order[k] as usize;
            let parent = scratch.parent[j] as usize;
            let from_parent = self.step(parent, j, placement);
            let step = distance(&self.positions[j], &self.positions[parent]).max(1e-12);
            let (mut sum, mut weight) = ([0.0f64; 2], 0.0f64);
            for &i in self.graph.of(j) {
                let i = i as usize;
                if !placement.placed[i] {
                    continue;
                }
                let candidate = if i == parent { from_parent } else { self.step(i, j, placement) };
                // Neighbours placed from the other side of the seam disagree; leave them out.
                let gap = ((candidate[0] - from_parent[0]).powi(2) + (candidate[1] - from_parent[1]).powi(2)).sqrt();
                if gap > step {
                    continue;
                }
                let w = 1.0 / distance(&self.positions[j], &self.positions[i]).max(1e-12).powi(2);
                sum[0] += w * candidate[0];
                sum[1] += w * candidate[1];
                weight += w;
            }
            placement.uv[j] = if weight > 0.0 { [sum[0] / weight, sum[1] / weight] } else { from_parent };
            placement.frame[j] =
                normalized(transport(&placement.frame[parent], &self.normals[parent], &self.normals[j]));
            placement.placed[j] = true;
        }
    }
}

impl Surface<'_> {
    /// Turns a piece so that the robot's up (+z) points up (+y) on the map,
    /// centred on 0: the map direction in which neighbour steps climb, summed
    /// over the piece's edges (seams left out). A piece that does not climb
    /// (a horizontal plate) is turned to its principal axes instead.
    fn orient_up(&self, members: &[u32], uv: &mut [[f64; 2]]) {
        let mut up = [0.0f64; 2];
        let mut climb = 0.0;
        for &i in members {
            let i = i as usize;
            for &j in self.graph.of(i) {
                let j = j as usize;
                let (step, map) =
                    (distance(&self.positions[i], &self.positions[j]), [uv[j][0] - uv[i][0], uv[j][1] - uv[i][1]]);
                let map_length = map[0].hypot(map[1]);
                if map_length > SEAM_RATIO * step || map_length < 1e-12 {
                    continue;
                }
                let rise = self.positions[j][2] - self.positions[i][2];
                up[0] += rise * map[0] / map_length;
                up[1] += rise * map[1] / map_length;
                climb += rise.abs();
            }
        }
        if up[0].hypot(up[1]) < 0.1 * climb || climb == 0.0 {
            principal_axes(members, uv);
            return;
        }
        let turn = std::f64::consts::FRAC_PI_2 - up[1].atan2(up[0]);
        rotate_about_centroid(members, uv, turn);
    }
}

/// Turns a piece by `turn` radians about its centroid, then centres it on 0.
fn rotate_about_centroid(members: &[u32], uv: &mut [[f64; 2]], turn: f64) {
    let count = members.len() as f64;
    let mean = members.iter().fold([0.0, 0.0], |m, &i| [m[0] + uv[i as usize][0], m[1] + uv[i as usize][1]]);
    let mean = [mean[0] / count, mean[1] / count];
    let (sin, cos) = turn.sin_cos();
    for &i in members {
        let (x, y) = (uv[i as usize][0] - mean[0], uv[i as usize][1] - mean[1]);
        uv[i as usize] = [x * cos - y * sin, x * sin + y * cos];
    }
}

/// Turns a piece so that its longest principal axis is vertical, centred on 0.
fn principal_axes(members: &[u32], uv: &mut [[f64; 2]]) {
    let count = members.len() as f64;
    let mean = members.iter().fold([0.0, 0.0], |m, &i| [m[0] + uv[i as usize][0], m[1] + uv[i as usize][1]]);
    let mean = [mean[0] / count, mean[1] / count];
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for &i in members {
        let (x, y) = (uv[i as usize][0] - mean[0], uv[i as usize][1] - mean[1]);
        sxx += x * x;
        sxy += x * y;
        syy += y * y;
    }
    // The major axis angle; rotate it onto +y.
    let major = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    rotate_about_centroid(members, uv, std::f64::consts::FRAC_PI_2 - major);
}

fn median_edge(positions: &[[f64; 3]], graph: &NeighbourGraph) -> f64 {
    let mut lengths: Vec<f64> = (0..graph.len())
        .flat_map(|i| graph.of(i).iter().map(move |&j| (i, j as usize)))
        .filter(|&(i, j)| i < j)
        .map(|(i, j)| distance(&positions[i], &positions[j]))
        .collect();
    if lengths.is_empty() {
        return 0.0;
    }
    let middle = lengths.len() / 2;
    *lengths.select_nth_unstable_by(middle, f64::total_cmp).1
}

/// The link most of `members` are on (the lowest of those tied; 0 without links).
fn main_link(members: &[u32], link_of: &[u16]) -> u16 {
    let mut counts: std::collections::BTreeMap<u16, usize> = std::collections::BTreeMap::new();
    for &m in members {
        *counts.entry(link_of.get(m as usize).copied().unwrap_or(0)).or_default() += 1;
    }
    counts.into_iter().max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0))).map_or(0, |(link, _)| link)
}

/// Packs the pieces without overlap, `gap` apart: the pieces of each link
/// (`link_of_piece`) shelf-packed into a block, then the blocks
/// shelf-packed, in the order of their first piece. A link of one piece is
/// a block of that piece alone. Moves the pieces' sensors in `uv`; returns
/// each piece's bounds.
fn pack(pieces: &[Vec<u32>], link_of_piece: &[u16], uv: &mut [[f64; 2]], gap: f64) -> Vec<[f64; 4]> {
    let bounds: Vec<[f64; 4]> = pieces
        .iter()
        .map(|members| {
            members.iter().fold([f64::MAX, f64::MAX, f64::MIN, f64::MIN], |b, &i| {
                let [x, y] = uv[i as usize];
                [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)]
            })
        })
        .collect();
    let mut blocks: Vec<Vec<usize>> = Vec::new();
    let mut block_of_link = std::collections::HashMap::new();
    for (p, link) in link_of_piece.iter().enumerate() {
        let block = *block_of_link.entry(link).or_insert_with(|| {
            blocks.push(Vec::new());
            blocks.len() - 1
        });
        blocks[block].push(p);
    }
    // Each piece placed in its block, then each block on the map.
    let mut placed = vec![[0.0; 4]; pieces.len()];
    let mut block_bounds = Vec::with_capacity(blocks.len());
    for members in &blocks {
        let boxes: Vec<[f64; 4]> = members.iter().map(|&p| bounds[p]).collect();
        let mut block = [f64::MAX, f64::MAX, f64::MIN, f64::MIN];
        for (&p, [x, y]) in members.iter().zip(shelve(&boxes, gap)) {
            let b = bounds[p];
            placed[p] = [x, y, x + (b[2] - b[0]), y + (b[3] - b[1])];
            block = [block[0].min(x), block[1].min(y), block[2].max(placed[p][2]), block[3].max(placed[p][3])];
        }
        block_bounds.push(block);
    }
    for ((members, block), [x, y]) in blocks.iter().zip(&block_bounds).zip(shelve(&block_bounds, gap)) {
        let shift = [x - block[0], y - block[1]];
        for &p in members {
            let spot = &mut placed[p];
            *spot = [spot[0] + shift[0], spot[1] + shift[1], spot[2] + shift[0], spot[3] + shift[1]];
            let delta = [spot[0] - bounds[p][0], spot[1] - bounds[p][1]];
            for &i in &pieces[p] {
                uv[i as usize][0] += delta[0];
                uv[i as usize][1] += delta[1];
            }
        }
    }
    placed
}

/// Shelf-packs `boxes` (tallest first) into rows about as wide as the whole
/// is tall, `gap` apart; returns where each box's lower left corner goes.
fn shelve(boxes: &[[f64; 4]], gap: f64) -> Vec<[f64; 2]> {
    let area: f64 = boxes.iter().map(|b| (b[2] - b[0] + gap) * (b[3] - b[1] + gap)).sum();
    let widest = boxes.iter().map(|b| b[2] - b[0] + gap).fold(0.0, f64::max);
    let row_width = (area.sqrt() * 1.3).max(widest);
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| (boxes[b][3] - boxes[b][1]).total_cmp(&(boxes[a][3] - boxes[a][1])).then(a.cmp(&b)));
    let (mut x, mut y, mut row_height) = (0.0, 0.0, 0.0f64);
    let mut corners = vec![[0.0; 2]; boxes.len()];
    for k in order {
        let b = boxes[k];
        let (w, h) = (b[2] - b[0], b[3] - b[1]);
        if x > 0.0 && x + w > row_width {
            x = 0.0;
            y += row_height + gap;
            row_height = 0.0;
        }
        corners[k] = [x, y];
        x += w + gap;
        row_height = row_height.max(h);
    }
    corners
}

fn measure(
    positions: &[[f64; 3]],
    normals: &[[f64; 3]],
    graph: &NeighbourGraph,
    uv: &[[f64; 2]],
    bounds: &[[f64; 4]],
) -> MapQuality {
    let (mut errors, seams) = edge_errors(positions, graph, uv);
    let edges = errors.len() + seams;
    let mean_relative_error = if errors.is_empty() { 0.0 } else { errors.iter().sum::<f64>() / errors.len() as f64 };
    let p95_relative_error = if errors.is_empty() {
        0.0
    } else {
        let k = ((errors.len() as f64 * 0.95) as usize).min(errors.len() - 1);
        *errors.select_nth_unstable_by(k, f64::total_cmp).1
    };
    let (triangles, flipped) = count_flipped_triangles(positions, normals, graph, uv);
    let stacked = count_stacked(positions, uv);
    MapQuality {
        mean_relative_error,
        p95_relative_error,
        seam_edge_fraction: if edges == 0 { 0.0 } else { seams as f64 / edges as f64 },
        triangles,
        flipped_fraction: if triangles == 0 { 0.0 } else { flipped as f64 / triangles as f64 },
        stacked_fraction: if uv.is_empty() { 0.0 } else { stacked as f64 / uv.len() as f64 },
        pieces_overlap: pieces_overlap(bounds),
        pieces: bounds.len(),
    }
}

/// The distance between sensors `i` and `j` on the map.
fn map_distance(uv: &[[f64; 2]], i: usize, j: usize) -> f64 {
    ((uv[i][0] - uv[j][0]).powi(2) + (uv[i][1] - uv[j][1]).powi(2)).sqrt()
}

/// Whether the edge `i`-`j` is cut by the map (stretched past [`SEAM_RATIO`]).
fn is_seam(positions: &[[f64; 3]], uv: &[[f64; 2]], i: usize, j: usize) -> bool {
    map_distance(uv, i, j) > SEAM_RATIO * distance(&positions[i], &positions[j])
}

/// The relative length error of every edge the map keeps, and the number of seam edges.
fn edge_errors(positions: &[[f64; 3]], graph: &NeighbourGraph, uv: &[[f64; 2]]) -> (Vec<f64>, usize) {
    let mut errors = Vec::new();
    let mut seams = 0usize;
    for i in 0..graph.len() {
        for &j in graph.of(i) {
            let j = j as usize;
            if j <= i {
                continue;
            }
            if is_seam(positions, uv, i, j) {
                seams += 1;
                continue;
            }
            let d3 = distance(&positions[i], &positions[j]).max(1e-12);
            errors.push((map_distance(uv, i, j) - d3).abs() / d3);
        }
    }
    (errors, seams)
}

/// Triangles of the neighbour graph without a seam edge, and how many of
/// them the map turns over relative to the surface's outward side.
fn count_flipped_triangles(
    positions: &[[f64; 3]],
    normals: &[[f64; 3]],
    graph: &NeighbourGraph,
    uv: &[[f64; 2]],
) -> (usize, usize) {
    let is_seam = |i: usize, j: usize| is_seam(positions, uv, i, j);
    let (mut triangles, mut flipped) = (0usize, 0usize);
    for i in 0..graph.len() {
        let around = graph.of(i);
        for (a, &j) in around.iter().enumerate() {
            let j = j as usize;
            if j <= i || is_seam(i, j) {
                continue;
            }
            for &k in &around[a + 1..] {
                let k = k as usize;
                if k <= i || !graph.of(j).contains(&(k as u32)) || is_seam(i, k) || is_seam(j, k) {
                    continue;
                }
                let normal = [0, 1, 2].map(|c| normals[i][c] + normals[j][c] + normals[k][c]);
                let oriented =
                    dot(&cross(&sub(&positions[j], &positions[i]), &sub(&positions[k], &positions[i])), &normal);
                let on_map =
                    (uv[j][0] - uv[i][0]) * (uv[k][1] - uv[i][1]) - (uv[j][1] - uv[i][1]) * (uv[k][0] - uv[i][0]);
                triangles += 1;
                if oriented * on_map < 0.0 {
                    flipped += 1;
                }
            }
        }
    }
    (triangles, flipped)
}

/// Sensors whose nearest neighbour on the map is much nearer than their
/// nearest neighbour in 3-D ([`STACKED_FRACTION`]): the map stacks them.
fn count_stacked(positions: &[[f64; 3]], uv: &[[f64; 2]]) -> usize {
    let tree3 = super::neighbours::spatial_index(positions);
    let nearest3 = super::neighbours::nearest_distances(&tree3, positions);
    let tree2: RTree<GeomWithData<[f64; 2], u32>> =
        RTree::bulk_load(uv.iter().enumerate().map(|(i, p)| GeomWithData::new(*p, i as u32)).collect());
    uv.iter()
        .enumerate()
        .filter(|&(i, p)| {
            tree2.nearest_neighbor_iter(p).find(|c| c.data as usize != i).is_some_and(|c| {
                let g = c.geom();
                ((g[0] - p[0]).powi(2) + (g[1] - p[1]).powi(2)).sqrt() < STACKED_FRACTION * nearest3[i]
            })
        })
        .count()
}

/// Whether any two pieces' bounds overlap.
fn pieces_overlap(bounds: &[[f64; 4]]) -> bool {
    let mut pieces_overlap = false;
    for a in 0..bounds.len() {
        for b in a + 1..bounds.len() {
            let (p, q) = (bounds[a], bounds[b]);
            if p[0] < q[2] && q[0] < p[2] && p[1] < q[3] && q[1] < p[3] {
                pieces_overlap = true;
            }
        }
    }
    pieces_overlap
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A spherical cap of half-angle 60°: not developable, so the map must
    /// stretch it, but only a little, and without folding it.
    #[test]
    #[cfg_attr(miri, ignore = "no unsafe code here; too slow under Miri")]
    fn a_spherical_cap_flattens_without_folds_and_with_small_distortion() {
        let (mut positions, mut normals) = (Vec::new(), Vec::new());
        let radius = 0.1;
        let count = 3000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        // A Fibonacci sphere, keeping the cap around +z.
        for k in 0..count * 4 {
            let z = 1.0 - (k as f64 + 0.5) / (count * 2) as f64;
            if z < 0.5 {
                break;
            }
            let r = (1.0 - z * z).sqrt();
            let a = golden * k as f64;
            let normal = [r * a.cos(), r * a.sin(), z];
            positions.push(normal.map(|c| c * radius));
            normals.push(normal);
        }
        let graph = super::super::neighbours::build(&positions, &normals);
        let map = build(&positions, &normals, &graph, &vec![0; positions.len()]);
        let q = &map.quality;
        eprintln!("spherical cap, {} sensors: {q:?}", positions.len());
        assert_eq!(q.pieces, 1, "{q:?}");
        assert!(q.mean_relative_error < 0.08, "{q:?}");
        assert!(q.flipped_fraction < 0.01, "{q:?}");
        assert_eq!(q.stacked_fraction, 0.0, "{q:?}");
        // A cap has no seam.
        assert_eq!(q.seam_edge_fraction, 0.0, "{q:?}");
    }

    /// Two links' pieces, interleaved in sensor order (as an iCub's triangle
    /// modules of two patches, each a piece of its own, might be): each
    /// link's pieces end up in a block of their own, overlapping neither
    /// the other link's block nor each other.
    #[test]
    fn the_pieces_of_one_link_are_packed_together() {
        let (mut positions, mut normals, mut link_of) = (Vec::new(), Vec::new(), Vec::new());
        for module in 0..16u16 {
            for k in 0..12 {
                let x = f64::from(module) * 0.02 + f64::from(k % 4) * 0.004;
                positions.push([x, f64::from(k / 4) * 0.004 + f64::from(module % 3) * 1e-5, 0.0]);
                normals.push([0.0, 0.0, 1.0]);
                link_of.push(module % 2);
            }
        }
        let graph = super::super::neighbours::build(&positions, &normals);
        let map = build(&positions, &normals, &graph, &link_of);
        assert_eq!(map.quality.pieces, 16, "each module a piece");
        assert!(!map.quality.pieces_overlap);
        let block = |link: u16| {
            let corners = map.positions.iter().zip(&link_of).filter(|(_, l)| **l == link).map(|(p, _)| *p);
            corners.fold([f32::MAX, f32::MAX, f32::MIN, f32::MIN], |b, [x, y]| {
                [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)]
            })
        };
        let (even, odd) = (block(0), block(1));
        let apart = even[2] < odd[0] || odd[2] < even[0] || even[3] < odd[1] || odd[3] < even[1];
        assert!(apart, "the links' blocks overlap: {even:?} {odd:?}");
    }
}
