//! Motion detection (the paper's demonstration service): for each region,
//! whether a contact slides, its direction and speed on the 2-D map and in
//! 3-D, where it started and where it is now. It reads the contact service:
//! a service built on another service.

use std::collections::VecDeque;

use crate::framework::ServicePayload;

use crate::contact::{RegionContacts, contact_flags};

/// The motion of the main contact of one region.
#[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct MotionRecord {
    /// [`motion_flags`].
    pub flags: u32,
    /// Speed along the surface in 3-D, m/s.
    pub speed_3d: f32,
    /// Speed on the 2-D map, m/s.
    pub speed_map: f32,
    /// Direction on the 2-D map, radians from the map's +x axis towards +y.
    pub direction_map_rad: f32,
    /// Velocity in 3-D, m/s.
    pub velocity_3d: [f32; 3],
    /// Velocity on the map, m/s.
    pub velocity_map: [f32; 2],
    /// Where the contact started, metres.
    pub start_3d: [f32; 3],
    /// Where it is now, metres.
    pub now_3d: [f32; 3],
    /// Where it started on the map, metres.
    pub start_map: [f32; 2],
    /// Where it is now on the map, metres.
    pub now_map: [f32; 2],
    /// Seconds since it started.
    pub duration_s: f32,
}

impl ServicePayload for MotionRecord {
    const SCHEMA: &'static str = "skinware.motion";
    const VERSION: u32 = 1;
}

/// Bits of [`MotionRecord::flags`].
pub mod motion_flags {
    /// The region's main contact slides (faster than the minimum speed).
    pub const SLIDING: u32 = 1;
    /// The region has a contact.
    pub const CONTACT: u32 = 2;
    /// The contact service, or a layer under it, is down for this region.
    pub const INPUT_FAULTED: u32 = 4;
}

/// Parameters of motion detection.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionParams {
    /// Velocities are fitted over this much recent history, seconds.
    pub window_s: f64,
    /// A contact moving slower than this is not sliding, m/s.
    pub min_speed: f64,
    /// A centroid jumping farther than this between frames is a new contact, metres.
    pub max_jump: f64,
}

impl Default for MotionParams {
    fn default() -> Self {
        MotionParams { window_s: 0.4, min_speed: 0.01, max_jump: 0.03 }
    }
}

#[derive(Clone, Copy)]
struct Sample {
    t: f64,
    position: [f64; 3],
    map: [f64; 2],
}

#[derive(Default)]
struct Track {
    samples: VecDeque<Sample>,
    /// Index in `samples` from which map positions are continuous (after a seam).
    map_from: usize,
    start: Option<Sample>,
}

/// Per-region tracks of the main contact.
pub struct MotionTracker {
    params: MotionParams,
    tracks: Vec<Track>,
}

impl MotionTracker {
    /// A tracker for `regions` regions.
    pub fn new(regions: usize, params: MotionParams) -> MotionTracker {
        MotionTracker { params, tracks: (0..regions).map(|_| Track::default()).collect() }
    }

    /// Processes one frame of the contact service, taken at `t_s` seconds
    /// (the contacts' acquisition time). `input_ok` is false when the
    /// contact service itself is down.
    pub fn update(&mut self, contacts: &[RegionContacts], t_s: f64, input_ok: bool, out: &mut [MotionRecord]) {
        for ((track, region), record) in self.tracks.iter_mut().zip(contacts).zip(out.iter_mut()) {
            *record = MotionRecord::default();
            if !input_ok || region.flags & contact_flags::INPUT_FAULTED != 0 {
                record.flags |= motion_flags::INPUT_FAULTED;
            }
            let Some(main) = region.contacts().first().filter(|_| input_ok) else {
                *track = Track::default();
                continue;
            };
            let sample = Sample { t: t_s, position: main.centroid.map(f64::from), map: main.map.map(f64::from) };
            if let Some(last) = track.samples.back() {
                let jump = distance3(&sample.position, &last.position);
                if jump > self.params.max_jump || sample.t <= last.t {
                    if sample.t <= last.t && jump <= self.params.max_jump {
                        // The same frame again: nothing new to fit.
                        fill(record, track, &self.params);
                        continue;
                    }
                    *track = Track::default();
                } else if distance2(&sample.map, &last.map) > 3.0 * jump + 0.005 {
                    // Crossed a seam of the map: map positions restart here.
                    track.map_from = track.samples.len();
                }
            }
            track.start.get_or_insert(sample);
            track.samples.push_back(sample);
            while track.samples.front().is_some_and(|s| t_s - s.t > self.params.window_s) {
                track.samples.pop_front();
                track.map_from = track.map_from.saturating_sub(1);
            }
            fill(record, track, &self.params);
        }
    }
}

fn fill(record: &mut MotionRecord, track: &Track, params: &MotionParams) {
    let (Some(start), Some(now)) = (track.start, track.samples.back().copied()) else {
        return;
    };
    record.flags |= motion_flags::CONTACT;
    record.start_3d = start.position.map(|v| v as f32);
    record.now_3d = now.position.map(|v| v as f32);
    record.start_map = start.map.map(|v| v as f32);
    record.now_map = now.map.map(|v| v as f32);
    record.duration_s = (now.t - start.t) as f32;
    let span = now.t - track.samples.front().map_or(now.t, |s| s.t);
    if track.samples.len() < 4 || span < 0.25 * params.window_s {
        return;
    }
    let velocity: [f64; 3] = [0, 1, 2].map(|c| slope(track.samples.iter().map(|s| (s.t, s.position[c]))));
    let speed = velocity.iter().map(|v| v * v).sum::<f64>().sqrt();
    record.velocity_3d = velocity.map(|v| v as f32);
    record.speed_3d = speed as f32;
    // Only the samples since the last seam crossing are continuous on the map.
    let on_map = || track.samples.iter().skip(track.map_from);
    if on_map().count() >= 3 {
        let velocity_map: [f64; 2] = [0, 1].map(|c| slope(on_map().map(|s| (s.t, s.map[c]))));
        record.velocity_map = velocity_map.map(|v| v as f32);
        record.speed_map = velocity_map[0].hypot(velocity_map[1]) as f32;
        record.direction_map_rad = velocity_map[1].atan2(velocity_map[0]) as f32;
    }
    if speed >= params.min_speed {
        record.flags |= motion_flags::SLIDING;
    }
}

/// Least-squares slope of y over t.
fn slope(points: impl Iterator<Item = (f64, f64)> + Clone) -> f64 {
    let (mut n, mut st, mut sy) = (0.0, 0.0, 0.0);
    for (t, y) in points.clone() {
        n += 1.0;
        st += t;
        sy += y;
    }
    if n < 2.0 {
        return 0.0;
    }
    let (mt, my) = (st / n, sy / n);
    let (mut num, mut den) = (0.0, 0.0);
    for (t, y) in points {
        num += (t - mt) * (y - my);
        den += (t - mt) * (t - mt);
    }
    if den > 0.0 { num / den } else { 0.0 }
}

fn distance3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn distance2(a: &[f64; 2], b: &[f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}
