//! Skinware drivers.
//!
//! * [`virtual_skin`]: the paper's virtual skin, a humanoid covered with (by
//!   default) 30,848 taxels, 12 per module, 4-16 modules per patch, split over
//!   L layers, with pressure blobs that press, slide and release, noise, slow
//!   baseline drift, and cable pulls on a schedule or on command.
//!
//! * [`can`]: CAN frames and the codecs of the transports real skins use
//!   (SLCAN, cannelloni, `candump` logs).
//!
//! * [`ethercat`]: tactile segments on EtherCAT, one SubDevice each, through
//!   the ethercrab MainDevice.

#![forbid(unsafe_code)]

pub mod can;
pub mod ethercat;
pub mod virtual_skin;

pub use virtual_skin::{
    CablePull, InvalidConfig, MAX_LAYERS, MAX_SENSORS, PressureField, Rate, ScriptedContact, VirtualBody, VirtualSkin,
    VirtualSkinConfig,
};
