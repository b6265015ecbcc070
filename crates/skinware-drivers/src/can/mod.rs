//! Real skins on a CAN bus: the frame vocabulary and the codecs of the
//! transports labs plug in.
//!
//! * [`CanFrame`]: one classic frame, an `embedded_can::Frame`;
//! * [`CanBus`]: a source and sink of frames, opened from a URL by [`open`]
//!   (SocketCAN, SLCAN, cannelloni, `candump` replay);
//! * [`slcan`]: the Lawicel ASCII protocol of USB-serial adapters;
//! * [`cannelloni`]: CAN frames in UDP datagrams;
//! * [`candump`]: the `candump -l` log format, to record real traffic once
//!   and replay it;
//! * the skins' own protocols, each a pure decoder from frames to taxel
//!   values plus what the host must send: [`icub_mtb`] (iCub's MTB boards),
//!   [`cyskin`] (CySkin CPM patches) and [`xela`] (XELA uSkin, 3 axes).
//!
//! Every decoder here takes bytes from a device, a network or a file, so each
//! is total: any input gives frames or a typed error (property-tested), and
//! nothing it allocates is sized by a number in the input.

mod bus;
pub mod candump;
pub mod cannelloni;
pub mod cyskin;
pub mod driver;
pub(crate) mod frame;
pub mod icub_mtb;
mod kernel;
mod replay;
mod serial;
pub mod slcan;
mod udp;
pub mod xela;

pub use bus::{BusError, CanBus};
pub use frame::CanFrame;
pub use kernel::SocketCanBus;
pub use replay::CandumpReplay;
pub use serial::SlcanBus;
pub use udp::CannelloniBus;

// Here, above the bus trait and the transports: `open` chooses a transport,
// and each transport implements the trait.
/// Opens the bus a URL names.
pub fn open(url: &str) -> Result<Box<dyn CanBus>, BusError> {
    let parsed = bus::BusUrl::parse(url)?;
    match parsed.scheme {
        "socketcan" => Ok(Box::new(kernel::SocketCanBus::open(&parsed)?)),
        "slcan" => Ok(Box::new(serial::SlcanBus::open(&parsed)?)),
        "cannelloni" => Ok(Box::new(udp::CannelloniBus::open(&parsed)?)),
        "candump" => Ok(Box::new(replay::CandumpReplay::open(&parsed)?)),
        other => Err(BusError::BadUrl { url: url.to_owned(), problem: format!("unknown transport {other:?}") }),
    }
}
