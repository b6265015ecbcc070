//! Contacts as pressure blobs: the scripted ones, at known places and times,
//! and the random ones that press, slide and release all over the body.

use super::SplitMix;
use super::body::{BODY, SensorPlace, part_names, surface_point};

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
    pub(super) fn blob(&self) -> Result<Blob, String> {
        let part = BODY
            .iter()
            .position(|p| p.name == self.part)
            .ok_or_else(|| format!("contact on part {:?}: the parts are {}", self.part, part_names()))?;
        let numbers = [
            self.at_s,
            self.angle_deg,
            self.height,
            self.velocity[0],
            self.velocity[1],
            self.peak,
            self.press_s,
            self.slide_s,
            self.release_s,
            self.sigma,
        ];
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

/// One pressure blob's life: it presses, slides along the surface, releases.
#[derive(Clone, Copy, Debug)]
pub(super) struct Blob {
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
pub(super) struct Contacts {
    /// In order of their start.
    blobs: Vec<Blob>,
    /// The longest blob's duration, s: no blob that started earlier than
    /// this before `t` is alive at `t`.
    longest_s: f64,
}

impl Contacts {
    /// Blobs for `horizon_s` seconds: the scripted ones, and (if `random`)
    /// four independent sequences of random blobs.
    pub(super) fn new(seed: u64, horizon_s: f64, scripted: &[ScriptedContact], random_contacts: bool) -> Contacts {
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
        blobs.sort_by(|a, b| a.start_s.total_cmp(&b.start_s));
        let longest_s = blobs.iter().map(|blob| blob.end_s() - blob.start_s).fold(0.0, f64::max);
        Contacts { blobs, longest_s }
    }

    /// Adds the pressure of every blob alive at `t` seconds to the responses
    /// of the sensors at `places`, which are in the body's order: by part,
    /// then by height (so that a blob's reach is one run of them).
    pub(super) fn press(&self, t: f64, places: &[SensorPlace], responses: &mut [u16]) {
        let first = self.blobs.partition_point(|blob| blob.start_s < t - self.longest_s);
        for blob in self.blobs[first..].iter().take_while(|blob| blob.start_s <= t) {
            let Some((amplitude, angle, height)) = blob.at(t) else {
                continue;
            };
            let radius = BODY[blob.part].radius;
            let reach = 3.0 * blob.sigma;
            let below = |place: &SensorPlace| (place.part, place.height) < (blob.part, height - reach);
            let within = |place: &SensorPlace| (place.part, place.height) <= (blob.part, height + reach);
            let (from, to) = (places.partition_point(below), places.partition_point(within));
            let touched = responses.iter_mut().zip(places).take(to).skip(from);
            // A response is a whole number and a press's pressure is added
            // to it and truncated, so a pressure below 1 changes nothing.
            // Beyond this squared distance it is below 1/e: such taxels are
            // skipped before their angle and `exp` are computed (most of
            // the band of heights that `reach` leaves, which goes all round
            // the part). NaN (no finite logarithm) skips nothing.
            let two_sigma2 = 2.0 * blob.sigma * blob.sigma;
            let negligible_beyond = two_sigma2 * ((blob.peak * amplitude).ln() + 1.0);
            for (response, place) in touched {
                if place.part != blob.part || (place.height - height).abs() > reach {
                    continue;
                }
                let height_d2 = (place.height - height).powi(2);
                if height_d2 > negligible_beyond {
                    continue;
                }
                let mut dangle = rem_tau(place.angle - angle);
                if dangle > std::f64::consts::PI {
                    dangle -= std::f64::consts::TAU;
                }
                let arc = dangle * radius;
                let d2 = arc * arc + height_d2;
                if d2 > negligible_beyond {
                    continue;
                }
                let pressure = blob.peak * amplitude * (-d2 / two_sigma2).exp();
                *response = (f64::from(*response) + pressure).min(f64::from(u16::MAX)) as u16;
            }
        }
    }
}

/// `x.rem_euclid(TAU)`, bit for bit, without the software `fmod` for the
/// usual angle difference: below TAU in size, `x % TAU` is `x` itself.
#[inline]
fn rem_tau(x: f64) -> f64 {
    use std::f64::consts::TAU;
    let r = if x.abs() < TAU { x } else { x % TAU };
    if r < 0.0 { r + TAU } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_skin::body::VirtualBody;

    /// Every blob alive at `t` against every sensor: what `press` computes
    /// through its sorted blobs and its one run of sensors per blob.
    fn press_everywhere(contacts: &Contacts, t: f64, places: &[SensorPlace], responses: &mut [u16]) {
        for blob in &contacts.blobs {
            let Some((amplitude, angle, height)) = blob.at(t) else { continue };
            let radius = BODY[blob.part].radius;
            for (response, place) in responses.iter_mut().zip(places) {
                if place.part != blob.part || (place.height - height).abs() > 3.0 * blob.sigma {
                    continue;
                }
                let mut dangle = (place.angle - angle).rem_euclid(std::f64::consts::TAU);
                if dangle > std::f64::consts::PI {
                    dangle -= std::f64::consts::TAU;
                }
                let d2 = (dangle * radius).powi(2) + (place.height - height).powi(2);
                let pressure = blob.peak * amplitude * (-d2 / (2.0 * blob.sigma * blob.sigma)).exp();
                *response = (f64::from(*response) + pressure).min(f64::from(u16::MAX)) as u16;
            }
        }
    }

    #[test]
    fn rem_tau_is_rem_euclid_bit_for_bit() {
        use std::f64::consts::TAU;
        let mut random = SplitMix(41);
        let edges = [
            0.0,
            -0.0,
            TAU,
            -TAU,
            TAU.next_down(),
            (-TAU).next_up(),
            3.0 * TAU,
            -7.5 * TAU,
            1e-300,
            -1e-300,
            f64::MIN_POSITIVE / 4.0,
            -f64::MIN_POSITIVE / 4.0,
            1e9,
            -1e9,
            f64::MAX,
            f64::MIN,
        ];
        let drawn = (0..100_000).map(|_| random.range(-40.0, 40.0));
        for x in edges.into_iter().chain(drawn) {
            assert_eq!(rem_tau(x).to_bits(), x.rem_euclid(TAU).to_bits(), "x = {x:e}");
        }
        for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            assert!(rem_tau(x).is_nan() && x.rem_euclid(TAU).is_nan(), "x = {x}");
        }
    }

    /// The skip of taxels whose pressure is below 1 at the edges: presses
    /// of no, tiny, negative and enormous peak, and responses at 0 and at
    /// saturation.
    #[test]
    fn pressing_at_the_edges_of_the_skip_changes_nothing() {
        let body = VirtualBody::new(30_848);
        let press = |peak: f64, at_s: f64, sigma: f64| ScriptedContact {
            part: BODY[2].name.to_owned(),
            at_s,
            angle_deg: 40.0,
            height: 0.5 * BODY[2].height,
            velocity: [0.05, 0.01],
            press_s: 0.3,
            slide_s: 1.0,
            release_s: 0.3,
            peak,
            sigma,
        };
        let scripted = [
            press(0.0, 0.0, 0.015),
            press(0.5, 0.0, 0.015),
            press(1.0, 0.1, 0.02),
            press(-300.0, 0.2, 0.02),
            press(2.5, 0.3, 1e-6),
            press(1e12, 0.4, 0.03),
        ];
        let contacts = Contacts::new(3, 0.0, &scripted, false);
        assert_eq!(contacts.blobs.len(), scripted.len(), "every scripted press is valid");
        let mut pressed = 0;
        for step in 0..80 {
            let t = step as f64 * 0.025;
            let mut fast: Vec<u16> = (0..body.places.len()).map(|i| [0, 1, 1000, 65_534, 65_535][i % 5]).collect();
            let mut everywhere = fast.clone();
            contacts.press(t, &body.places, &mut fast);
            press_everywhere(&contacts, t, &body.places, &mut everywhere);
            assert_eq!(fast, everywhere, "t = {t}");
            pressed +=
                usize::from(fast.iter().zip([0u16, 1, 1000, 65_534, 65_535].iter().cycle()).any(|(a, b)| a != b));
        }
        assert!(pressed > 40, "the presses changed responses at only {pressed} instants");
    }

    #[test]
    fn pressing_only_the_blobs_alive_and_the_sensors_in_reach_changes_nothing() {
        let body = VirtualBody::new(30_848);
        let contacts = Contacts::new(7, 120.0, &[], true);
        let mut pressed_somewhere = 0;
        for step in 0..400 {
            let t = step as f64 * 0.29;
            // Whole body, and a layer-like slice that cuts a part in two.
            for range in [0..body.places.len(), 4_000..10_169] {
                let places = &body.places[range];
                let mut fast = vec![1000u16; places.len()];
                let mut everywhere = fast.clone();
                contacts.press(t, places, &mut fast);
                press_everywhere(&contacts, t, places, &mut everywhere);
                assert_eq!(fast, everywhere, "t = {t}");
                pressed_somewhere += usize::from(fast.iter().any(|&r| r > 1000));
            }
        }
        assert!(pressed_somewhere > 100, "the test saw too few contacts: {pressed_somewhere}");
    }
}
