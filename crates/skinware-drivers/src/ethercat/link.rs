//! How ethercrab's frames reach the bus: a network interface through its
//! raw-socket task, or any in-process [`FrameExchange`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Wake, Waker};
use std::thread::{self, Thread};
use std::time::Duration;

use ethercrab::{PduRx, PduTx};

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
/// ethercrab's task ended): the session must start again.
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
            let returned = bus.lock().unwrap_or_else(|p| p.into_inner()).exchange(&mut buffer);
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

fn run_interface(name: &str, tx: PduTx<'_>, rx: PduRx<'_>, stop: &AtomicBool) -> Result<(), String> {
    let task = ethercrab::std::tx_rx_task(name, tx, rx).map_err(|e| {
        let hint = if e.kind() == std::io::ErrorKind::PermissionDenied {
            " (a raw socket needs CAP_NET_RAW: run as root or `setcap cap_net_raw+ep` the binary)"
        } else {
            ""
        };
        format!("cannot open interface {name}: {e}{hint}")
    })?;
    let frames = async {
        // ethercrab's task ends on the first frame it cannot take (an
        // answer to a frame it already gave up on, for one).
        match task.await {
            Ok(_) => Ok(()),
            Err(e) => Err(format!("interface {name}: frame I/O ended: {e}")),
        }
    };
    let stopped = async {
        while !stop.load(Ordering::Acquire) {
            async_io::Timer::after(Duration::from_millis(10)).await;
        }
        Ok(())
    };
    async_io::block_on(futures_lite::future::or(frames, stopped))
}
