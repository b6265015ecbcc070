//! Reads every layer of a skin, in one reader mode, into a board that holds
//! only the newest frame of each layer: whatever a browser does not take in
//! time is overwritten, never queued. Every browser in the same mode shares
//! one sampler ([`Samplers`]), so ten browsers cost the skin's writers and
//! this process one reader per layer, not ten.

#![forbid(unsafe_code)]

use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, OnceLock, Weak};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use skinware::{Error, Reader, ReaderOptions, Stop, Ticker, WriterState};

use crate::message::ReadMode;
use crate::range::{RangeTracker, ResponseRange};

/// How long a blocking read waits before it looks at the writer's state again,
/// so that a fault or a vanished writer shows within this time.
const STATE_POLL: Duration = Duration::from_millis(100);
/// Window over which rates are measured.
const RATE_WINDOW: Duration = Duration::from_millis(500);

/// The newest of one layer, as read. Cloning it is cheap: the responses are
/// shared, not copied.
#[derive(Clone, Debug)]
pub struct LayerSlot {
    /// The writer's state when last looked at; `None` while connecting,
    /// before this reader first looked at the layer (its channel does not
    /// exist yet, or the reader has just started): not known, so not gone.
    pub state: Option<WriterState>,
    /// Frames the writer published per second over the last window.
    pub writer_rate_hz: f32,
    /// Fresh frames this reader obtained per second over the last window.
    pub read_rate_hz: f32,
    /// Publish minus acquisition time of the newest frame read, milliseconds.
    pub latency_ms: f32,
    /// Sequence number of the newest frame read; 0 before the first.
    pub seq: u64,
    /// Whether that frame carries the fault status.
    pub fault_frame: bool,
    /// What the layer's responses spanned so far (its colour range);
    /// `None` before its first frame.
    pub range: Option<ResponseRange>,
    /// Its responses, shared with the browsers' sessions that are sending
    /// them, so that each sends them straight from here: the layer's reader
    /// writes in place when no session holds them, and into a new buffer
    /// when one does (the session keeps what it took).
    pub responses: Arc<Vec<u16>>,
    /// The same responses in the compact encoding ([`crate::compact`]),
    /// made by the first session that sends them and shared with every
    /// other: one encoding per frame, however many browsers watch. Only
    /// [`LayerSlot::store_responses`] changes the responses, and it starts
    /// a new encoding each time; read it with [`LayerSlot::compact_responses`].
    pub(crate) compact: Arc<OnceLock<Vec<u8>>>,
}

impl LayerSlot {
    /// Stores `responses` (up to the slot's length; sensors beyond a shorter
    /// frame keep their last value), without touching any session's copy.
    fn store_responses(&mut self, responses: &[u16]) {
        let n = responses.len().min(self.responses.len());
        match Arc::get_mut(&mut self.responses) {
            Some(own) => own[..n].copy_from_slice(&responses[..n]),
            None => {
                let mut fresh = Vec::with_capacity(self.responses.len());
                fresh.extend_from_slice(&responses[..n]);
                fresh.extend_from_slice(&self.responses[n..]);
                self.responses = Arc::new(fresh);
            }
        }
        // New responses, not yet encoded: the old encoding stays with the
        // sessions that took it.
        match Arc::get_mut(&mut self.compact) {
            Some(own) => drop(own.take()),
            None => self.compact = Arc::new(OnceLock::new()),
        }
    }

    /// Its responses in the compact encoding, encoded now by the first
    /// caller since they changed and then shared.
    pub fn compact_responses(&self) -> &[u8] {
        self.compact.get_or_init(|| {
            let mut out = Vec::with_capacity(crate::compact::max_encoded_bytes(self.responses.len()));
            crate::compact::encode(&self.responses, &mut out);
            out
        })
    }
}

/// The newest frame of every layer, and a version that changes with anything in it.
#[derive(Debug)]
pub struct Board {
    /// Bumped on every change.
    pub version: u64,
    /// One slot per layer, in geometry order.
    pub layers: Vec<LayerSlot>,
    /// Bumped by each on-request read the browser asks for.
    requests: u64,
}

/// The board and the condition its readers signal.
#[derive(Debug)]
struct Shared {
    board: Mutex<Board>,
    changed: Condvar,
    requested: Condvar,
}

fn lock(shared: &Shared) -> MutexGuard<'_, Board> {
    // A reader thread that panicked left a consistent board (it only ever
    // stores whole values), so a poisoned lock is still usable.
    shared.board.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// One layer to read: its channel name, its sensor count and type.
#[derive(Clone, Debug)]
pub struct LayerToRead {
    /// Channel name.
    pub name: String,
    /// Sensors, the length of its frames.
    pub sensors: usize,
    /// Its sensor type (its layers share a colour range).
    pub sensor_type: String,
}

impl LayerToRead {
    /// Every layer of `geometry`, in its order.
    pub fn all_of(geometry: &skinware_geometry::SkinGeometry) -> Vec<LayerToRead> {
        geometry
            .layers
            .iter()
            .map(|layer| LayerToRead {
                name: layer.name.clone(),
                sensors: layer.sensors.len(),
                sensor_type: layer.sensor_type.clone(),
            })
            .collect()
    }
}

/// The samplers running, one per reader mode (and set of layers), shared by
/// every browser that reads in that mode; a sampler stops when its last
/// browser leaves or changes mode.
#[derive(Debug)]
pub struct Samplers {
    skin: String,
    dir: Option<PathBuf>,
    running: Mutex<Vec<RunningSampler>>,
}

#[derive(Debug)]
struct RunningSampler {
    mode: ReadMode,
    layers: Vec<(String, usize)>,
    sampler: Weak<Sampler>,
}

impl Samplers {
    /// No sampler yet for `skin`'s layers (in segment directory `dir`).
    pub fn new(skin: &str, dir: Option<PathBuf>) -> Samplers {
        Samplers { skin: skin.to_owned(), dir, running: Mutex::new(Vec::new()) }
    }

    /// The sampler of `layers` in `mode`: the one already running for
    /// another browser, or a new one.
    pub fn subscribe(&self, layers: &[LayerToRead], mode: ReadMode) -> std::io::Result<Arc<Sampler>> {
        let key: Vec<(String, usize)> = layers.iter().map(|layer| (layer.name.clone(), layer.sensors)).collect();
        let mut running = self.running.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        running.retain(|entry| entry.sampler.strong_count() > 0);
        let shared = running
            .iter()
            .filter(|entry| entry.mode == mode && entry.layers == key)
            .find_map(|entry| entry.sampler.upgrade());
        if let Some(sampler) = shared {
            return Ok(sampler);
        }
        // The colour ranges another mode's readers learnt of the same
        // layers (the browser's previous mode, which it still holds), so
        // that a change of mode keeps the scale.
        let learnt = running
            .iter()
            .filter(|entry| entry.layers == key)
            .find_map(|entry| entry.sampler.upgrade())
            .map(|other| other.ranges())
            .unwrap_or_default();
        let sampler = Arc::new(Sampler::start(&self.skin, self.dir.clone(), layers, mode, &learnt)?);
        running.push(RunningSampler { mode, layers: key, sampler: Arc::downgrade(&sampler) });
        Ok(sampler)
    }

    /// Samplers running now.
    #[cfg(test)]
    fn running(&self) -> usize {
        let running = self.running.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        running.iter().filter(|entry| entry.sampler.strong_count() > 0).count()
    }
}

/// The reader threads of one mode, shared by the browsers reading in it.
#[derive(Debug)]
pub struct Sampler {
    shared: Arc<Shared>,
    stop: Stop,
    threads: Vec<JoinHandle<()>>,
}

impl Sampler {
    /// Starts one reader thread per layer of `skin`, reading in `mode`.
    /// Every layer is connecting (state `None`) until its reader first
    /// looked at it: a layer not yet read is not known to be gone. Its
    /// colour range starts from `learnt` (by layer, as another sampler's
    /// [`Sampler::ranges`]; missing ones from nothing).
    pub fn start(
        skin: &str,
        dir: Option<PathBuf>,
        layers: &[LayerToRead],
        mode: ReadMode,
        learnt: &[Option<ResponseRange>],
    ) -> std::io::Result<Sampler> {
        let slots = layers
            .iter()
            .enumerate()
            .map(|(index, layer)| LayerSlot {
                state: None,
                writer_rate_hz: 0.0,
                read_rate_hz: 0.0,
                latency_ms: 0.0,
                seq: 0,
                fault_frame: false,
                range: learnt.get(index).copied().flatten(),
                responses: Arc::new(vec![0; layer.sensors]),
                compact: Arc::default(),
            })
            .collect();
        let shared = Arc::new(Shared {
            board: Mutex::new(Board { version: 0, layers: slots, requests: 0 }),
            changed: Condvar::new(),
            requested: Condvar::new(),
        });
        let stop = Stop::new();
        // Built before the threads start, so that a failure stops those already started (on drop).
        let mut sampler = Sampler { shared: shared.clone(), stop: stop.clone(), threads: Vec::new() };
        for (index, layer) in layers.iter().enumerate() {
            let job = LayerJob {
                skin: skin.to_owned(),
                dir: dir.clone(),
                name: layer.name.clone(),
                index,
                mode,
                shared: shared.clone(),
                stop: stop.clone(),
                range: RangeTracker::starting_from(learnt.get(index).copied().flatten()),
            };
            let thread = std::thread::Builder::new().name(format!("view-{}", layer.name)).spawn(move || job.run())?;
            sampler.threads.push(thread);
        }
        Ok(sampler)
    }

    /// Waits up to `timeout` for the board to differ from `seen`; then calls
    /// `take` with it (locked) and returns what it returns.
    pub fn take_newer<T>(&self, seen: u64, timeout: Duration, take: impl FnOnce(&Board) -> T) -> Option<T> {
        let board = lock(&self.shared);
        let (board, _) = self
            .shared
            .changed
            .wait_timeout_while(board, timeout, |board| board.version == seen)
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        (board.version != seen).then(|| take(&board))
    }

    /// Each layer's colour range as learnt so far, in layer order.
    pub fn ranges(&self) -> Vec<Option<ResponseRange>> {
        lock(&self.shared).layers.iter().map(|slot| slot.range).collect()
    }

    /// On-request mode: asks every layer's reader for one frame (which every
    /// browser in this mode then gets).
    pub fn request(&self) {
        lock(&self.shared).requests += 1;
        self.shared.requested.notify_all();
    }

    /// Stops the reader threads and waits for them; the board keeps what it
    /// holds. Dropping the sampler does this.
    fn stop(&mut self) {
        self.stop.stop();
        self.shared.requested.notify_all();
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
    }
}

impl Drop for Sampler {
    fn drop(&mut self) {
        Sampler::stop(self);
    }
}

/// One layer's reader thread.
struct LayerJob {
    skin: String,
    dir: Option<PathBuf>,
    name: String,
    index: usize,
    mode: ReadMode,
    shared: Arc<Shared>,
    stop: Stop,
    /// The layer's colour range, from the frames this thread read.
    range: RangeTracker,
}

/// Rate measurement over [`RATE_WINDOW`].
struct RateWindow {
    started: Instant,
    writer_frames: u64,
    reads: u64,
}

impl LayerJob {
    fn open(&self) -> Option<Reader> {
        let options = ReaderOptions { allow_gone: true, dir: self.dir.clone(), ..ReaderOptions::default() };
        let mut reader = Reader::open_with(&self.skin, &self.name, &options).ok()?;
        reader.set_stop(&self.stop);
        Some(reader)
    }

    fn run(mut self) {
        // The channel may not exist yet (its driver is starting) or any more.
        let mut reader = loop {
            if let Some(reader) = self.open() {
                break reader;
            }
            if !self.stop.sleep_until(skinware::os::monotonic_ns() + 250_000_000) {
                return;
            }
        };
        let mut ticker = match self.mode {
            ReadMode::Periodic { rate_hz } => Some(Ticker::from_hz(rate_hz)),
            _ => None,
        };
        let mut requests_served = 0;
        let mut window = RateWindow { started: Instant::now(), writer_frames: reader.writer_stats().frames, reads: 0 };
        let mut first = true;
        // When the kernel was last asked whether the writer lives.
        let mut asked_kernel = Instant::now();
        // Whether the board shows this layer's writer gone.
        let mut shown_gone = false;
        // The sequence number of the frame on the board (only this thread writes it).
        let mut last_seq = 0;
        // When the resting level is next looked at (a median of the frame).
        let mut next_median = Instant::now();
        while !self.stop.is_stopped() {
            let result = match (self.mode, &mut ticker) {
                (ReadMode::Periodic { .. }, Some(ticker)) => reader.next_periodic(ticker),
                (ReadMode::Request, _) if !first => match self.wait_for_request(&mut requests_served) {
                    true => reader.request(Duration::from_secs(1)),
                    false => Err(Error::Timeout { channel: self.name.clone(), timeout: STATE_POLL }),
                },
                // The first read of every mode shows the newest frame at once.
                _ if first => reader.latest(),
                _ => reader.wait_newer(STATE_POLL),
            };
            first = false;
            let mut fresh_frame = false;
            match result {
                Ok(frame) => {
                    fresh_frame = frame.is_fresh();
                    if fresh_frame {
                        window.reads += 1;
                    }
                    self.store(&frame, &mut last_seq, &mut next_median);
                }
                Err(Error::Stopped { .. }) => return,
                // A gone writer may have a successor under the same name, which the reader follows: keep waiting.
                Err(Error::Timeout { .. } | Error::NoFrameYet { .. } | Error::WriterGone { .. }) => {}
                Err(e) => {
                    tracing::debug!(layer = %self.name, "read failed: {e}");
                    if !self.stop.sleep_until(skinware::os::monotonic_ns() + STATE_POLL.as_nanos() as u64) {
                        return;
                    }
                }
            }
            // A fresh frame says the writer lived a period ago; a stale one
            // (periodic reads of a writer that died) says nothing, and the
            // kernel is asked at least every STATE_POLL regardless.
            let trust_stored = fresh_frame && asked_kernel.elapsed() < STATE_POLL;
            if !trust_stored {
                asked_kernel = Instant::now();
            }
            self.refresh_state(&mut reader, &mut window, trust_stored, &mut shown_gone);
        }
    }

    /// Puts `frame` on the board, if it is not the one there already,
    /// with the layer's colour range (computed before the board is locked:
    /// the sessions and the other layers' readers do not wait for it).
    fn store(&mut self, frame: &skinware::Frame<'_>, last_seq: &mut u64, next_median: &mut Instant) {
        if frame.seq() == *last_seq {
            return;
        }
        *last_seq = frame.seq();
        let with_median = Instant::now() >= *next_median;
        if with_median {
            *next_median = Instant::now() + RATE_WINDOW;
        }
        self.range.observe(frame.responses(), with_median);
        let mut board = lock(&self.shared);
        let slot = &mut board.layers[self.index];
        slot.store_responses(frame.responses());
        slot.seq = frame.seq();
        slot.fault_frame = frame.status().is_fault();
        slot.latency_ms = frame.published_ns().saturating_sub(frame.acquired_ns()) as f32 / 1e6;
        slot.range = self.range.range();
        board.version += 1;
        // Outside the lock, so that the woken sessions do not wait for it
        // (nor the other layers' readers).
        drop(board);
        self.shared.changed.notify_all();
    }

    /// Waits (at most [`STATE_POLL`]) until the browser asked for more frames
    /// than this layer served.
    fn wait_for_request(&self, served: &mut u64) -> bool {
        let board = lock(&self.shared);
        let (board, _) = self
            .shared
            .requested
            .wait_timeout_while(board, STATE_POLL, |board| board.requests == *served && !self.stop.is_stopped())
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        let asked = board.requests != *served;
        *served = board.requests;
        asked && !self.stop.is_stopped()
    }

    /// Publishes the writer's state at once when it changes, and the rates at
    /// the end of each window. With `trust_stored` (just after a fresh
    /// frame) the state the writer stored is enough: it was alive a period
    /// ago, and asking the kernel (an `fcntl`) for every frame was a tenth of
    /// the readers' time. Otherwise the kernel says whether it still lives,
    /// and a writer gone is followed to its successor.
    ///
    /// A writer found gone is shown gone (`shown_gone`) before its successor
    /// is followed, one read later: a successor that starts at once would
    /// otherwise hide that the layer died.
    fn refresh_state(&self, reader: &mut Reader, window: &mut RateWindow, trust_stored: bool, shown_gone: &mut bool) {
        let state = if trust_stored {
            reader.stored_writer_state()
        } else {
            let state = reader.writer_state();
            // A successor makes a new channel, which every reader mode must follow.
            if state == WriterState::Gone && *shown_gone && reader.follow_recreated() {
                // The successor's frame count starts again.
                *window = RateWindow { started: Instant::now(), writer_frames: reader.writer_stats().frames, reads: 0 };
                reader.writer_state()
            } else {
                state
            }
        };
        *shown_gone = state == WriterState::Gone;
        let elapsed = window.started.elapsed();
        let rates = (elapsed >= RATE_WINDOW).then(|| {
            let frames = reader.writer_stats().frames;
            let seconds = elapsed.as_secs_f64();
            let writer =
                if state == WriterState::Gone { 0.0 } else { frames.saturating_sub(window.writer_frames) as f64 };
            let rates = ((writer / seconds) as f32, (window.reads as f64 / seconds) as f32);
            *window = RateWindow { started: Instant::now(), writer_frames: frames, reads: 0 };
            rates
        });
        let mut board = lock(&self.shared);
        let slot = &mut board.layers[self.index];
        let mut changed = slot.state != Some(state);
        slot.state = Some(state);
        if let Some((writer_rate_hz, read_rate_hz)) = rates {
            changed |= slot.writer_rate_hz != writer_rate_hz || slot.read_rate_hz != read_rate_hz;
            slot.writer_rate_hz = writer_rate_hz;
            slot.read_rate_hz = read_rate_hz;
        }
        if changed {
            board.version += 1;
            drop(board);
            self.shared.changed.notify_all();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Browsers in one mode share a sampler, another mode gets its own, and a
    /// sampler stops with its last browser.
    #[test]
    fn browsers_in_one_mode_share_one_sampler() {
        let dir = std::env::temp_dir().join(format!("skin-samplers-{}", std::process::id()));
        let samplers = Samplers::new("nosuchskin", Some(dir));
        let layers = [LayerToRead { name: "tactile".into(), sensors: 4, sensor_type: "pressure".into() }];
        let first = samplers.subscribe(&layers, ReadMode::Asap).unwrap();
        let second = samplers.subscribe(&layers, ReadMode::Asap).unwrap();
        assert!(Arc::ptr_eq(&first, &second));
        let periodic = samplers.subscribe(&layers, ReadMode::Periodic { rate_hz: 10.0 }).unwrap();
        assert!(!Arc::ptr_eq(&first, &periodic));
        let other_rate = samplers.subscribe(&layers, ReadMode::Periodic { rate_hz: 20.0 }).unwrap();
        assert!(!Arc::ptr_eq(&periodic, &other_rate));
        let other_layers = [LayerToRead { name: "tactile".into(), sensors: 8, sensor_type: "pressure".into() }];
        let resized = samplers.subscribe(&other_layers, ReadMode::Asap).unwrap();
        assert!(!Arc::ptr_eq(&first, &resized), "a skin whose layers changed gets new readers");
        assert_eq!(samplers.running(), 4);
        drop((first, periodic, other_rate, resized));
        assert_eq!(samplers.running(), 1, "the second browser still holds the shared sampler");
        drop(second);
        assert_eq!(samplers.running(), 0);
    }

    /// Sessions that take the same board share its responses (the same
    /// bytes, not copies); a frame stored while a session holds them goes
    /// into a new buffer and leaves the session's as it took it; once no
    /// session holds them, frames are written in place again.
    #[test]
    fn sessions_share_responses_and_keep_what_they_took() {
        let mut slot = LayerSlot {
            state: Some(WriterState::Running),
            writer_rate_hz: 0.0,
            read_rate_hz: 0.0,
            latency_ms: 0.0,
            seq: 1,
            fault_frame: false,
            range: None,
            responses: Arc::new(vec![0; 4]),
            compact: Arc::default(),
        };
        slot.store_responses(&[1, 2, 3, 4]);
        let first_session = slot.clone();
        let second_session = slot.clone();
        assert!(Arc::ptr_eq(&first_session.responses, &second_session.responses), "one buffer for both");
        // One encoding, by whichever session sends first, for both.
        let encoded = first_session.compact_responses().as_ptr();
        assert_eq!(second_session.compact_responses().as_ptr(), encoded, "encoded once, shared");
        let mut expected = Vec::new();
        crate::compact::encode(&[1, 2, 3, 4], &mut expected);
        assert_eq!(second_session.compact_responses(), expected);
        slot.store_responses(&[5, 6]);
        assert_eq!(*first_session.responses, [1, 2, 3, 4], "a session keeps what it took");
        assert_eq!(first_session.compact_responses(), expected, "and its encoding");
        let mut newer = Vec::new();
        crate::compact::encode(&[5, 6, 3, 4], &mut newer);
        assert_eq!(slot.compact_responses(), newer, "a new frame is encoded anew");
        assert_eq!(*slot.responses, [5, 6, 3, 4], "a shorter frame leaves the other sensors as they were");
        assert!(!Arc::ptr_eq(&slot.responses, &first_session.responses));
        drop((first_session, second_session));
        let buffer = Arc::as_ptr(&slot.responses);
        slot.store_responses(&[7, 8, 9, 10, 11]);
        assert_eq!(Arc::as_ptr(&slot.responses), buffer, "written in place when no session holds it");
        assert_eq!(*slot.responses, [7, 8, 9, 10], "a longer frame is cut to the layer's sensors");
    }

    /// The board as it is now.
    fn board_now<T>(sampler: &Sampler, look: impl FnOnce(&Board) -> T) -> T {
        sampler.take_newer(u64::MAX, Duration::ZERO, look).unwrap()
    }

    /// Waits (up to a minute: a loaded machine) until the board satisfies `done`.
    fn board_until(sampler: &Sampler, what: &str, done: impl Fn(&Board) -> bool) {
        let deadline = Instant::now() + Duration::from_secs(60);
        while !board_now(sampler, &done) {
            assert!(Instant::now() < deadline, "the board never showed {what}");
            sampler.take_newer(board_now(sampler, |b| b.version), Duration::from_millis(50), |_| ());
        }
    }

    /// A layer the sampler has not read yet is connecting, not gone: while
    /// its channel does not exist, however long; then running with the
    /// frame and its colour range; gone once its writer is.
    #[test]
    fn a_layer_is_connecting_until_read_then_running_then_gone() {
        let dir = std::env::temp_dir().join(format!("skin-sampler-connecting-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut builder = skinware::TopologyBuilder::new("tactile", "pressure", 100.0);
        builder.patch(1).module(1, 1..=4);
        let topology = builder.build().unwrap();
        let layers = [LayerToRead { name: "tactile".into(), sensors: 4, sensor_type: "pressure".into() }];
        let sampler = Sampler::start("connecting", Some(dir.clone()), &layers, ReadMode::Asap, &[]).unwrap();
        assert_eq!(board_now(&sampler, |b| b.layers[0].state), None, "connecting from the start");
        // Its reader looks for the channel every 250 ms: whatever it found
        // meanwhile, the layer is still connecting.
        std::thread::sleep(Duration::from_millis(600));
        assert_eq!(board_now(&sampler, |b| (b.layers[0].state, b.layers[0].seq)), (None, 0));

        let options = skinware::WriterOptions { dir: Some(dir.clone()), ..skinware::WriterOptions::default() };
        let mut writer =
            skinware::Writer::create("connecting", "tactile", topology.frame_bytes(), &topology.encode(), &options)
                .unwrap();
        let responses: Vec<u8> = [15u16, 15, 255, 14].iter().flat_map(|r| r.to_ne_bytes()).collect();
        writer.publish_bytes(&responses, skinware::FrameStatus::default()).unwrap();
        board_until(&sampler, "the layer running with its frame", |b| {
            b.layers[0].state == Some(WriterState::Running) && b.layers[0].seq == 1
        });
        let (responses, range) = board_now(&sampler, |b| (b.layers[0].responses.clone(), b.layers[0].range));
        assert_eq!(*responses, [15, 15, 255, 14]);
        assert_eq!(range, Some(ResponseRange { resting: 15, highest: 255 }), "resting: the median");
        assert_eq!(sampler.ranges(), [range]);

        drop(writer);
        board_until(&sampler, "the layer gone", |b| b.layers[0].state == Some(WriterState::Gone));
        drop(sampler);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// A browser that changes mode gets new readers, which keep the colour
    /// ranges the old ones learnt.
    #[test]
    fn a_new_mode_keeps_the_ranges_learnt() {
        let dir = std::env::temp_dir().join(format!("skin-sampler-ranges-{}", std::process::id()));
        let samplers = Samplers::new("nosuchskin", Some(dir));
        let layers = [
            LayerToRead { name: "a".into(), sensors: 2, sensor_type: "pressure".into() },
            LayerToRead { name: "b".into(), sensors: 2, sensor_type: "pressure".into() },
        ];
        let asap = samplers.subscribe(&layers, ReadMode::Asap).unwrap();
        let learnt = ResponseRange { resting: 15, highest: 200 };
        lock(&asap.shared).layers[1].range = Some(learnt);
        let request = samplers.subscribe(&layers, ReadMode::Request).unwrap();
        assert_eq!(request.ranges(), [None, Some(learnt)]);
        assert_eq!(board_now(&request, |b| b.layers[1].state), None, "its own state is not known yet");
    }
}
