//! Simulated EtherCAT tactile segments, on raw frames.
//!
//! A [`Segment`] is a line of [`TactileSubDevice`]s, each an ET1100-class
//! ESC model (registers, SII EEPROM, FMMUs, SyncManagers, AL state machine)
//! with the firmware of a tactile skin segment behind it. It takes whole
//! Ethernet frames (EtherType 0x88A4) as bytes and answers them in place, as
//! the ring would, so the same model serves a MainDevice in the same process
//! (ethercrab's `PduTx`/`PduRx`) and, later, one on a network interface.
//!
//! Process data of each segment ([`tactile`]): inputs on SM3,
//! `u16 counter, u16 status, u16 taxel[N]`; outputs on SM2,
//! `u16 command, u16 config`. Taxel values come from a [`TaxelSource`].
//!
//! Fault switches: [`SegmentFaults`] (lose, or answer late, every Nth
//! process-data frame; link down) and
//! [`SubDeviceFaults`] (leave OP after K cycles or S seconds, a wrong
//! working counter).
//!
//! ```
//! use skinware_emulate::ethercat::{Command, Fate, FrameBuilder, Segment, TactileConfig, TactileSubDevice, datagrams};
//!
//! let segment = |sample: u64, taxels: &mut [u16]| taxels.fill(sample as u16);
//! let mut ring = Segment::new(vec![TactileSubDevice::new(TactileConfig::new(12, 1), segment).unwrap()]);
//! // Count the SubDevices, as a MainDevice does first: a broadcast read.
//! let mut frame = FrameBuilder::new().datagram(Command::Brd, 0, 0, &[0]).build();
//! assert_eq!(ring.process(&mut frame).unwrap(), Fate::Returned);
//! assert_eq!(datagrams(&frame).unwrap()[0].working_counter, 1);
//! ```

mod emulation;
mod esc;
mod interface;
pub mod pcapng;
mod segment;
mod sii;
pub mod tactile;
mod wire;

pub use emulation::{EmulationError, EmulationFaults, EthercatEmulation};
pub use esc::{AlState, ConfigError, LeaveOp, SubDeviceFaults, TactileConfig, TactileSubDevice, al_status_code};
pub use interface::{FrameObserver, InterfaceError, InterfaceStats, serve_interface};
pub use segment::{Fate, Segment, SegmentFaults, SegmentStats};
pub use sii::{Identity, RXPDO_INDEX, TAXELS_PER_PDO, TXPDO_HEADER_INDEX, TXPDO_TAXELS_INDEX, checksum, tactile_image};
pub use tactile::TaxelSource;
pub use wire::{
    Command, DATAGRAM_HEADER_LEN, Datagram, DatagramContents, ETHERCAT_HEADER_LEN, ETHERNET_HEADER_LEN,
    ETHERTYPE_ETHERCAT, FrameBuilder, FrameError, FrameLayout, WORKING_COUNTER_LEN, check_frame, datagrams,
};
