//! SocketCAN, through the `socketcan` crate: what real robots use. This
//! machine's kernel has no CAN support, so here it is compiled and checked,
//! and opening it gives a clear error.

use std::time::Duration;

use embedded_can::Frame as _;
use socketcan::{CanSocket, Socket};

use super::CanFrame;
use super::bus::{BusError, BusUrl, CanBus};

/// A SocketCAN interface (`socketcan://can0`).
pub struct SocketCanBus {
    socket: CanSocket,
    url: String,
}

impl SocketCanBus {
    pub(crate) fn open(url: &BusUrl<'_>) -> Result<SocketCanBus, BusError> {
        url.only(&[])?;
        let socket = CanSocket::open(url.path).map_err(|source| {
            let no_can = source.raw_os_error() == Some(EAFNOSUPPORT) || !std::path::Path::new("/proc/net/can").exists();
            let hint = if no_can {
                "this kernel has no CAN support (no AF_CAN): load the `can` and `can_raw` modules, or use an SLCAN adapter".to_owned()
            } else {
                format!(
                    "is {} up? (`ip link set {} up type can bitrate 1000000`)",
                    url.path, url.path
                )
            };
            BusError::Open { url: url.url.to_owned(), source, hint }
        })?;
        Ok(SocketCanBus { socket, url: url.url.to_owned() })
    }
}

/// EAFNOSUPPORT on Linux: what `socket(AF_CAN)` gives without the modules.
const EAFNOSUPPORT: i32 = 97;

impl CanBus for SocketCanBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        let lost = |source| BusError::Lost { url: self.url.clone(), source };
        let kernel_frame = if frame.is_remote() {
            socketcan::CanFrame::new_remote(frame.id(), frame.dlc())
        } else {
            socketcan::CanFrame::new(frame.id(), frame.bytes())
        };
        let kernel_frame = kernel_frame.ok_or_else(|| lost(std::io::ErrorKind::InvalidInput.into()))?;
        self.socket.write_frame(&kernel_frame).map_err(lost)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        match self.socket.read_frame_timeout(timeout) {
            Ok(frame) => Ok(match frame {
                socketcan::CanFrame::Data(data) => CanFrame::data(data.id(), data.data()),
                socketcan::CanFrame::Remote(remote) => CanFrame::remote(remote.id(), remote.dlc()),
                // Bus errors are the controller's business; the protocol
                // layer sees their effect (missing frames).
                socketcan::CanFrame::Error(_) => None,
            }),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut || e.kind() == std::io::ErrorKind::WouldBlock => {
                Ok(None)
            }
            Err(source) => Err(BusError::Lost { url: self.url.clone(), source }),
        }
    }

    fn url(&self) -> &str {
        &self.url
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Needs a kernel with CAN and a `vcan0`; says why it skips otherwise.
    #[test]
    #[cfg_attr(
        skip_no_vcan0,
        ignore = "needs a vcan0 interface: a kernel with AF_CAN (modprobe vcan; ip link add vcan0 type vcan; ip link set up vcan0)"
    )]
    fn opens_vcan0_where_the_kernel_has_can() {
        match crate::can::open("socketcan://vcan0") {
            Ok(bus) => assert_eq!(bus.url(), "socketcan://vcan0"),
            Err(BusError::Open { source, hint, .. }) => {
                println!("SKIPPED: socketcan://vcan0 cannot be opened here ({source}): {hint}");
            }
            Err(other) => panic!("{other}"),
        }
    }
}
