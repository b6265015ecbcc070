//! What the services add on top of the heatmap: motion arrows and contact
//! markers, in map coordinates (metres on the 2-D map).

#![forbid(unsafe_code)]

use std::path::PathBuf;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use skinware::{ChannelKind, ReaderOptions, WriterState};
use skinware_services::framework::ServiceReader;
use skinware_services::{MotionRecord, RegionContacts, motion_flags};

/// A sliding contact: from where it is on the map towards where it is going, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Arrow {
    /// Tail, map metres.
    pub from: [f32; 2],
    /// Head, map metres.
    pub to: [f32; 2],
}

/// A contact: its centre and radius on the map, metres, and its pressure
/// (response above baseline, in the layer's units).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Marker {
    /// Centre, map metres.
    pub at: [f32; 2],
    /// Radius, metres.
    pub radius: f32,
    /// Pressure above baseline.
    pub pressure: f32,
}

/// Everything drawn over the heatmap in one update.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overlays {
    /// Motion arrows (the motion service).
    pub arrows: Vec<Arrow>,
    /// Contact markers (the contact service).
    pub markers: Vec<Marker>,
}

/// The newest frame of a running service, unless it is older than a few of
/// its periods: a paused, faulted, hung or gone service shows nothing rather
/// than stale marks.
fn current<T: skinware_services::framework::ServicePayload>(
    reader: &mut ServiceReader<T>,
) -> Option<skinware_services::framework::ServiceFrame<'_, T>> {
    if reader.writer_state() != WriterState::Running {
        return None;
    }
    let period = reader.reader().writer_period();
    let frame = reader.latest().ok()?;
    (!skinware_services::is_stale(frame.published_ns, period)).then_some(frame)
}

/// Seconds of motion an arrow shows: it points from the contact to where it
/// will be this much later at its current velocity.
const ARROW_SECONDS: f32 = 0.5;
/// How often the segment directory is searched for new services.
const DISCOVERY_PERIOD: Duration = Duration::from_secs(1);

/// Where the viewer gets its overlays from: the skin's contact and motion
/// services, found by their schemas, whatever they are called.
pub struct OverlaySource {
    skin: String,
    dir: Option<PathBuf>,
    contacts: Vec<(String, ServiceReader<RegionContacts>)>,
    motions: Vec<(String, ServiceReader<MotionRecord>)>,
    next_discovery: Instant,
}

impl std::fmt::Debug for OverlaySource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OverlaySource")
            .field("skin", &self.skin)
            .field("contacts", &self.contacts.iter().map(|(n, _)| n).collect::<Vec<_>>())
            .field("motions", &self.motions.iter().map(|(n, _)| n).collect::<Vec<_>>())
            .finish()
    }
}

impl OverlaySource {
    /// The overlay source of `skin`'s services (in segment directory `dir`,
    /// or the default).
    pub fn new(skin: &str, dir: Option<PathBuf>) -> OverlaySource {
        OverlaySource {
            skin: skin.to_owned(),
            dir,
            contacts: Vec::new(),
            motions: Vec::new(),
            next_discovery: Instant::now(),
        }
    }

    /// Attaches to services that appeared since the last look.
    fn discover(&mut self) {
        let dir = self.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        let Ok(channels) = skinware::list_channels(&dir) else {
            return;
        };
        let options = ReaderOptions { allow_gone: true, dir: self.dir.clone(), ..ReaderOptions::default() };
        for channel in channels.iter().filter(|c| c.skin == self.skin && c.kind == Some(ChannelKind::Service)) {
            let name = &channel.channel;
            if self.contacts.iter().any(|(n, _)| n == name) || self.motions.iter().any(|(n, _)| n == name) {
                continue;
            }
            // A channel of another schema refuses both; that is how they are told apart.
            if let Ok(reader) = ServiceReader::<RegionContacts>::open_with(&self.skin, name, &options) {
                self.contacts.push((name.clone(), reader));
            } else if let Ok(reader) = ServiceReader::<MotionRecord>::open_with(&self.skin, name, &options) {
                self.motions.push((name.clone(), reader));
            }
        }
    }

    /// The newest overlays. Never blocks: called once per update sent. A
    /// service that is gone contributes nothing rather than stale marks.
    pub fn poll(&mut self) -> Overlays {
        if Instant::now() >= self.next_discovery {
            self.next_discovery = Instant::now() + DISCOVERY_PERIOD;
            self.discover();
        }
        let mut overlays = Overlays::default();
        // Overlapping regions report the same contact once each: keep one per peak taxel.
        let mut peaks = std::collections::HashSet::new();
        for (_, reader) in &mut self.contacts {
            reader.reader().follow_recreated();
            let Some(frame) = current(reader) else { continue };
            for region in frame.records {
                for contact in region.contacts() {
                    if peaks.insert(contact.peak_sensor) {
                        overlays.markers.push(Marker {
                            at: contact.map,
                            radius: (contact.area_m2 / std::f32::consts::PI).sqrt(),
                            pressure: contact.peak,
                        });
                    }
                }
            }
        }
        let mut heads = Vec::new();
        for (_, reader) in &mut self.motions {
            reader.reader().follow_recreated();
            let Some(frame) = current(reader) else { continue };
            for record in frame.records {
                if record.flags & motion_flags::SLIDING == 0 || heads.contains(&record.now_map) {
                    continue;
                }
                heads.push(record.now_map);
                let [x, y] = record.now_map;
                let [vx, vy] = record.velocity_map;
                overlays.arrows.push(Arrow { from: [x, y], to: [x + vx * ARROW_SECONDS, y + vy * ARROW_SECONDS] });
            }
        }
        overlays
    }
}

/// One overlay source for every browser: the services are searched for and
/// attached once, not once per browser (a search opens every segment of the
/// directory), and each update still polls them for the newest overlays.
#[derive(Debug)]
pub struct SharedOverlays(Mutex<OverlaySource>);

impl SharedOverlays {
    /// The shared overlay source of `skin`'s services (in segment directory
    /// `dir`, or the default).
    pub fn new(skin: &str, dir: Option<PathBuf>) -> SharedOverlays {
        SharedOverlays(Mutex::new(OverlaySource::new(skin, dir)))
    }

    /// The newest overlays ([`OverlaySource::poll`]).
    pub fn poll(&self) -> Overlays {
        // A session that panicked while polling left the readers usable.
        self.0.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).poll()
    }
}
