//! The bridge: every layer and service of a skin, read as an ordinary reader
//! (so acquisition cannot notice it) and published on zenoh, for remote
//! skinware readers and for ROS 2 nodes on rmw_zenoh.
//!
//! One thread per channel reads its newest frame (as soon as it is published,
//! or at most `--max-hz` times a second) and hands it to zenoh with
//! congestion control *drop*: when the link is slower than the writer, zenoh
//! drops what finds no room in its two-batch queue rather than build a
//! backlog, and nothing waits (a thread blocked on a full queue can also
//! stall zenoh's own threads, which we saw on a 1 Mbit/s link). Nothing is
//! lost silently: every frame carries the writer's sequence number, so a
//! remote reader counts each frame it did not get (`skipped`, as a local
//! reader does), and the bridge counts the frames it did not send (`dropped`:
//! rate limit, or it read too late) in each channel's state.
//!
//! A second thread publishes every channel's state ten times a second (its
//! absence tells a remote reader the link is cut) and picks up channels
//! that appear later; a third serves frames on request; a fourth renders the
//! 2-D map for ROS.

use std::collections::{BTreeMap, VecDeque};
use std::path::PathBuf;
use std::sync::atomic::{AtomicI64, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use skinware::{ChannelKind, Error, Reader, ReaderOptions, Stop, WriterState};
use skinware_geometry::SkinGeometry;
use skinware_record::heatmap::{HeatMap, LayerLook};
use skinware_record::msgs::{Header, Image, Time};
use skinware_services::{RegionContacts, ServiceInfo};
use zenoh::bytes::ZBytes;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Publisher;
use zenoh::qos::{CongestionControl, Priority};
use zenoh::{Session, Wait};

use crate::link::LinkOptions;
use crate::protocol::{self, ChannelList, ChannelState, ReaderReport, RemoteChannel};
use crate::ros2::{self, Attachment, EntityKind, Liveliness};
use crate::{BridgeError, messages};

/// What to bridge, and how.
#[derive(Clone, Debug)]
pub struct BridgeOptions {
    /// The skin.
    pub skin: String,
    /// Where its channels are (default: the usual segment directory).
    pub dir: Option<PathBuf>,
    /// Only these layers (`None`: all).
    pub layers: Option<Vec<String>>,
    /// Services too.
    pub services: bool,
    /// At most this many frames a second per channel (`None`: every frame),
    /// unless `max_hz_per_channel` says otherwise.
    pub max_hz: Option<f64>,
    /// Per-channel limits.
    pub max_hz_per_channel: BTreeMap<String, f64>,
    /// Publish for ROS 2 (rmw_zenoh) as well.
    pub ros: bool,
    /// The ROS domain id.
    pub domain: u32,
    /// Map images a second (0: none).
    pub map_hz: f64,
    /// Map width in pixels.
    pub map_width: usize,
    /// Endpoints and zenoh configuration.
    pub link: LinkOptions,
}

impl BridgeOptions {
    /// Options for `skin`: every layer and service, every frame, ROS domain 0,
    /// the map at 5 Hz, listening on this machine only.
    pub fn new(skin: &str) -> BridgeOptions {
        BridgeOptions {
            skin: skin.to_owned(),
            dir: None,
            layers: None,
            services: true,
            max_hz: None,
            max_hz_per_channel: BTreeMap::new(),
            ros: true,
            domain: 0,
            map_hz: 5.0,
            map_width: 480,
            link: LinkOptions::default(),
        }
    }
}

/// One channel's figures since the bridge started.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChannelReport {
    /// The channel.
    pub channel: String,
    /// `layer` or `service`.
    pub kind: String,
    /// The writer's state.
    pub state: String,
    /// Frames handed to zenoh for remote skinware readers.
    pub sent: u64,
    /// Frames the writer published that the bridge did not hand to zenoh
    /// (the rate limit, or it read too late). What zenoh then drops on a
    /// full link is in `remote_lost`, as the remote readers report it.
    pub dropped: u64,
    /// ROS messages sent (0 while no ROS subscriber listens).
    pub ros_sent: u64,
    /// Frames sent per second over the last interval.
    pub rate_hz: f64,
    /// Acquisition to hand-over to zenoh, over the last 1024 frames, µs.
    pub latency_p50_us: f64,
    /// The same, 99th percentile.
    pub latency_p99_us: f64,
    /// Remote skinware readers that reported in the last 5 s.
    pub remote_readers: u64,
    /// Frames those readers did not get although the bridge sent them
    /// (lost on the link, or dropped by zenoh's queue when the link was
    /// full), summed over the readers.
    pub remote_lost: u64,
    /// The slowest reader's mean acquisition-to-receipt time over its last second, µs.
    pub remote_latency_us: f64,
    /// Errors (encoding, zenoh).
    pub errors: u64,
    /// The last error.
    pub last_error: Option<String>,
}

#[derive(Default)]
struct Counters {
    sent: AtomicU64,
    dropped: AtomicU64,
    ros_sent: AtomicU64,
    errors: AtomicU64,
    state: AtomicU32,
    published_seq: AtomicU64,
    latencies: Mutex<VecDeque<u64>>,
    last_error: Mutex<Option<String>>,
    rate: Mutex<(u64, u64, f64)>,
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

impl Counters {
    fn error(&self, message: String) {
        self.errors.fetch_add(1, Ordering::Relaxed);
        tracing::warn!("{message}");
        *lock(&self.last_error) = Some(message);
    }

    fn latency(&self, ns: u64) {
        let mut latencies = lock(&self.latencies);
        if latencies.len() == LATENCY_WINDOW {
            latencies.pop_front();
        }
        latencies.push_back(ns);
    }

    fn mean_latency_ns(&self) -> u64 {
        let latencies = lock(&self.latencies);
        if latencies.is_empty() { 0 } else { latencies.iter().sum::<u64>() / latencies.len() as u64 }
    }
}

const LATENCY_WINDOW: usize = 1024;

struct Channel {
    info: RemoteChannel,
    counters: Counters,
    requests: RequestQueue,
}

/// Queries for a frame on request, waiting for this channel's request thread.
/// Filled from zenoh's thread, which must never wait: past
/// [`MAX_WAITING_REQUESTS`] a query is dropped (its asker times out).
#[derive(Default)]
struct RequestQueue {
    queries: Mutex<VecDeque<zenoh::query::Query>>,
    arrived: std::sync::Condvar,
}

/// Requests one channel holds before it drops new ones.
const MAX_WAITING_REQUESTS: usize = 16;

impl RequestQueue {
    fn push(&self, query: zenoh::query::Query) {
        let mut queries = lock(&self.queries);
        if queries.len() < MAX_WAITING_REQUESTS {
            queries.push_back(query);
            self.arrived.notify_one();
        }
    }

    fn pop(&self, timeout: Duration) -> Option<zenoh::query::Query> {
        let mut queries = lock(&self.queries);
        if queries.is_empty() {
            queries = self.arrived.wait_timeout(queries, timeout).map(|(q, _)| q).unwrap_or_else(|p| p.into_inner().0);
        }
        queries.pop_front()
    }
}

/// A ROS publisher: its key, GID, sequence numbers and graph token.
struct RosPublisher {
    publisher: Publisher<'static>,
    gid: [u8; 16],
    sequence: AtomicI64,
    _token: LivelinessToken,
}

impl RosPublisher {
    fn declare(shared: &Shared, topic: &str, type_name: &str) -> Result<RosPublisher, BridgeError> {
        let hash = ros2::type_hash(type_name)
            .ok_or_else(|| BridgeError::Invalid(format!("no type description for {type_name}")))?;
        let key = ros2::topic_key(shared.options.domain, topic, type_name, &hash);
        let zid = shared.session.zid().to_string();
        let token_key = Liveliness {
            domain: shared.options.domain,
            zid: &zid,
            node_id: 0,
            entity_id: shared.next_entity.fetch_add(1, Ordering::Relaxed),
            kind: EntityKind::Publisher,
            namespace: "/",
            node: &shared.node_name,
            topic: Some((topic, type_name, &hash)),
        }
        .key();
        let zenoh = |e: zenoh::Error| BridgeError::Zenoh(format!("cannot declare the ROS 2 topic {topic}: {e}"));
        // As rmw_zenoh publishes a keep-last topic: drop rather than block.
        let publisher = shared
            .session
            .declare_publisher(key)
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::Data)
            .wait()
            .map_err(zenoh)?;
        let token = shared.session.liveliness().declare_token(token_key.clone()).wait().map_err(zenoh)?;
        Ok(RosPublisher { publisher, gid: ros2::gid(&token_key), sequence: AtomicI64::new(0), _token: token })
    }

    /// Whether any subscriber listens (the message need not be built otherwise).
    fn wanted(&self) -> bool {
        self.publisher.matching_status().wait().map(|m| m.matching()).unwrap_or(true)
    }

    fn put(&self, payload: Vec<u8>, now_wall_ns: i64) -> Result<(), BridgeError> {
        let attachment = Attachment {
            sequence_number: self.sequence.fetch_add(1, Ordering::Relaxed) + 1,
            source_timestamp: now_wall_ns,
            source_gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(ZBytes::from(attachment.encode().to_vec()))
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot publish on {}: {e}", self.publisher.key_expr())))
    }
}

/// The newest report of each remote reader: (channel, reader) -> (report, when it came).
type ReaderReports = BTreeMap<(String, String), (ReaderReport, std::time::Instant)>;

struct Shared {
    options: BridgeOptions,
    dir: PathBuf,
    session: Session,
    stop: Stop,
    clock_offset_ns: i64,
    node_name: String,
    next_entity: AtomicU32,
    channels: Mutex<BTreeMap<String, Arc<Channel>>>,
    threads: Mutex<Vec<JoinHandle<()>>>,
    _node_token: Option<LivelinessToken>,
    _bridge_token: LivelinessToken,
    reader_reports: Arc<Mutex<ReaderReports>>,
    _reports: zenoh::pubsub::Subscriber<()>,
}

impl Shared {
    fn wall_now_ns(&self) -> i64 {
        (skinware::os::monotonic_ns() as i64).saturating_add(self.clock_offset_ns)
    }

    fn reader_options(&self) -> ReaderOptions {
        ReaderOptions { allow_gone: true, dir: Some(self.dir.clone()), ..ReaderOptions::default() }
    }

    fn max_hz(&self, channel: &str) -> Option<f64> {
        self.options.max_hz_per_channel.get(channel).copied().or(self.options.max_hz).filter(|hz| *hz > 0.0)
    }

    fn spawn(
        self: &Arc<Self>,
        name: String,
        run: impl FnOnce(Arc<Shared>) + Send + 'static,
    ) -> Result<(), BridgeError> {
        let shared = Arc::clone(self);
        let handle = std::thread::Builder::new()
            .name(name.chars().take(15).collect())
            .spawn(move || run(shared))
            .map_err(|e| BridgeError::Invalid(format!("cannot start the bridge thread {name}: {e}")))?;
        lock(&self.threads).push(handle);
        Ok(())
    }

    fn wanted(&self, info: &skinware::ChannelInfo) -> bool {
        match info.kind {
            Some(ChannelKind::Layer) => {
                self.options.layers.as_ref().is_none_or(|layers| layers.contains(&info.channel))
            }
            Some(ChannelKind::Service) => self.options.services,
            None => false,
        }
    }

    /// Opens the channels not bridged yet and starts their threads.
    fn discover(self: &Arc<Self>) -> Result<usize, BridgeError> {
        let mut added = 0;
        let listed = skinware::list_skin_channels(&self.dir, &self.options.skin)?;
        for info in listed.iter().filter(|c| c.skin == self.options.skin && self.wanted(c)) {
            if lock(&self.channels).contains_key(&info.channel) || info.state == WriterState::Gone {
                continue;
            }
            let reader = match Reader::open_with(&self.options.skin, &info.channel, &self.reader_options()) {
                Ok(reader) => reader,
                Err(e) => {
                    tracing::warn!("cannot read {} to bridge it: {e}", info.channel);
                    continue;
                }
            };
            let channel = Arc::new(Channel {
                info: RemoteChannel {
                    name: info.channel.clone(),
                    kind: reader.kind(),
                    payload_bytes: reader.payload_bytes(),
                    slots: reader.slots(),
                    period: reader.writer_period(),
                    schema: reader.schema(),
                    description: reader.description(),
                },
                counters: Counters::default(),
                requests: RequestQueue::default(),
            });
            lock(&self.channels).insert(info.channel.clone(), Arc::clone(&channel));
            let answering = Arc::clone(&channel);
            self.spawn(format!("rq-{}", info.channel), move |shared| serve_requests(&shared, &answering))?;
            self.spawn(format!("br-{}", info.channel), move |shared| {
                if let Err(e) = send_channel(&shared, &channel, reader) {
                    channel.counters.error(format!("bridging {} stopped: {e}", channel.info.name));
                }
            })?;
            added += 1;
        }
        Ok(added)
    }
}

/// A running bridge. Dropping it stops it.
pub struct Bridge {
    shared: Arc<Shared>,
    _requests: Option<zenoh::query::Queryable<()>>,
}

impl Bridge {
    /// Opens the zenoh session, starts bridging every chosen channel of the
    /// skin, and keeps picking up channels that appear later.
    pub fn start(options: BridgeOptions) -> Result<Bridge, BridgeError> {
        skinware::shm::validate_name("skin", &options.skin)?;
        if let Some(hz) = options
            .max_hz
            .into_iter()
            .chain(options.max_hz_per_channel.values().copied())
            .find(|hz| !(hz.is_finite() && *hz > 0.0))
        {
            return Err(BridgeError::Invalid(format!(
                "--max-hz {hz}: a rate limit is a positive number of frames a second"
            )));
        }
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        let live: Vec<skinware::ChannelInfo> = skinware::list_skin_channels(&dir, &options.skin)?
            .into_iter()
            .filter(|c| c.skin == options.skin && c.state != WriterState::Gone)
            .collect();
        let names: Vec<&str> = live.iter().map(|c| c.channel.as_str()).collect();
        let layers: Vec<&str> =
            live.iter().filter(|c| c.kind == Some(ChannelKind::Layer)).map(|c| c.channel.as_str()).collect();
        for wanted in options.layers.iter().flatten() {
            if !layers.contains(&wanted.as_str()) {
                return Err(BridgeError::Invalid(format!(
                    "--layers {wanted}: skin {} has no live layer of that name; its layers are {layers:?}",
                    options.skin
                )));
            }
        }
        for limited in options.max_hz_per_channel.keys() {
            if !names.contains(&limited.as_str()) {
                return Err(BridgeError::Invalid(format!(
                    "--max-hz {limited}=...: skin {} has no live channel of that name; its channels are {names:?}",
                    options.skin
                )));
            }
        }
        if live.is_empty() {
            return Err(BridgeError::Invalid(format!(
                "skin {:?} has no live channel in {} to bridge; start it first (skin run CONFIG, or skin demo)",
                options.skin,
                dir.display()
            )));
        }
        let session = options.link.open()?;
        let node_name = format!("skin_bridge_{}", ros2::ros_name(&options.skin).trim_start_matches('_'));
        let node_token = if options.ros {
            let zid = session.zid().to_string();
            let key = Liveliness {
                domain: options.domain,
                zid: &zid,
                node_id: 0,
                entity_id: 0,
                kind: EntityKind::Node,
                namespace: "/",
                node: &node_name,
                topic: None,
            }
            .key();
            Some(
                session
                    .liveliness()
                    .declare_token(key)
                    .wait()
                    .map_err(|e| BridgeError::Zenoh(format!("cannot announce the ROS 2 node: {e}")))?,
            )
        } else {
            None
        };
        let bridge_token = session
            .liveliness()
            .declare_token(protocol::bridge_token_key(&options.skin))
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot announce the bridge: {e}")))?;
        let reader_reports = Arc::new(Mutex::new(BTreeMap::new()));
        let into = Arc::clone(&reader_reports);
        let reports = session
            .declare_subscriber(format!("{}/*/readers/*", protocol::skin_prefix(&options.skin)))
            .callback(move |sample: zenoh::sample::Sample| {
                let key = sample.key_expr().as_str();
                let mut parts = key.rsplit('/');
                let (Some(reader), Some(_), Some(channel)) = (parts.next(), parts.next(), parts.next()) else { return };
                if let Ok(report) = ReaderReport::decode(&sample.payload().to_bytes()) {
                    let mut reports = lock(&into);
                    // A reader per session and channel; a hostile flood of ids stays bounded.
                    if reports.len() < 4096 || reports.contains_key(&(channel.to_owned(), reader.to_owned())) {
                        reports.insert((channel.to_owned(), reader.to_owned()), (report, std::time::Instant::now()));
                    }
                }
            })
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot listen to the remote readers' reports: {e}")))?;
        let shared = Arc::new(Shared {
            reader_reports,
            _reports: reports,
            _bridge_token: bridge_token,
            dir,
            session,
            stop: Stop::new(),
            clock_offset_ns: skinware_record::recorder::clock_offset_ns(),
            node_name,
            next_entity: AtomicU32::new(1),
            channels: Mutex::new(BTreeMap::new()),
            threads: Mutex::new(Vec::new()),
            _node_token: node_token,
            options,
        });
        let bridge = Bridge { shared: Arc::clone(&shared), _requests: None };
        shared.discover()?;
        shared.spawn("br-describe".into(), |shared| {
            if let Err(e) = serve_descriptions(&shared) {
                tracing::warn!("the bridge no longer describes the skin: {e}");
            }
        })?;
        shared.spawn("br-state".into(), |shared| heartbeat(&shared))?;
        shared.spawn("br-discover".into(), |shared| {
            // New channels (a service started later), apart from the states'
            // thread: opening a channel that does not answer takes a while.
            let mut ticker = skinware::Ticker::new(Duration::from_secs(1));
            while ticker.wait(&shared.stop).is_some() {
                if let Err(e) = shared.discover() {
                    tracing::warn!("cannot look for new channels: {e}");
                }
            }
        })?;
        let mut bridge = bridge;
        bridge._requests = Some(declare_requests(&shared)?);
        if shared.options.ros && shared.options.map_hz > 0.0 {
            shared.spawn("br-map".into(), |shared| {
                if let Err(e) = publish_map(&shared) {
                    tracing::warn!("the bridge publishes no map: {e}");
                }
            })?;
        }
        Ok(bridge)
    }

    /// The zenoh session's id.
    pub fn zid(&self) -> String {
        self.shared.session.zid().to_string()
    }

    /// The channels bridged so far.
    pub fn channels(&self) -> Vec<String> {
        lock(&self.shared.channels).keys().cloned().collect()
    }

    /// The stop signal (stop it to end the bridge).
    pub fn stop_signal(&self) -> &Stop {
        &self.shared.stop
    }

    /// Every channel's figures.
    pub fn report(&self) -> Vec<ChannelReport> {
        let channels: Vec<Arc<Channel>> = lock(&self.shared.channels).values().cloned().collect();
        let now = skinware::os::monotonic_ns();
        channels
            .iter()
            .map(|channel| {
                let c = &channel.counters;
                let sent = c.sent.load(Ordering::Relaxed);
                let rate_hz = {
                    let mut rate = lock(&c.rate);
                    let (at, count, hz) = &mut *rate;
                    if *at == 0 {
                        (*at, *count) = (now, sent);
                    } else if now - *at >= 500_000_000 {
                        *hz = (sent - *count) as f64 * 1e9 / (now - *at) as f64;
                        (*at, *count) = (now, sent);
                    }
                    *hz
                };
                let (mut remote_readers, mut remote_lost, mut remote_latency_ns) = (0, 0, 0);
                {
                    let mut reports = lock(&self.shared.reader_reports);
                    reports.retain(|_, (_, at)| at.elapsed() < Duration::from_secs(60));
                    for ((name, _), (report, at)) in reports.iter() {
                        if *name == channel.info.name && at.elapsed() < Duration::from_secs(5) {
                            remote_readers += 1;
                            remote_lost += report.lost;
                            remote_latency_ns = remote_latency_ns.max(report.latency_ns);
                        }
                    }
                }
                let mut latencies: Vec<u64> = lock(&c.latencies).iter().copied().collect();
                latencies.sort_unstable();
                let quantile = |q: f64| {
                    latencies
                        .get(((latencies.len() as f64 - 1.0) * q).round() as usize)
                        .map_or(0.0, |&ns| ns as f64 / 1e3)
                };
                ChannelReport {
                    channel: channel.info.name.clone(),
                    kind: skinware_record::file::kind_str(channel.info.kind).to_owned(),
                    state: protocol::state_of_code(c.state.load(Ordering::Relaxed))
                        .unwrap_or(WriterState::Gone)
                        .to_string(),
                    sent,
                    dropped: c.dropped.load(Ordering::Relaxed),
                    ros_sent: c.ros_sent.load(Ordering::Relaxed),
                    rate_hz,
                    latency_p50_us: quantile(0.5),
                    latency_p99_us: quantile(0.99),
                    remote_readers,
                    remote_lost,
                    remote_latency_us: remote_latency_ns as f64 / 1e3,
                    errors: c.errors.load(Ordering::Relaxed),
                    last_error: lock(&c.last_error).clone(),
                }
            })
            .collect()
    }

    /// Stops every thread and closes the session.
    pub fn stop(self) -> Vec<ChannelReport> {
        let report = self.report();
        drop(self);
        report
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.shared.stop.stop();
        // Closing the session first releases a thread waiting for a slow link.
        let _ = self.shared.session.close().wait();
        // A thread started while these are joined is joined on the next pass.
        loop {
            let threads: Vec<JoinHandle<()>> = lock(&self.shared.threads).drain(..).collect();
            if threads.is_empty() {
                break;
            }
            for thread in threads {
                let _ = thread.join();
            }
        }
    }
}

/// One channel: its newest frame, each time (or at most `max_hz` a second).
fn send_channel(shared: &Arc<Shared>, channel: &Channel, mut reader: Reader) -> Result<(), BridgeError> {
    let skin = &shared.options.skin;
    let name = &channel.info.name;
    reader.set_stop(&shared.stop);
    let frames = shared
        .session
        .declare_publisher(protocol::frame_key(skin, name))
        .congestion_control(CongestionControl::Drop)
        .priority(Priority::Data)
        .wait()
        .map_err(|e| BridgeError::Zenoh(format!("cannot declare the publisher of {name}: {e}")))?;
    // The recorder's topic of the channel (a recording and the bridge agree).
    let ros_topic = |suffix: &str| format!("{}/{suffix}", skinware_record::frame_topic(skin, name));
    let ros = if !shared.options.ros {
        None
    } else if channel.info.kind == ChannelKind::Layer {
        Some(RosPublisher::declare(shared, &ros_topic("state"), ros2::TACTILE_STATE_TYPE)?)
    } else if channel.info.schema.0 == <RegionContacts as skinware_services::ServicePayload>::SCHEMA {
        Some(RosPublisher::declare(shared, &ros_topic("contacts"), ros2::TACTILE_CONTACTS_TYPE)?)
    } else {
        None
    };
    let layer = match channel.info.kind {
        ChannelKind::Layer => Some(
            skinware::LayerTopology::decode(&channel.info.description, name)
                .map_err(|e| BridgeError::Invalid(format!("{name}: its description is not a layer topology: {e}")))?,
        ),
        ChannelKind::Service => None,
    };
    let regions = ServiceInfo::parse(&channel.info.description).map(|info| info.labels).unwrap_or_default();
    let min_interval_ns = shared.max_hz(name).map(|hz| (1e9 / hz) as u64);
    let mut next_allowed_ns = 0u64;
    let mut last_sent_seq: Option<u64> = None;
    while !shared.stop.is_stopped() {
        if min_interval_ns.is_some() && !shared.stop.sleep_until(next_allowed_ns) {
            break;
        }
        let frame = match reader.wait_newer(Duration::from_millis(100)) {
            Ok(frame) => frame,
            Err(Error::Timeout { .. } | Error::WriterGone { .. } | Error::NoFrameYet { .. }) => continue,
            Err(Error::Stopped { .. }) => break,
            Err(e) => {
                channel.counters.error(format!("reading {name}: {e}"));
                if !shared.stop.sleep_until(skinware::os::monotonic_ns() + 100_000_000) {
                    break;
                }
                continue;
            }
        };
        let seq = frame.seq();
        // Frames published since the last one sent: skipped by this reader,
        // or (after a writer's restart) everything the new writer published first.
        let missed = match last_sent_seq {
            Some(last) if seq > last => seq - last - 1,
            // A restarted writer counts from 1 again: what it published before this one.
            Some(_) => seq.saturating_sub(1),
            // What was published before the bridge started is not its to send.
            None => 0,
        };
        channel.counters.dropped.fetch_add(missed, Ordering::Relaxed);
        last_sent_seq = Some(seq);
        let acquired_ns = frame.acquired_ns();
        match protocol::encode_frame(channel.info.kind, &frame, shared.clock_offset_ns) {
            Ok(bytes) => match frames.put(bytes).wait() {
                Ok(()) => {
                    channel.counters.sent.fetch_add(1, Ordering::Relaxed);
                    channel.counters.latency(skinware::os::monotonic_ns().saturating_sub(acquired_ns));
                }
                Err(e) => channel.counters.error(format!("sending a frame of {name}: {e}")),
            },
            Err(e) => channel.counters.error(format!("encoding a frame of {name}: {e}")),
        }
        if let Some(ros) = ros.as_ref().filter(|r| r.wanted()) {
            let stamp = Time::from_ns((acquired_ns as i64).saturating_add(shared.clock_offset_ns).max(0) as u64);
            let message = match &layer {
                Some(layer) => messages::tactile_state(layer, frame.responses(), stamp),
                None => {
                    let records: Vec<RegionContacts> = frame
                        .bytes()
                        .chunks_exact(std::mem::size_of::<RegionContacts>())
                        .map(bytemuck::pod_read_unaligned)
                        .collect();
                    messages::tactile_contacts(&regions, &records, stamp)
                }
            };
            match message.and_then(|bytes| ros.put(bytes, shared.wall_now_ns())) {
                Ok(()) => {
                    channel.counters.ros_sent.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => channel.counters.error(format!("ROS 2 message of {name}: {e}")),
            }
        }
        if let Some(interval) = min_interval_ns {
            next_allowed_ns = skinware::os::monotonic_ns().max(next_allowed_ns.saturating_add(interval));
            next_allowed_ns = next_allowed_ns.max(skinware::os::monotonic_ns() + interval / 2);
        }
    }
    Ok(())
}

/// Every channel's state, 10 times a second; new channels every second.
fn heartbeat(shared: &Arc<Shared>) {
    let mut publishers: BTreeMap<String, (Publisher<'static>, Reader)> = BTreeMap::new();
    let mut ticker = skinware::Ticker::new(HEARTBEAT);
    while ticker.wait(&shared.stop).is_some() {
        let channels: Vec<Arc<Channel>> = lock(&shared.channels).values().cloned().collect();
        for channel in channels {
            let name = &channel.info.name;
            if !publishers.contains_key(name) {
                let publisher = shared
                    .session
                    .declare_publisher(protocol::state_key(&shared.options.skin, name))
                    .congestion_control(CongestionControl::Drop)
                    .priority(Priority::DataHigh)
                    .express(true)
                    .wait();
                let reader = Reader::open_with(&shared.options.skin, name, &shared.reader_options());
                match (publisher, reader) {
                    (Ok(publisher), Ok(reader)) => {
                        publishers.insert(name.clone(), (publisher, reader));
                    }
                    (Err(e), _) => channel.counters.error(format!("cannot declare the state of {name}: {e}")),
                    (_, Err(e)) => channel.counters.error(format!("cannot watch the state of {name}: {e}")),
                }
            }
            let Some((publisher, reader)) = publishers.get_mut(name) else { continue };
            reader.follow_recreated();
            let state = reader.writer_state();
            channel.counters.state.store(protocol::state_code(state), Ordering::Relaxed);
            channel.counters.published_seq.store(reader.published_seq(), Ordering::Relaxed);
            let message = ChannelState {
                state,
                published_seq: reader.published_seq(),
                sent: channel.counters.sent.load(Ordering::Relaxed),
                dropped: channel.counters.dropped.load(Ordering::Relaxed),
                latency_ns: channel.counters.mean_latency_ns(),
                period_ns: reader.writer_period().map_or(0, |p| p.as_nanos() as u64),
            };
            if let Err(e) = publisher.put(message.encode()).wait() {
                channel.counters.error(format!("sending the state of {name}: {e}"));
            }
        }
    }
}

/// How often every channel's state is sent.
pub const HEARTBEAT: Duration = Duration::from_millis(100);

/// The channel list and the geometry, answered from a thread of the bridge:
/// a reply waits for room on a slow link, which must never block zenoh's own
/// threads (as a reply from a callback would).
fn serve_descriptions(shared: &Arc<Shared>) -> Result<(), BridgeError> {
    let skin = &shared.options.skin;
    let zenoh = |what: &str, e: zenoh::Error| BridgeError::Zenoh(format!("cannot declare {what}: {e}"));
    let channels = shared
        .session
        .declare_queryable(protocol::channels_key(skin))
        .wait()
        .map_err(|e| zenoh("the channel list", e))?;
    let geometry =
        shared.session.declare_queryable(protocol::geometry_key(skin)).wait().map_err(|e| zenoh("the geometry", e))?;
    while !shared.stop.is_stopped() {
        if let Ok(Some(query)) = channels.recv_timeout(Duration::from_millis(50)) {
            let list = ChannelList {
                skin: skin.clone(),
                channels: lock(&shared.channels).values().map(|c| c.info.clone()).collect(),
            };
            let _ = query.reply(query.key_expr().clone(), list.encode()).wait();
        }
        while let Ok(Some(query)) = geometry.try_recv() {
            let path = SkinGeometry::published_path(&shared.dir, skin);
            let _ = match skinware::shm::read_regular(&path, SkinGeometry::MAX_PUBLISHED_BYTES) {
                Ok(bytes) => query.reply(query.key_expr().clone(), bytes).wait(),
                Err(e) => query
                    .reply_err(format!(
                        "the skin publishes no geometry ({}: {e}); its layers can still be read",
                        path.display()
                    ))
                    .wait(),
            };
        }
    }
    Ok(())
}

/// Frames on request for one channel: its own thread and reader, so that a
/// request waiting for a slow or sporadic writer delays no other channel's.
fn serve_requests(shared: &Arc<Shared>, channel: &Channel) {
    let skin = &shared.options.skin;
    let name = &channel.info.name;
    let mut reader: Option<Reader> = None;
    while !shared.stop.is_stopped() {
        let Some(query) = channel.requests.pop(Duration::from_millis(100)) else { continue };
        if reader.is_none() {
            match Reader::open_with(skin, name, &shared.reader_options()) {
                Ok(mut opened) => {
                    opened.set_stop(&shared.stop);
                    reader = Some(opened);
                }
                Err(e) => {
                    let _ = query.reply_err(format!("error: cannot read {skin}/{name}: {e}")).wait();
                    continue;
                }
            }
        }
        let Some(reader) = reader.as_mut() else { continue };
        let timeout = query
            .parameters()
            .get("timeout_ms")
            .and_then(|t| t.parse::<u64>().ok())
            .map_or(Duration::from_secs(1), Duration::from_millis)
            .min(Duration::from_secs(10));
        let answer = match reader.request(timeout) {
            Ok(frame) => protocol::encode_frame(channel.info.kind, &frame, shared.clock_offset_ns)
                .map_err(|e| format!("error: {e}")),
            Err(e @ (Error::Timeout { .. } | Error::WriterGone { .. })) => {
                Err(format!("{}{e}", protocol::TIMEOUT_PREFIX))
            }
            Err(e) => Err(format!("error: {e}")),
        };
        let _ = match answer {
            Ok(bytes) => query.reply(query.key_expr().clone(), bytes).wait(),
            Err(e) => query.reply_err(e).wait(),
        };
    }
}

/// Routes each request to its channel's queue, from zenoh's thread, without waiting.
fn declare_requests(shared: &Arc<Shared>) -> Result<zenoh::query::Queryable<()>, BridgeError> {
    let weak = Arc::downgrade(shared);
    shared
        .session
        .declare_queryable(format!("{}/*/request", protocol::skin_prefix(&shared.options.skin)))
        .callback(move |query: zenoh::query::Query| {
            let Some(shared) = weak.upgrade() else { return };
            let name = query.key_expr().as_str().rsplit('/').nth(1).unwrap_or_default().to_owned();
            let channel = lock(&shared.channels).get(&name).cloned();
            // An unknown channel's query is dropped: its asker times out and
            // says the channel is not bridged (it checked the list first).
            if let Some(channel) = channel {
                channel.requests.push(query);
            }
        })
        .wait()
        .map_err(|e| BridgeError::Zenoh(format!("cannot declare the request queryable: {e}")))
}

/// The 2-D map as a `sensor_msgs/Image`, a few times a second.
fn publish_map(shared: &Arc<Shared>) -> Result<(), BridgeError> {
    let skin = &shared.options.skin;
    let geometry = SkinGeometry::open_in(&shared.dir, skin)
        .map_err(|e| BridgeError::Invalid(format!("skin {skin} publishes no geometry to draw: {e}")))?;
    let ros = RosPublisher::declare(shared, &skinware_record::map_topic(skin), ros2::IMAGE_TYPE)?;
    let mut heatmap = HeatMap::new(&geometry, shared.options.map_width);
    let (width, height) = heatmap.dimensions();
    let mut readers: Vec<Option<Reader>> = geometry.layers.iter().map(|_| None).collect();
    let mut ticker = skinware::Ticker::from_hz(shared.options.map_hz);
    while ticker.wait(&shared.stop).is_some() {
        if !ros.wanted() {
            continue;
        }
        let mut newest: Vec<(Option<Vec<u16>>, LayerLook)> = Vec::with_capacity(readers.len());
        for (slot, layer) in readers.iter_mut().zip(&geometry.layers) {
            if slot.is_none() {
                *slot = Reader::open_with(skin, &layer.name, &shared.reader_options()).ok();
            }
            let read = slot.as_mut().map(|reader| {
                reader.follow_recreated();
                let look = match reader.writer_state() {
                    WriterState::Gone => LayerLook::Gone,
                    WriterState::Faulted => LayerLook::Faulted,
                    _ => LayerLook::Live,
                };
                (reader.latest().ok().map(|f| f.responses().to_vec()), look)
            });
            newest.push(read.unwrap_or((None, LayerLook::Gone)));
        }
        let layers: Vec<(Option<&[u16]>, LayerLook)> = newest.iter().map(|(r, look)| (r.as_deref(), *look)).collect();
        let data = heatmap.render(&layers);
        let now = shared.wall_now_ns();
        let image = Image {
            header: Header { stamp: Time::from_ns(now.max(0) as u64), frame_id: format!("{skin}/map") },
            height,
            width,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: width * 3,
            data,
        };
        let sent = skinware_record::msgs::encode(&image, 64 + image.data.len())
            .map_err(|e| BridgeError::Encode(e.to_string()))
            .and_then(|bytes| ros.put(bytes, now));
        if let Err(e) = sent {
            tracing::warn!("map: {e}");
        }
    }
    Ok(())
}
