//! What the services add on top of the heatmap: motion arrows and contact
//! markers, in map coordinates (metres on the 2-D map).

#![forbid(unsafe_code)]

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, TryLockError};
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

    /// Attaches to services that appeared since the last look. A reader
    /// whose writer is gone, and which no successor of the same shape took
    /// over, is let go, so that a service restarted with another shape (other
    /// regions, say) is attached afresh by name.
    fn discover(&mut self) {
        self.contacts.retain(|(_, reader)| reader.writer_state() != WriterState::Gone);
        self.motions.retain(|(_, reader)| reader.writer_state() != WriterState::Gone);
        let dir = self.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        let Ok(channels) = skinware::list_skin_channels(&dir, &self.skin) else {
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
        let now = Instant::now();
        if now >= self.next_discovery {
            self.next_discovery = now + DISCOVERY_PERIOD;
            self.discover();
        }
        let mut overlays = Overlays::default();
        if self.contacts.is_empty() && self.motions.is_empty() {
            return overlays;
        }
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

/// No overlays: what an update carries while no service runs.
pub static NO_OVERLAYS: Overlays = Overlays { arrows: Vec::new(), markers: Vec::new() };

/// The overlays of one browser's updates, which follow its reader mode: they
/// are polled from the services only for an update that brings new frames,
/// so that they show the contacts of the frames drawn under them (in the
/// on-request mode, of the frames requested; in the periodic mode, at its
/// rate), and held for the updates between (which carry only new states or
/// rates). They are dropped once no layer runs: a stopped skin shows no
/// contacts.
#[derive(Debug, Default)]
pub struct HeldOverlays {
    held: Option<Arc<Overlays>>,
}

impl HeldOverlays {
    /// The overlays for an update: `poll`ed anew if it brings `fresh_frames`,
    /// else those held; none unless `any_running` (some layer's writer runs).
    pub fn for_update(
        &mut self,
        fresh_frames: bool,
        any_running: bool,
        poll: impl FnOnce() -> Option<Arc<Overlays>>,
    ) -> &Overlays {
        if !any_running {
            self.held = None;
        } else if fresh_frames {
            self.held = poll();
        }
        self.held.as_deref().unwrap_or(&NO_OVERLAYS)
    }
}

/// One overlay source for every browser: the services are searched for and
/// attached once, not once per browser (a search opens every segment of the
/// directory), and each update still polls them for the newest overlays.
#[derive(Debug)]
pub struct SharedOverlays {
    source: Mutex<OverlaySource>,
    /// What the last poll found, for a session that finds another polling.
    last: Mutex<Option<Arc<Overlays>>>,
    /// Until when (`monotonic_ns`) there is nothing to poll: a poll that
    /// found no service sets it to the next search for them, and until
    /// then every session's poll answers at once, without writing anything
    /// that the others share.
    quiet_until_ns: AtomicU64,
}

impl SharedOverlays {
    /// The shared overlay source of `skin`'s services (in segment directory
    /// `dir`, or the default).
    pub fn new(skin: &str, dir: Option<PathBuf>) -> SharedOverlays {
        SharedOverlays {
            source: Mutex::new(OverlaySource::new(skin, dir)),
            last: Mutex::new(None),
            quiet_until_ns: AtomicU64::new(0),
        }
    }

    /// The newest overlays ([`OverlaySource::poll`]; `None` for none), or,
    /// while another browser's session is polling, the ones it polled
    /// last: a poll may search the segment directory or wait for a service
    /// that does not answer, and the browsers must not queue behind each
    /// other for it. After a poll that found no service, `None` at once,
    /// without a look, until the next search for services.
    pub fn poll(&self) -> Option<Arc<Overlays>> {
        if skinware::os::monotonic_ns() < self.quiet_until_ns.load(Ordering::Relaxed) {
            return None;
        }
        let mut source = match self.source.try_lock() {
            Ok(source) => source,
            // A session that panicked while polling left the readers usable.
            Err(TryLockError::Poisoned(poisoned)) => poisoned.into_inner(),
            Err(TryLockError::WouldBlock) => return self.last_polled(),
        };
        let polled = source.poll();
        if source.contacts.is_empty() && source.motions.is_empty() {
            let until_search = source.next_discovery.saturating_duration_since(Instant::now());
            let until_ns = skinware::os::monotonic_ns().saturating_add(until_search.as_nanos() as u64);
            self.quiet_until_ns.store(until_ns, Ordering::Relaxed);
        }
        let newest = (!polled.arrows.is_empty() || !polled.markers.is_empty()).then(|| Arc::new(polled));
        let mut last = self.last.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if last.is_some() || newest.is_some() {
            *last = newest.clone();
        }
        newest
    }

    fn last_polled(&self) -> Option<Arc<Overlays>> {
        self.last.lock().unwrap_or_else(|poisoned| poisoned.into_inner()).clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_browser_never_waits_for_another_ones_poll() {
        let dir = std::env::temp_dir().join(format!("skinware-overlays-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let shared = SharedOverlays::new("nothing-here", Some(dir.clone()));
        let mut found = Overlays::default();
        found.markers.push(Marker { at: [0.1, 0.2], radius: 0.01, pressure: 3.0 });
        *shared.last.lock().unwrap() = Some(Arc::new(found.clone()));
        // Another session is polling (holding the source): this one gets
        // the last overlays at once instead of queueing.
        let polling = shared.source.lock().unwrap();
        assert_eq!(shared.poll().as_deref(), Some(&found));
        drop(polling);
        // Free: it polls (no services in the directory: nothing to draw).
        assert_eq!(shared.poll(), None);
        assert_eq!(*shared.last.lock().unwrap(), None, "what the next session gets while one polls");
        // Until the next search for services, there is nothing to poll.
        let quiet_for = shared.quiet_until_ns.load(Ordering::Relaxed).saturating_sub(skinware::os::monotonic_ns());
        assert!(quiet_for > 0 && quiet_for <= DISCOVERY_PERIOD.as_nanos() as u64, "{quiet_for} ns");
        // Meanwhile the answer comes without the source, even while it is
        // held (a deadline far ahead, so that a slow machine cannot end it).
        shared.quiet_until_ns.store(u64::MAX, Ordering::Relaxed);
        let polling = shared.source.lock().unwrap();
        *shared.last.lock().unwrap() = Some(Arc::new(found.clone()));
        assert_eq!(shared.poll(), None, "quiet: neither the source nor the last overlays are looked at");
        // Once it ends, sessions look again.
        shared.quiet_until_ns.store(0, Ordering::Relaxed);
        assert_eq!(shared.poll().as_deref(), Some(&found), "no longer quiet: the source is asked for");
        drop(polling);
        let _ = std::fs::remove_dir_all(&dir);
    }

    fn marker_at(x: f32) -> Option<Arc<Overlays>> {
        Some(Arc::new(Overlays {
            arrows: Vec::new(),
            markers: vec![Marker { at: [x, 0.0], radius: 0.01, pressure: 1.0 }],
        }))
    }

    /// What a browser's updates carry in each reader mode, as its session
    /// gets them: the services move on between updates (each poll finds the
    /// contact further along), and the overlays move only with the frames.
    #[test]
    fn overlays_follow_the_frames_of_the_reader_mode() {
        let mut services_at = 0.0;
        let mut poll = || {
            services_at += 1.0;
            marker_at(services_at)
        };
        let at = |overlays: &Overlays| overlays.markers.first().map(|m| m.at[0]);

        // As soon as available: every update brings frames, and the newest overlays.
        let mut asap = HeldOverlays::default();
        assert_eq!(at(asap.for_update(true, true, &mut poll)), Some(1.0));
        assert_eq!(at(asap.for_update(true, true, &mut poll)), Some(2.0));

        // On request: updates of states and rates between requests keep the
        // requested frames' contacts, however the services moved meanwhile.
        let mut request = HeldOverlays::default();
        assert_eq!(at(request.for_update(true, true, &mut poll)), Some(3.0), "the frames requested");
        for _ in 0..5 {
            assert_eq!(at(request.for_update(false, true, || panic!("polled without frames"))), Some(3.0));
        }
        assert_eq!(at(request.for_update(true, true, &mut poll)), Some(4.0), "the next request's");

        // Periodic below the writers' rates: a tick's frames bring the
        // overlays; a rate change between ticks does not.
        let mut periodic = HeldOverlays::default();
        assert_eq!(at(periodic.for_update(true, true, &mut poll)), Some(5.0));
        assert_eq!(at(periodic.for_update(false, true, &mut poll)), Some(5.0));
        assert_eq!(at(periodic.for_update(true, true, &mut poll)), Some(6.0), "polled once per tick, not between");

        // The skin stopped: every layer gone (or not read yet), nothing drawn.
        assert_eq!(*request.for_update(false, false, &mut poll), NO_OVERLAYS);
        assert_eq!(*request.for_update(false, true, &mut poll), NO_OVERLAYS, "not the contacts of before");
    }
}
