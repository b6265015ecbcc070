//! The DDS bridge: every layer and service of a skin, read as an ordinary
//! reader (acquisition cannot notice it), published as standard ROS 2
//! topics for nodes on the default RMW.
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
//! One thread does it all, on a ticker as fast as the fastest topic: a
//! topic is sent when its rate says it is due, only if a subscriber is
//! matched (checked once a second), and only with a frame it has not sent.
//! A layer's clouds are phased over their period, so that a receiver gets
//! them spread out rather than as one burst of datagrams its socket buffer
//! would drop.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use ros2_client::{Context, ContextOptions, Name, Node, NodeName, NodeOptions, Publisher};
use serde::Serialize;
use skinware::{ChannelKind, LayerTopology, Reader, ReaderOptions, Stop, WriterState, lock};
use skinware_geometry::SkinGeometry;
use skinware_ros2::cloud::{LayerClouds, LinkCloud, static_transforms};
use skinware_ros2::diagnostics::{ChannelHealth, diagnostic_array};
use skinware_ros2::markers::ContactMarkers;
use skinware_ros2::rate::Every;
use skinware_ros2::standard::{DIAGNOSTIC_ARRAY, MARKER_ARRAY, POINT_CLOUD2, TF_MESSAGE};
use skinware_ros2::{Header, HeatMap, IMAGE, LayerLook, TACTILE_CONTACTS, TACTILE_STATE, Time};
use skinware_services::{RegionContacts, ServiceInfo, ServicePayload};

use crate::DdsError;
use crate::qos::{QosClass, profile};

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

/// The DDS map's default width, pixels.
pub const DEFAULT_MAP_WIDTH: usize = 200;

/// What to publish, and how.
#[derive(Clone, Debug)]
pub struct DdsOptions {
    /// The skin.
    pub skin: String,
    /// Where its channels are (default: the usual segment directory).
    pub dir: Option<PathBuf>,
    /// Only these layers (`None`: all).
    pub layers: Option<Vec<String>>,
    /// Services too.
    pub services: bool,
    /// The ROS domain (`ROS_DOMAIN_ID`).
    pub domain: u16,
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
}

impl DdsOptions {
    /// Every layer and service of `skin`, domain 0, the default rates,
    /// links at `base_link`.
    pub fn new(skin: &str) -> DdsOptions {
        DdsOptions {
            skin: skin.to_owned(),
            dir: None,
            layers: None,
            services: true,
            domain: 0,
            root_frame: Some("base_link".into()),
            rates: Rates::default(),
            topic_hz: BTreeMap::new(),
            map_width: DEFAULT_MAP_WIDTH,
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

/// One topic: its DDS writer, its rate and its figures.
struct Topic<M: Serialize> {
    publisher: Publisher<M>,
    every: Every,
    report: TopicReport,
    /// When `report.subscribers` is next checked.
    check_at: Instant,
}

impl<M: Serialize> Topic<M> {
    fn declare(
        node: &mut Node,
        options: &DdsOptions,
        topic: &str,
        type_name: &'static str,
        class: QosClass,
        kind_hz: f64,
        phase: f64,
    ) -> Result<Topic<M>, DdsError> {
        let dds = |e: &dyn std::fmt::Display| DdsError::Dds(format!("cannot declare the ROS 2 topic {topic}: {e}"));
        let name = Name::parse(topic).map_err(|e| dds(&format!("{e:?}")))?;
        let qos = profile(class);
        let ros_topic = node.create_topic(&name, crate::type_name(type_name), &qos).map_err(|e| dds(&e))?;
        let publisher = node.create_publisher::<M>(&ros_topic, Some(qos)).map_err(|e| dds(&e))?;
        let hz = options.topic_hz.get(topic).copied().unwrap_or(kind_hz);
        Ok(Topic {
            publisher,
            every: Every::phased(hz, phase),
            report: TopicReport { topic: topic.to_owned(), type_name, class, hz, sent: 0, failed: 0, subscribers: 0 },
            check_at: Instant::now(),
        })
    }

    /// Whether a message is due now and someone listens (checked once a second).
    fn due(&mut self, node: &Node, now: Instant) -> bool {
        if now >= self.check_at {
            self.report.subscribers = node.subscription_count(&self.report.topic);
            self.check_at = now + Duration::from_secs(1);
        }
        self.every.at(now) && self.report.subscribers > 0
    }

    fn publish(&mut self, message: M) {
        match self.publisher.publish(message) {
            Ok(()) => self.report.sent += 1,
            Err(e) => {
                self.report.failed += 1;
                tracing::debug!(topic = %self.report.topic, "DDS refused a write: {e}");
            }
        }
    }
}

/// A layer: its reader and its topics.
struct LayerSource {
    reader: Reader,
    topology: LayerTopology,
    state: Topic<skinware_ros2::TactileState>,
    /// Each link's cloud, its topic and the newest frame it sent.
    clouds: Vec<(LinkCloud, Topic<skinware_ros2::standard::PointCloud2>, u64)>,
    /// The newest frame the state sent.
    state_seq: u64,
}

/// A contact service: its reader and its topics.
struct ContactSource {
    reader: Reader,
    regions: Vec<String>,
    markers: Topic<skinware_ros2::standard::MarkerArray>,
    contacts: Topic<skinware_ros2::TactileContacts>,
    sent_seq: (u64, u64),
}

/// A channel watched for `/diagnostics`: its reader and its frame count at the last report.
struct Watched {
    name: String,
    reader: Reader,
    frames_then: Option<(u64, Instant)>,
}

/// Everything the bridge's thread owns.
struct Publishing {
    options: DdsOptions,
    clock_offset_ns: i64,
    geometry: Option<SkinGeometry>,
    layers: Vec<LayerSource>,
    contacts: Vec<ContactSource>,
    watched: Vec<Watched>,
    diagnostics: Topic<skinware_ros2::standard::DiagnosticArray>,
    map: Option<(HeatMap, Topic<skinware_ros2::Image>)>,
    tf_static: Option<Topic<skinware_ros2::standard::TfMessage>>,
    reports: Arc<Mutex<Vec<TopicReport>>>,
    /// After the topics: fields drop in order, and a writer dropped after
    /// its participant logs errors.
    node: Node,
    /// After the node, which drops its context before its own writers.
    _context: Context,
}

/// A running DDS bridge. Dropping it stops it.
pub struct DdsBridge {
    stop: Stop,
    thread: Option<JoinHandle<()>>,
    reports: Arc<Mutex<Vec<TopicReport>>>,
    node_name: String,
}

impl DdsBridge {
    /// Joins the DDS domain as node `skin_bridge_<skin>`, declares every
    /// topic of the chosen channels, sends `/tf_static`, and starts
    /// publishing.
    pub fn start(options: DdsOptions) -> Result<DdsBridge, DdsError> {
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        skinware::shm::validate_name("skin", &options.skin)?;
        let context = Context::with_options(ContextOptions::new().domain_id(options.domain))
            .map_err(|e| DdsError::Dds(format!("cannot join DDS domain {}: {e}", options.domain)))?;
        let node_name = format!("skin_bridge_{}", skinware_ros2::ros_name(&options.skin).trim_start_matches('_'));
        let node = context
            .new_node(
                NodeName::new("/", &node_name)
                    .map_err(|e| DdsError::Invalid(format!("node name {node_name}: {e:?}")))?,
                NodeOptions::new().enable_rosout(false).start_parameter_services(false),
            )
            .map_err(|e| DdsError::Dds(format!("cannot create the ROS 2 node {node_name}: {e:?}")))?;
        let publishing = Publishing::declare(options, dir, node, context)?;
        *lock(&publishing.reports) = publishing.reports();
        let stop = Stop::new();
        let reports = Arc::clone(&publishing.reports);
        let stopping = stop.clone();
        let thread = std::thread::Builder::new()
            .name("dds-bridge".into())
            .spawn(move || publishing.run(&stopping))
            .map_err(|source| DdsError::Thread { thread: "the DDS bridge".into(), source })?;
        Ok(DdsBridge { stop, thread: Some(thread), reports, node_name })
    }

    /// The bridge's node name in the ROS graph.
    pub fn node_name(&self) -> &str {
        &self.node_name
    }

    /// Every topic's figures, as of the last tick.
    pub fn report(&self) -> Vec<TopicReport> {
        lock(&self.reports).clone()
    }

    /// Stops publishing and leaves the domain; the topics' figures.
    pub fn stop(mut self) -> Vec<TopicReport> {
        self.halt();
        self.report()
    }

    fn halt(&mut self) {
        self.stop.stop();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for DdsBridge {
    fn drop(&mut self) {
        self.halt();
    }
}

impl Publishing {
    /// Opens the chosen channels and declares their topics.
    fn declare(options: DdsOptions, dir: PathBuf, mut node: Node, context: Context) -> Result<Publishing, DdsError> {
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
            watched.push(Watched {
                name: info.channel.clone(),
                reader: Reader::open_with(&skin, &info.channel, &reader_options)?,
                frames_then: None,
            });
            if reader.kind() == ChannelKind::Layer {
                layers.push(LayerSource::declare(&mut node, &options, geometry.as_ref(), reader, &info.channel)?);
            } else if reader.schema().0 == <RegionContacts as ServicePayload>::SCHEMA {
                contacts.push(ContactSource::declare(&mut node, &options, reader, &info.channel)?);
            }
        }
        if watched.is_empty() {
            return Err(DdsError::Invalid(format!(
                "skin {skin:?} has no live channel in {} to publish; start it first (skin run CONFIG, or skin demo)",
                dir.display()
            )));
        }
        let (diagnostics, mut map, tf_static) = declare_fixed(&mut node, &options, geometry.as_ref())?;
        phase_large_topics(&mut layers, map.as_mut().map(|(_, topic)| topic));
        Ok(Publishing {
            options,
            clock_offset_ns: skinware_ros2::clock_offset_ns(),
            node,
            geometry,
            layers,
            contacts,
            watched,
            diagnostics,
            map,
            tf_static,
            reports: Arc::new(Mutex::new(Vec::new())),
            _context: context,
        })
    }

    /// Publishes until `stop`.
    fn run(mut self, stop: &Stop) {
        self.send_static();
        let fastest = [
            self.options.rates.state_hz,
            self.options.rates.cloud_hz,
            self.options.rates.markers_hz,
            self.options.rates.contacts_hz,
            self.options.rates.map_hz,
        ]
        .into_iter()
        .chain(self.options.topic_hz.values().copied())
        .filter(|hz| hz.is_finite())
        .fold(self.options.rates.diagnostics_hz.max(1.0), f64::max);
        // Fast enough to send each large topic at its own phase (two ticks
        // between them), not several in one tick's burst.
        let large: usize = self.layers.iter().map(|l| l.clouds.len()).sum::<usize>() + usize::from(self.map.is_some());
        let phased = 2.0 * large as f64 * self.options.rates.cloud_hz.max(self.options.rates.map_hz);
        let mut ticker = skinware::Ticker::from_hz(fastest.max(phased).clamp(1.0, 1000.0));
        while ticker.wait(stop).is_some() {
            let now = Instant::now();
            self.send_layers(now);
            self.send_contacts(now);
            self.send_map(now);
            self.send_diagnostics(now);
            let reports = self.reports();
            *lock(&self.reports) = reports;
        }
    }

    fn reports(&self) -> Vec<TopicReport> {
        let mut reports = Vec::new();
        for layer in &self.layers {
            reports.push(layer.state.report.clone());
            reports.extend(layer.clouds.iter().map(|(_, topic, _)| topic.report.clone()));
        }
        for source in &self.contacts {
            reports.push(source.markers.report.clone());
            reports.push(source.contacts.report.clone());
        }
        reports.push(self.diagnostics.report.clone());
        reports.extend(self.map.iter().map(|(_, topic)| topic.report.clone()));
        reports.extend(self.tf_static.iter().map(|topic| topic.report.clone()));
        reports
    }

    /// `/tf_static`, once: transient-local, so later subscribers get it too.
    fn send_static(&mut self) {
        let (Some(topic), Some(geometry), Some(root)) = (&mut self.tf_static, &self.geometry, &self.options.root_frame)
        else {
            return;
        };
        let stamp = Time::from_ns(skinware_ros2::now_unix_ns(self.clock_offset_ns));
        topic.publish(static_transforms(geometry, root, stamp));
    }

    fn send_layers(&mut self, now: Instant) {
        for layer in &mut self.layers {
            layer.reader.follow_recreated();
            let state_due = layer.state.due(&self.node, now);
            let clouds_due: Vec<bool> =
                layer.clouds.iter_mut().map(|(_, topic, _)| topic.due(&self.node, now)).collect();
            if !state_due && !clouds_due.contains(&true) {
                continue;
            }
            let Ok(frame) = layer.reader.latest() else { continue };
            let stamp = skinware_ros2::ros_time(frame.acquired_ns(), self.clock_offset_ns);
            let seq = frame.seq();
            if state_due && seq != layer.state_seq {
                layer.state_seq = seq;
                layer.state.publish(skinware_ros2::tactile_state_message(&layer.topology, frame.responses(), stamp));
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
        let drawing = ContactMarkers {
            geometry: self.geometry.as_ref(),
            root: self.options.root_frame.as_deref().unwrap_or("base_link"),
            lifetime: marker_lifetime(self.options.rates.markers_hz),
        };
        for source in &mut self.contacts {
            let markers_due = source.markers.due(&self.node, now);
            let contacts_due = source.contacts.due(&self.node, now);
            if !markers_due && !contacts_due {
                continue;
            }
            source.reader.follow_recreated();
            let Ok(frame) = source.reader.latest() else { continue };
            let (seq, records) = (frame.seq(), frame.records::<RegionContacts>());
            let stamp = skinware_ros2::ros_time(frame.acquired_ns(), self.clock_offset_ns);
            if markers_due && seq != source.sent_seq.0 {
                source.sent_seq.0 = seq;
                source.markers.publish(drawing.markers(&records, stamp));
            }
            if contacts_due && seq != source.sent_seq.1 {
                source.sent_seq.1 = seq;
                source.contacts.publish(skinware_ros2::tactile_contacts_message(&source.regions, &records, stamp));
            }
        }
    }

    fn send_map(&mut self, now: Instant) {
        let Some((heatmap, topic)) = &mut self.map else { return };
        if !topic.due(&self.node, now) {
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
        let stamp = Time::from_ns(skinware_ros2::now_unix_ns(self.clock_offset_ns));
        let header = Header { stamp, frame_id: format!("{}/map", self.options.skin) };
        topic.publish(heatmap.image(pixels, header));
    }

    fn send_diagnostics(&mut self, now: Instant) {
        if !self.diagnostics.due(&self.node, now) {
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
        let stamp = Time::from_ns(skinware_ros2::now_unix_ns(self.clock_offset_ns));
        self.diagnostics.publish(diagnostic_array(&self.options.skin, &channels, stamp));
    }
}

/// The skin's own topics: `/diagnostics`, the map and `/tf_static`.
type FixedTopics = (
    Topic<skinware_ros2::standard::DiagnosticArray>,
    Option<(HeatMap, Topic<skinware_ros2::Image>)>,
    Option<Topic<skinware_ros2::standard::TfMessage>>,
);

fn declare_fixed(
    node: &mut Node,
    options: &DdsOptions,
    geometry: Option<&SkinGeometry>,
) -> Result<FixedTopics, DdsError> {
    let rates = options.rates;
    let diagnostics = Topic::declare(
        node,
        options,
        skinware_ros2::DIAGNOSTICS_TOPIC,
        DIAGNOSTIC_ARRAY,
        QosClass::Status,
        rates.diagnostics_hz,
        0.0,
    )?;
    let map = match geometry {
        Some(geometry) if rates.map_hz > 0.0 => {
            let topic = skinware_ros2::map_topic(&options.skin);
            let map_topic = Topic::declare(node, options, &topic, IMAGE, QosClass::Sensor, rates.map_hz, 0.5)?;
            Some((HeatMap::new(geometry, options.map_width.clamp(16, 4096)), map_topic))
        }
        _ => None,
    };
    let tf_static = match (geometry, &options.root_frame) {
        (Some(_), Some(_)) => {
            Some(Topic::declare(node, options, skinware_ros2::TF_STATIC_TOPIC, TF_MESSAGE, QosClass::Static, 0.0, 0.0)?)
        }
        _ => None,
    };
    Ok((diagnostics, map, tf_static))
}

impl ContactSource {
    fn declare(node: &mut Node, options: &DdsOptions, reader: Reader, name: &str) -> Result<ContactSource, DdsError> {
        let regions = ServiceInfo::parse(&reader.description()).map(|i| i.labels).unwrap_or_default();
        let markers_topic = skinware_ros2::markers_topic(&options.skin, name);
        let contacts_topic = skinware_ros2::contacts_topic(&options.skin, name);
        let (sensor, rates) = (QosClass::Sensor, options.rates);
        Ok(ContactSource {
            reader,
            regions,
            markers: Topic::declare(node, options, &markers_topic, MARKER_ARRAY, sensor, rates.markers_hz, 0.0)?,
            contacts: Topic::declare(node, options, &contacts_topic, TACTILE_CONTACTS, sensor, rates.contacts_hz, 0.0)?,
            sent_seq: (0, 0),
        })
    }
}

impl LayerSource {
    fn declare(
        node: &mut Node,
        options: &DdsOptions,
        geometry: Option<&SkinGeometry>,
        reader: Reader,
        name: &str,
    ) -> Result<LayerSource, DdsError> {
        let skin = &options.skin;
        let topology = LayerTopology::decode(&reader.description(), name).map_err(|e| {
            DdsError::Invalid(format!(
                "layer {name} of skin {skin} describes no topology ({e}); is its writer skinware's?"
            ))
        })?;
        let state_topic = skinware_ros2::tactile_state_topic(skin, name);
        let sensor = QosClass::Sensor;
        let state = Topic::declare(node, options, &state_topic, TACTILE_STATE, sensor, options.rates.state_hz, 0.0)?;
        let link_clouds = geometry
            .and_then(|g| g.layers.iter().position(|l| l.name == name).and_then(|index| LayerClouds::new(g, index)));
        let mut clouds = Vec::new();
        let mut taken = std::collections::BTreeSet::new();
        for cloud in link_clouds.into_iter().flat_map(|c| c.clouds) {
            let mut topic = skinware_ros2::cloud_topic(skin, name, &cloud.link);
            let mut n = 2;
            while !taken.insert(topic.clone()) {
                topic = format!("{}_{n}", skinware_ros2::cloud_topic(skin, name, &cloud.link));
                n += 1;
            }
            // Phased with the skin's other large topics (`phase_large_topics`).
            let declared = Topic::declare(node, options, &topic, POINT_CLOUD2, sensor, options.rates.cloud_hz, 0.0)?;
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
fn check_layers(options: &DdsOptions, live: &[skinware::ChannelInfo]) -> Result<(), DdsError> {
    let layers: Vec<&str> =
        live.iter().filter(|c| c.kind == Some(ChannelKind::Layer)).map(|c| c.channel.as_str()).collect();
    for wanted in options.layers.iter().flatten() {
        if !layers.contains(&wanted.as_str()) {
            return Err(DdsError::Invalid(format!(
                "--layers {wanted}: skin {} has no live layer of that name; its layers are {layers:?}",
                options.skin
            )));
        }
    }
    for (topic, hz) in &options.topic_hz {
        if !(hz.is_finite() && *hz >= 0.0) {
            return Err(DdsError::Invalid(format!(
                "--topic-hz {topic}={hz}: a rate is 0 (never) or a positive number of messages a second"
            )));
        }
    }
    Ok(())
}
