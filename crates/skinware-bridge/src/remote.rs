//! Reading a skin on another machine, through its bridge, like a local one:
//! the same three modes (periodic, as soon as available, on request), the
//! writer's state, and `unreachable` when the link is cut, from which a
//! reader resumes by itself when the link returns.
//!
//! ```no_run
//! use std::time::Duration;
//! use skinware_bridge::link::LinkOptions;
//! use skinware_bridge::remote::RemoteSkin;
//!
//! let link = LinkOptions { connect: vec!["tcp/robot-pc:7447".into()], ..LinkOptions::default() };
//! let skin = RemoteSkin::connect(&link, "default", Duration::from_secs(5))?;
//! let mut reader = skin.reader("virtual-0")?;
//! let frame = reader.wait_newer(Duration::from_secs(1))?;
//! println!("seq {} with {} responses", frame.seq, frame.responses().len());
//! println!("the layer is {}", reader.state().name());
//! # Ok::<(), skinware_bridge::BridgeError>(())
//! ```

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use skinware::{FrameStatus, LayerTopology, Stop, Ticker, Writer, WriterOptions, WriterState, lock};
use skinware_geometry::SkinGeometry;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::query::Reply;
use zenoh::sample::{Sample, SampleKind};
use zenoh::{Session, Wait};

use crate::BridgeError;
use crate::link::LinkOptions;
use crate::protocol::{self, ChannelList, ChannelState, ReaderReport, RemoteChannel};

/// A remote channel's state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RemoteState {
    /// Its writer, as the bridge last said.
    Writer(WriterState),
    /// Nothing heard from the bridge for longer than the reader's
    /// `unreachable_after`: the link is cut, or the bridge stopped.
    Unreachable,
}

impl RemoteState {
    /// `running`, `paused`, `faulted`, `gone` or `unreachable`.
    pub fn name(self) -> &'static str {
        match self {
            RemoteState::Writer(state) => state.as_str(),
            RemoteState::Unreachable => "unreachable",
        }
    }
}

/// A connection to a remote skin's bridge.
pub struct RemoteSkin {
    session: Session,
    skin: String,
    list: ChannelList,
}

/// Queries `key` and returns the first good reply's bytes.
fn query_bytes(session: &Session, key: &str, timeout: Duration) -> Result<Option<Vec<u8>>, BridgeError> {
    let replies: FifoChannelHandler<Reply> =
        session.get(key).timeout(timeout).wait().map_err(|e| BridgeError::Zenoh(format!("cannot query {key}: {e}")))?;
    let mut refusal = None;
    while let Ok(reply) = replies.recv() {
        match reply.result() {
            Ok(sample) => return Ok(Some(sample.payload().to_bytes().into_owned())),
            Err(error) => refusal = Some(error.payload().try_to_string().map(|s| s.into_owned()).unwrap_or_default()),
        }
    }
    match refusal {
        // zenoh's own answer when nothing replied in time.
        Some(reason) if reason == "Timeout" => Ok(None),
        Some(reason) => Err(BridgeError::Invalid(format!("{key}: the bridge refused: {reason}"))),
        None => Ok(None),
    }
}

impl RemoteSkin {
    /// Connects and asks the bridge of `skin` for its channels, trying until
    /// `timeout` (the link may take a moment to come up).
    pub fn connect(link: &LinkOptions, skin: &str, timeout: Duration) -> Result<RemoteSkin, BridgeError> {
        skinware::shm::validate_name("skin", skin)?;
        let session = link.open()?;
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now()).min(Duration::from_secs(5));
            if let Some(bytes) =
                query_bytes(&session, &protocol::channels_key(skin), left.max(Duration::from_millis(100)))?
            {
                let list = ChannelList::decode(&bytes)?;
                return Ok(RemoteSkin { session, skin: skin.to_owned(), list });
            }
            if Instant::now() >= deadline {
                let elsewhere = Self::answering_skins(&session);
                let endpoints = if link.connect.is_empty() {
                    "the configuration file's endpoints".to_owned()
                } else {
                    link.connect.join(", ")
                };
                return Err(BridgeError::Timeout(if elsewhere.is_empty() {
                    format!(
                        "no bridge of skin {skin:?} answered within {timeout:?} at {endpoints}; is `skin bridge` running \
                         there, listening where this connects (it listens on {} unless told otherwise)?",
                        crate::link::DEFAULT_LISTEN
                    )
                } else {
                    format!("no bridge of skin {skin:?} at {endpoints}; bridges there serve {elsewhere:?}: pass --skin")
                }));
            }
            // Nothing answers at once when no bridge is there yet: do not spin.
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The skins whose bridges answer on `session` now.
    fn answering_skins(session: &Session) -> Vec<String> {
        let Ok(replies) = session.get("skinware/*/@channels").timeout(Duration::from_millis(500)).wait() else {
            return Vec::new();
        };
        let mut skins = Vec::new();
        while let Ok(reply) = replies.recv() {
            if let Ok(list) = reply
                .result()
                .map_err(|_| ())
                .and_then(|s| ChannelList::decode(&s.payload().to_bytes()).map_err(|_| ()))
            {
                skins.push(list.skin);
            }
        }
        skins
    }

    /// Every skin whose bridge answers within `timeout`.
    pub fn list(link: &LinkOptions, timeout: Duration) -> Result<Vec<ChannelList>, BridgeError> {
        let session = link.open()?;
        let deadline = Instant::now() + timeout;
        let mut skins = BTreeMap::new();
        while Instant::now() < deadline && skins.is_empty() {
            let replies: FifoChannelHandler<Reply> = session
                .get("skinware/*/@channels")
                .timeout(deadline.saturating_duration_since(Instant::now()).min(Duration::from_secs(1)))
                .wait()
                .map_err(|e| BridgeError::Zenoh(format!("cannot ask for bridges: {e}")))?;
            while let Ok(reply) = replies.recv() {
                // One bad answer does not hide the good ones.
                match reply.result().map(|sample| ChannelList::decode(&sample.payload().to_bytes())) {
                    Ok(Ok(list)) => {
                        skins.insert(list.skin.clone(), list);
                    }
                    Ok(Err(e)) => tracing::warn!("{e}"),
                    Err(_) => {}
                }
            }
            if skins.is_empty() {
                std::thread::sleep(Duration::from_millis(100));
            }
        }
        let _ = session.close().wait();
        Ok(skins.into_values().collect())
    }

    /// The skin's name.
    pub fn skin(&self) -> &str {
        &self.skin
    }

    /// Its bridged channels, as the bridge listed them when this connected.
    pub fn channels(&self) -> &[RemoteChannel] {
        &self.list.channels
    }

    /// The skin's geometry file (topology of every layer, calibration,
    /// regions, neighbour graph, 2-D map), decoded.
    pub fn geometry(&self, timeout: Duration) -> Result<SkinGeometry, BridgeError> {
        let bytes = query_bytes(&self.session, &protocol::geometry_key(&self.skin), timeout)?.ok_or_else(|| {
            BridgeError::Timeout(format!("the bridge of {} sent no geometry within {timeout:?}", self.skin))
        })?;
        SkinGeometry::decode(&bytes)
            .map_err(|e| BridgeError::Malformed { what: "geometry".into(), reason: e.to_string() })
    }

    /// A reader of `channel`.
    pub fn reader(&self, channel: &str) -> Result<Reader, BridgeError> {
        let Some(info) = self.list.channels.iter().find(|c| c.name == channel) else {
            let names: Vec<&str> = self.list.channels.iter().map(|c| c.name.as_str()).collect();
            return Err(BridgeError::Invalid(format!(
                "the bridge of skin {} has no channel {channel:?}; it bridges {names:?}",
                self.skin
            )));
        };
        Reader::open(&self.session, &self.skin, info.clone())
    }
}

/// One frame of a remote channel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RemoteFrame {
    /// The writer's sequence number.
    pub seq: u64,
    /// Acquisition time, ns since the Unix epoch (the robot PC's clock).
    pub acquired_unix_ns: u64,
    /// Publication time, ns since the Unix epoch.
    pub published_unix_ns: u64,
    /// The frame's status.
    pub status: FrameStatus,
    /// Frames of the writer this reader did not get since its previous one
    /// (dropped by the bridge or lost on the link).
    pub skipped: u64,
    /// Of those, the frames the bridge had sent (lost on the link, or
    /// dropped by zenoh on a full link); the rest the bridge never sent.
    pub lost: u64,
    /// The payload, in the channel's own layout (a layer's responses as
    /// native-endian `u16`s).
    pub bytes: Vec<u8>,
}

impl RemoteFrame {
    /// A layer's responses.
    pub fn responses(&self) -> Vec<u16> {
        self.bytes.chunks_exact(2).map(|b| u16::from_ne_bytes([b[0], b[1]])).collect()
    }
}

/// What a remote reader counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RemoteStats {
    /// Frames received.
    pub received: u64,
    /// Frames of the writer never received (sequence gaps).
    pub skipped: u64,
    /// Of those, the frames the bridge had sent.
    pub lost: u64,
    /// Messages refused as malformed.
    pub malformed: u64,
    /// Times the link was found cut.
    pub unreachable: u64,
}

/// A reader of one remote channel.
pub struct Reader {
    session: Session,
    skin: String,
    channel: RemoteChannel,
    _frames: Subscriber<()>,
    newest_sample: Arc<NewestSample>,
    _states: Subscriber<()>,
    state_queue: Arc<Mutex<VecDeque<Arrived>>>,
    _bridge: Subscriber<()>,
    bridge_events: Arc<Mutex<VecDeque<bool>>>,
    bridge_alive: bool,
    newest: Option<RemoteFrame>,
    state: Option<ChannelState>,
    heard_at: Instant,
    was_unreachable: bool,
    unreachable_after: Duration,
    stats: RemoteStats,
    reports: Publisher<'static>,
    reported_at: Instant,
    latency_sum_ns: u64,
    latency_count: u64,
    clock_offset_ns: i64,
}

impl Reader {
    fn open(session: &Session, skin: &str, channel: RemoteChannel) -> Result<Reader, BridgeError> {
        // The bridge's liveliness token goes when zenoh finds the link dead
        // (its lease, 1 s); a slow link that still carries data keeps it.
        let token = protocol::bridge_token_key(skin);
        // Callbacks that never block: a full channel would block zenoh's own
        // thread, and with it every subscription of the session.
        let bridge_events = Arc::new(Mutex::new(VecDeque::new()));
        let events = Arc::clone(&bridge_events);
        let bridge = session
            .liveliness()
            .declare_subscriber(token.clone())
            .history(true)
            .callback(move |sample: Sample| push_bounded(&events, sample.kind() == SampleKind::Put))
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot watch {token}: {e}")))?;
        let newest_sample = Arc::new(NewestSample::default());
        let state_queue = Arc::new(Mutex::new(VecDeque::new()));
        let queue = Arc::clone(&state_queue);
        Ok(Reader {
            _bridge: bridge,
            bridge_events,
            state_queue,
            bridge_alive: true,
            _frames: {
                let key = protocol::frame_key(skin, &channel.name);
                let slot = Arc::clone(&newest_sample);
                session
                    .declare_subscriber(key.clone())
                    .callback(move |sample: Sample| slot.put(sample.payload().to_bytes().into_owned()))
                    .wait()
                    .map_err(|e| BridgeError::Zenoh(format!("cannot subscribe to {key}: {e}")))?
            },
            newest_sample,
            // Every state in order (a ring of one could hide a bad one behind a good one).
            _states: session
                .declare_subscriber(protocol::state_key(skin, &channel.name))
                .callback(move |sample: Sample| {
                    push_bounded(&queue, (sample.payload().to_bytes().into_owned(), Instant::now()))
                })
                .wait()
                .map_err(|e| BridgeError::Zenoh(format!("cannot subscribe to the state of {}: {e}", channel.name)))?,
            reports: session
                .declare_publisher(protocol::reader_report_key(skin, &channel.name, &session.zid().to_string()))
                .congestion_control(zenoh::qos::CongestionControl::Drop)
                .wait()
                .map_err(|e| BridgeError::Zenoh(format!("cannot declare the reports of {}: {e}", channel.name)))?,
            reported_at: Instant::now(),
            latency_sum_ns: 0,
            latency_count: 0,
            clock_offset_ns: skinware_ros2::clock_offset_ns(),
            session: session.clone(),
            skin: skin.to_owned(),
            channel,
            newest: None,
            state: None,
            heard_at: Instant::now(),
            was_unreachable: false,
            unreachable_after: DEFAULT_UNREACHABLE_AFTER,
            stats: RemoteStats::default(),
        })
    }

    /// The channel's description, as the bridge listed it.
    pub fn channel(&self) -> &RemoteChannel {
        &self.channel
    }

    /// A layer's topology.
    pub fn topology(&self) -> Result<LayerTopology, BridgeError> {
        LayerTopology::decode(&self.channel.description, &self.channel.name).map_err(|e| BridgeError::Malformed {
            what: format!("topology of {}", self.channel.name),
            reason: e.to_string(),
        })
    }

    /// Sets how long without a word from the bridge makes the channel
    /// unreachable (default [`DEFAULT_UNREACHABLE_AFTER`]).
    pub fn set_unreachable_after(&mut self, after: Duration) {
        self.unreachable_after = after;
    }

    /// What this reader counted.
    pub fn stats(&self) -> RemoteStats {
        self.stats
    }

    /// The bridge's newest word on the channel (its figures), if any.
    pub fn bridge_state(&mut self) -> Option<ChannelState> {
        self.drain_states();
        self.state
    }

    fn drain_states(&mut self) {
        let events: Vec<bool> = lock(&self.bridge_events).drain(..).collect();
        for alive in events {
            self.bridge_alive = alive;
            if self.bridge_alive {
                self.heard_at = Instant::now();
            }
        }
        let states: Vec<Arrived> = lock(&self.state_queue).drain(..).collect();
        for (bytes, arrived) in states {
            match ChannelState::decode(&bytes) {
                Ok(state) => {
                    self.state = Some(state);
                    self.heard_at = self.heard_at.max(arrived);
                }
                Err(e) => {
                    self.stats.malformed += 1;
                    tracing::debug!("{e}");
                }
            }
        }
    }

    /// The channel's state: the writer's, or `unreachable`.
    pub fn state(&mut self) -> RemoteState {
        self.drain_states();
        self.report_if_due();
        let unreachable = !self.bridge_alive || self.heard_at.elapsed() > self.unreachable_after;
        if unreachable && !self.was_unreachable {
            self.stats.unreachable += 1;
        }
        self.was_unreachable = unreachable;
        match (unreachable, self.state) {
            (true, _) => RemoteState::Unreachable,
            (false, Some(state)) => RemoteState::Writer(state.state),
            // Connected, but the bridge has not spoken yet.
            (false, None) => RemoteState::Writer(WriterState::Running),
        }
    }

    fn accept(&mut self, bytes: &[u8], arrived: Instant) -> Result<(), BridgeError> {
        let frame = protocol::decode_frame(&self.channel, bytes).inspect_err(|_| {
            self.stats.malformed += 1;
        })?;
        self.heard_at = self.heard_at.max(arrived);
        let skipped = match &self.newest {
            Some(previous) if frame.seq > previous.seq => frame.seq - previous.seq - 1,
            // The first frame, or a restarted writer counting from 1 again.
            _ => 0,
        };
        // The frame says how many the bridge itself did not send before it.
        let lost = skipped.saturating_sub(frame.skipped);
        self.stats.received += 1;
        self.stats.skipped += skipped;
        self.stats.lost += lost;
        let now_unix = skinware_ros2::now_unix_ns(self.clock_offset_ns);
        self.latency_sum_ns += now_unix.saturating_sub(frame.stamp.to_ns());
        self.latency_count += 1;
        let bytes = frame.channel_bytes();
        self.report_if_due();
        self.newest = Some(RemoteFrame {
            seq: frame.seq,
            acquired_unix_ns: frame.stamp.to_ns(),
            published_unix_ns: frame.published.to_ns(),
            status: FrameStatus(frame.status),
            skipped,
            lost,
            bytes,
        });
        Ok(())
    }

    /// Tells the bridge, once a second, what this reader received: frames
    /// lost on the link then show on the robot PC too (`skin bridge --stats`).
    fn report_if_due(&mut self) {
        if self.reported_at.elapsed() < Duration::from_secs(1) {
            return;
        }
        self.reported_at = Instant::now();
        let report = ReaderReport {
            received: self.stats.received,
            skipped: self.stats.skipped,
            lost: self.stats.lost,
            malformed: self.stats.malformed,
            latency_ns: self.latency_sum_ns.checked_div(self.latency_count).unwrap_or(0),
        };
        (self.latency_sum_ns, self.latency_count) = (0, 0);
        let _ = self.reports.put(report.encode()).wait();
    }

    /// The newest frame received (none yet: an error saying so).
    pub fn latest(&mut self) -> Result<&RemoteFrame, BridgeError> {
        if let Some((bytes, arrived)) = self.newest_sample.take() {
            self.accept(&bytes, arrived)?;
        }
        self.newest.as_ref().ok_or_else(|| self.nothing_yet())
    }

    fn nothing_yet(&self) -> BridgeError {
        BridgeError::Timeout(format!("no frame of {}/{} has arrived yet", self.skin, self.channel.name))
    }

    /// As soon as available: waits up to `timeout` for the next frame the
    /// bridge sends (a restarted writer's frames count from 1 again). A
    /// malformed message is returned as [`BridgeError::Malformed`] at once;
    /// the next call waits for the next frame.
    pub fn wait_newer(&mut self, timeout: Duration) -> Result<&RemoteFrame, BridgeError> {
        match self.newest_sample.wait(Instant::now() + timeout) {
            Some((bytes, arrived)) => {
                self.accept(&bytes, arrived)?;
                self.newest.as_ref().ok_or_else(|| self.nothing_yet())
            }
            None => {
                let state = self.state().name();
                Err(BridgeError::Timeout(format!(
                    "no new frame of {}/{} within {timeout:?} (state: {state})",
                    self.skin, self.channel.name,
                )))
            }
        }
    }

    /// Periodic: waits for `ticker`'s next deadline and returns the newest frame then.
    pub fn next_periodic(&mut self, ticker: &mut Ticker, stop: &Stop) -> Result<&RemoteFrame, BridgeError> {
        if ticker.wait(stop).is_none() {
            return Err(BridgeError::Invalid(format!(
                "the periodic reader of {}/{} was stopped (its stop signal was set)",
                self.skin, self.channel.name
            )));
        }
        self.latest()
    }

    /// On request: the bridge asks the writer for a frame newer than any
    /// published now (as a local reader's `request`) and sends it back.
    pub fn request(&mut self, timeout: Duration) -> Result<&RemoteFrame, BridgeError> {
        let key = protocol::request_key(&self.skin, &self.channel.name);
        let selector = format!("{key}?timeout_ms={}", timeout.as_millis());
        let replies: FifoChannelHandler<Reply> = self
            .session
            .get(selector)
            .timeout(timeout + Duration::from_millis(500))
            .wait()
            .map_err(|e| BridgeError::Zenoh(format!("cannot request a frame of {}: {e}", self.channel.name)))?;
        match replies.recv() {
            Ok(reply) => match reply.result() {
                Ok(sample) => {
                    self.accept(&sample.payload().to_bytes(), Instant::now())?;
                    self.newest.as_ref().ok_or_else(|| self.nothing_yet())
                }
                Err(error) => {
                    let text = error.payload().try_to_string().map(|s| s.into_owned()).unwrap_or_default();
                    let state = self.state().name();
                    // zenoh's own "Timeout", or the bridge's: the writer gave no frame in time.
                    if text == "Timeout" || text.starts_with(protocol::TIMEOUT_PREFIX) {
                        Err(BridgeError::Timeout(format!(
                            "no frame of {}/{} on request within {timeout:?} (state: {state}): {text}",
                            self.skin, self.channel.name
                        )))
                    } else {
                        Err(BridgeError::Invalid(format!(
                            "the bridge could not get a frame of {}/{} on request: {text}",
                            self.skin, self.channel.name
                        )))
                    }
                }
            },
            Err(_) => {
                let state = self.state().name();
                Err(BridgeError::Timeout(format!(
                    "no answer to a request for {}/{} within {timeout:?} (state: {state})",
                    self.skin, self.channel.name,
                )))
            }
        }
    }
}

impl std::fmt::Debug for Reader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reader").field("skin", &self.skin).field("channel", &self.channel.name).finish_non_exhaustive()
    }
}

impl std::fmt::Debug for RemoteSkin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteSkin")
            .field("skin", &self.skin)
            .field("channels", &self.list.channels.len())
            .finish_non_exhaustive()
    }
}

/// A message's bytes and when it arrived.
type Arrived = (Vec<u8>, Instant);

/// The newest frame message not read yet: filled from zenoh's thread (which
/// never waits here), taken by the reader.
#[derive(Default)]
struct NewestSample {
    slot: Mutex<Option<Arrived>>,
    arrived: Condvar,
}

impl NewestSample {
    fn put(&self, bytes: Vec<u8>) {
        *lock(&self.slot) = Some((bytes, Instant::now()));
        self.arrived.notify_all();
    }

    fn take(&self) -> Option<Arrived> {
        lock(&self.slot).take()
    }

    fn wait(&self, deadline: Instant) -> Option<Arrived> {
        let mut slot = lock(&self.slot);
        loop {
            if let Some(newest) = slot.take() {
                return Some(newest);
            }
            let left = deadline.checked_duration_since(Instant::now()).filter(|d| !d.is_zero())?;
            slot = self.arrived.wait_timeout(slot, left).map(|(guard, _)| guard).unwrap_or_else(|p| p.into_inner().0);
        }
    }
}

/// Keeps the newest 64 items: a reader that looks at its state rarely loses
/// the oldest, and nothing ever waits.
fn push_bounded<T>(queue: &Mutex<VecDeque<T>>, item: T) {
    let mut queue = lock(queue);
    if queue.len() == 64 {
        queue.pop_front();
    }
    queue.push_back(item);
}

/// How long without a word from the bridge (it speaks every 100 ms) makes a
/// channel unreachable even while zenoh still holds the link (a bridge that
/// hangs, or a link slower than this holds back). A link zenoh finds dead
/// (no traffic for its lease) is unreachable at once.
pub const DEFAULT_UNREACHABLE_AFTER: Duration = Duration::from_secs(3);

/// A remote skin copied into local channels, so that every local tool (the
/// viewer, Python, a recorder) reads it as if it were here. An unreachable
/// channel is marked faulted until the link returns.
pub struct Mirror {
    stop: Stop,
    threads: Vec<JoinHandle<()>>,
    channels: Vec<String>,
}

impl Mirror {
    /// Creates `local_skin`'s channels in `dir` (and its geometry, when the
    /// bridge serves one) and starts copying frames into them.
    pub fn start(remote: &RemoteSkin, local_skin: &str, dir: &Path) -> Result<Mirror, BridgeError> {
        // Built first: a failure half-way stops (on drop) what already runs.
        let mut mirror = Mirror { stop: Stop::new(), threads: Vec::new(), channels: Vec::new() };
        match remote.geometry(Duration::from_secs(5)) {
            Ok(mut geometry) => {
                geometry.skin = local_skin.to_owned();
                geometry.publish(dir).map_err(|source| BridgeError::Geometry {
                    context: format!("cannot publish the remote skin's geometry in {}", dir.display()),
                    source: Box::new(source),
                })?;
            }
            Err(e) => tracing::warn!("the mirror has no geometry: {e}"),
        }
        for channel in remote.channels() {
            let options = WriterOptions {
                slots: channel.slots.clamp(skinware::MIN_SLOTS, skinware::MAX_SLOTS),
                period: channel.period,
                kind: channel.kind,
                schema_name: channel.schema.0.clone(),
                schema_version: channel.schema.1,
                unlink_on_drop: true,
                dir: Some(dir.to_owned()),
                ..WriterOptions::default()
            };
            let writer =
                Writer::create(local_skin, &channel.name, channel.payload_bytes, &channel.description, &options)?;
            let reader = remote.reader(&channel.name)?;
            let stop = mirror.stop.clone();
            mirror.channels.push(channel.name.clone());
            mirror.threads.push(
                std::thread::Builder::new()
                    .name(format!("mirror-{}", channel.name).chars().take(15).collect())
                    .spawn(move || mirror_channel(reader, writer, &stop))
                    .map_err(|source| BridgeError::Thread {
                        thread: format!("the mirror thread of {}", channel.name),
                        source,
                    })?,
            );
        }
        Ok(mirror)
    }

    /// The mirrored channels.
    pub fn channels(&self) -> &[String] {
        &self.channels
    }
}

impl Drop for Mirror {
    fn drop(&mut self) {
        self.stop.stop();
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}

fn mirror_channel(mut reader: Reader, mut writer: Writer, stop: &Stop) {
    let mut shown = WriterState::Running;
    let offset_ns = skinware_ros2::clock_offset_ns();
    while !stop.is_stopped() {
        let state = match reader.state() {
            RemoteState::Writer(WriterState::Gone) | RemoteState::Unreachable => WriterState::Faulted,
            RemoteState::Writer(state) => state,
        };
        if state != shown {
            writer.set_state(state);
            shown = state;
        }
        let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) else { continue };
        if frame.bytes.len() != writer.payload_bytes() {
            continue;
        }
        let mut out = writer.begin();
        if out.write_bytes(0, &frame.bytes).is_err() {
            continue;
        }
        out.set_acquired_ns(skinware_ros2::monotonic_ns(frame.acquired_unix_ns, offset_ns));
        out.set_status(frame.status);
        out.publish();
        if shown != WriterState::Running && matches!(reader.state(), RemoteState::Writer(WriterState::Running)) {
            writer.set_state(WriterState::Running);
            shown = WriterState::Running;
        }
    }
}
