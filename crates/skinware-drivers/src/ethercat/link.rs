//! How ethercrab's frames reach the bus: a network interface through a raw
//! socket of our own, or any in-process [`FrameExchange`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Wake, Waker};
use std::thread::{self, Thread};
use std::time::Duration;

use ethercrab::{PduRx, PduTx};

/// The EtherType of EtherCAT frames; the socket sees every other kind too.
const ETHERTYPE_ETHERCAT: u16 = 0x88A4;

/// Something that takes an EtherCAT frame round a bus and gives back what
/// returned: an emulated segment in the same process, a capture replay.
pub trait FrameExchange: Send {
    /// Sends `frame` (a whole Ethernet frame) round the bus. Returns `true`
    /// with the frame that came back in `frame`, or `false` if none did.
    fn exchange(&mut self, frame: &mut Vec<u8>) -> bool;
}

/// Where the driver's frames go.
#[derive(Clone)]
pub enum FrameLink {
    /// A network interface (`eth0`), through a raw socket: the process needs
    /// `CAP_NET_RAW` (or root).
    Interface(String),
    /// An in-process bus.
    InProcess(Arc<Mutex<dyn FrameExchange>>),
}

impl std::fmt::Debug for FrameLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FrameLink::Interface(name) => write!(f, "interface {name}"),
            FrameLink::InProcess(_) => f.write_str("in-process bus"),
        }
    }
}

/// Wakes the I/O thread when ethercrab has a frame to send.
struct ThreadWaker(Thread);

impl Wake for ThreadWaker {
    fn wake(self: Arc<Self>) {
        self.0.unpark();
    }
}

/// Moves frames between ethercrab and the bus until `stop`. An error means
/// the link cannot carry frames any more (the socket would not open, or
/// failed): the session must start again.
pub(crate) fn run(link: &FrameLink, tx: PduTx<'_>, rx: PduRx<'_>, stop: &AtomicBool) -> Result<(), String> {
    match link {
        FrameLink::InProcess(bus) => {
            run_in_process(bus, tx, rx, stop);
            Ok(())
        }
        FrameLink::Interface(name) => run_interface(name, tx, rx, stop),
    }
}

fn run_in_process(bus: &Mutex<dyn FrameExchange>, mut tx: PduTx<'_>, mut rx: PduRx<'_>, stop: &AtomicBool) {
    let waker = Waker::from(Arc::new(ThreadWaker(thread::current())));
    let mut buffer = Vec::with_capacity(1600);
    while !stop.load(Ordering::Acquire) {
        tx.replace_waker(&waker);
        let mut sent = false;
        while let Some(frame) = tx.next_sendable_frame() {
            sent = true;
            buffer.clear();
            let sent_ok = frame.send_blocking(|bytes| {
                buffer.extend_from_slice(bytes);
                Ok(bytes.len())
            });
            if sent_ok.is_err() {
                continue;
            }
            let returned = skinware::lock(bus).exchange(&mut buffer);
            // An answer ethercrab no longer waits for (it gave the frame up)
            // is refused; that is the lost frame's business, not the link's.
            if returned && let Err(e) = rx.receive_frame(&buffer) {
                tracing::debug!(error = %e, "answer not taken");
            }
        }
        if !sent {
            thread::park_timeout(Duration::from_millis(1));
        }
    }
}

/// How long a receive waits before it looks at the stop flag again.
const RECEIVE_POLL: Duration = Duration::from_millis(2);

/// Frames over a raw AF_PACKET socket on `name`: this thread sends each
/// frame ethercrab has ready, a second one takes the answers. Unlike
/// ethercrab's own `tx_rx_task`, an answer ethercrab refuses (to a frame it
/// already gave up on, say) is that frame's business and does not end the
/// link; only the socket failing does (the interface gone or down).
fn run_interface(name: &str, tx: PduTx<'_>, rx: PduRx<'_>, stop: &AtomicBool) -> Result<(), String> {
    let (sender, receiver) = open_interface(name)?;
    // Either half ending (stop, or its socket failing) ends the other.
    let ended = AtomicBool::new(false);
    // Held from a frame's send until ethercrab marks it sent: an answer
    // quicker than that (a veth pair answers in microseconds) would find its
    // frame not yet sent, and be refused.
    let sending = Mutex::new(());
    let ended_or_stopped = || stop.load(Ordering::Acquire) || ended.load(Ordering::Acquire);
    thread::scope(|scope| {
        let receiving = thread::Builder::new()
            .name(format!("ethercat-rx-{name}"))
            .spawn_scoped(scope, || {
                let result = receive_answers(name, receiver, rx, &sending, &ended_or_stopped);
                ended.store(true, Ordering::Release);
                result
            })
            .map_err(|e| format!("interface {name}: cannot start the receiving thread: {e}"))?;
        let sent = send_frames(name, sender, tx, &sending, &ended_or_stopped);
        ended.store(true, Ordering::Release);
        let received =
            receiving.join().unwrap_or_else(|_| Err(format!("interface {name}: the receiving thread panicked")));
        sent.and(received)
    })
}

type Sender = Box<dyn pnet_datalink::DataLinkSender>;
type Receiver = Box<dyn pnet_datalink::DataLinkReceiver>;

fn open_interface(name: &str) -> Result<(Sender, Receiver), String> {
    let nic = pnet_datalink::interfaces()
        .into_iter()
        .find(|nic| nic.name == name)
        .ok_or_else(|| format!("no network interface {name:?}: `ip link` lists the ones there are"))?;
    let config = pnet_datalink::Config {
        read_timeout: Some(RECEIVE_POLL),
        read_buffer_size: 65536,
        write_buffer_size: 65536,
        // Answers come back to the broadcast address ethercrab sends to;
        // the NIC need not be put in promiscuous mode for them.
        promiscuous: false,
        ..pnet_datalink::Config::default()
    };
    match pnet_datalink::channel(&nic, config) {
        Ok(pnet_datalink::Channel::Ethernet(sender, receiver)) => Ok((sender, receiver)),
        Ok(_) => Err(format!("interface {name} does not carry Ethernet frames")),
        Err(e) => {
            let hint = if e.kind() == std::io::ErrorKind::PermissionDenied {
                " (a raw socket needs CAP_NET_RAW: run as root or `setcap cap_net_raw+ep` the binary)"
            } else {
                ""
            };
            Err(format!("cannot open interface {name}: {e}{hint}"))
        }
    }
}

/// Whether a send that failed this way may succeed if tried again.
fn transient(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::{Interrupted, TimedOut, WouldBlock};
    // ENOBUFS: the NIC's queue is full for a moment.
    matches!(e.kind(), Interrupted | TimedOut | WouldBlock) || e.raw_os_error() == Some(105)
}

fn send_frames(
    name: &str,
    mut sender: Sender,
    mut tx: PduTx<'_>,
    sending: &Mutex<()>,
    ended: &dyn Fn() -> bool,
) -> Result<(), String> {
    let waker = Waker::from(Arc::new(ThreadWaker(thread::current())));
    while !ended() {
        tx.replace_waker(&waker);
        let mut failure = None;
        while let Some(frame) = tx.next_sendable_frame() {
            let _sending = skinware::lock(sending);
            let sent = frame.send_blocking(|bytes| match sender.send_to(bytes, None) {
                Some(Ok(())) => Ok(bytes.len()),
                Some(Err(e)) => {
                    let error = if transient(&e) { None } else { Some(e) };
                    failure = Some(error);
                    Err(ethercrab::error::Error::SendFrame)
                }
                None => {
                    failure = Some(Some(std::io::Error::other("the socket took no frame")));
                    Err(ethercrab::error::Error::SendFrame)
                }
            });
            if sent.is_err() {
                break;
            }
        }
        match failure {
            Some(Some(e)) => return Err(format!("interface {name}: sending a frame failed: {e}")),
            // The frame stays ready to send; ethercrab's timeout bounds the wait.
            Some(None) => thread::sleep(Duration::from_micros(200)),
            None => thread::park_timeout(Duration::from_millis(1)),
        }
    }
    Ok(())
}

fn receive_answers(
    name: &str,
    mut receiver: Receiver,
    mut rx: PduRx<'_>,
    sending: &Mutex<()>,
    ended: &dyn Fn() -> bool,
) -> Result<(), String> {
    let mut refused: u64 = 0;
    while !ended() {
        let bytes = match receiver.next() {
            Ok(bytes) => bytes,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => continue,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            // pnet reports a socket error pending (POLLERR: the interface
            // went down or away) as an unexpected poll event.
            Err(e) => {
                return Err(format!(
                    "interface {name}: receiving failed ({e}): is it down or gone? `ip link show {name}` tells"
                ));
            }
        };
        if bytes.len() < 14 || u16::from_be_bytes([bytes[12], bytes[13]]) != ETHERTYPE_ETHERCAT {
            continue;
        }
        // A refused answer is late (ethercrab gave its frame up: that
        // frame's timeout reports it) or not ours; the link carries on.
        let taken = {
            let _sent = skinware::lock(sending);
            rx.receive_frame(bytes)
        };
        if let Err(e) = taken {
            refused += 1;
            tracing::debug!(interface = name, error = %e, refused, "answer not taken");
        }
    }
    Ok(())
}
