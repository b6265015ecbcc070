//! Contact detection, in the spirit of iCub's skinManager: a per-taxel
//! baseline that follows slow drift while the taxel is not touched, a touch
//! threshold from each taxel's measured noise, contacts as connected groups
//! of touched taxels on the neighbour graph, reported per region; and taxels
//! that never change (dead) or sit at saturation (stuck).

use std::ops::Range;

use crate::framework::ServicePayload;
use memory::{Layout, Placed, TaxelMemory};
use skinware_geometry::SkinGeometry;
use taxels::{Limits, TaxelTracks, list_non_idle};

mod memory;
mod taxels;

/// Contacts reported per region and frame; more are counted in `flags`.
pub const MAX_CONTACTS: usize = 8;

/// One contact: a connected group of touched taxels within one region.
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct Contact {
    /// Touched taxels in it.
    pub taxels: u32,
    /// Global index of its most pressed taxel.
    pub peak_sensor: u32,
    /// Pressure-weighted centroid, metres.
    pub centroid: [f32; 3],
    /// Pressure-weighted mean outward normal (unit).
    pub normal: [f32; 3],
    /// Pressure-weighted centroid on the 2-D map, metres.
    pub map: [f32; 2],
    /// Sensing area of its taxels, m².
    pub area_m2: f32,
    /// Sum of responses above baseline.
    pub total: f32,
    /// Largest response above baseline.
    pub peak: f32,
}

/// The contacts of one region in one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct RegionContacts {
    /// Valid entries of `contacts`, largest total pressure first.
    pub count: u32,
    /// [`contact_flags`].
    pub flags: u32,
    /// Dead taxels in the region (never change).
    pub dead: u32,
    /// Stuck taxels in the region (saturated).
    pub stuck: u32,
    /// The contacts.
    pub contacts: [Contact; MAX_CONTACTS],
}

impl RegionContacts {
    /// The valid contacts.
    pub fn contacts(&self) -> &[Contact] {
        &self.contacts[..(self.count as usize).min(MAX_CONTACTS)]
    }
}

impl ServicePayload for RegionContacts {
    const SCHEMA: &'static str = "skinware.contacts";
    const VERSION: u32 = 1;
}

/// Bits of [`RegionContacts::flags`].
pub mod contact_flags {
    /// A layer holding some of the region's taxels is faulted, gone or stale:
    /// those taxels are left out, and contacts there are not seen.
    pub const INPUT_FAULTED: u32 = 1;
    /// More than [`super::MAX_CONTACTS`] contacts; the smallest were dropped.
    pub const MORE_CONTACTS: u32 = 2;
}

/// The state of one taxel, published per taxel by the contact service's
/// `NAME-taxels` channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(transparent)]
pub struct TaxelState(pub u8);

impl TaxelState {
    /// Not touched.
    pub const IDLE: TaxelState = TaxelState(0);
    /// Above its touch threshold.
    pub const TOUCHED: TaxelState = TaxelState(1);
    /// Its response never changes.
    pub const DEAD: TaxelState = TaxelState(2);
    /// Its response sits at saturation.
    pub const STUCK: TaxelState = TaxelState(3);
    /// Its layer is faulted, gone or stale.
    pub const NO_INPUT: TaxelState = TaxelState(4);
}

impl ServicePayload for TaxelState {
    const SCHEMA: &'static str = "skinware.taxel-state";
    const VERSION: u32 = 1;
}

/// Parameters of contact detection.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactParams {
    /// The touch threshold is this many noise standard deviations above the baseline...
    pub threshold_sigma: f32,
    /// ...and at least this many response units.
    pub min_threshold: f32,
    /// Time constant of the baseline and noise estimates, seconds.
    pub baseline_tau_s: f32,
    /// A taxel whose response has not changed for this many frames is dead.
    pub dead_frames: u32,
    /// A response at or above this is saturated...
    pub saturation: u16,
    /// ...and a taxel saturated for this many frames is stuck.
    pub stuck_frames: u32,
}

impl Default for ContactParams {
    fn default() -> Self {
        ContactParams {
            threshold_sigma: 6.0,
            min_threshold: 60.0,
            baseline_tau_s: 3.0,
            dead_frames: 100,
            saturation: 65_000,
            stuck_frames: 50,
        }
    }
}

/// Running per-region accumulation of one contact.
#[derive(Clone, Copy, Default)]
struct Accumulator {
    weight: f64,
    position: [f64; 3],
    normal: [f64; 3],
    map: [f64; 2],
    map_weight: f64,
    taxels: u32,
    area: f64,
    peak: f32,
    peak_sensor: u32,
}

/// The contact detector's state: one baseline and noise estimate per taxel.
pub struct ContactDetector {
    params: ContactParams,
    /// Region names (the geometry's, or one `skin` region for the whole skin).
    names: Vec<String>,
    /// Every per-taxel array below that is [`Placed`], in one block.
    memory: TaxelMemory,
    /// What the contacts need of each taxel, in one record per taxel.
    sites: Placed<Site>,
    /// Each taxel's regions: `member_regions[site.regions[0]..site.regions[1]]`.
    member_regions: Vec<u32>,
    /// Each region's layers.
    region_layers: Vec<Vec<usize>>,
    /// Each layer's taxels: a contiguous range of the global order.
    layer_ranges: Vec<Range<usize>>,
    /// Whether each layer's baselines have been set from its first frame.
    layer_initialized: Vec<bool>,
    /// Whether each layer's states, lists and residuals are those of its
    /// current frame (it was classified and has had input since).
    layer_classified: Vec<bool>,
    /// Seconds since each layer's baselines last stepped: a layer without a
    /// new frame is not classified again, so its next frame steps them by
    /// all the time since, and their time constant stays in seconds
    /// whatever the layer's rate against the service's.
    layer_elapsed_s: Vec<f32>,
    /// Each layer's touched taxels (global indices) as its last
    /// classification listed them.
    layer_touched: Vec<Vec<u32>>,
    /// Each layer's dead and stuck taxels, likewise.
    layer_dead_or_stuck: Vec<Vec<u32>>,
    tracks: TaxelTracks,
    states: Placed<TaxelState>,
    /// The touched taxels of the last update (each layer's as of its last
    /// classification), in global order: where the component search
    /// starts, so that it does not scan the whole skin.
    touched: Vec<u32>,
    /// Each taxel's response above its baseline, by taxel, written for the
    /// touched taxels of each layer's last classification only (the
    /// others' are stale and never read: a component holds touched taxels
    /// only). By taxel rather than
    /// beside `touched`: the accumulation looks each one up twice, and on
    /// skin demo's 1,100-1,600 touched taxels a frame, a binary search of
    /// `touched` for each cost the service more than the search for the
    /// components itself.
    residuals: Placed<f32>,
    /// The dead and stuck taxels of the last update, for the regions' counts.
    dead_or_stuck: Vec<u32>,
    /// One bit per taxel: touched this frame and not yet in a component.
    /// Set from `touched` before the search, cleared as the search reaches
    /// each taxel. The search tests one bit of 4 KB per neighbour, rather
    /// than the neighbour's state (30 KB of states) and a visited bit.
    pending: Vec<u64>,
    queue: Vec<u32>,
    accumulators: Vec<Accumulator>,
    touched_regions: Vec<u32>,
    found: Vec<Vec<Contact>>,
}

impl ContactDetector {
    /// A detector for the skin of `geometry`, reporting per region (or for
    /// the whole skin as one region `skin` when the geometry has none).
    pub fn new(geometry: &SkinGeometry, params: ContactParams) -> ContactDetector {
        let n = geometry.sensor_count();
        // A built or decoded geometry has one of each per sensor; a missing
        // one would read as zeros below (a contact at the map's origin).
        debug_assert!(
            geometry.positions.len() == n
                && geometry.normals.len() == n
                && geometry.radii.len() == n
                && geometry.map.positions.len() == n,
            "a geometry whose per-sensor arrays are not all {n} long"
        );
        let (names, sets): (Vec<String>, Vec<Vec<u32>>) = if geometry.regions.names.is_empty() {
            (vec!["skin".to_owned()], vec![(0..n as u32).collect()])
        } else {
            (geometry.regions.names.clone(), geometry.regions.sensors.clone())
        };
        let mut per_sensor: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (r, set) in sets.iter().enumerate() {
            for &s in set {
                per_sensor[s as usize].push(r as u32);
            }
        }
        // The arrays walked every frame first, then those of touched taxels.
        let mut layout = Layout::default();
        let (tracks, states) = TaxelTracks::place(&mut layout, n, params.dead_frames, params.stuck_frames);
        let (residuals, sites) = (layout.place(n), layout.place(n));
        let mut memory = TaxelMemory::new(&layout);
        let member_regions = fill_sites(geometry, &per_sensor, memory.get_mut(sites));
        let layer_ranges: Vec<Range<usize>> =
            (0..geometry.layers.len()).map(|l| geometry.layer_starts[l]..geometry.layer_starts[l + 1]).collect();
        let mut layer_of = vec![0usize; n];
        for (l, range) in layer_ranges.iter().enumerate() {
            layer_of[range.clone()].fill(l);
        }
        let region_layers = sets
            .iter()
            .map(|set| {
                let mut layers: Vec<usize> = set.iter().map(|&s| layer_of[s as usize]).collect();
                layers.sort_unstable();
                layers.dedup();
                layers
            })
            .collect();
        let regions = names.len();
        ContactDetector {
            params,
            names,
            memory,
            sites,
            member_regions,
            region_layers,
            layer_initialized: vec![false; layer_ranges.len()],
            layer_classified: vec![false; layer_ranges.len()],
            layer_elapsed_s: vec![0.0; layer_ranges.len()],
            layer_touched: vec![Vec::new(); layer_ranges.len()],
            layer_dead_or_stuck: vec![Vec::new(); layer_ranges.len()],
            layer_ranges,
            tracks,
            states,
            touched: Vec::new(),
            residuals,
            dead_or_stuck: Vec::new(),
            pending: vec![0; n.div_ceil(64)],
            queue: Vec::new(),
            accumulators: vec![Accumulator::default(); regions],
            touched_regions: Vec::new(),
            found: vec![Vec::new(); regions],
        }
    }

    /// The regions reported, in record order.
    pub fn region_names(&self) -> &[String] {
        &self.names
    }

    /// Every taxel's state after the last [`update`](Self::update).
    pub fn taxel_states(&self) -> &[TaxelState] {
        self.memory.get(self.states)
    }

    /// Processes one frame of the whole skin: `responses` in global order,
    /// `layer_ok` per layer, `layer_fresh` per layer (a new frame since the
    /// previous update), `dt_s` seconds since the previous update. Writes one
    /// record per region into `out`.
    ///
    /// A layer that is not fresh holds the frame the previous update saw: its
    /// taxels keep the states they had, and its baselines step when its next
    /// frame comes, by the time since they last did. So a baseline follows
    /// each new response once, dead and stuck taxels are counted in frames,
    /// and a layer slower than the service costs nothing between its frames.
    pub fn update(
        &mut self,
        geometry: &SkinGeometry,
        responses: &[u16],
        layer_ok: &[bool],
        layer_fresh: &[bool],
        dt_s: f32,
        out: &mut [RegionContacts],
    ) {
        let starts = &geometry.layer_starts;
        let layer_responses = |layer: usize| responses.get(*starts.get(layer)?..*starts.get(layer + 1)?);
        self.update_layers(geometry, layer_responses, layer_ok, layer_fresh, dt_s, out);
    }

    /// [`update`](Self::update) with each layer's responses where they are
    /// (for example in each layer reader's copy, [`crate::SkinInputs::layer_responses`]),
    /// rather than gathered into one array: `layer_responses(l)` gives layer
    /// `l`'s, or `None` for a layer without input. A layer whose responses
    /// are not exactly its taxels has no input either.
    pub fn update_layers<'r>(
        &mut self,
        geometry: &SkinGeometry,
        layer_responses: impl Fn(usize) -> Option<&'r [u16]>,
        layer_ok: &[bool],
        layer_fresh: &[bool],
        dt_s: f32,
        out: &mut [RegionContacts],
    ) {
        self.classify_taxels(&layer_responses, layer_ok, layer_fresh, dt_s);
        self.find_contacts(geometry);
        self.write_region_records(layer_ok, out);
        self.count_dead_and_stuck(out);
    }

    /// Follows each taxel's baseline and noise, sets its state, and lists the
    /// touched, dead and stuck taxels.
    fn classify_taxels<'r>(
        &mut self,
        layer_responses: &impl Fn(usize) -> Option<&'r [u16]>,
        layer_ok: &[bool],
        layer_fresh: &[bool],
        dt_s: f32,
    ) {
        let p = &self.params;
        let tau_s = p.baseline_tau_s.max(1e-3);
        let mut limits = Limits {
            threshold_sigma: p.threshold_sigma,
            min_threshold: p.min_threshold,
            saturation: p.saturation,
            stuck_frames: p.stuck_frames,
            dead_frames: p.dead_frames,
            alpha: 0.0,
        };
        self.touched.clear();
        self.dead_or_stuck.clear();
        let covered_end = self.layer_ranges.last().map_or(0, |r| r.end);
        self.memory.get_mut(self.states)[covered_end..].fill(TaxelState::NO_INPUT);
        for (layer, range) in self.layer_ranges.iter().enumerate() {
            // A layer whose responses are not all there (inputs shorter than
            // the skin: a caller's mistake) has no input, rather than a panic.
            let input = layer_responses(layer).filter(|input| input.len() == range.len());
            let (Some(input), true) = (input, layer_ok.get(layer).copied().unwrap_or(false)) else {
                self.memory.get_mut(self.states)[range.clone()].fill(TaxelState::NO_INPUT);
                self.layer_classified[layer] = false;
                self.layer_elapsed_s[layer] = 0.0;
                self.layer_touched[layer].clear();
                self.layer_dead_or_stuck[layer].clear();
                continue;
            };
            // At most one time constant: a layer without a period (sporadic)
            // may hold one frame for minutes, and one step by all that time
            // would set each noise estimate from one response.
            self.layer_elapsed_s[layer] = (self.layer_elapsed_s[layer] + dt_s.max(0.0)).min(tau_s);
            // A caller that says nothing of a layer's freshness (a short
            // `layer_fresh`) gets it classified, as a frame read again.
            let said = layer_fresh.get(layer).copied();
            let fresh = said.unwrap_or(false);
            if said != Some(false) || !self.layer_classified[layer] {
                if !self.layer_initialized[layer] {
                    self.layer_initialized[layer] = true;
                    self.tracks.initialize(&mut self.memory, range.clone(), input);
                }
                limits.alpha = 1.0 - (-self.layer_elapsed_s[layer] / tau_s).exp();
                self.layer_elapsed_s[layer] = 0.0;
                self.layer_classified[layer] = true;
                self.tracks.classify(&mut self.memory, self.states, range.clone(), input, fresh, &limits);
                let (touched, dead_or_stuck) = (&mut self.layer_touched[layer], &mut self.layer_dead_or_stuck[layer]);
                touched.clear();
                dead_or_stuck.clear();
                let states = &self.memory.get(self.states)[range.clone()];
                list_non_idle(states, range.start, touched, dead_or_stuck);
                // A touched taxel's baseline was not moved by this frame: its
                // residual now is the one it was classified with, and stays
                // so until the layer's next classification.
                for &i in touched.iter() {
                    let i = i as usize;
                    let residual = self.tracks.residual(&self.memory, i, input[i - range.start]);
                    self.memory.get_mut(self.residuals)[i] = residual;
                }
            }
            self.touched.extend_from_slice(&self.layer_touched[layer]);
            self.dead_or_stuck.extend_from_slice(&self.layer_dead_or_stuck[layer]);
        }
    }

    /// Groups the touched taxels into connected components on the neighbour
    /// graph and adds each, split by region, to `found`.
    fn find_contacts(&mut self, geometry: &SkinGeometry) {
        for found in &mut self.found {
            found.clear();
        }
        // The search leaves every bit clear; cleared anyway (4 KB), so that a
        // search cut short by a panic cannot leave phantom taxels behind.
        self.pending.fill(0);
        for &i in &self.touched {
            set(&mut self.pending, i as usize);
        }
        self.load_contact_data(geometry);
        // A component holds each touched taxel at most once, and the search
        // writes one slot past the component's end.
        self.queue.resize(self.touched.len() + 1, 0);
        for k in 0..self.touched.len() {
            let start = self.touched[k] as usize;
            if !is_set(&self.pending, start) {
                continue;
            }
            let taxels = self.collect_component(geometry, start);
            self.accumulate_component(taxels);
        }
    }

    /// Reads, once, the memory that the search and the accumulation will
    /// read for each touched taxel: its site and its neighbours. Between two
    /// frames of a running service these lines leave the caches (other
    /// threads, other processes, and on a VM the hypervisor), and the search
    /// reads them in a dependent order (each taxel found leads to its
    /// neighbours): one cache miss after another, about 30 µs per frame for
    /// 200 touched taxels of the paper's skin, against 5 µs with the lines
    /// cached. Here each taxel's loads are independent of the others', so the
    /// CPU has many misses in flight at once.
    fn load_contact_data(&self, geometry: &SkinGeometry) {
        let mut bits = 0u32;
        let sites = self.memory.get(self.sites);
        for &i in &self.touched {
            let i = i as usize;
            let site = &sites[i];
            bits ^= site.position[0].to_bits()
                ^ self.member_regions.get(site.regions[0] as usize).copied().unwrap_or(0)
                ^ geometry.neighbours_of(i).first().copied().unwrap_or(0);
        }
        std::hint::black_box(bits);
    }

    /// Breadth-first search from `start` over pending taxels (touched, not
    /// yet in a component), clearing their bits and leaving them in
    /// `queue[..taxels]`; returns `taxels`.
    ///
    /// Without a branch on the neighbour's bit: every neighbour is written
    /// at the queue's end and its bit cleared, and the end moves on only if
    /// the bit was set. Whether a neighbour is pending is as good as random,
    /// and a mispredicted branch per neighbour cost more than the search's
    /// memory once `load_contact_data` has brought it in.
    fn collect_component(&mut self, geometry: &SkinGeometry, start: usize) -> usize {
        let (queue, pending) = (&mut self.queue, &mut self.pending);
        queue[0] = start as u32;
        clear(pending, start);
        let (mut k, mut taxels) = (0, 1);
        while k < taxels {
            for &j in geometry.neighbours_of(queue[k] as usize) {
                let (word, bit) = (&mut pending[j as usize / 64], j % 64);
                let was_pending = (*word >> bit) & 1;
                *word &= !(1 << bit);
                queue[taxels] = j;
                taxels += was_pending as usize;
            }
            k += 1;
        }
        taxels
    }

    /// Writes each region's largest contacts and its flags into `out`.
    fn write_region_records(&mut self, layer_ok: &[bool], out: &mut [RegionContacts]) {
        for (r, record) in out.iter_mut().enumerate().take(self.found.len()) {
            let found = &mut self.found[r];
            found.sort_by(|a, b| b.total.total_cmp(&a.total));
            let mut flags = 0;
            if self.region_layers[r].iter().any(|&l| !layer_ok.get(l).copied().unwrap_or(false)) {
                flags |= contact_flags::INPUT_FAULTED;
            }
            if found.len() > MAX_CONTACTS {
                flags |= contact_flags::MORE_CONTACTS;
            }
            *record =
                RegionContacts { count: found.len().min(MAX_CONTACTS) as u32, flags, ..RegionContacts::default() };
            for (slot, contact) in record.contacts.iter_mut().zip(found.iter()) {
                *slot = *contact;
            }
        }
    }

    /// The regions of taxel `i`.
    fn regions_of(&self, i: usize) -> &[u32] {
        let [first, end] = self.memory.get(self.sites)[i].regions;
        &self.member_regions[first as usize..end as usize]
    }

    /// Adds the dead and stuck taxels to the counts of their regions' records.
    fn count_dead_and_stuck(&self, out: &mut [RegionContacts]) {
        let states = self.memory.get(self.states);
        for &i in &self.dead_or_stuck {
            let i = i as usize;
            for &r in self.regions_of(i) {
                let Some(record) = out.get_mut(r as usize) else { continue };
                if states[i] == TaxelState::DEAD {
                    record.dead += 1;
                } else {
                    record.stuck += 1;
                }
            }
        }
    }

    /// Splits the component in `queue[..taxels]` by region and adds one
    /// contact to each.
    fn accumulate_component(&mut self, taxels: usize) {
        let component = &self.queue[..taxels];
        self.touched_regions.clear();
        // Every taxel of the component is touched: its residual is the one
        // its layer's last classification found.
        let (residuals, sites) = (self.memory.get(self.residuals), self.memory.get(self.sites));
        let residual = |i: usize| residuals.get(i).copied().unwrap_or(0.0);
        for &i in component {
            let i = i as usize;
            let residual = residual(i);
            let w = f64::from(residual.max(0.0));
            let site = &sites[i];
            let position = site.position.map(f64::from);
            let normal = site.normal.map(f64::from);
            let radius = f64::from(site.radius);
            let [first, end] = site.regions;
            for &r in &self.member_regions[first as usize..end as usize] {
                let a = &mut self.accumulators[r as usize];
                if a.taxels == 0 {
                    self.touched_regions.push(r);
                }
                a.weight += w;
                for c in 0..3 {
                    a.position[c] += w * position[c];
                    a.normal[c] += w * normal[c];
                }
                a.taxels += 1;
                a.area += std::f64::consts::PI * radius * radius;
                if residual > a.peak || a.taxels == 1 {
                    a.peak = residual;
                    a.peak_sensor = i as u32;
                }
            }
        }
        // The map centroid, relative to the peak: a contact across a seam of
        // the map keeps the taxels on the peak's side only.
        for &i in component {
            let i = i as usize;
            let w = f64::from(residual(i).max(0.0));
            let site = &sites[i];
            let m = site.map;
            let [first, end] = site.regions;
            for &r in &self.member_regions[first as usize..end as usize] {
                let a = &mut self.accumulators[r as usize];
                let peak = a.peak_sensor as usize;
                let pm = sites[peak].map;
                let map_step = ((m[0] - pm[0]).powi(2) + (m[1] - pm[1]).powi(2)).sqrt();
                let p = site.position;
                let pp = sites[peak].position;
                let step = ((p[0] - pp[0]).powi(2) + (p[1] - pp[1]).powi(2) + (p[2] - pp[2]).powi(2)).sqrt();
                if map_step <= 2.0 * step + 1e-3 {
                    a.map[0] += w * f64::from(m[0]);
                    a.map[1] += w * f64::from(m[1]);
                    a.map_weight += w;
                }
            }
        }
        for &r in &self.touched_regions {
            let a = std::mem::take(&mut self.accumulators[r as usize]);
            let w = a.weight.max(1e-12);
            let norm = a.normal.iter().map(|v| v * v).sum::<f64>().sqrt().max(1e-12);
            let mw = a.map_weight.max(1e-12);
            self.found[r as usize].push(Contact {
                taxels: a.taxels,
                peak_sensor: a.peak_sensor,
                centroid: a.position.map(|v| (v / w) as f32),
                normal: a.normal.map(|v| (v / norm) as f32),
                map: a.map.map(|v| (v / mw) as f32),
                area_m2: a.area as f32,
                total: a.weight as f32,
                peak: a.peak,
            });
        }
    }
}

/// Writes each taxel's site from `geometry` and its regions (`per_sensor`)
/// into `sites`; returns every taxel's regions, one after another, which
/// the sites' `regions` index.
fn fill_sites(geometry: &SkinGeometry, per_sensor: &[Vec<u32>], sites: &mut [Site]) -> Vec<u32> {
    let mut member_regions = Vec::new();
    for (i, (site, regions)) in sites.iter_mut().zip(per_sensor).enumerate() {
        let first = member_regions.len() as u32;
        member_regions.extend_from_slice(regions);
        *site = Site {
            position: geometry.positions.get(i).copied().unwrap_or_default(),
            normal: geometry.normals.get(i).copied().unwrap_or_default(),
            map: geometry.map.positions.get(i).copied().unwrap_or_default(),
            radius: geometry.radii.get(i).copied().unwrap_or_default(),
            regions: [first, member_regions.len() as u32],
            unused: 0,
        };
    }
    member_regions
}

/// What contact accumulation needs of one taxel, from the geometry, in one
/// place: a touched taxel costs one or two cache lines rather than one in each
/// of the geometry's arrays.
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct Site {
    position: [f32; 3],
    normal: [f32; 3],
    map: [f32; 2],
    radius: f32,
    /// Its regions' range in `member_regions`.
    regions: [u32; 2],
    /// Whole words (48 bytes), as the detector's memory holds them.
    unused: u32,
}

fn is_set(bits: &[u64], i: usize) -> bool {
    bits[i / 64] & (1 << (i % 64)) != 0
}

fn set(bits: &mut [u64], i: usize) {
    bits[i / 64] |= 1 << (i % 64);
}

fn clear(bits: &mut [u64], i: usize) {
    bits[i / 64] &= !(1 << (i % 64));
}

#[cfg(test)]
mod tests {
    use super::*;
    use skinware::TopologyBuilder;
    use skinware_geometry::{Calibration, SensorCalibration};

    fn strip() -> SkinGeometry {
        let mut builder = TopologyBuilder::new("strip", "pressure", 1.0);
        builder.patch(1).module(1, 1..=12);
        let mut calibration = Calibration::new();
        for uid in 1..=12u32 {
            let place = SensorCalibration {
                position: [f64::from(uid) * 0.005, 0.0, 0.0],
                normal: [0.0, 0.0, 1.0],
                radius: 0.002,
                link: "palm".into(),
            };
            calibration.insert("strip", uid, place).unwrap();
        }
        SkinGeometry::build("s", &[builder.build().unwrap()], &calibration, &[]).unwrap()
    }

    /// Three layers of 12 taxels in a row: `a` and `b` on the palm, `c` on
    /// the finger but its last four on the wrist; regions `hand` (palm and
    /// finger) and `palm` overlap, and the wrist's taxels are in neither.
    fn three_layers() -> SkinGeometry {
        let mut calibration = Calibration::new();
        let mut topologies = Vec::new();
        for (l, name) in ["a", "b", "c"].into_iter().enumerate() {
            let mut builder = TopologyBuilder::new(name, "pressure", 1.0);
            builder.patch(1).module(1, 1..=12);
            topologies.push(builder.build().unwrap());
            for uid in 1..=12u32 {
                let link = match (name, uid) {
                    ("c", 9..) => "wrist",
                    ("c", _) => "finger",
                    _ => "palm",
                };
                let place = SensorCalibration {
                    position: [(l as f64 * 12.0 + f64::from(uid)) * 0.005, 0.0, 0.0],
                    normal: [0.0, 0.0, 1.0],
                    radius: 0.002,
                    link: link.into(),
                };
                calibration.insert(name, uid, place).unwrap();
            }
        }
        let region = |name: &str, links: &[&str]| skinware_geometry::RegionSpec {
            name: name.into(),
            selectors: links.iter().map(|l| skinware_geometry::Selector::Link((*l).into())).collect(),
        };
        let regions = [region("hand", &["palm", "finger"]), region("palm", &["palm"])];
        SkinGeometry::build("s", &topologies, &calibration, &regions).unwrap()
    }

    /// Two detectors of `geometry` to compare, each with its records.
    fn two_detectors(geometry: &SkinGeometry) -> [(ContactDetector, Vec<RegionContacts>); 2] {
        [(); 2].map(|()| {
            let detector = ContactDetector::new(geometry, ContactParams::default());
            let records = vec![RegionContacts::default(); detector.region_names().len()];
            (detector, records)
        })
    }

    #[test]
    fn layers_given_apart_detect_what_one_array_does() {
        let geometry = three_layers();
        let [(mut whole, mut out_whole), (mut apart, mut out_apart)] = two_detectors(&geometry);
        let ok = [true, false, true];
        for frame in 0..60u16 {
            let mut responses: Vec<u16> = (0..36u16).map(|i| 1000 + (i * 7 + frame * 3) % 11).collect();
            if frame >= 40 {
                // Pressed: the end of `a` and across `c` into the wrist.
                for i in [9, 10, 11, 26, 27, 28, 32, 33, 34] {
                    responses[i] = 9000;
                }
            }
            let fresh = [true, frame % 2 == 0, true];
            whole.update(&geometry, &responses, &ok, &fresh, 0.02, &mut out_whole);
            let layer = |l: usize| responses.get(geometry.layer_starts[l]..geometry.layer_starts[l + 1]);
            apart.update_layers(&geometry, layer, &ok, &fresh, 0.02, &mut out_apart);
            assert_eq!(out_whole, out_apart, "frame {frame}");
            assert_eq!(whole.taxel_states(), apart.taxel_states(), "frame {frame}");
        }
        assert!(out_whole[0].count >= 2, "the presses are found: {:?}", out_whole[0]);
        assert_ne!(out_whole[0].flags & contact_flags::INPUT_FAULTED, 0, "layer b is down");
        assert!(whole.taxel_states()[12..24].iter().all(|s| *s == TaxelState::NO_INPUT));
    }

    /// A service at twice a layer's rate reads each of its frames twice. The
    /// second read is not classified again: the layer's taxels must keep
    /// their states, touched lists and residuals, and the next frame must
    /// step the baselines by both reads' time, so that the detector publishes
    /// what a detector at the layer's own rate does.
    #[test]
    fn a_frame_read_twice_gives_what_reading_it_once_does() {
        let geometry = three_layers();
        let [(mut twice, mut out_twice), (mut once, mut out_once)] = two_detectors(&geometry);
        let ok = [true; 3];
        for frame in 0..200u32 {
            let mut responses: Vec<u16> = (0..36u32).map(|i| (1000 + (i * 7 + frame * 13) % 23) as u16).collect();
            if frame >= 150 {
                for i in [9, 10, 11, 12, 13] {
                    responses[i] = 1400 + (frame % 7) as u16;
                }
            }
            // Once at the layers' 50 Hz; twice at 100 Hz, the second time with
            // no new frame (the same responses, as a reader would hold them).
            once.update(&geometry, &responses, &ok, &[true; 3], 0.02, &mut out_once);
            twice.update(&geometry, &responses, &ok, &[true; 3], 0.01, &mut out_twice);
            twice.update(&geometry, &responses, &ok, &[false; 3], 0.01, &mut out_twice);
            assert_eq!(out_twice, out_once, "frame {frame}");
            assert_eq!(twice.taxel_states(), once.taxel_states(), "frame {frame}");
        }
        assert!(out_once[0].count >= 1, "the press is found: {:?}", out_once[0]);
    }

    #[test]
    fn short_inputs_are_no_input_not_a_panic() {
        let geometry = strip();
        let mut detector = ContactDetector::new(&geometry, ContactParams::default());
        let mut out = [];
        detector.update(&geometry, &[1000; 5], &[], &[], 0.02, &mut out);
        assert!(detector.taxel_states().iter().all(|s| *s == TaxelState::NO_INPUT));
    }

    #[test]
    fn dead_and_stuck_are_counted_in_frames_not_in_updates() {
        let geometry = strip();
        let mut detector = ContactDetector::new(&geometry, ContactParams::default());
        let mut out = [RegionContacts::default()];
        let mut responses = [1000u16; 12];
        responses[3] = u16::MAX;
        // A slow layer: the same frame read 300 times by a faster service.
        for update in 0..300 {
            detector.update(&geometry, &responses, &[true], &[update == 0], 0.02, &mut out);
        }
        assert_eq!((out[0].dead, out[0].stuck), (0, 0), "one frame is not 100 unchanged frames");
        // 120 new frames: the constant taxels are dead, the saturated one stuck.
        for frame in 0..120u16 {
            for (k, r) in responses.iter_mut().enumerate() {
                if k != 3 && k != 7 {
                    *r = 1000 + frame % 5;
                }
            }
            detector.update(&geometry, &responses, &[true], &[true], 0.02, &mut out);
        }
        assert_eq!((out[0].dead, out[0].stuck), (1, 1), "{:?}", out[0]);
        assert_eq!(detector.taxel_states()[7], TaxelState::DEAD);
        assert_eq!(detector.taxel_states()[3], TaxelState::STUCK);
        // A layer down: its taxels have no input and the region says so.
        detector.update(&geometry, &responses, &[false], &[false], 0.02, &mut out);
        assert_ne!(out[0].flags & contact_flags::INPUT_FAULTED, 0);
        assert!(detector.taxel_states().iter().all(|s| *s == TaxelState::NO_INPUT));
    }
}
