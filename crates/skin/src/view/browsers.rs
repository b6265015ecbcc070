//! The browsers of one sampler, served together: their acknowledgements are
//! read and their updates sent by whichever thread is awake anyway.
//!
//! A thread per browser, sleeping until its browser acknowledged, woke once
//! per update: on this machine a wake-up of a halted vCPU is most of what a
//! browser cost. Here the layers' readers, which wake for every frame
//! anyway, dispatch after they changed the board (at most once per
//! [`DISPATCH_INTERVAL`]): one `epoll_wait` that does not wait finds the
//! browsers that spoke, and every browser with credit gets the board as it
//! is, at once. An update needs a board change to carry anything new, so
//! nothing waits longer than it did. Only while the board is quiet (on
//! request, a stopped skin) does the doorman, one thread per sampler, sleep
//! on the browsers' sockets and dispatch when one speaks.
//!
//! A dispatcher never waits for a browser: it only tries each one's lock,
//! and writes without waiting; what a slow browser does not take at once,
//! its own thread writes (see [`super::session`]).

#![forbid(unsafe_code)]

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, TryLockError};
use std::time::{Duration, Instant};

use rustix::event::epoll;
use skinware::Stop;

use super::overlays::SharedOverlays;
use super::sampler::Board;
use super::session::{Browser, Connection};

/// The least time between two dispatches started by the layers' readers
/// (which change the board up to 5,000 times a second at 1 kHz).
pub const DISPATCH_INTERVAL: Duration = Duration::from_millis(1);
/// The board is quiet when it has not changed for this long: the doorman
/// then waits on the browsers' sockets itself.
const QUIET: Duration = Duration::from_millis(5);
/// How long the doorman sleeps or waits at a time; a change the readers'
/// dispatches skipped goes out within this time.
const DOORMAN_POLL: Duration = Duration::from_millis(20);
/// How long the doorman backs off when a browser that spoke was busy with
/// its own thread (its socket stays readable until someone reads it).
const BUSY_BACKOFF: Duration = Duration::from_millis(2);
/// Events taken from the epoll set per call.
const EVENTS: usize = 64;

/// The browsers reading from one sampler, and what dispatching to them needs.
#[derive(Debug)]
pub struct Browsers {
    /// Every browser's socket, keyed by [`Browser::key`], level-triggered.
    epoll: std::os::fd::OwnedFd,
    /// The browsers; held by one dispatch at a time.
    list: Mutex<Vec<Arc<Browser>>>,
    /// Monotonic ns when a dispatch last started.
    last_dispatch_ns: AtomicU64,
    /// Monotonic ns when the board last changed.
    last_change_ns: AtomicU64,
    overlays: Arc<SharedOverlays>,
}

/// Whether a dispatch waits for another one to finish.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Turn {
    /// Skip the dispatch if another is running (the readers).
    Try,
    /// Wait for it (the doorman).
    Wait,
}

fn since(ns: &AtomicU64) -> Duration {
    Duration::from_nanos(skinware::os::monotonic_ns().saturating_sub(ns.load(Ordering::Relaxed)))
}

impl Browsers {
    /// No browser yet; updates carry `overlays`.
    pub fn new(overlays: Arc<SharedOverlays>) -> std::io::Result<Browsers> {
        let epoll = epoll::create(epoll::CreateFlags::CLOEXEC)?;
        Ok(Browsers {
            epoll,
            list: Mutex::new(Vec::new()),
            last_dispatch_ns: AtomicU64::new(0),
            last_change_ns: AtomicU64::new(0),
            overlays,
        })
    }

    fn list(&self, turn: Turn) -> Option<MutexGuard<'_, Vec<Arc<Browser>>>> {
        match (turn, self.list.try_lock()) {
            (_, Ok(list)) => Some(list),
            // A dispatch that panicked left whole values.
            (_, Err(TryLockError::Poisoned(poisoned))) => Some(poisoned.into_inner()),
            (Turn::Try, Err(TryLockError::WouldBlock)) => None,
            (Turn::Wait, Err(TryLockError::WouldBlock)) => {
                Some(self.list.lock().unwrap_or_else(|poisoned| poisoned.into_inner()))
            }
        }
    }

    /// Serves `browser` from now on. Never called with its connection locked.
    pub fn add(&self, browser: &Arc<Browser>) -> std::io::Result<()> {
        {
            let connection = browser.lock();
            epoll::add(
                &self.epoll,
                connection.stream(),
                epoll::EventData::new_u64(browser.key),
                epoll::EventFlags::IN | epoll::EventFlags::RDHUP,
            )?;
        }
        self.list(Turn::Wait).expect("a waiting turn always gets the list").push(browser.clone());
        Ok(())
    }

    /// Serves `browser` no more. Never called with its connection locked.
    pub fn remove(&self, browser: &Arc<Browser>) {
        self.list(Turn::Wait).expect("a waiting turn always gets the list").retain(|b| !Arc::ptr_eq(b, browser));
        // Already gone from the set if a dispatch saw it leave.
        let _ = epoll::delete(&self.epoll, browser.lock().stream());
    }

    /// Notes a change of the board; dispatches if none started for
    /// [`DISPATCH_INTERVAL`] (the readers call this, holding nothing).
    pub fn board_changed(&self, board: &Mutex<Board>, request: impl Fn()) {
        let now = skinware::os::monotonic_ns();
        self.last_change_ns.store(now, Ordering::Relaxed);
        if now.saturating_sub(self.last_dispatch_ns.load(Ordering::Relaxed)) >= DISPATCH_INTERVAL.as_nanos() as u64 {
            self.dispatch(Turn::Try, board, request);
        }
    }

    /// Reads what the browsers said and sends the board to every browser
    /// that may have an update. Returns whether a browser that spoke was
    /// busy with its own thread (and is still to be read).
    pub fn dispatch(&self, turn: Turn, board: &Mutex<Board>, request: impl Fn()) -> bool {
        let Some(list) = self.list(turn) else { return false };
        self.last_dispatch_ns.store(skinware::os::monotonic_ns(), Ordering::Relaxed);
        let mut busy = false;
        let mut events = Vec::with_capacity(EVENTS);
        let zero = rustix::time::Timespec { tv_sec: 0, tv_nsec: 0 };
        if let Err(e) = epoll::wait(&self.epoll, rustix::buffer::spare_capacity(&mut events), Some(&zero)) {
            tracing::warn!("cannot poll the browsers' connections: {e}");
        }
        for event in &events {
            let key = event.data.u64();
            let Some(browser) = list.iter().find(|b| b.key == key) else { continue };
            let Some(mut connection) = browser.try_lock() else {
                busy = true;
                continue;
            };
            let heard = connection.read_messages();
            if heard.request {
                request();
            }
            if connection.left {
                // Its socket would stay readable (at its end) until its
                // thread removes it.
                let _ = epoll::delete(&self.epoll, connection.stream());
            }
            if connection.wants_its_thread() {
                browser.call_its_thread();
            }
        }
        let now = Instant::now();
        let mut ready: Vec<(&Arc<Browser>, MutexGuard<'_, Connection>)> = list
            .iter()
            .filter_map(|browser| browser.try_lock().map(|connection| (browser, connection)))
            .filter(|(_, connection)| connection.ready_for_update(now))
            .collect();
        if ready.is_empty() {
            return busy;
        }
        // The board's lock only long enough to share each layer's
        // responses: the encoding and the writes happen after.
        let (version, layers) = {
            let board = board.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
            (board.version, board.layers.clone())
        };
        ready.retain(|(_, connection)| !connection.has_seen(version));
        if ready.is_empty() {
            return busy;
        }
        let overlays = self.overlays.poll();
        for (browser, connection) in &mut ready {
            connection.send_update(version, &layers, &overlays);
            if connection.wants_its_thread() {
                browser.call_its_thread();
            }
        }
        busy
    }

    /// The doorman of one sampler: dispatches what the readers' dispatches
    /// left (a change just after one, a browser that spoke while the board
    /// is quiet), and waits on the browsers' sockets while the board is
    /// quiet. Returns when `stop` is stopped.
    pub fn doorman(&self, stop: &Stop, board: &Mutex<Board>, request: impl Fn()) {
        let mut events = Vec::with_capacity(EVENTS);
        while !stop.is_stopped() {
            let busy = self.dispatch(Turn::Wait, board, &request);
            let pause = if busy { BUSY_BACKOFF } else { DOORMAN_POLL };
            if busy || since(&self.last_change_ns) < QUIET {
                if !stop.sleep_until(skinware::os::monotonic_ns() + pause.as_nanos() as u64) {
                    return;
                }
                continue;
            }
            let timeout = rustix::time::Timespec { tv_sec: 0, tv_nsec: pause.as_nanos() as i64 };
            events.clear();
            match epoll::wait(&self.epoll, rustix::buffer::spare_capacity(&mut events), Some(&timeout)) {
                Ok(_) | Err(rustix::io::Errno::INTR) => {}
                Err(e) => {
                    tracing::warn!("cannot wait for the browsers' connections: {e}");
                    if !stop.sleep_until(skinware::os::monotonic_ns() + pause.as_nanos() as u64) {
                        return;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::net::{TcpListener, TcpStream};
    use std::sync::mpsc;

    use skin::viewer_message::ReadMode;
    use skinware::WriterState;
    use tungstenite::protocol::Role;
    use tungstenite::{Message, WebSocket};

    use super::*;
    use crate::view::protocol::{LAYER_RECORD_BYTES, OVERLAY_RECORD_BYTES, UPDATE_HEADER_BYTES};
    use crate::view::sampler::LayerSlot;
    use crate::view::session::BrowserStream;

    fn slot(seq: u64, responses: Vec<u16>) -> LayerSlot {
        LayerSlot {
            state: WriterState::Running,
            writer_rate_hz: 0.0,
            read_rate_hz: 0.0,
            latency_ms: 0.0,
            seq,
            fault_frame: false,
            responses: Arc::new(responses),
        }
    }

    /// A browser connected over loopback TCP: the server's side as the
    /// dispatcher serves it, and the client's side as a page speaks.
    fn connect(browsers: &Browsers, layers: usize) -> (Arc<Browser>, WebSocket<TcpStream>) {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let client = TcpStream::connect(listener.local_addr().unwrap()).unwrap();
        let (server, _) = listener.accept().unwrap();
        let server = WebSocket::from_raw_socket(BrowserStream::new(server), Role::Server, None);
        let browser = Arc::new(Browser::new(server, layers, ReadMode::Asap));
        browsers.add(&browser).unwrap();
        (browser, WebSocket::from_raw_socket(client, Role::Client, None))
    }

    fn browsers() -> Browsers {
        let dir = std::env::temp_dir().join(format!("skin-browsers-{}", std::process::id()));
        Browsers::new(Arc::new(SharedOverlays::new("nothing-here", Some(dir)))).unwrap()
    }

    /// The next message the client gets within `wait`, if any.
    fn receive(client: &mut WebSocket<TcpStream>, wait: Duration) -> Option<Vec<u8>> {
        client.get_mut().set_read_timeout(Some(wait)).unwrap();
        match client.read() {
            Ok(Message::Binary(bytes)) => Some(bytes.to_vec()),
            Ok(other) => panic!("expected an update, got {other:?}"),
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
            {
                None
            }
            Err(e) => panic!("{e}"),
        }
    }

    fn responses_of(update: &[u8], layers: usize) -> Vec<u16> {
        let at = UPDATE_HEADER_BYTES + layers * LAYER_RECORD_BYTES;
        let arrows = usize::from(u16::from_le_bytes([update[8], update[9]]));
        let markers = usize::from(u16::from_le_bytes([update[10], update[11]]));
        update[at + (arrows + markers) * OVERLAY_RECORD_BYTES..]
            .chunks_exact(2)
            .map(|pair| u16::from_le_bytes([pair[0], pair[1]]))
            .collect()
    }

    /// A dispatch reads every browser's acknowledgements and sends each
    /// browser with credit the board as it is, once per version it has not
    /// seen; a browser without credit gets nothing.
    #[test]
    fn each_acknowledgement_buys_one_update_of_a_newer_board() {
        let browsers = browsers();
        let board = Mutex::new(Board::new(vec![slot(1, vec![10, 20, 30])]));
        board.lock().unwrap().version = 1;
        let (first, mut first_client) = connect(&browsers, 1);
        let (_second, mut second_client) = connect(&browsers, 1);
        let no_request = || panic!("nobody asked for a frame");
        browsers.dispatch(Turn::Wait, &board, no_request);
        assert_eq!(receive(&mut first_client, Duration::from_millis(50)), None, "no credit, no update");

        first_client.send(Message::text(r#"{"ack":2}"#)).unwrap();
        browsers.dispatch(Turn::Wait, &board, no_request);
        let update = receive(&mut first_client, Duration::from_secs(5)).expect("an update after the acknowledgement");
        assert_eq!(responses_of(&update, 1), [10, 20, 30]);
        assert_eq!(receive(&mut second_client, Duration::from_millis(50)), None, "the other browser gave no credit");
        browsers.dispatch(Turn::Wait, &board, no_request);
        assert_eq!(receive(&mut first_client, Duration::from_millis(50)), None, "nothing new on the board");

        {
            let mut board = board.lock().unwrap();
            board.layers[0] = slot(2, vec![11, 21, 31]);
            board.version = 2;
        }
        first_client.send(Message::text(r#"{"ack":1}"#)).unwrap();
        second_client.send(Message::text(r#"{"ack":1}"#)).unwrap();
        browsers.dispatch(Turn::Wait, &board, no_request);
        for client in [&mut first_client, &mut second_client] {
            let update = receive(client, Duration::from_secs(5)).expect("the newer board");
            assert_eq!(responses_of(&update, 1), [11, 21, 31]);
        }
        assert!(!first.lock().wants_its_thread());
    }

    /// A browser that takes nothing holds up no dispatch: what it did not
    /// take is left to its own thread, which writes the rest, and the
    /// browser gets the whole update, intact.
    #[test]
    fn a_browser_that_does_not_read_holds_up_no_dispatch() {
        let browsers = browsers();
        let big: Vec<u16> = (0..400_000u32).map(|i| (i * 7 % 65_521) as u16).collect();
        let board = Mutex::new(Board::new(vec![slot(1, big.clone())]));
        board.lock().unwrap().version = 1;
        let (browser, mut client) = connect(&browsers, 1);
        // Loopback's buffers grow to megabytes: keep the server's small.
        rustix::net::sockopt::set_socket_send_buffer_size(browser.lock().stream(), 16 * 1024).unwrap();
        client.send(Message::text(r#"{"ack":1}"#)).unwrap();
        let (done, dispatched) = mpsc::channel();
        std::thread::scope(|scope| {
            scope.spawn(|| {
                browsers.dispatch(Turn::Wait, &board, || {});
                done.send(()).unwrap();
            });
            // 800 KB do not fit the sockets' buffers: a dispatch that waited
            // for the browser would never return, as nobody reads yet.
            dispatched
                .recv_timeout(Duration::from_secs(20))
                .expect("the dispatch waited for a browser that reads nothing");
        });
        assert!(browser.lock().wants_its_thread(), "the rest is left to the browser's thread");
        let reading = std::thread::spawn(move || receive(&mut client, Duration::from_secs(20)));
        browser.lock().finish_update().unwrap();
        assert!(!browser.lock().wants_its_thread());
        let update = reading.join().unwrap().expect("the whole update");
        assert_eq!(responses_of(&update, 1), big);
    }

    /// A mode change and a browser that leaves are for the browser's own
    /// thread; a request is for the sampler.
    #[test]
    fn mode_changes_and_departures_call_the_browsers_thread() {
        let browsers = browsers();
        let board = Mutex::new(Board::new(vec![slot(0, vec![0; 3])]));
        let (browser, mut client) = connect(&browsers, 1);
        client.send(Message::text(r#"{"mode":"request"}"#)).unwrap();
        client.send(Message::text(r#"{"request":true}"#)).unwrap();
        let requests = std::sync::atomic::AtomicU32::new(0);
        browsers.dispatch(Turn::Wait, &board, || {
            requests.fetch_add(1, Ordering::Relaxed);
        });
        assert_eq!(requests.load(Ordering::Relaxed), 1);
        assert_eq!(browser.lock().mode_asked(), Some(ReadMode::Request));
        assert!(browser.lock().wants_its_thread());

        let (other, client) = connect(&browsers, 1);
        drop(client);
        browsers.dispatch(Turn::Wait, &board, || {});
        assert!(other.lock().left, "a closed connection is a browser that left");
        browsers.remove(&other);
        browsers.remove(&browser);
        assert!(browsers.list(Turn::Try).unwrap().is_empty());
    }
}
