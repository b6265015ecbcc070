//! The humanoid body: its parts (vertical cylinders), every sensor's place
//! on them, and the topology of the generated layers.

use skinware::TopologyBuilder;
use skinware::driver::LayerSpec;

use super::{Rate, SplitMix, VirtualSkinConfig};

/// A body part: a vertical cylinder (axis along z) at `base`, `radius`, `height`.
#[derive(Clone, Copy, Debug)]
pub(super) struct BodyPart {
    pub(super) name: &'static str,
    pub(super) base: [f64; 3],
    pub(super) radius: f64,
    pub(super) height: f64,
}

pub(super) const BODY: [BodyPart; 9] = [
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

/// The body parts' names, for error messages.
pub(super) fn part_names() -> String {
    BODY.iter().map(|p| p.name).collect::<Vec<_>>().join(", ")
}

/// The point of body part `part` at `angle` around its axis and `height` along it, and its normal.
pub(super) fn surface_point(part: usize, angle: f64, height: f64) -> ([f64; 3], [f64; 3]) {
    let p = BODY[part];
    let normal = [angle.cos(), angle.sin(), 0.0];
    ([p.base[0] + p.radius * normal[0], p.base[1] + p.radius * normal[1], p.base[2] + height], normal)
}

/// The layers of a generated skin: `config.sensors` sensors split equally
/// over `config.layers` layers of patches and modules, each layer at its
/// rate; and the global index of each layer's first sensor.
pub(super) fn generate_layers(config: &VirtualSkinConfig) -> Result<(Vec<LayerSpec>, Vec<usize>), String> {
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
    Ok((layers, first_sensor))
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
