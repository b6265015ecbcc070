//! The skin as standard ROS 2 topics, for any transport: every layer and
//! service of a skin, read as an ordinary reader (acquisition cannot notice
//! it), as the messages ROS tools draw. A transport ([`Transport`]: DDS in
//! `skinware-dds`, rmw_zenoh in `skinware-bridge`) declares each topic and
//! sends what the view gives it.
//!
//! | topic | message | QoS | default rate |
//! |---|---|---|---|
//! | `/skin/<skin>/<layer>/cloud/<link>` | `sensor_msgs/PointCloud2` | sensor | 10 Hz |
//! | `/skin/<skin>/<layer>/state` | `tactile_msgs/TactileState` | sensor | 30 Hz |
//! | `/skin/<skin>/<service>/markers` | `visualization_msgs/MarkerArray` | sensor | 30 Hz |
//! | `/skin/<skin>/<service>/contacts` | `tactile_msgs/TactileContacts` | sensor | 30 Hz |
//! | `/skin/<skin>/map` | `sensor_msgs/Image` | sensor | 5 Hz |
//! | `/diagnostics` | `diagnostic_msgs/DiagnosticArray` | status | 1 Hz |
//! | `/tf_static` | `tf2_msgs/TFMessage` | static | once |
//!
//! A topic whose rate is 0 is not declared at all. One thread runs a view
//! ([`View::run`]), on a ticker as fast as the fastest topic: a topic is
//! sent when its rate says it is due, only if a subscriber is matched
//! (checked once a second), and only with a frame it has not sent. The
//! large topics (every link's cloud, the map) are phased over one grid of
//! slots, so that a receiver gets them spread out rather than as bursts of
//! datagrams its socket buffer would drop.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde::Serialize;
use skinware::{ChannelKind, LayerTopology, Reader, ReaderOptions, Stop, WriterState, lock};
use skinware_geometry::SkinGeometry;
use skinware_services::{RegionContacts, ServiceInfo, ServicePayload};

use crate::cloud::{LayerClouds, LinkCloud, static_transforms};
use crate::diagnostics::{ChannelHealth, diagnostic_array};
use crate::markers::ContactMarkers;
use crate::qos::QosClass;
use crate::rate::Every;
use crate::standard::{DIAGNOSTIC_ARRAY, MARKER_ARRAY, POINT_CLOUD2, TF_MESSAGE};
use crate::{Header, HeatMap, IMAGE, LayerLook, TACTILE_CONTACTS, TACTILE_STATE, Time};

/// A transport of ROS 2 messages: declares a topic, and gives the sink its
/// messages go to.
pub trait Transport {
    /// Declares `topic` of `type_name` with the QoS of `class`.
    fn declare<M: Serialize + Send + 'static>(
        &mut self,
        topic: &str,
        type_name: &'static str,
        class: QosClass,
    ) -> Result<Box<dyn Sink<M>>, ViewError>;
}

/// Where one topic's messages go.
pub trait Sink<M>: Send {
    /// Sends `message`; an error is counted, never waited on.
    fn publish(&mut self, message: M) -> Result<(), SinkError>;
    /// How many subscribers are matched now (a message nobody hears is not built).
    fn subscribers(&self) -> usize;
}

/// A message the transport refused.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct SinkError(pub String);

/// What keeps a view from starting.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// Options that name what the skin does not have.
    #[error("{0}")]
    Invalid(String),
    /// A channel could not be read.
    #[error(transparent)]
    Skinware(#[from] skinware::Error),
    /// The transport could not declare a topic.
    #[error("{0}")]
    Transport(String),
}

/// Each kind of topic's rate, messages a second (0: not published).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rates {
    /// A layer's `TactileState`.
    pub state_hz: f64,
    /// A layer's clouds (each link's).
    pub cloud_hz: f64,
    /// A contact service's markers.
    pub markers_hz: f64,
    /// A contact service's `TactileContacts`.
    pub contacts_hz: f64,
    /// `/diagnostics`.
    pub diagnostics_hz: f64,
    /// The 2-D map image.
    pub map_hz: f64,
}

impl Default for Rates {
    /// What a stock subscriber keeps up with, with no loss, on a default
    /// socket buffer (docs/ros2.md gives the measurement).
    fn default() -> Rates {
        Rates { state_hz: 30.0, cloud_hz: 10.0, markers_hz: 30.0, contacts_hz: 30.0, diagnostics_hz: 1.0, map_hz: 5.0 }
    }
}

/// The slowest rate a topic may have, Hz (0 is none at all).
pub const MIN_HZ: f64 = 0.001;
/// The fastest rate a topic may have, Hz.
pub const MAX_HZ: f64 = 10_000.0;

/// The map's default width, pixels: 100 KB a message, which a DDS
/// receiver's default socket buffer takes whole.
pub const DEFAULT_MAP_WIDTH: usize = 200;

/// What to publish, and how.
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// The skin.
    pub skin: String,
    /// Where its channels are (default: the usual segment directory).
    pub dir: Option<PathBuf>,
    /// Only these layers (`None`: all).
    pub layers: Option<Vec<String>>,
    /// Services too.
    pub services: bool,
    /// The frame every link hangs from on `/tf_static` (`None`: no `/tf_static`).
    pub root_frame: Option<String>,
    /// Each kind of topic's rate.
    pub rates: Rates,
    /// Per-topic rates (full topic name → Hz), over the kind's.
    pub topic_hz: BTreeMap<String, f64>,
    /// The map image's width in pixels (200 by default: 100 KB a message,
    /// which a default socket buffer takes whole; 480, rmw_zenoh's, is
    /// 580 KB, which needs the large-message profile).
    pub map_width: usize,
    /// The tactile messages (`TactileState`, `TactileContacts`) and the map
    /// too; `false` where a transport publishes them itself (rmw_zenoh's
    /// channel threads), whatever the rates say.
    pub tactile_and_map: bool,
}

impl ViewOptions {
    /// Every layer and service of `skin`, the default rates, links at `base_link`.
    pub fn new(skin: &str) -> ViewOptions {
        ViewOptions {
            skin: skin.to_owned(),
            dir: None,
            layers: None,
            services: true,
            root_frame: Some("base_link".into()),
            rates: Rates::default(),
            topic_hz: BTreeMap::new(),
            map_width: DEFAULT_MAP_WIDTH,
            tactile_and_map: true,
        }
    }
}

/// One topic's figures.
#[derive(Clone, Debug, PartialEq)]
pub struct TopicReport {
    /// Its full name.
    pub topic: String,
    /// Its message type.
    pub type_name: &'static str,
    /// Its QoS.
    pub class: QosClass,
    /// Its rate limit, Hz (0: once).
    pub hz: f64,
    /// Messages written.
    pub sent: u64,
    /// Writes DDS refused (a full reliable history), or messages that could not be made.
    pub failed: u64,
    /// Subscribers matched, at the last check.
    pub subscribers: usize,
}

/// One topic: its sink (none if its rate is 0: not declared), its rate
/// and its figures.
struct Topic<M> {
    sink: Option<Box<dyn Sink<M>>>,
    every: Every,
    report: TopicReport,
    /// When `report.subscribers` is next checked.
    check_at: Instant,
}

impl<M: Serialize + Send + 'static> Topic<M> {
    /// Declares `topic` on `transport` unless its rate (`kind_hz`, or its
    /// own in the options) is 0, or it is not `allowed`; `None` (once) for
    /// static data.
    fn declare<T: Transport>(
        transport: &mut T,
        options: &ViewOptions,
        topic: &str,
        (type_name, class): (&'static str, QosClass),
        kind_hz: Option<f64>,
        allowed: bool,
    ) -> Result<Topic<M>, ViewError> {
        let hz = options.topic_hz.get(topic).copied().or(kind_hz);
        let declared = allowed && hz.is_none_or(|hz| hz > 0.0);
        let sink = if declared { Some(transport.declare(topic, type_name, class)?) } else { None };
        let hz = hz.unwrap_or(0.0);
        Ok(Topic {
            sink,
            every: Every::phased(hz, 0.0),
            report: TopicReport { topic: topic.to_owned(), type_name, class, hz, sent: 0, failed: 0, subscribers: 0 },
            check_at: Instant::now(),
        })
    }

    /// Whether a message is due now and someone listens (checked once a second).
    fn due(&mut self, now: Instant) -> bool {
        let Some(sink) = &self.sink else { return false };
        if now >= self.check_at {
            self.report.subscribers = sink.subscribers();
            self.check_at = now + Duration::from_secs(1);
        }
        self.every.at(now) && self.report.subscribers > 0
    }

    fn publish(&mut self, message: M) {
        let Some(sink) = &mut self.sink else { return };
        match sink.publish(message) {
            Ok(()) => self.report.sent += 1,
            Err(e) => {
                self.report.failed += 1;
                tracing::debug!(topic = %self.report.topic, "a message was not sent: {e}");
            }
        }
    }

    /// Its rate, if it was declared (`None`: not, or once).
    fn declared_hz(&self) -> Option<f64> {
        self.sink.as_ref().map(|_| self.report.hz).filter(|hz| *hz > 0.0)
    }

    /// Its figures, if it was declared.
    fn declared_report(&self) -> Option<TopicReport> {
        self.sink.as_ref().map(|_| self.report.clone())
    }
}

/// A layer: its reader and its topics.
struct LayerSource {
    reader: Reader,
    topology: LayerTopology,
    state: Topic<crate::TactileState>,
    /// Each link's cloud, its topic and the newest frame it sent.
    clouds: Vec<(LinkCloud, Topic<crate::standard::PointCloud2>, u64)>,
    /// The newest frame the state sent.
    state_seq: u64,
}

/// A contact service: its reader and its topics.
struct ContactSource {
    reader: Reader,
    regions: Vec<String>,
    markers: Topic<crate::standard::MarkerArray>,
    contacts: Topic<crate::TactileContacts>,
    sent_seq: (u64, u64),
}

/// A channel watched for `/diagnostics`: its reader and its frame count at the last report.
struct Watched {
    name: String,
    reader: Reader,
    frames_then: Option<(u64, Instant)>,
}

/// The skin as ROS 2 topics on one transport: what a view's thread owns.
pub struct View<T: Transport> {
    options: ViewOptions,
    clock_offset_ns: i64,
    geometry: Option<SkinGeometry>,
    layers: Vec<LayerSource>,
    contacts: Vec<ContactSource>,
    watched: Vec<Watched>,
    diagnostics: Topic<crate::standard::DiagnosticArray>,
    map: Option<(HeatMap, Topic<crate::Image>)>,
    tf_static: Option<Topic<crate::standard::TfMessage>>,
    reports: Arc<Mutex<Vec<TopicReport>>>,
    /// After the topics: fields drop in order, and a DDS writer dropped
    /// after its participant logs errors.
    transport: T,
}

impl<T: Transport> View<T> {
    /// Opens the chosen channels of `options.skin` and declares their
    /// topics on `transport`.
    pub fn declare(options: ViewOptions, mut transport: T) -> Result<View<T>, ViewError> {
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        skinware::shm::validate_name("skin", &options.skin)?;
        let skin = options.skin.clone();
        let listed: Vec<skinware::ChannelInfo> = skinware::list_skin_channels(&dir, &skin)?
            .into_iter()
            .filter(|c| c.skin == skin && c.state != WriterState::Gone && c.problem.is_none())
            .collect();
        check_layers(&options, &listed)?;
        let geometry = SkinGeometry::open_in(&dir, &skin).ok();
        let reader_options = ReaderOptions { dir: Some(dir.clone()), allow_gone: true, ..ReaderOptions::default() };
        let mut layers: Vec<LayerSource> = Vec::new();
        let mut contacts = Vec::new();
        let mut watched = Vec::new();
        for info in &listed {
            let wanted = match info.kind {
                Some(ChannelKind::Layer) => options.layers.as_ref().is_none_or(|l| l.contains(&info.channel)),
                Some(ChannelKind::Service) => options.services,
                None => false,
            };
            if !wanted {
                continue;
            }
            let reader = Reader::open_with(&skin, &info.channel, &reader_options)?;
            // Its frame count now: the first `/diagnostics` already has a rate.
            let watcher = Reader::open_with(&skin, &info.channel, &reader_options)?;
            let frames_then = Some((watcher.writer_stats().frames, Instant::now()));
            watched.push(Watched { name: info.channel.clone(), reader: watcher, frames_then });
            if reader.kind() == ChannelKind::Layer {
                layers.push(LayerSource::declare(&mut transport, &options, geometry.as_ref(), reader, &info.channel)?);
            } else if reader.schema().0 == <RegionContacts as ServicePayload>::SCHEMA {
                contacts.push(ContactSource::declare(&mut transport, &options, reader, &info.channel)?);
            }
        }
        if watched.is_empty() {
            return Err(ViewError::Invalid(format!(
                "skin {skin:?} has no live channel in {} to publish; start it first (skin run CONFIG, or skin demo)",
                dir.display()
            )));
        }
        let (diagnostics, mut map, tf_static) = declare_fixed(&mut transport, &options, geometry.as_ref())?;
        phase_large_topics(&mut layers, map.as_mut().map(|(_, topic)| topic));
        let view = View {
            options,
            clock_offset_ns: crate::clock_offset_ns(),
            geometry,
            layers,
            contacts,
            watched,
            diagnostics,
            map,
            tf_static,
            reports: Arc::new(Mutex::new(Vec::new())),
            transport,
        };
        check_topic_rates(&view)?;
        *lock(&view.reports) = view.reports();
        Ok(view)
    }

    /// Every declared topic's figures, as of the last tick, shared with
    /// whoever started the view's thread.
    pub fn shared_reports(&self) -> Arc<Mutex<Vec<TopicReport>>> {
        Arc::clone(&self.reports)
    }

    /// The transport.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// Publishes until `stop`.
    pub fn run(&mut self, stop: &Stop) {
        self.send_static();
        let mut ticker = skinware::Ticker::from_hz(self.tick_hz());
        let mut report_at = Instant::now();
        while ticker.wait(stop).is_some() {
            let now = Instant::now();
            self.send_layers(now);
            self.send_contacts(now);
            self.send_map(now);
            self.send_diagnostics(now);
            if now >= report_at {
                let reports = self.reports();
                *lock(&self.reports) = reports;
                report_at = now + Duration::from_secs(1);
            }
        }
        let reports = self.reports();
        *lock(&self.reports) = reports;
    }

    /// The ticker's rate: as fast as the fastest topic, and fast enough to
    /// send each large topic in its own slot of the grid
    /// `phase_large_topics` made (two ticks a slot), at most 1 kHz.
    fn tick_hz(&self) -> f64 {
        let mut rates: Vec<f64> = Vec::new();
        let mut large: Vec<f64> = Vec::new();
        for layer in &self.layers {
            rates.extend(layer.state.declared_hz());
            large.extend(layer.clouds.iter().filter_map(|(_, topic, _)| topic.declared_hz()));
        }
        for source in &self.contacts {
            rates.extend(source.markers.declared_hz().into_iter().chain(source.contacts.declared_hz()));
        }
        rates.extend(self.diagnostics.declared_hz());
        large.extend(self.map.iter().filter_map(|(_, topic)| topic.declared_hz()));
        let fastest = rates.iter().chain(&large).copied().fold(1.0, f64::max);
        let slots = 2.0 * large.len() as f64 * large.iter().copied().fold(0.0, f64::max);
        fastest.max(slots).clamp(1.0, 1000.0)
    }

    fn reports(&self) -> Vec<TopicReport> {
        let mut reports = Vec::new();
        for layer in &self.layers {
            reports.extend(layer.state.declared_report());
            reports.extend(layer.clouds.iter().filter_map(|(_, topic, _)| topic.declared_report()));
        }
        for source in &self.contacts {
            reports.extend(source.markers.declared_report());
            reports.extend(source.contacts.declared_report());
        }
        reports.extend(self.diagnostics.declared_report());
        reports.extend(self.map.iter().filter_map(|(_, topic)| topic.declared_report()));
        reports.extend(self.tf_static.iter().filter_map(Topic::declared_report));
        reports
    }

    /// `/tf_static`, once: transient-local, so later subscribers get it too.
    fn send_static(&mut self) {
        let (Some(topic), Some(geometry), Some(root)) = (&mut self.tf_static, &self.geometry, &self.options.root_frame)
        else {
            return;
        };
        let stamp = Time::from_ns(crate::now_unix_ns(self.clock_offset_ns));
        topic.publish(static_transforms(geometry, root, stamp));
    }

    fn send_layers(&mut self, now: Instant) {
        for layer in &mut self.layers {
            layer.reader.follow_recreated();
            let state_due = layer.state.due(now);
            let clouds_due: Vec<bool> = layer.clouds.iter_mut().map(|(_, topic, _)| topic.due(now)).collect();
            if !state_due && !clouds_due.contains(&true) {
                continue;
            }
            let Ok(frame) = layer.reader.latest() else { continue };
            let stamp = crate::ros_time(frame.acquired_ns(), self.clock_offset_ns);
            let seq = frame.seq();
            if state_due && seq != layer.state_seq {
                layer.state_seq = seq;
                layer.state.publish(crate::tactile_state_message(&layer.topology, frame.responses(), stamp));
            }
            // Each link's cloud is sent when its phase is due, of a frame it did not send.
            for ((cloud, topic, sent_seq), due) in layer.clouds.iter_mut().zip(clouds_due) {
                if due && seq != *sent_seq {
                    *sent_seq = seq;
                    topic.publish(cloud.cloud(frame.responses(), stamp));
                }
            }
        }
    }

    fn send_contacts(&mut self, now: Instant) {
        for source in &mut self.contacts {
            // A few of this topic's own periods.
            let drawing = ContactMarkers {
                geometry: self.geometry.as_ref(),
                root: self.options.root_frame.as_deref().unwrap_or("base_link"),
                lifetime: marker_lifetime(source.markers.report.hz),
            };
            let markers_due = source.markers.due(now);
            let contacts_due = source.contacts.due(now);
            if !markers_due && !contacts_due {
                continue;
            }
            source.reader.follow_recreated();
            let Ok(frame) = source.reader.latest() else { continue };
            let (seq, records) = (frame.seq(), frame.records::<RegionContacts>());
            let stamp = crate::ros_time(frame.acquired_ns(), self.clock_offset_ns);
            if markers_due && seq != source.sent_seq.0 {
                source.sent_seq.0 = seq;
                source.markers.publish(drawing.markers(&records, stamp));
            }
            if contacts_due && seq != source.sent_seq.1 {
                source.sent_seq.1 = seq;
                source.contacts.publish(crate::tactile_contacts_message(&source.regions, &records, stamp));
            }
        }
    }

    fn send_map(&mut self, now: Instant) {
        let Some((heatmap, topic)) = &mut self.map else { return };
        if !topic.due(now) {
            return;
        }
        let Some(geometry) = &self.geometry else { return };
        let mut newest: Vec<(Option<Vec<u16>>, LayerLook)> = Vec::new();
        for layer in &geometry.layers {
            let source = self.layers.iter_mut().find(|l| l.topology.name == layer.name);
            newest.push(match source {
                Some(source) => {
                    let look = match source.reader.writer_state() {
                        WriterState::Gone => LayerLook::Gone,
                        WriterState::Faulted => LayerLook::Faulted,
                        _ => LayerLook::Live,
                    };
                    (source.reader.latest().ok().map(|f| f.responses().to_vec()), look)
                }
                None => (None, LayerLook::Gone),
            });
        }
        let layers: Vec<(Option<&[u16]>, LayerLook)> = newest.iter().map(|(r, look)| (r.as_deref(), *look)).collect();
        let pixels = heatmap.render(&layers);
        let stamp = Time::from_ns(crate::now_unix_ns(self.clock_offset_ns));
        let header = Header { stamp, frame_id: format!("{}/map", self.options.skin) };
        topic.publish(heatmap.image(pixels, header));
    }

    fn send_diagnostics(&mut self, now: Instant) {
        if !self.diagnostics.due(now) {
            return;
        }
        let mut channels = Vec::with_capacity(self.watched.len());
        for watched in &mut self.watched {
            watched.reader.follow_recreated();
            let stats = watched.reader.writer_stats();
            let rate_hz = match watched.frames_then {
                Some((frames, then)) if now > then => {
                    stats.frames.saturating_sub(frames) as f64 / now.duration_since(then).as_secs_f64()
                }
                _ => 0.0,
            };
            watched.frames_then = Some((stats.frames, now));
            // The period is the writer's number: one under a microsecond
            // (or none) is no nominal rate to judge by.
            let nominal_hz = watched
                .reader
                .writer_period()
                .filter(|p| *p >= Duration::from_micros(1))
                .map_or(0.0, |p| 1.0 / p.as_secs_f64());
            channels.push(ChannelHealth {
                channel: watched.name.clone(),
                writer: format!("skinware {}", self.options.skin),
                state: watched.reader.writer_state(),
                rate_hz,
                nominal_hz,
                stats,
                restarts: None,
            });
        }
        let stamp = Time::from_ns(crate::now_unix_ns(self.clock_offset_ns));
        self.diagnostics.publish(diagnostic_array(&self.options.skin, &channels, stamp));
    }
}

/// The skin's own topics: `/diagnostics`, the map and `/tf_static`.
type FixedTopics = (
    Topic<crate::standard::DiagnosticArray>,
    Option<(HeatMap, Topic<crate::Image>)>,
    Option<Topic<crate::standard::TfMessage>>,
);

fn declare_fixed<T: Transport>(
    transport: &mut T,
    options: &ViewOptions,
    geometry: Option<&SkinGeometry>,
) -> Result<FixedTopics, ViewError> {
    let rates = options.rates;
    let diagnostics = Topic::declare(
        transport,
        options,
        crate::DIAGNOSTICS_TOPIC,
        (DIAGNOSTIC_ARRAY, QosClass::Status),
        Some(rates.diagnostics_hz),
        true,
    )?;
    let map = match geometry {
        Some(geometry) if options.tactile_and_map => {
            let topic = crate::map_topic(&options.skin);
            let map_topic =
                Topic::declare(transport, options, &topic, (IMAGE, QosClass::Sensor), Some(rates.map_hz), true)?;
            Some((HeatMap::new(geometry, options.map_width.clamp(16, 4096)), map_topic))
        }
        _ => None,
    };
    let tf_static = match (geometry, &options.root_frame) {
        (Some(_), Some(_)) => Some(Topic::declare(
            transport,
            options,
            crate::TF_STATIC_TOPIC,
            (TF_MESSAGE, QosClass::Static),
            None,
            true,
        )?),
        _ => None,
    };
    Ok((diagnostics, map, tf_static))
}

impl ContactSource {
    fn declare<T: Transport>(
        transport: &mut T,
        options: &ViewOptions,
        reader: Reader,
        name: &str,
    ) -> Result<ContactSource, ViewError> {
        let regions = ServiceInfo::parse(&reader.description()).map(|i| i.labels).unwrap_or_default();
        let markers_topic = crate::markers_topic(&options.skin, name);
        let contacts_topic = crate::contacts_topic(&options.skin, name);
        let (sensor, rates) = (QosClass::Sensor, options.rates);
        Ok(ContactSource {
            reader,
            regions,
            markers: Topic::declare(
                transport,
                options,
                &markers_topic,
                (MARKER_ARRAY, sensor),
                Some(rates.markers_hz),
                true,
            )?,
            contacts: Topic::declare(
                transport,
                options,
                &contacts_topic,
                (TACTILE_CONTACTS, sensor),
                Some(rates.contacts_hz),
                options.tactile_and_map,
            )?,
            sent_seq: (0, 0),
        })
    }
}

impl LayerSource {
    fn declare<T: Transport>(
        transport: &mut T,
        options: &ViewOptions,
        geometry: Option<&SkinGeometry>,
        reader: Reader,
        name: &str,
    ) -> Result<LayerSource, ViewError> {
        let skin = &options.skin;
        let topology = LayerTopology::decode(&reader.description(), name).map_err(|e| {
            ViewError::Invalid(format!(
                "layer {name} of skin {skin} describes no topology ({e}); is its writer skinware's?"
            ))
        })?;
        let state_topic = crate::tactile_state_topic(skin, name);
        let sensor = QosClass::Sensor;
        let state = Topic::declare(
            transport,
            options,
            &state_topic,
            (TACTILE_STATE, sensor),
            Some(options.rates.state_hz),
            options.tactile_and_map,
        )?;
        let link_clouds = geometry
            .and_then(|g| g.layers.iter().position(|l| l.name == name).and_then(|index| LayerClouds::new(g, index)));
        let mut clouds = Vec::new();
        let mut taken = std::collections::BTreeSet::new();
        for cloud in link_clouds.into_iter().flat_map(|c| c.clouds) {
            let mut topic = crate::cloud_topic(skin, name, &cloud.link);
            let mut n = 2;
            while !taken.insert(topic.clone()) {
                topic = format!("{}_{n}", crate::cloud_topic(skin, name, &cloud.link));
                n += 1;
            }
            // Phased with the skin's other large topics (`phase_large_topics`).
            let declared =
                Topic::declare(transport, options, &topic, (POINT_CLOUD2, sensor), Some(options.rates.cloud_hz), true)?;
            clouds.push((cloud, declared, 0));
        }
        Ok(LayerSource { reader, topology, state, clouds, state_seq: 0 })
    }
}

/// Spreads the large messages (every link's cloud, the map) evenly over
/// their period: a receiver's socket buffer (208 KiB by default) holds one
/// burst of a cloud's datagrams, not all of them at once, and a datagram
/// dropped for room takes its whole message with it.
fn phase_large_topics<M: Serialize>(layers: &mut [LayerSource], map: Option<&mut Topic<M>>) {
    let mut large: Vec<&mut Every> =
        layers.iter_mut().flat_map(|layer| layer.clouds.iter_mut().map(|(_, topic, _)| &mut topic.every)).collect();
    if let Some(map) = map {
        large.push(&mut map.every);
    }
    // Slots of the shortest period, one per topic: a slower topic (the map
    // at 5 Hz beside clouds at 10) lands in its own slot of every period.
    let Some(shortest) = large.iter().filter_map(|every| every.period()).min() else { return };
    let count = large.len() as f64;
    for (k, every) in large.into_iter().enumerate() {
        let Some(period) = every.period() else { continue };
        let offset = shortest.as_secs_f64() * k as f64 / count;
        *every = every.rephased(offset / period.as_secs_f64());
    }
}

/// How long a contact's arrow lives without an update: a few of the markers' periods.
fn marker_lifetime(markers_hz: f64) -> Duration {
    let period = if markers_hz > 0.0 && markers_hz.is_finite() { 1.0 / markers_hz } else { 1.0 };
    Duration::from_secs_f64((3.0 * period).clamp(0.2, 10.0))
}

/// Refuses a `--layers` name the skin does not have.
fn check_layers(options: &ViewOptions, live: &[skinware::ChannelInfo]) -> Result<(), ViewError> {
    let layers: Vec<&str> =
        live.iter().filter(|c| c.kind == Some(ChannelKind::Layer)).map(|c| c.channel.as_str()).collect();
    for wanted in options.layers.iter().flatten() {
        if !layers.contains(&wanted.as_str()) {
            return Err(ViewError::Invalid(format!(
                "--layers {wanted}: skin {} has no live layer of that name; its layers are {layers:?}",
                options.skin
            )));
        }
    }
    let rates = options.rates;
    let kinds = [
        ("--state-hz", rates.state_hz),
        ("--cloud-hz", rates.cloud_hz),
        ("--contacts-hz", rates.markers_hz),
        ("--contacts-hz", rates.contacts_hz),
        ("--map-hz", rates.map_hz),
        ("the diagnostics' rate", rates.diagnostics_hz),
    ];
    let topics = options.topic_hz.iter().map(|(topic, hz)| ("--topic-hz", *hz, Some(topic)));
    for (flag, hz, topic) in kinds.into_iter().map(|(flag, hz)| (flag, hz, None)).chain(topics) {
        if !(hz == 0.0 || (MIN_HZ..=MAX_HZ).contains(&hz)) {
            let named = topic.map_or(String::new(), |topic| format!(" {topic}="));
            return Err(ViewError::Invalid(format!(
                "{flag}{named} {hz}: a rate is 0 (none) or {MIN_HZ} to {MAX_HZ} messages a second"
            )));
        }
    }
    Ok(())
}

/// Refuses a `--topic-hz` that names no topic of this view.
fn check_topic_rates<T: Transport>(view: &View<T>) -> Result<(), ViewError> {
    let mut known: Vec<&str> = Vec::new();
    for layer in &view.layers {
        known.push(&layer.state.report.topic);
        known.extend(layer.clouds.iter().map(|(_, topic, _)| topic.report.topic.as_str()));
    }
    for source in &view.contacts {
        known.extend([source.markers.report.topic.as_str(), source.contacts.report.topic.as_str()]);
    }
    known.push(&view.diagnostics.report.topic);
    known.extend(view.map.iter().map(|(_, topic)| topic.report.topic.as_str()));
    for topic in view.options.topic_hz.keys() {
        if !known.contains(&topic.as_str()) {
            let some: Vec<&str> = known.iter().copied().take(8).collect();
            return Err(ViewError::Invalid(format!(
                "--topic-hz {topic}=...: skin {} has no such topic; its topics include {some:?} (skin bridge --stats lists them all)",
                view.options.skin
            )));
        }
    }
    Ok(())
}
