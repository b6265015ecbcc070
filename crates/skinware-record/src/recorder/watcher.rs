//! The watcher thread: the map image a few times a second, every
//! channel's statistics once a second, and the messages for ROS tools
//! (`ros_view`), from readers of its own (the map
//! needs every layer of the geometry, recorded or not), so that neither
//! delays a recorded frame.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use skinware::rt::Ticker;
use skinware::{ChannelKind, FrameStatus, Reader, ReaderOptions, WriterState};
use skinware_geometry::SkinGeometry;
use skinware_ros2::rate::Every;
use skinware_ros2::{Header, HeatMap, LayerLook, LayerStats, Time, now_unix_ns, unix_ns};

use super::queue::QueueSender;
use super::ros_view::RosView;
use super::summary::Recorded;
use super::{Item, STATS_INTERVAL, Shared};

/// The map image and the statistics, from readers of its own.
pub(super) struct Watcher {
    pub(super) skin: String,
    pub(super) dir: PathBuf,
    pub(super) geometry: Option<SkinGeometry>,
    /// The map image's MCAP channel and its renderer.
    pub(super) map: Option<(u16, HeatMap)>,
    pub(super) map_hz: f64,
    /// The messages for ROS tools, and how often to write clouds and markers.
    pub(super) ros: Option<RosView>,
    pub(super) ros2_hz: f64,
    pub(super) channels: Vec<Recorded>,
    /// The MCAP channel of each recorded channel's statistics.
    pub(super) stats_channels: Vec<u16>,
    pub(super) clock_offset_ns: i64,
    pub(super) sender: QueueSender<Item>,
    pub(super) shared: Arc<Shared>,
}

/// The newest frame of every layer the watcher reads.
struct NewestLayers {
    skin: String,
    options: ReaderOptions,
    names: Vec<String>,
    /// A reader per name, once its layer could be opened.
    readers: Vec<Option<Reader>>,
    /// Per name, the newest responses and how to draw them, once read.
    newest: Vec<Option<(Vec<u16>, LayerLook)>>,
    /// Per name, its newest frame's sequence number and acquisition time
    /// (CLOCK_MONOTONIC ns).
    seq_and_acquired: Vec<(u64, u64)>,
}

impl NewestLayers {
    fn open(skin: &str, options: ReaderOptions, names: Vec<String>) -> NewestLayers {
        let readers = names.iter().map(|name| Reader::open_with(skin, name, &options).ok()).collect();
        let newest = vec![None; names.len()];
        let seq_and_acquired = vec![(0, 0); names.len()];
        NewestLayers { skin: skin.to_owned(), options, names, readers, newest, seq_and_acquired }
    }

    /// Reads every layer's newest frame; a layer not read keeps its last
    /// responses, drawn as gone.
    fn read(&mut self) {
        let layers = self.readers.iter_mut().zip(&mut self.newest).zip(&self.names);
        for (((reader, slot), name), seq_and_acquired) in layers.zip(&mut self.seq_and_acquired) {
            if reader.is_none() {
                *reader = Reader::open_with(&self.skin, name, &self.options).ok();
            }
            let Some(reader) = reader else { continue };
            let state = reader.writer_state();
            match reader.latest() {
                Ok(frame) => {
                    let look = match state {
                        WriterState::Gone => LayerLook::Gone,
                        WriterState::Faulted => LayerLook::Faulted,
                        _ if frame.status().contains(FrameStatus::FAULT) => LayerLook::Faulted,
                        _ => LayerLook::Live,
                    };
                    let values: Vec<u16> =
                        frame.bytes().chunks_exact(2).map(|b| u16::from_ne_bytes([b[0], b[1]])).collect();
                    *seq_and_acquired = (frame.seq(), frame.acquired_ns());
                    *slot = Some((values, look));
                }
                Err(_) => {
                    if let Some((_, look)) = slot {
                        *look = LayerLook::Gone;
                    }
                }
            }
        }
    }

    /// Every layer as the map draws it.
    fn for_map(&self) -> Vec<(Option<&[u16]>, LayerLook)> {
        self.newest
            .iter()
            .map(|n| match n {
                Some((values, look)) => (Some(values.as_slice()), *look),
                None => (None, LayerLook::Gone),
            })
            .collect()
    }

    /// Per name, the newest responses read, their sequence number and
    /// acquisition time (Unix ns): what the clouds show.
    fn newest_frames(&self, clock_offset_ns: i64) -> Vec<Option<(&[u16], u64, u64)>> {
        self.newest
            .iter()
            .zip(&self.seq_and_acquired)
            .map(|(newest, &(seq, acquired_ns))| {
                newest.as_ref().map(|(values, _)| (values.as_slice(), seq, unix_ns(acquired_ns, clock_offset_ns)))
            })
            .collect()
    }

    /// Smallest, largest and mean response of layer `name`'s newest frame (zeros if none).
    fn response_range(&self, name: &str) -> (u16, u16, f64) {
        self.names
            .iter()
            .position(|l| l == name)
            .and_then(|l| self.newest[l].as_ref())
            .filter(|(values, _)| !values.is_empty())
            .map_or((0, 0, 0.0), |(values, _)| {
                let sum: u64 = values.iter().map(|&v| u64::from(v)).sum();
                (
                    *values.iter().min().unwrap_or(&0),
                    *values.iter().max().unwrap_or(&0),
                    sum as f64 / values.len() as f64,
                )
            })
    }
}

/// Each channel's frame count and summed latency when the last statistics were written.
struct StatsInterval {
    started: Instant,
    previous: Vec<(u64, u64)>,
}

impl Watcher {
    pub(super) fn run(mut self) {
        let options = ReaderOptions { dir: Some(self.dir.clone()), allow_gone: true, ..ReaderOptions::default() };
        // The map needs every layer of the geometry, recorded or not; the statistics every recorded layer.
        let layer_names: Vec<String> = match &self.geometry {
            Some(g) => g.layers.iter().map(|l| l.name.clone()).collect(),
            None => self.channels.iter().filter(|c| c.kind == ChannelKind::Layer).map(|c| c.name.clone()).collect(),
        };
        let mut layers = NewestLayers::open(&self.skin, options, layer_names);
        let map_hz = if self.map.is_some() { self.map_hz.clamp(0.1, 60.0) } else { 0.0 };
        let ros_hz = if self.ros.is_some() { self.ros2_hz.clamp(0.1, 60.0) } else { 0.0 };
        let mut ticker = Ticker::from_hz(map_hz.max(ros_hz).max(1.0));
        let mut map_due = Every::new(map_hz);
        let mut ros_due = Every::new(ros_hz);
        let mut interval = StatsInterval { started: Instant::now(), previous: vec![(0, 0); self.channels.len()] };
        while ticker.wait(&self.shared.stop).is_some() {
            layers.read();
            let now_ns = now_unix_ns(self.clock_offset_ns);
            if map_due.now() && !self.write_map(&layers, now_ns) {
                return;
            }
            if ros_due.now() && !self.write_ros(&layers) {
                return;
            }
            let elapsed = interval.started.elapsed();
            if elapsed >= STATS_INTERVAL {
                interval.started = Instant::now();
                if !self.write_stats(&layers, &mut interval.previous, elapsed, now_ns) {
                    return;
                }
            }
        }
    }

    /// Sends the map image, if the map is recorded; `false` once the file is gone.
    fn write_map(&mut self, layers: &NewestLayers, now_ns: u64) -> bool {
        let Some((channel_id, heat)) = &mut self.map else { return true };
        let header = Header { stamp: Time::from_ns(now_ns), frame_id: format!("skin/{}/map", self.skin) };
        let pixels = heat.render(&layers.for_map());
        let image = heat.image(pixels, header);
        if let Ok(data) = skinware_ros2::encode(&image, image.data.len() + 64) {
            let item = Item { channel_id: *channel_id, sequence: 0, log_time: now_ns, publish_time: now_ns, data };
            if self.sender.send(item).is_err() {
                return false;
            }
            self.shared.images.fetch_add(1, Ordering::Relaxed);
        }
        true
    }

    /// Sends the clouds of the layers with a new frame, and the contact
    /// services' markers; `false` once the file is gone.
    fn write_ros(&mut self, layers: &NewestLayers) -> bool {
        let Some(ros) = &mut self.ros else { return true };
        ros.send_clouds(&layers.newest_frames(self.clock_offset_ns), &self.sender)
            && ros.send_markers(self.geometry.as_ref(), self.clock_offset_ns, &self.sender)
    }

    /// Sends every channel's statistics over the last `elapsed` (and, for
    /// ROS tools, their health); `false` once the file is gone.
    fn write_stats(
        &mut self,
        layers: &NewestLayers,
        previous: &mut [(u64, u64)],
        elapsed: Duration,
        now_ns: u64,
    ) -> bool {
        let mut states = Vec::with_capacity(self.channels.len());
        let mut rates_hz = Vec::with_capacity(self.channels.len());
        for (k, channel) in self.channels.iter().enumerate() {
            let counters = &channel.counters;
            let frames = counters.frames.load(Ordering::Relaxed);
            let latency = counters.latency_ns.load(Ordering::Relaxed);
            let (frames_before, latency_before) = previous[k];
            previous[k] = (frames, latency);
            let new_frames = frames - frames_before;
            let (min, max, mean) = layers.response_range(&channel.name);
            let state =
                WriterState::from_number(counters.state.load(Ordering::Relaxed)).unwrap_or(WriterState::Running);
            let stats = LayerStats {
                stamp: Time::from_ns(now_ns),
                channel: channel.name.clone(),
                state: state.as_str().to_owned(),
                frames,
                lost: counters.lost.load(Ordering::Relaxed),
                faulted: counters.faulted.load(Ordering::Relaxed),
                rate_hz: new_frames as f64 / elapsed.as_secs_f64(),
                latency_ms: if new_frames == 0 {
                    0.0
                } else {
                    (latency - latency_before) as f64 / new_frames as f64 / 1e6
                },
                min_response: min,
                max_response: max,
                mean_response: mean,
            };
            if let Ok(data) = skinware_ros2::encode(&stats, 128) {
                let item = Item {
                    channel_id: self.stats_channels[k],
                    sequence: 0,
                    log_time: now_ns,
                    publish_time: now_ns,
                    data,
                };
                if self.sender.send(item).is_err() {
                    return false;
                }
            }
            states.push(state);
            rates_hz.push(stats.rate_hz);
        }
        match &mut self.ros {
            Some(ros) => ros.send_diagnostics(&states, &rates_hz, now_ns, &self.sender),
            None => true,
        }
    }
}
