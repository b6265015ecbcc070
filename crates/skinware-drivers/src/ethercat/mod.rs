//! The EtherCAT skin driver: tactile segments, one SubDevice each, brought up
//! to OP by [ethercrab](https://docs.rs/ethercrab) as the MainDevice and
//! cycled at the layer rate.
//!
//! Each segment's process data (the PDO map the SII describes):
//! * inputs (SM3, TxPDO): `u16 counter, u16 status, u16 taxel[N]`;
//! * outputs (SM2, RxPDO): `u16 command, u16 config` (bit 0 of `command`:
//!   acquire; bit 0 of `config`: baseline-subtracted taxels).
//!
//! Each segment is its own ethercrab group, so that a frame lost, a working
//! counter wrong or a state other than OP is the fault of that segment (and
//! of its layer) only; the bus as a whole (a pulled cable) faults every
//! layer. See [`EthercatDriver`].
//!
//! Frames reach the bus through a [`FrameLink`]: a network interface (raw
//! socket; `CAP_NET_RAW`) or, for tests and in-process emulators, anything
//! that implements [`FrameExchange`].

mod bus;
mod config;
mod driver;
mod link;
mod shared;

pub use config::{EthercatConfigError, EthercatDriverConfig, SegmentConfig, expected_working_counter};
pub use driver::{EthercatDriver, EthercatStatus};
pub use link::{FrameExchange, FrameLink};
pub use shared::SegmentStatus;

/// `command` bit: the segment acquires.
pub const COMMAND_ACQUIRE: u16 = 0x0001;
/// `config` bit: the segment reports baseline-subtracted taxels.
pub const CONFIG_BASELINE: u16 = 0x0001;
/// `status` bit: the segment is acquiring.
pub const STATUS_ACQUIRING: u16 = 0x0001;
/// `status` bit: the segment did not understand its command or config.
pub const STATUS_UNKNOWN_COMMAND: u16 = 0x8000;
/// Bytes of a segment's inputs before its taxels (`counter`, `status`).
pub const INPUTS_HEADER_BYTES: usize = 4;
/// Bytes of a segment's outputs (`command`, `config`).
pub const OUTPUTS_BYTES: usize = 4;
/// Most taxels on one segment.
pub const MAX_TAXELS: usize = 2048;
/// Most segments on one driver.
pub const MAX_SEGMENTS: usize = 16;
