//! Software skin boards that users and tests run in place of hardware. They
//! speak the real protocol on the device side, obey the host's configuration
//! and start/stop commands, and their taxels feel the virtual body's moving
//! contacts ([`skinware_drivers::PressureField`]).
//!
//! * [`SlcanDevice`]: the device end of an SLCAN adapter, on a
//!   pseudo-terminal whose other end the host opens as `slcan:///dev/pts/N`;
//! * [`MtbBoards`]: iCub MTB boards, with fault switches (drop tails, an
//!   error nibble, silence after a while);
//! * [`run_mtb`]: boards on a link until stopped, optionally logging what
//!   they sent in `candump -l` format;
//! * [`MtbEmulation`]: all of it as `skin emulate` runs it;
//! * [`ethercat`]: EtherCAT tactile segments (an ESC model per segment) that
//!   answer raw EtherCAT frames, with fault switches.

#![forbid(unsafe_code)]

mod emulation;
pub mod ethercat;
mod mtb;
mod slcan_device;

pub use emulation::{MtbEmulation, Transport};

pub use mtb::{MtbBoards, MtbFaults, Touch, contacts, raw_value, run_mtb};
pub use slcan_device::SlcanDevice;

use skinware_drivers::can::CanFrame;

/// The device side of a link to a host: frames the host sent, and frames to it.
pub trait DeviceLink: Send {
    /// The host's frames that arrive within `timeout`.
    fn poll(&mut self, timeout: std::time::Duration) -> std::io::Result<Vec<CanFrame>>;
    /// Sends a frame to the host; dropped if the host is not there or not reading.
    fn send(&mut self, frame: &CanFrame) -> std::io::Result<()>;
}

impl DeviceLink for Box<dyn skinware_drivers::can::CanBus> {
    fn poll(&mut self, timeout: std::time::Duration) -> std::io::Result<Vec<CanFrame>> {
        let deadline = std::time::Instant::now() + timeout;
        let mut frames = Vec::new();
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            match self.receive(left) {
                Ok(Some(frame)) => frames.push(frame),
                Ok(None) => return Ok(frames),
                Err(e) => return Err(std::io::Error::other(e.to_string())),
            }
            if left.is_zero() {
                return Ok(frames);
            }
        }
    }

    fn send(&mut self, frame: &CanFrame) -> std::io::Result<()> {
        skinware_drivers::can::CanBus::send(self.as_mut(), frame).map_err(|e| std::io::Error::other(e.to_string()))
    }
}
