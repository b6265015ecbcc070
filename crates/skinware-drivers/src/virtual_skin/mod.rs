//! The virtual skin: a deterministic simulation of a skin-covered humanoid.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::{FrameWriter, RtOptions};
use skinware_geometry::{Calibration, SensorCalibration};

mod body;
mod contacts;
mod faults;
pub mod pattern;

pub use body::{SensorPlace, VirtualBody};
pub use contacts::ScriptedContact;
pub use faults::CablePull;

use body::generate_layers;
use contacts::Contacts;
use faults::LayerFaults;

/// Most sensors a virtual skin may have: 32 times the paper's skin. Its body
/// takes about 100 bytes per sensor, so a config of a few bytes cannot ask
/// for more memory than the machine has.
pub const MAX_SENSORS: usize = 1_000_000;
/// Most layers a virtual skin may have: each one is a channel and a writer thread.
pub const MAX_LAYERS: usize = 1024;

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
    /// Publish the [`pattern`] (a function of each frame's sequence number
    /// and each sensor's index) instead of the simulation, for readers that
    /// verify every frame (`skin bench soak`). Contacts, dead and stuck
    /// taxels are then not simulated; cable pulls still are.
    pub verify_pattern: bool,
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
            verify_pattern: false,
        }
    }
}

/// A virtual skin configuration that cannot be built: what is wrong and the
/// accepted values.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{reason}")]
pub struct InvalidConfig {
    /// What is wrong, naming the parameter.
    pub reason: String,
}

impl VirtualSkinConfig {
    /// Checks the parameters, saying what is wrong.
    pub fn validate(&self) -> Result<(), InvalidConfig> {
        self.check().map_err(|reason| InvalidConfig { reason })
    }

    fn check(&self) -> Result<(), String> {
        let (layers, sensors) = match &self.explicit_layers {
            Some(layers) => (layers.len(), layers.iter().map(|l| l.topology.sensors.len()).sum()),
            None => (self.layers, self.sensors),
        };
        if layers == 0 && self.explicit_layers.is_some() {
            return Err("no layers given".into());
        }
        if layers == 0 || sensors < layers {
            return Err(format!(
                "{sensors} sensors cannot be split over {layers} layers; give at least one sensor per layer"
            ));
        }
        if sensors > MAX_SENSORS {
            return Err(format!("{sensors} sensors are more than a virtual skin may have ({MAX_SENSORS})"));
        }
        if layers > MAX_LAYERS {
            return Err(format!("{layers} layers are more than a virtual skin may have ({MAX_LAYERS})"));
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
        let layer_names = self.layer_names();
        for pull in &self.cable_pulls {
            if !layer_names.contains(&pull.layer) {
                return Err(format!("cable pull names layer {:?}, which is not one of {layer_names:?}", pull.layer));
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
    pub fn new(config: VirtualSkinConfig) -> Result<VirtualSkin, InvalidConfig> {
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
        let (layers, first_sensor) = generate_layers(&config).map_err(|reason| InvalidConfig { reason })?;
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
            let faults = LayerFaults {
                dead: local(&self.config.dead_taxels),
                stuck: local(&self.config.stuck_taxels),
                pulls,
                pull_file: self.config.pull_files.as_ref().and_then(|files| files.get(l).cloned()),
                pull_file_seen: (Instant::now(), false),
            };
            sources.push(Box::new(VirtualLayer {
                faults,
                name: spec.topology.name.clone(),
                body: self.body.clone(),
                contacts: contacts.clone(),
                sensors: first..first + count,
                phases: drift_phases(&self.body.places[first..first + count]),
                started,
                noise: SplitMix(self.config.seed ^ (l as u64 + 1).wrapping_mul(0x5851_F42D)),
                responses: vec![0; count],
                noise_lanes: vec![0; count.div_ceil(4) * 4],
                verify_pattern: self.config.verify_pattern,
            }));
        }
        Ok(sources)
    }
}

struct VirtualLayer {
    faults: LayerFaults,
    name: String,
    body: Arc<VirtualBody>,
    contacts: Arc<Contacts>,
    sensors: std::ops::Range<usize>,
    phases: Vec<DriftPhase>,
    started: Instant,
    noise: SplitMix,
    /// This frame's random 16-bit words, one per sensor (and up to 3 more:
    /// a whole random word's worth), from which each sensor's noise comes.
    noise_lanes: Vec<u16>,
    responses: Vec<u16>,
    /// Publish [`pattern`] frames instead of the simulation.
    verify_pattern: bool,
}

/// The responses of the sensors at `places` (whose [`drift_phases`] are
/// `phases`) at `t` seconds, before noise: a baseline of about 1000 with a
/// slow drift, plus the contacts' pressure.
fn pressures(t: f64, places: &[SensorPlace], phases: &[DriftPhase], contacts: &Contacts, responses: &mut [u16]) {
    // Baseline with a slow drift, different per sensor: 40 sin(0.05 t + φ),
    // expanded so that a frame costs a multiply-add per sensor instead of a
    // sine (a 1 kHz skin of 30,848 taxels would spend most of a core on
    // them), in fixed point: integer lanes vectorise, where the compiler
    // converts floating point to a saturated `u16` one sensor at a time
    // (1.3 against 0.6 ns a sensor here). The sum is the drift times
    // 2^DRIFT_SHIFT; shifting it down rounds towards minus infinity, as
    // truncating 1000 + drift (always positive) does. Against the same
    // sum in `f64` a response differs by 1 in about 0.2 % of samples.
    let (sin_t, cos_t) = (0.05 * t).sin_cos();
    let scale = 40.0 * f64::from(1u32 << (DRIFT_SHIFT - PHASE_BITS));
    let (sin_t, cos_t) = ((sin_t * scale).round() as i32, (cos_t * scale).round() as i32);
    for (response, &[sin_phase, cos_phase]) in responses.iter_mut().zip(phases) {
        let drift = sin_t * i32::from(cos_phase) + cos_t * i32::from(sin_phase);
        *response = (i32::from(BASELINE) + (drift >> DRIFT_SHIFT)) as u16;
    }
    contacts.press(t, places, responses);
}

/// A sensor's drift phase φ as (sin φ, cos φ) in fixed point, times 2^PHASE_BITS.
type DriftPhase = [i16; 2];

/// The drift phases' fixed point: 2^14 fits a sine of 1 in an `i16`.
const PHASE_BITS: u32 = 14;

/// The drift sum's fixed point: 40 · 2^11 · 2^14 · (|sin| + |cos| ≤ √2)
/// stays within an `i32`.
const DRIFT_SHIFT: u32 = 25;

/// Fills `lanes` (a multiple of 4 long) with random 16-bit words, four
/// from each of `noise`'s words, lowest bits first.
fn draw_noise_lanes(noise: &mut SplitMix, lanes: &mut [u16]) {
    for lanes in lanes.chunks_exact_mut(4) {
        let word = noise.next();
        lanes.copy_from_slice(&[word as u16, (word >> 16) as u16, (word >> 32) as u16, (word >> 48) as u16]);
    }
}

/// Adds to each response its noise, from -8 to 8, drawn from its random
/// 16-bit word in `lanes`.
fn add_noise(responses: &mut [u16], lanes: &[u16]) {
    for (response, &lane) in responses.iter_mut().zip(lanes) {
        let noise = i32::from(lane % 17) - 8;
        *response = (i32::from(*response) + noise).clamp(0, i32::from(u16::MAX)) as u16;
    }
}

/// Each sensor's drift phase φ, for [`pressures`].
fn drift_phases(places: &[SensorPlace]) -> Vec<DriftPhase> {
    let one = f64::from(1u32 << PHASE_BITS);
    places
        .iter()
        .map(|place| {
            let (sin, cos) = (place.angle + place.height * 7.0).sin_cos();
            [(sin * one).round() as i16, (cos * one).round() as i16]
        })
        .collect()
}

/// The virtual body's moving contacts as a field of pressures, for software
/// skin boards (`skin emulate`) whose taxels should feel what the virtual
/// skin's do.
#[derive(Debug)]
pub struct PressureField {
    body: VirtualBody,
    phases: Vec<DriftPhase>,
    contacts: Contacts,
}

/// The baseline response of an untouched virtual taxel.
pub const BASELINE: u16 = 1000;

impl PressureField {
    /// A body of `sensors` taxels, with random contacts drawn from `seed`
    /// for the next `horizon_s` seconds.
    pub fn new(sensors: usize, seed: u64, horizon_s: f64) -> PressureField {
        PressureField::with_contacts(sensors, seed, horizon_s, &[], true)
    }

    /// A body of `sensors` taxels pressed by `scripted` contacts and, with
    /// `random_contacts`, by random ones drawn from `seed` for the next
    /// `horizon_s` seconds: what a [`VirtualSkin`] of the same settings
    /// feels, before its noise, in its global sensor order.
    pub fn with_contacts(
        sensors: usize,
        seed: u64,
        horizon_s: f64,
        scripted: &[ScriptedContact],
        random_contacts: bool,
    ) -> PressureField {
        let body = VirtualBody::new(sensors);
        let phases = drift_phases(&body.places);
        PressureField { body, phases, contacts: Contacts::new(seed, horizon_s, scripted, random_contacts) }
    }

    /// Taxels on the body.
    pub fn len(&self) -> usize {
        self.body.places.len()
    }

    /// Whether the body has no taxel.
    pub fn is_empty(&self) -> bool {
        self.body.places.is_empty()
    }

    /// Responses of taxels `first..first + out.len()` at `t` seconds: about
    /// [`BASELINE`] untouched, up to 65,535 under a hard press.
    pub fn responses(&self, t: f64, first: usize, out: &mut [u16]) {
        let end = (first + out.len()).min(self.body.places.len());
        let places = self.body.places.get(first..end).unwrap_or(&[]);
        let phases = self.phases.get(first..end).unwrap_or(&[]);
        pressures(t, places, phases, &self.contacts, &mut out[..places.len()]);
    }
}

impl LayerSource for VirtualLayer {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let t = self.started.elapsed().as_secs_f64();
        if self.faults.cable_pulled(t) {
            return Err(format!("cable pulled: layer {} does not answer", self.name).into());
        }
        if self.verify_pattern {
            // The frame's own number: the one it is published under, since a
            // frame that fails is discarded without using its number.
            pattern::fill_pattern(frame.seq(), &mut self.responses);
            frame.write_responses(0, &self.responses)?;
            return Ok(());
        }
        let places = &self.body.places[self.sensors.clone()];
        pressures(t, places, &self.phases, &self.contacts, &mut self.responses);
        // ±8 of noise per sensor, four sensors' worth from each random word:
        // the words drawn first (the generator is sequential), then added in
        // a pass of its own, which the compiler does with vector
        // instructions. In one scalar loop, the noise took about half of a
        // 100,000-taxel skin's 57 % of a core at 1 kHz.
        draw_noise_lanes(&mut self.noise, &mut self.noise_lanes);
        add_noise(&mut self.responses, &self.noise_lanes);
        self.faults.apply_to(&mut self.responses);
        frame.write_responses(0, &self.responses)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_noise_drawn_ahead_is_the_noise_drawn_four_sensors_at_a_time() {
        // What the noise was, one random word per four sensors in one loop.
        fn noise_one_loop(noise: &mut SplitMix, responses: &mut [u16]) {
            for chunk in responses.chunks_mut(4) {
                let mut bits = noise.next();
                for response in chunk {
                    let noise = ((bits & 0xFFFF) % 17) as i32 - 8;
                    bits >>= 16;
                    *response = (i32::from(*response) + noise).clamp(0, i32::from(u16::MAX)) as u16;
                }
            }
        }
        for len in [0, 1, 3, 4, 5, 7, 12, 1001] {
            let start: Vec<u16> = (0..len).map(|i| [0, 3, 1000, 65_530, u16::MAX][i % 5]).collect();
            let (mut old_noise, mut new_noise) = (SplitMix(len as u64), SplitMix(len as u64));
            let mut expected = start.clone();
            noise_one_loop(&mut old_noise, &mut expected);
            let mut lanes = vec![0u16; len.div_ceil(4) * 4];
            draw_noise_lanes(&mut new_noise, &mut lanes);
            let mut responses = start;
            add_noise(&mut responses, &lanes);
            assert_eq!(responses, expected, "{len} sensors");
            assert_eq!(old_noise.next(), new_noise.next(), "as many words drawn for {len} sensors");
        }
    }

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

    /// The expanded drift is the sine it replaced, to within the truncation
    /// to a response.
    #[test]
    fn the_expanded_drift_is_the_sine() {
        let body = VirtualBody::new(2_000);
        let phases = drift_phases(&body.places);
        let none = Contacts::new(1, 0.0, &[], false);
        for t in [0.0, 1.5, 77.25, 3_000.0] {
            let mut responses = vec![0; body.places.len()];
            pressures(t, &body.places, &phases, &none, &mut responses);
            for (response, place) in responses.iter().zip(&body.places) {
                let sine = 1000.0 + 40.0 * (0.05 * t + place.angle + place.height * 7.0).sin();
                // Truncated (below by less than 1), give or take the fixed
                // point's rounding, well under a hundredth.
                let below = sine - f64::from(*response);
                assert!((-0.01..1.01).contains(&below), "{response} against {sine} at t = {t}");
            }
        }
    }

    #[test]
    fn invalid_parameters_are_explained() {
        let zero = VirtualSkinConfig { layers: 0, ..VirtualSkinConfig::default() };
        assert!(zero.validate().unwrap_err().reason.contains("layers"));
        let bad_pull = VirtualSkinConfig {
            cable_pulls: vec![CablePull { layer: "nope".into(), at_s: 0.0, duration_s: 1.0, every_s: None }],
            ..VirtualSkinConfig::default()
        };
        assert!(bad_pull.validate().unwrap_err().reason.contains("nope"));
    }

    /// Found while writing the `config` fuzz target: `sensors = 99999999999`
    /// asked for terabytes of body (an allocation failure under the fuzz
    /// target), and 300,000 layers took 20 s to generate.
    #[test]
    fn sizes_beyond_the_limits_are_refused_before_anything_is_built() {
        let huge = VirtualSkinConfig { sensors: 99_999_999_999, ..VirtualSkinConfig::default() };
        assert!(VirtualSkin::new(huge).err().unwrap().reason.contains("more than a virtual skin may have"));
        let many = VirtualSkinConfig { sensors: 300_000, layers: 300_000, ..VirtualSkinConfig::default() };
        assert!(VirtualSkin::new(many).err().unwrap().reason.contains("300000 layers"));
        let largest = VirtualSkinConfig { sensors: MAX_SENSORS, layers: MAX_LAYERS, ..VirtualSkinConfig::default() };
        assert!(largest.validate().is_ok());
    }
}
