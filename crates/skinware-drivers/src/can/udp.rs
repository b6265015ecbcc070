//! cannelloni: CAN frames in UDP datagrams, to and from one peer.

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use super::CanFrame;
use super::bus::{BusError, BusUrl, CanBus};
use super::cannelloni;

/// A cannelloni tunnel end (`cannelloni://LOCAL:PORT?peer=REMOTE:PORT`).
pub struct CannelloniBus {
    socket: UdpSocket,
    peer: SocketAddr,
    url: String,
    received: VecDeque<CanFrame>,
    sequence: u8,
    last_received_sequence: Option<u8>,
    lost_datagrams: u64,
    rejected_datagrams: u64,
    buffer: Vec<u8>,
}

impl CannelloniBus {
    pub(crate) fn open(url: &BusUrl<'_>) -> Result<CannelloniBus, BusError> {
        url.only(&["peer"])?;
        let bad = |problem: String| BusError::BadUrl { url: url.url.to_owned(), problem };
        let local: SocketAddr =
            url.path.parse().map_err(|_| bad(format!("{:?} is not an address:port to listen on", url.path)))?;
        let peer: String = url.option("peer", String::new())?;
        if peer.is_empty() {
            return Err(bad("it needs ?peer=ADDRESS:PORT, where the other end listens".into()));
        }
        let peer: SocketAddr = peer.parse().map_err(|_| bad(format!("peer {peer:?} is not an address:port")))?;
        let socket = UdpSocket::bind(local).map_err(|source| BusError::Open {
            url: url.url.to_owned(),
            hint: format!("is another program bound to {local}? pick another local port"),
            source,
        })?;
        Ok(CannelloniBus {
            socket,
            peer,
            url: url.url.to_owned(),
            received: VecDeque::new(),
            sequence: 0,
            last_received_sequence: None,
            lost_datagrams: 0,
            rejected_datagrams: 0,
            buffer: vec![0; 65_536],
        })
    }

    /// The local address (useful when the URL asked for port 0).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.socket.local_addr().ok()
    }

    /// Datagrams the sequence numbers say were lost, and datagrams refused
    /// as not cannelloni, since opening.
    pub fn losses(&self) -> (u64, u64) {
        (self.lost_datagrams, self.rejected_datagrams)
    }
}

impl CanBus for CannelloniBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        let mut datagram = Vec::with_capacity(32);
        cannelloni::encode(self.sequence, std::slice::from_ref(frame), &mut datagram);
        self.sequence = self.sequence.wrapping_add(1);
        self.socket
            .send_to(&datagram, self.peer)
            .map(|_| ())
            .map_err(|source| BusError::Lost { url: self.url.clone(), source })
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(frame) = self.received.pop_front() {
                return Ok(Some(frame));
            }
            // At least one read, even with no time to wait.
            let left = deadline.saturating_duration_since(Instant::now()).max(Duration::from_micros(100));
            let _ = self.socket.set_read_timeout(Some(left));
            let waited_out = || Instant::now() >= deadline;
            let (len, from) = match self.socket.recv_from(&mut self.buffer) {
                Ok(received) => received,
                // A signal (EINTR) is no loss of the link either.
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
                    ) =>
                {
                    if waited_out() {
                        return Ok(None);
                    }
                    continue;
                }
                // The peer's port was closed (ICMP unreachable after a send): it is not there yet.
                Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                    if waited_out() {
                        return Ok(None);
                    }
                    continue;
                }
                Err(source) => return Err(BusError::Lost { url: self.url.clone(), source }),
            };
            if from.ip() != self.peer.ip() {
                if waited_out() && self.received.is_empty() {
                    return Ok(None);
                }
                continue;
            }
            match cannelloni::decode(&self.buffer[..len]) {
                Ok(packet) => {
                    if let Some(last) = self.last_received_sequence {
                        self.lost_datagrams += u64::from(packet.sequence.wrapping_sub(last).wrapping_sub(1));
                    }
                    self.last_received_sequence = Some(packet.sequence);
                    self.received.extend(packet.frames);
                }
                Err(e) => {
                    self.rejected_datagrams += 1;
                    tracing::debug!(url = %self.url, error = %e, "datagram refused");
                }
            }
            if waited_out() && self.received.is_empty() {
                return Ok(None);
            }
        }
    }

    fn url(&self) -> &str {
        &self.url
    }
}
