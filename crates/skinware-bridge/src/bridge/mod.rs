//! The bridge: every layer and service of a skin, read as an ordinary reader
//! (so acquisition cannot notice it) and published on zenoh, for remote
//! skinware readers and for ROS 2 nodes on rmw_zenoh.
//!
//! One thread per channel (`frames`) reads its newest frame (as soon as it is
//! published, or at most `--max-hz` times a second) and hands it to zenoh with
//! congestion control *drop*: when the link is slower than the writer, zenoh
//! drops what finds no room in its two-batch queue rather than build a
//! backlog, and nothing waits (a thread blocked on a full queue can also
//! stall zenoh's own threads, which we saw on a 1 Mbit/s link). Nothing is
//! lost silently: every frame carries the writer's sequence number, so a
//! remote reader counts each frame it did not get (`skipped`, as a local
//! reader does), and the bridge counts the frames it did not send (`dropped`:
//! rate limit, or it read too late) in each channel's state.
//!
//! Beside them: a thread publishes every channel's state ten times a second
//! (`heartbeat`; its absence tells a remote reader the link is cut), one
//! picks up channels that appear later, one answers for the channel list and
//! the geometry and one per channel serves frames on request (`queries`), and
//! one renders the 2-D map for ROS (`map`), and one publishes the standard
//! ROS 2 topics (`standard`: clouds, markers, `/diagnostics`). `channel`
//! holds what each channel counts, and `ros` the bridge's node and
//! publishers in the ROS graph.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicU32;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use skinware::{ChannelKind, Reader, ReaderOptions, Stop, WriterState, lock};
use zenoh::liveliness::LivelinessToken;
use zenoh::{Session, Wait};

use crate::BridgeError;
use crate::link::LinkOptions;
use crate::protocol::{self, ReaderReport, RemoteChannel};

mod channel;
mod frames;
mod heartbeat;
mod map;
mod queries;
mod ros;
mod standard;

pub use channel::ChannelReport;
use channel::{Channel, Counters, RequestQueue};
pub use heartbeat::HEARTBEAT;

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
    /// The standard ROS 2 topics' rates (`skinware_ros2::view`): clouds,
    /// markers and `/diagnostics` (the tactile messages and the map are
    /// the rates above; all 0: none).
    pub standard: skinware_ros2::view::Rates,
    /// Per-topic rates of the standard topics (full topic name → Hz).
    pub topic_hz: BTreeMap<String, f64>,
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
            standard: skinware_ros2::view::Rates::default(),
            topic_hz: BTreeMap::new(),
            link: LinkOptions::default(),
        }
    }
}

/// The newest report of each remote reader: (channel, reader) -> (report, when it came).
type ReaderReports = BTreeMap<(String, String), (ReaderReport, std::time::Instant)>;

/// What every thread of the bridge shares.
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
    /// Now on the wall clock, ns since the Unix epoch (the attachment's source time).
    fn wall_now_ns(&self) -> i64 {
        skinware_ros2::now_unix_ns(self.clock_offset_ns) as i64
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
            .map_err(|source| BridgeError::Thread { thread: format!("the bridge thread {name}"), source })?;
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
            self.spawn(format!("rq-{}", info.channel), move |shared| queries::serve_requests(&shared, &answering))?;
            self.spawn(format!("br-{}", info.channel), move |shared| {
                if let Err(e) = frames::send_channel(&shared, &channel, reader) {
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
        let dir = options.dir.clone().unwrap_or_else(skinware::shm::segment_dir);
        check_options(&options, &dir)?;
        let session = options.link.open()?;
        let node_name = format!("skin_bridge_{}", skinware_ros2::ros_name(&options.skin).trim_start_matches('_'));
        let node_token =
            if options.ros { Some(ros::declare_node(&session, options.domain, &node_name)?) } else { None };
        let bridge_token = session
            .liveliness()
            .declare_token(protocol::bridge_token_key(&options.skin))
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot announce the bridge: {e}")))?;
        let reader_reports = Arc::new(Mutex::new(BTreeMap::new()));
        let reports = subscribe_reports(&session, &options.skin, Arc::clone(&reader_reports))?;
        let shared = Arc::new(Shared {
            reader_reports,
            _reports: reports,
            _bridge_token: bridge_token,
            dir,
            session,
            stop: Stop::new(),
            clock_offset_ns: skinware_ros2::clock_offset_ns(),
            node_name,
            next_entity: AtomicU32::new(1),
            channels: Mutex::new(BTreeMap::new()),
            threads: Mutex::new(Vec::new()),
            _node_token: node_token,
            options,
        });
        Bridge::run(shared)
    }

    /// Starts the threads. The bridge exists before the first of them, so
    /// that a failure stops those already started (on drop).
    fn run(shared: Arc<Shared>) -> Result<Bridge, BridgeError> {
        let mut bridge = Bridge { shared: Arc::clone(&shared), _requests: None };
        shared.discover()?;
        shared.spawn("br-describe".into(), |shared| {
            if let Err(e) = queries::serve_descriptions(&shared) {
                tracing::warn!("the bridge no longer describes the skin: {e}");
            }
        })?;
        shared.spawn("br-state".into(), |shared| heartbeat::heartbeat(&shared))?;
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
        bridge._requests = Some(queries::declare_requests(&shared)?);
        if shared.options.ros {
            shared.spawn("br-standard".into(), |shared| {
                if let Err(e) = standard::publish_standard(&shared) {
                    tracing::warn!("the bridge publishes no standard ROS 2 topics: {e}");
                }
            })?;
        }
        if shared.options.ros && shared.options.map_hz > 0.0 {
            shared.spawn("br-map".into(), |shared| {
                if let Err(e) = map::publish_map(&shared) {
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
        channels.iter().map(|channel| channel.report(now, &self.shared.reader_reports)).collect()
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

/// Refuses options that name what the skin does not have, before anything is opened.
fn check_options(options: &BridgeOptions, dir: &Path) -> Result<(), BridgeError> {
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
    let live: Vec<skinware::ChannelInfo> = skinware::list_skin_channels(dir, &options.skin)?
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
    Ok(())
}

/// Listens to the remote readers' reports of what they received, into `into`.
fn subscribe_reports(
    session: &Session,
    skin: &str,
    into: Arc<Mutex<ReaderReports>>,
) -> Result<zenoh::pubsub::Subscriber<()>, BridgeError> {
    session
        .declare_subscriber(format!("{}/*/readers/*", protocol::skin_prefix(skin)))
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
        .map_err(|e| BridgeError::Zenoh(format!("cannot listen to the remote readers' reports: {e}")))
}
