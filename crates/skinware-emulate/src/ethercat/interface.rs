//! A segment on a network interface: it answers the EtherCAT frames that
//! arrive there (from a MainDevice on the other end of a veth pair, or of a
//! cable), as the ring would. Needs `CAP_NET_RAW` (or a network namespace
//! of one's own, `unshare -rn`).

use std::sync::{Mutex, mpsc};
use std::time::{Duration, Instant};

use super::segment::{Fate, Segment};
use super::wire::{ETHERNET_HEADER_LEN, ETHERTYPE_ETHERCAT};

/// Why the segment cannot serve an interface.
#[derive(Debug, thiserror::Error)]
pub enum InterfaceError {
    /// No interface of that name.
    #[error("no network interface {name:?} (ip link shows the ones there are)")]
    NoSuchInterface {
        /// The name asked for.
        name: String,
    },
    /// The raw socket would not open or failed.
    #[error("interface {name}: {source} (a raw socket needs CAP_NET_RAW, or a network namespace of one's own)")]
    Socket {
        /// The interface.
        name: String,
        /// What failed.
        #[source]
        source: std::io::Error,
    },
    /// The link layer is not Ethernet.
    #[error("interface {name} does not carry Ethernet frames")]
    NotEthernet {
        /// The interface.
        name: String,
    },
}

/// Sees each frame as it came in and, if answered, as it went back.
pub type FrameObserver<'a> = dyn FnMut(&[u8], Option<&[u8]>) + 'a;

/// What the segment did on the interface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InterfaceStats {
    /// EtherCAT frames from a MainDevice it took.
    pub frames: u64,
    /// Answers it sent (late ones included).
    pub answered: u64,
}

/// Answers EtherCAT frames arriving on `interface` with `segment` until
/// `stop()` says so (checked at least every 50 ms). `on_frame` sees each
/// frame as it came and, if it was answered, as it went back (to record a
/// capture). The segment's own fault switches decide which frames are lost.
pub fn serve_interface(
    segment: &Mutex<Segment>,
    interface: &str,
    stop: &dyn Fn() -> bool,
    mut on_frame: Option<&mut FrameObserver<'_>>,
) -> Result<InterfaceStats, InterfaceError> {
    let socket_error = |source| InterfaceError::Socket { name: interface.to_string(), source };
    let mut stats = InterfaceStats::default();
    let mut frame = Vec::with_capacity(1600);
    let mut opened_once = false;
    while !stop() {
        let nic = pnet_datalink::interfaces()
            .into_iter()
            .find(|nic| nic.name == interface)
            .ok_or_else(|| InterfaceError::NoSuchInterface { name: interface.to_string() })?;
        let config = pnet_datalink::Config {
            read_timeout: Some(Duration::from_millis(50)),
            read_buffer_size: 65536,
            write_buffer_size: 65536,
            ..pnet_datalink::Config::default()
        };
        let (tx, mut rx) = match pnet_datalink::channel(&nic, config) {
            Ok(pnet_datalink::Channel::Ethernet(tx, rx)) => (tx, rx),
            Ok(_) => return Err(InterfaceError::NotEthernet { name: interface.to_string() }),
            // Opening fails outright (no permission): say so at once; later,
            // the link may just be down for a while.
            Err(e) if !opened_once => return Err(socket_error(e)),
            Err(_) => {
                std::thread::sleep(Duration::from_millis(10));
                continue;
            }
        };
        opened_once = true;
        let tx = Mutex::new(tx);
        // Late answers go from a thread of their own, so that holding one
        // back holds up no other frame.
        let (late_answers, held_back) = mpsc::channel::<(Instant, Vec<u8>)>();
        std::thread::scope(|scope| {
            scope.spawn(|| {
                for (due, answer) in held_back {
                    std::thread::sleep(due.saturating_duration_since(Instant::now()));
                    let _ = skinware::lock(&tx).send_to(&answer, None);
                }
            });
            while !stop() {
                let received = match rx.next() {
                    Ok(bytes) => bytes,
                    Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => {
                        continue;
                    }
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                    Err(_) => {
                        // The link went down (the socket reports an error it
                        // never clears): a segment keeps its power and waits,
                        // then opens the interface again.
                        std::thread::sleep(Duration::from_millis(10));
                        break;
                    }
                };
                if received.len() < ETHERNET_HEADER_LEN
                    || u16::from_be_bytes([received[12], received[13]]) != ETHERTYPE_ETHERCAT
                    // An answer (this segment's own, which the socket sees going
                    // out, or another ring's): the first ESC marked its source.
                    || received[6] & 0x02 != 0
                {
                    continue;
                }
                stats.frames += 1;
                frame.clear();
                frame.extend_from_slice(received);
                let fate = skinware::lock(segment).process(&mut frame);
                let answered = matches!(fate, Ok(Fate::Returned | Fate::Late(_)));
                if let Some(on_frame) = on_frame.as_mut() {
                    // `frame` was changed in place; `received` is still the frame as it came.
                    on_frame(received, answered.then_some(frame.as_slice()));
                }
                match fate {
                    Ok(Fate::Returned) => {
                        // An answer that cannot go is lost with the link, as on a cable.
                        if let Some(Ok(())) = skinware::lock(&tx).send_to(&frame, None) {
                            stats.answered += 1;
                        }
                    }
                    Ok(Fate::Late(by)) => {
                        stats.answered += 1;
                        let _ = late_answers.send((Instant::now() + by, frame.clone()));
                    }
                    _ => {}
                }
            }
            drop(late_answers);
        });
    }
    Ok(stats)
}
