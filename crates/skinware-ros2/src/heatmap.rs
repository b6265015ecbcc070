//! The skin's 2-D map as a `sensor_msgs/Image` of its responses, coloured
//! the way the viewer colours them: what a recording holds for Foxglove's
//! Image panel and what a ROS 2 transport publishes for `rqt_image_view`.

use skinware_geometry::SkinGeometry;

use crate::messages::{Header, Image};

/// Full colour at this response above a taxel's baseline (as in the viewer).
const SCALE_MAX: f32 = 20000.0;
/// How fast a baseline follows a rising response, per image; it follows a
/// falling one at once, so a pressed taxel keeps its colour for seconds.
const BASELINE_RISE: f32 = 0.01;
const MARGIN: usize = 8;
const BACKGROUND: [u8; 3] = [11, 12, 15];
/// Taxels of a faulted layer.
const FAULTED: [u8; 3] = [112, 52, 52];
/// Taxels of a layer whose writer is gone.
const GONE: [u8; 3] = [70, 70, 70];

/// How a layer's taxels are drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerLook {
    /// By their responses.
    Live,
    /// Hatched red: the layer is faulted.
    Faulted,
    /// Grey: nothing is publishing it.
    Gone,
}

/// Renders the map of one skin, again and again.
pub struct HeatMap {
    width: usize,
    height: usize,
    /// Each taxel's top-left pixel.
    corner: Vec<(usize, usize)>,
    size: usize,
    layer_starts: Vec<usize>,
    baseline: Vec<f32>,
    lut: [[u8; 3]; 256],
}

impl HeatMap {
    /// A renderer of `geometry`'s map, `width` pixels wide (the height follows the map's shape).
    pub fn new(geometry: &SkinGeometry, width: usize) -> HeatMap {
        let positions = &geometry.map.positions;
        let (mut min, mut max) = ([f32::MAX; 2], [f32::MIN; 2]);
        for p in positions {
            for axis in 0..2 {
                min[axis] = min[axis].min(p[axis]);
                max[axis] = max[axis].max(p[axis]);
            }
        }
        if positions.is_empty() {
            (min, max) = ([0.0; 2], [1.0; 2]);
        }
        let span = [(max[0] - min[0]).max(1e-6), (max[1] - min[1]).max(1e-6)];
        let width = width.max(2 * MARGIN + 16);
        let scale = (width - 2 * MARGIN) as f32 / span[0];
        let height = ((span[1] * scale) as usize + 2 * MARGIN).clamp(2 * MARGIN + 16, 4 * width);
        let scale = scale.min((height - 2 * MARGIN) as f32 / span[1]);
        let size = ((0.8 * typical_spacing(positions) * scale) as usize).clamp(1, 8);
        let corner = positions
            .iter()
            .map(|p| {
                let x = MARGIN as f32 + (p[0] - min[0]) * scale;
                let y = height as f32 - MARGIN as f32 - (p[1] - min[1]) * scale;
                let left = (x as usize).saturating_sub(size / 2).min(width - size);
                let top = (y as usize).saturating_sub(size / 2).min(height - size);
                (left, top)
            })
            .collect();
        HeatMap {
            width,
            height,
            corner,
            size,
            layer_starts: geometry.layer_starts.clone(),
            baseline: Vec::new(),
            lut: colour_table(),
        }
    }

    /// Width and height in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        (self.width as u32, self.height as u32)
    }

    /// The image (`rgb8`, rows top to bottom) of the newest responses of
    /// every layer (`None`: not read yet, drawn as gone).
    pub fn render(&mut self, layers: &[(Option<&[u16]>, LayerLook)]) -> Vec<u8> {
        let mut pixels = BACKGROUND.repeat(self.width * self.height);
        let sensors = *self.layer_starts.last().unwrap_or(&0);
        if self.baseline.len() != sensors {
            self.baseline = vec![f32::NAN; sensors];
        }
        for (layer, (responses, look)) in layers.iter().enumerate() {
            let (Some(&first), Some(&end)) = (self.layer_starts.get(layer), self.layer_starts.get(layer + 1)) else {
                continue;
            };
            for global in first..end {
                let colour = match (responses, look) {
                    (Some(values), LayerLook::Live) => {
                        let r = f32::from(values.get(global - first).copied().unwrap_or(0));
                        let b = &mut self.baseline[global];
                        if b.is_nan() || r < *b {
                            *b = r;
                        } else {
                            *b += (r - *b) * BASELINE_RISE;
                        }
                        let above = ((r - *b) / SCALE_MAX).clamp(0.0, 1.0);
                        self.lut[(255.0 * above.sqrt()).round() as usize]
                    }
                    (_, LayerLook::Faulted) => FAULTED,
                    _ => GONE,
                };
                let (left, top) = self.corner[global];
                for row in top..top + self.size {
                    let start = 3 * (row * self.width + left);
                    for pixel in pixels[start..start + 3 * self.size].chunks_exact_mut(3) {
                        pixel.copy_from_slice(&colour);
                    }
                }
            }
        }
        pixels
    }

    /// `pixels` from [`render`](Self::render) as a `sensor_msgs/Image`
    /// (`rgb8`). The header is the caller's: a recording stamps an image
    /// with the time its layers were read, the bridge with the time it is sent.
    pub fn image(&self, pixels: Vec<u8>, header: Header) -> Image {
        let (width, height) = self.dimensions();
        Image { header, height, width, encoding: "rgb8".into(), is_bigendian: 0, step: 3 * width, data: pixels }
    }
}

/// The viewer's colour scale, 256 steps.
fn colour_table() -> [[u8; 3]; 256] {
    const STOPS: [[f32; 4]; 6] = [
        [0.0, 30.0, 34.0, 56.0],
        [0.15, 40.0, 30.0, 110.0],
        [0.35, 30.0, 110.0, 200.0],
        [0.55, 40.0, 200.0, 170.0],
        [0.75, 240.0, 220.0, 60.0],
        [1.0, 255.0, 70.0, 40.0],
    ];
    let mut table = [[0u8; 3]; 256];
    for (i, entry) in table.iter_mut().enumerate() {
        let t = i as f32 / 255.0;
        let k = STOPS.iter().position(|s| s[0] >= t).unwrap_or(STOPS.len() - 1).max(1);
        let (a, b) = (STOPS[k - 1], STOPS[k]);
        let f = (t - a[0]) / (b[0] - a[0]);
        for c in 0..3 {
            entry[c] = (a[c + 1] + f * (b[c + 1] - a[c + 1])).round() as u8;
        }
    }
    table
}

/// The usual distance between neighbouring taxels on the map, from a sample.
fn typical_spacing(positions: &[[f32; 2]]) -> f32 {
    let step = (positions.len() / 200).max(1);
    let mut nearest: Vec<f32> = positions
        .iter()
        .step_by(step)
        .enumerate()
        .filter_map(|(k, p)| {
            let own = k * step;
            positions
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != own)
                .map(|(_, q)| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2))
                .filter(|&d| d > 0.0)
                .min_by(f32::total_cmp)
        })
        .collect();
    nearest.sort_by(f32::total_cmp);
    nearest.get(nearest.len() / 2).map_or(0.01, |d| d.sqrt())
}

#[cfg(test)]
mod tests {
    use skinware::TopologyBuilder;
    use skinware_geometry::{Calibration, SensorCalibration};

    use super::*;
    use crate::messages::Time;

    /// One layer of 12 taxels in a row, 5 mm apart.
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

    #[test]
    fn the_image_is_rgb8_rows_of_the_maps_size() {
        let mut map = HeatMap::new(&strip(), 200);
        let header = Header { stamp: Time { sec: 1, nanosec: 0 }, frame_id: "s/map".into() };
        let pixels = map.render(&[(Some(&[0; 12]), LayerLook::Live)]);
        let image = map.image(pixels, header.clone());
        let (width, height) = map.dimensions();
        assert_eq!((image.width, image.height, image.step), (width, height, 3 * width));
        assert_eq!(image.data.len(), (3 * width * height) as usize);
        assert_eq!((image.encoding.as_str(), image.is_bigendian, &image.header), ("rgb8", 0, &header));
    }

    #[test]
    fn faulted_and_gone_layers_have_their_own_colours() {
        let mut map = HeatMap::new(&strip(), 200);
        let has = |pixels: &[u8], colour: [u8; 3]| pixels.chunks_exact(3).any(|p| p == colour);
        assert!(has(&map.render(&[(None, LayerLook::Faulted)]), FAULTED));
        assert!(has(&map.render(&[(None, LayerLook::Gone)]), GONE));
        // A pressed taxel, after its baseline was taken at rest, has the top colour.
        map.render(&[(Some(&[0; 12]), LayerLook::Live)]);
        let mut pressed = [0u16; 12];
        pressed[5] = 30_000;
        assert!(has(&map.render(&[(Some(&pressed), LayerLook::Live)]), colour_table()[255]));
    }
}
