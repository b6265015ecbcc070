//! The virtual skin: a deterministic simulation of a skin-covered humanoid.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::{FrameWriter, RtOptions, TopologyBuilder};
use skinware_geometry::{Calibration, SensorCalibration};

/// A layer's acquisition rate.
#[derive(Clone, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(untagged, deny_unknown_fields)]
pub enum Rate {
    /// A fixed rate in Hz.
    Fixed(f64),
    /// A rate drawn uniformly from `random = [min, max]` Hz, once per layer (the
    /// paper's "random 30-50 Hz").
    Random {
        /// `[min, max]` in Hz.
        random: [f64; 2],
    },
}

/// A scheduled disconnection of one layer: from `at_s` seconds after start,
/// for `duration_s` seconds, repeating every `every_s` seconds if given.
#[derive(Clone, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct CablePull {
    /// Layer name.
    pub layer: String,
    /// Seconds after the driver starts.
    pub at_s: f64,
    /// Seconds the cable stays out.
    pub duration_s: f64,
    /// Period of repetition, seconds.
    #[serde(default)]
    pub every_s: Option<f64>,
}

impl CablePull {
    fn pulled_at(&self, elapsed_s: f64) -> bool {
        if elapsed_s < self.at_s {
            return false;
        }
        let since = elapsed_s - self.at_s;
        let phase = match self.every_s {
            Some(every) if every > 0.0 => since % every,
            _ => since,
        };
        phase < self.duration_s
    }
}

/// A contact scripted at a known place, time and velocity (for tests and
/// demonstrations): it presses for `press_s`, slides at `velocity` for
/// `slide_s`, and releases for `release_s`.
#[derive(Clone, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct ScriptedContact {
    /// Body part (link) name, e.g. `"left_forearm"`.
    pub part: String,
    /// Seconds after the driver starts.
    pub at_s: f64,
    /// Where it starts: angle around the part's axis, degrees.
    pub angle_deg: f64,
    /// Where it starts: height along the part's axis from its base, metres.
    pub height: f64,
    /// Sliding velocity along the surface, m/s: `[around the axis, along it]`.
    #[serde(default)]
    pub velocity: [f64; 2],
    /// Seconds to press.
    #[serde(default = "default_ramp_s")]
    pub press_s: f64,
    /// Seconds to slide (or hold, without velocity).
    pub slide_s: f64,
    /// Seconds to release.
    #[serde(default = "default_ramp_s")]
    pub release_s: f64,
    /// Peak response above the baseline.
    #[serde(default = "default_peak")]
    pub peak: f64,
    /// Gaussian radius of the pressure, metres.
    #[serde(default = "default_sigma")]
    pub sigma: f64,
}

fn default_ramp_s() -> f64 {
    0.3
}
fn default_peak() -> f64 {
    30_000.0
}
fn default_sigma() -> f64 {
    0.015
}

impl ScriptedContact {
    fn blob(&self) -> Result<Blob, String> {
        let part = BODY
            .iter()
            .position(|p| p.name == self.part)
            .ok_or_else(|| format!("contact on part {:?}: the parts are {}", self.part, part_names()))?;
        let numbers = [self.at_s, self.angle_deg, self.height, self.velocity[0], self.velocity[1], self.peak];
        if !numbers.iter().all(|v| v.is_finite())
            || self.at_s < 0.0
            || !(self.press_s > 0.0 && self.slide_s >= 0.0 && self.release_s > 0.0 && self.sigma > 0.0)
        {
            return Err(format!(
                "contact on {}: times must be finite, at_s >= 0, press_s, release_s and sigma above 0",
                self.part
            ));
        }
        Ok(Blob {
            part,
            start_s: self.at_s,
            press_s: self.press_s,
            slide_s: self.slide_s,
            release_s: self.release_s,
            angle: self.angle_deg.to_radians(),
            height: self.height,
            velocity: self.velocity,
            peak: self.peak,
            sigma: self.sigma,
        })
    }

    /// The true centre of the contact at `t` seconds after the driver
    /// started: its 3-D position and outward normal, or `None` outside its life.
    pub fn centre_at(&self, t: f64) -> Option<([f64; 3], [f64; 3])> {
        let blob = self.blob().ok()?;
        let (_, angle, height) = blob.at(t)?;
        Some(surface_point(blob.part, angle, height))
    }

    /// The true surface velocity while sliding, in 3-D, at `t` seconds.
    pub fn velocity_3d_at(&self, t: f64) -> Option<[f64; 3]> {
        let blob = self.blob().ok()?;
        let (_, angle, _) = blob.at(t)?;
        let tangent = [-angle.sin(), angle.cos(), 0.0];
        Some([tangent[0] * self.velocity[0], tangent[1] * self.velocity[0], self.velocity[1]])
    }
}

fn part_names() -> String {
    BODY.iter().map(|p| p.name).collect::<Vec<_>>().join(", ")
}

/// The point of body part `part` at `angle` around its axis and `height` along it, and its normal.
fn surface_point(part: usize, angle: f64, height: f64) -> ([f64; 3], [f64; 3]) {
    let p = BODY[part];
    let normal = [angle.cos(), angle.sin(), 0.0];
    ([p.base[0] + p.radius * normal[0], p.base[1] + p.radius * normal[1], p.base[2] + height], normal)
}

/// Parameters of the virtual skin.
#[derive(Clone, Debug)]
pub struct VirtualSkinConfig {
    /// Driver name (also the prefix of its layer names: `NAME-0`, `NAME-1`, ...).
    pub name: String,
    /// Total sensors over all layers.
    pub sensors: usize,
    /// Number of layers the sensors are split over (equally).
    pub layers: usize,
    /// Sensors per module (the last module of a layer may have fewer).
    pub sensors_per_module: usize,
    /// Modules per patch, drawn from this inclusive range.
    pub modules_per_patch: (usize, usize),
    /// Acquisition rate of each layer.
    pub rate: Rate,
    /// Seed of every random choice (rates, patch sizes, contacts, noise).
    pub seed: u64,
    /// Scheduled cable pulls.
    pub cable_pulls: Vec<CablePull>,
    /// Files whose existence pulls a layer's cable (one per layer, same order
    /// as the layers); `None` for no on-command pulls.
    pub pull_files: Option<Vec<PathBuf>>,
    /// Real-time settings of every layer's writer thread.
    pub rt: RtOptions,
    /// Layers with a given topology and real-time settings, instead of
    /// generating `layers` layers of `sensors` sensors (then `sensors`,
    /// `layers`, `sensors_per_module`, `modules_per_patch` and `rt` are unused).
    pub explicit_layers: Option<Vec<LayerSpec>>,
    /// Contacts at known places and times.
    pub contacts: Vec<ScriptedContact>,
    /// Whether random contacts press, slide and release all over the body.
    pub random_contacts: bool,
    /// Uids of taxels that are dead: their response never changes.
    pub dead_taxels: Vec<u32>,
    /// Uids of taxels that are stuck at saturation.
    pub stuck_taxels: Vec<u32>,
}

impl Default for VirtualSkinConfig {
    fn default() -> Self {
        VirtualSkinConfig {
            name: "virtual".into(),
            sensors: 30_848,
            layers: 1,
            sensors_per_module: 12,
            modules_per_patch: (4, 16),
            rate: Rate::Random { random: [30.0, 50.0] },
            seed: 1,
            cable_pulls: Vec::new(),
            pull_files: None,
            rt: RtOptions::default(),
            explicit_layers: None,
            contacts: Vec::new(),
            random_contacts: true,
            dead_taxels: Vec::new(),
            stuck_taxels: Vec::new(),
        }
    }
}

impl VirtualSkinConfig {
    /// Checks the parameters, saying what is wrong.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(layers) = &self.explicit_layers {
            if layers.is_empty() {
                return Err("no layers given".into());
            }
        } else if self.layers == 0 || self.sensors < self.layers {
            return Err(format!(
                "{} sensors cannot be split over {} layers; give at least one sensor per layer",
                self.sensors, self.layers
            ));
        }
        if self.sensors_per_module == 0 {
            return Err("sensors_per_module must be at least 1".into());
        }
        let (min, max) = self.modules_per_patch;
        if min == 0 || min > max {
            return Err(format!("modules_per_patch [{min}, {max}] must be a range with 1 <= min <= max"));
        }
        let rates = match &self.rate {
            Rate::Fixed(hz) => [*hz, *hz],
            Rate::Random { random } => *random,
        };
        if !(rates[0] > 0.0 && rates[0] <= rates[1] && rates[1] <= 100_000.0) {
            return Err(format!("rate {rates:?} Hz must be positive, min <= max, at most 100 kHz"));
        }
        for contact in &self.contacts {
            contact.blob()?;
        }
        for pull in &self.cable_pulls {
            if !self.layer_names().contains(&pull.layer) {
                return Err(format!(
                    "cable pull names layer {:?}, which is not one of {:?}",
                    pull.layer,
                    self.layer_names()
                ));
            }
        }
        Ok(())
    }

    /// The layer names: `NAME-0 .. NAME-(L-1)`.
    pub fn layer_names(&self) -> Vec<String> {
        if let Some(layers) = &self.explicit_layers {
            return layers.iter().map(|l| l.topology.name.clone()).collect();
        }
        (0..self.layers).map(|l| format!("{}-{l}", self.name)).collect()
    }
}

/// A small deterministic generator (SplitMix64).
#[derive(Clone)]
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }
}

/// A body part: a vertical cylinder (axis along z) at `base`, `radius`, `height`.
#[derive(Clone, Copy, Debug)]
struct BodyPart {
    name: &'static str,
    base: [f64; 3],
    radius: f64,
    height: f64,
}

const BODY: [BodyPart; 9] = [
    BodyPart { name: "torso", base: [0.0, 0.0, 0.9], radius: 0.16, height: 0.55 },
    BodyPart { name: "left_upper_arm", base: [0.24, 0.0, 1.15], radius: 0.05, height: 0.3 },
    BodyPart { name: "right_upper_arm", base: [-0.24, 0.0, 1.15], radius: 0.05, height: 0.3 },
    BodyPart { name: "left_forearm", base: [0.24, 0.0, 0.85], radius: 0.042, height: 0.28 },
    BodyPart { name: "right_forearm", base: [-0.24, 0.0, 0.85], radius: 0.042, height: 0.28 },
    BodyPart { name: "left_thigh", base: [0.09, 0.0, 0.45], radius: 0.075, height: 0.42 },
    BodyPart { name: "right_thigh", base: [-0.09, 0.0, 0.45], radius: 0.075, height: 0.42 },
    BodyPart { name: "left_shin", base: [0.09, 0.0, 0.05], radius: 0.055, height: 0.38 },
    BodyPart { name: "right_shin", base: [-0.09, 0.0, 0.05], radius: 0.055, height: 0.38 },
];

/// Where one sensor sits: its body part and surface coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorPlace {
    /// Index of the body part.
    pub part: usize,
    /// Angle around the part's axis, radians.
    pub angle: f64,
    /// Height along the part's axis from its base, m.
    pub height: f64,
    /// 3-D position, m.
    pub position: [f64; 3],
    /// Outward unit normal.
    pub normal: [f64; 3],
}

/// The humanoid body of the virtual skin: every sensor's place.
#[derive(Debug)]
pub struct VirtualBody {
    /// One place per sensor, in global sensor order.
    pub places: Vec<SensorPlace>,
    /// Radius of a taxel's sensing area: a third of the mean pitch, metres.
    pub taxel_radius: f64,
}

impl VirtualBody {
    /// Spreads `sensors` over the body parts in proportion to their area, on
    /// a grid of rows and columns per part.
    pub fn new(sensors: usize) -> VirtualBody {
        let areas: Vec<f64> = BODY.iter().map(|p| 2.0 * std::f64::consts::PI * p.radius * p.height).collect();
        let total: f64 = areas.iter().sum();
        let mut counts: Vec<usize> = areas.iter().map(|a| (a / total * sensors as f64).floor() as usize).collect();
        let assigned: usize = counts.iter().sum();
        counts[0] += sensors - assigned;
        let mut places = Vec::with_capacity(sensors);
        for (part_index, (part, &count)) in BODY.iter().zip(&counts).enumerate() {
            let circumference = 2.0 * std::f64::consts::PI * part.radius;
            let columns = ((count as f64 * circumference / part.height).sqrt().round() as usize).max(1);
            let rows = count.div_ceil(columns).max(1);
            for k in 0..count {
                let (row, column) = (k / columns, k % columns);
                let angle = (column as f64 + 0.5 * (row % 2) as f64) / columns as f64 * std::f64::consts::TAU;
                let height = (row as f64 + 0.5) / rows as f64 * part.height;
                let normal = [angle.cos(), angle.sin(), 0.0];
                let position = [
                    part.base[0] + part.radius * normal[0],
                    part.base[1] + part.radius * normal[1],
                    part.base[2] + height,
                ];
                places.push(SensorPlace { part: part_index, angle, height, position, normal });
            }
        }
        let pitch = (total / sensors.max(1) as f64).sqrt();
        VirtualBody { places, taxel_radius: pitch / 3.0 }
    }

    /// The point of body part `part` (by name) at `angle_rad` around its axis
    /// and `height` metres along it, with its outward normal.
    pub fn surface_point(part: &str, angle_rad: f64, height: f64) -> Option<([f64; 3], [f64; 3])> {
        BODY.iter().position(|p| p.name == part).map(|p| surface_point(p, angle_rad, height))
    }

    /// The name of body part `part`.
    pub fn part_name(part: usize) -> &'static str {
        BODY.get(part).map_or("unknown", |p| p.name)
    }
}

/// One pressure blob's life: it presses, slides along the surface, releases.
#[derive(Clone, Copy, Debug)]
struct Blob {
    part: usize,
    start_s: f64,
    press_s: f64,
    slide_s: f64,
    release_s: f64,
    angle: f64,
    height: f64,
    /// Sliding velocity along the surface: (arc length m/s, height m/s).
    velocity: [f64; 2],
    peak: f64,
    sigma: f64,
}

impl Blob {
    fn end_s(&self) -> f64 {
        self.start_s + self.press_s + self.slide_s + self.release_s
    }

    /// Amplitude (0..1) and surface position (angle, height) at time `t`.
    fn at(&self, t: f64) -> Option<(f64, f64, f64)> {
        let local = t - self.start_s;
        if local < 0.0 || t >= self.end_s() {
            return None;
        }
        let moving = (local - self.press_s).clamp(0.0, self.slide_s);
        let radius = BODY[self.part].radius;
        let angle = self.angle + self.velocity[0] * moving / radius;
        let height = self.height + self.velocity[1] * moving;
        let amplitude = if local < self.press_s {
            local / self.press_s
        } else if local < self.press_s + self.slide_s {
            1.0
        } else {
            1.0 - (local - self.press_s - self.slide_s) / self.release_s
        };
        Some((amplitude, angle, height))
    }
}

/// The contact schedule: a few blobs at a time, each drawn from the seed.
#[derive(Debug)]
struct Contacts {
    blobs: Vec<Blob>,
}

impl Contacts {
    /// Blobs for `horizon_s` seconds: the scripted ones, and (if `random`)
    /// four independent sequences of random blobs.
    fn new(seed: u64, horizon_s: f64, scripted: &[ScriptedContact], random_contacts: bool) -> Contacts {
        let mut random = SplitMix(seed ^ 0xC0A7_AC75);
        let mut blobs: Vec<Blob> = scripted.iter().filter_map(|c| c.blob().ok()).collect();
        let lanes = if random_contacts { 4 } else { 0 };
        for _lane in 0..lanes {
            let mut t = random.range(0.0, 1.0);
            while t < horizon_s {
                let part = (random.next() % BODY.len() as u64) as usize;
                let speed = random.range(0.02, 0.12);
                let direction = random.range(0.0, std::f64::consts::TAU);
                let blob = Blob {
                    part,
                    start_s: t,
                    press_s: random.range(0.2, 0.5),
                    slide_s: random.range(0.8, 2.5),
                    release_s: random.range(0.2, 0.5),
                    angle: random.range(0.0, std::f64::consts::TAU),
                    height: random.range(0.2, 0.8) * BODY[part].height,
                    velocity: [speed * direction.cos(), speed * direction.sin()],
                    peak: random.range(15_000.0, 50_000.0),
                    sigma: random.range(0.012, 0.03),
                };
                t = blob.end_s() + random.range(0.1, 1.0);
                blobs.push(blob);
            }
        }
        Contacts { blobs }
    }
}

/// The virtual skin driver.
pub struct VirtualSkin {
    config: VirtualSkinConfig,
    body: Arc<VirtualBody>,
    layers: Vec<LayerSpec>,
    /// Global index of each layer's first sensor.
    first_sensor: Vec<usize>,
}

impl VirtualSkin {
    /// Builds the body, the topology of every layer and its rate.
    pub fn new(config: VirtualSkinConfig) -> Result<VirtualSkin, String> {
        config.validate()?;
        if let Some(explicit) = &config.explicit_layers {
            let total: usize = explicit.iter().map(|l| l.topology.sensors.len()).sum();
            let mut first_sensor = Vec::new();
            let mut next = 0;
            for layer in explicit {
                first_sensor.push(next);
                next += layer.topology.sensors.len();
            }
            let layers = explicit.clone();
            return Ok(VirtualSkin { body: Arc::new(VirtualBody::new(total)), config, layers, first_sensor });
        }
        let body = Arc::new(VirtualBody::new(config.sensors));
        let mut random = SplitMix(config.seed);
        let mut layers = Vec::new();
        let mut first_sensor = Vec::new();
        let names = config.layer_names();
        let mut uid = 1u32;
        let mut module_id = 1u32;
        let mut patch_id = 1u32;
        for (l, name) in names.iter().enumerate() {
            let first = config.sensors * l / config.layers;
            let last = config.sensors * (l + 1) / config.layers;
            first_sensor.push(first);
            let rate_hz = match config.rate {
                Rate::Fixed(hz) => hz,
                Rate::Random { random: [lo, hi] } => (random.range(lo, hi) * 10.0).round() / 10.0,
            };
            let mut builder = TopologyBuilder::new(name, "pressure", rate_hz);
            let mut remaining = last - first;
            while remaining > 0 {
                builder.patch(patch_id);
                patch_id += 1;
                let (min, max) = config.modules_per_patch;
                let modules = min + (random.next() % (max - min + 1) as u64) as usize;
                for _ in 0..modules {
                    if remaining == 0 {
                        break;
                    }
                    let count = config.sensors_per_module.min(remaining);
                    builder.module(module_id, uid..uid + count as u32);
                    module_id += 1;
                    uid += count as u32;
                    remaining -= count;
                }
            }
            let topology = builder.build().map_err(|e| e.to_string())?;
            layers.push(LayerSpec { topology, rt: config.rt.clone() });
        }
        Ok(VirtualSkin { config, body, layers, first_sensor })
    }

    /// The simulated body (positions and normals of every sensor, in global order).
    pub fn body(&self) -> &VirtualBody {
        &self.body
    }

    /// The virtual skin's own calibration: every sensor's place on the body,
    /// keyed by layer name and uid, its link the body part.
    pub fn calibration(&self) -> Calibration {
        let mut calibration = Calibration::new();
        for (l, spec) in self.layers.iter().enumerate() {
            for (k, sensor) in spec.topology.sensors.iter().enumerate() {
                let place = &self.body.places[self.first_sensor[l] + k];
                let entry = SensorCalibration {
                    position: place.position,
                    normal: place.normal,
                    radius: self.body.taxel_radius,
                    link: VirtualBody::part_name(place.part).to_owned(),
                };
                calibration
                    .insert(&spec.topology.name, sensor.uid, entry)
                    .expect("the virtual body's places are finite with unit normals");
            }
        }
        calibration
    }
}

impl Driver for VirtualSkin {
    fn name(&self) -> &str {
        &self.config.name
    }

    fn layers(&self) -> Vec<LayerSpec> {
        self.layers.clone()
    }

    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError> {
        let started = Instant::now();
        let contacts =
            Arc::new(Contacts::new(self.config.seed, 3600.0, &self.config.contacts, self.config.random_contacts));
        let mut sources: Vec<Box<dyn LayerSource>> = Vec::new();
        for (l, spec) in self.layers.iter().enumerate() {
            let first = self.first_sensor[l];
            let count = spec.topology.sensors.len();
            let pulls = self.config.cable_pulls.iter().filter(|p| p.layer == spec.topology.name).cloned().collect();
            let local = |uids: &[u32]| -> Vec<usize> {
                uids.iter().filter_map(|&uid| spec.topology.sensor_by_uid(uid)).collect()
            };
            sources.push(Box::new(VirtualLayer {
                dead: local(&self.config.dead_taxels),
                stuck: local(&self.config.stuck_taxels),
                name: spec.topology.name.clone(),
                body: self.body.clone(),
                contacts: contacts.clone(),
                sensors: first..first + count,
                started,
                pulls,
                pull_file: self.config.pull_files.as_ref().and_then(|files| files.get(l).cloned()),
                pull_file_seen: (Instant::now(), false),
                noise: SplitMix(self.config.seed ^ (l as u64 + 1).wrapping_mul(0x5851_F42D)),
                responses: vec![0; count],
            }));
        }
        Ok(sources)
    }
}

struct VirtualLayer {
    /// Local indices of dead and stuck taxels.
    dead: Vec<usize>,
    stuck: Vec<usize>,
    name: String,
    body: Arc<VirtualBody>,
    contacts: Arc<Contacts>,
    sensors: std::ops::Range<usize>,
    started: Instant,
    pulls: Vec<CablePull>,
    pull_file: Option<PathBuf>,
    /// When the pull file was last checked, and whether it existed.
    pull_file_seen: (Instant, bool),
    noise: SplitMix,
    responses: Vec<u16>,
}

impl VirtualLayer {
    fn cable_pulled(&mut self, elapsed_s: f64) -> bool {
        if let Some(file) = &self.pull_file {
            // A stat at most every 50 ms: this is the simulated bus, not the exchange.
            if self.pull_file_seen.0.elapsed() >= Duration::from_millis(50) {
                self.pull_file_seen = (Instant::now(), file.exists());
            }
        }
        self.pull_file_seen.1 || self.pulls.iter().any(|p| p.pulled_at(elapsed_s))
    }
}

impl LayerSource for VirtualLayer {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let t = self.started.elapsed().as_secs_f64();
        if self.cable_pulled(t) {
            return Err(format!("cable pulled: layer {} does not answer", self.name).into());
        }
        let places = &self.body.places[self.sensors.clone()];
        for (response, place) in self.responses.iter_mut().zip(places) {
            // Baseline with a slow drift, different per sensor.
            let drift = 40.0 * (0.05 * t + place.angle + place.height * 7.0).sin();
            *response = (1000.0 + drift) as u16;
        }
        for blob in &self.contacts.blobs {
            let Some((amplitude, angle, height)) = blob.at(t) else {
                continue;
            };
            let radius = BODY[blob.part].radius;
            let reach = 3.0 * blob.sigma;
            for (response, place) in self.responses.iter_mut().zip(places) {
                if place.part != blob.part || (place.height - height).abs() > reach {
                    continue;
                }
                let mut dangle = (place.angle - angle).rem_euclid(std::f64::consts::TAU);
                if dangle > std::f64::consts::PI {
                    dangle -= std::f64::consts::TAU;
                }
                let arc = dangle * radius;
                let d2 = arc * arc + (place.height - height).powi(2);
                let pressure = blob.peak * amplitude * (-d2 / (2.0 * blob.sigma * blob.sigma)).exp();
                *response = (f64::from(*response) + pressure).min(f64::from(u16::MAX)) as u16;
            }
        }
        for response in self.responses.iter_mut() {
            let noise = (self.noise.next() % 17) as i32 - 8;
            *response = (i32::from(*response) + noise).clamp(0, i32::from(u16::MAX)) as u16;
        }
        for &k in &self.dead {
            self.responses[k] = 1000;
        }
        for &k in &self.stuck {
            self.responses[k] = u16::MAX;
        }
        frame.write_responses(0, &self.responses)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_skin_matches_the_paper() {
        let skin = VirtualSkin::new(VirtualSkinConfig { layers: 5, ..VirtualSkinConfig::default() }).unwrap();
        let layers = skin.layers();
        assert_eq!(layers.iter().map(|l| l.topology.sensors.len()).sum::<usize>(), 30_848);
        for layer in &layers {
            let topology = &layer.topology;
            assert!((30.0..=50.0).contains(&topology.rate_hz), "{}", topology.rate_hz);
            assert!(topology.modules.iter().all(|m| m.sensors.len() <= 12));
            // All patches but a layer's last have 4..=16 modules.
            let full = &topology.patches[..topology.patches.len() - 1];
            assert!(full.iter().all(|p| (4..=16).contains(&p.modules.len())));
        }
        let uids: std::collections::HashSet<u32> =
            layers.iter().flat_map(|l| l.topology.sensors.iter().map(|s| s.uid)).collect();
        assert_eq!(uids.len(), 30_848, "uids must be unique over the whole skin");
    }

    #[test]
    fn body_places_sensors_on_the_surfaces() {
        let body = VirtualBody::new(5000);
        assert_eq!(body.places.len(), 5000);
        for place in &body.places {
            let part = BODY[place.part];
            let radial =
                ((place.position[0] - part.base[0]).powi(2) + (place.position[1] - part.base[1]).powi(2)).sqrt();
            assert!((radial - part.radius).abs() < 1e-9);
            let norm = place.normal.iter().map(|n| n * n).sum::<f64>().sqrt();
            assert!((norm - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn cable_pull_schedule() {
        let pull = CablePull { layer: "x".into(), at_s: 2.0, duration_s: 1.0, every_s: Some(5.0) };
        assert!(!pull.pulled_at(1.9));
        assert!(pull.pulled_at(2.5));
        assert!(!pull.pulled_at(3.5));
        assert!(pull.pulled_at(7.2));
    }

    #[test]
    fn invalid_parameters_are_explained() {
        let zero = VirtualSkinConfig { layers: 0, ..VirtualSkinConfig::default() };
        assert!(zero.validate().unwrap_err().contains("layers"));
        let bad_pull = VirtualSkinConfig {
            cable_pulls: vec![CablePull { layer: "nope".into(), at_s: 0.0, duration_s: 1.0, every_s: None }],
            ..VirtualSkinConfig::default()
        };
        assert!(bad_pull.validate().unwrap_err().contains("nope"));
    }
}
