//! `[[emulator]]` tables: software skin boards that `skin run` starts before
//! the drivers, so that a configuration can run a real driver path without
//! hardware.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Result, bail};
use serde::Deserialize;
use skinware_emulate::{MtbEmulation, MtbFaults, Transport};

use super::process::RestartConfig;

/// The kinds of emulated boards.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum EmulatorKind {
    /// iCub MTB boards.
    IcubMtb,
}

/// One `[[emulator]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Unique among the emulators.
    pub name: String,
    /// Which boards.
    pub kind: EmulatorKind,
    /// Boards on the bus, addresses 1..=boards.
    #[serde(default = "default_boards")]
    pub boards: u8,
    /// Triangles per board.
    #[serde(default = "default_triangles")]
    pub triangles: u8,
    /// Streaming rate until the host configures a period.
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    /// SLCAN: the symbolic link to its pseudo-terminal that drivers open.
    pub link: Option<PathBuf>,
    /// cannelloni: the emulator's own address ...
    pub cannelloni: Option<String>,
    /// ... and the host's.
    pub peer: Option<String>,
    /// A `candump -l` log of every frame sent.
    pub candump: Option<PathBuf>,
    /// Fault: never send a triangle's tail frame.
    #[serde(default)]
    pub drop_tails: bool,
    /// Fault: this error code in every tail.
    pub error_nibble: Option<u8>,
    /// Fault: fall silent this many seconds after streaming starts.
    pub silence_after_s: Option<f64>,
    /// Seed of the virtual body's contacts.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// SCHED_FIFO priority of the boards' thread (0: the normal scheduler).
    #[serde(default = "default_priority")]
    pub fifo_priority: u8,
    /// Restart policy of its process.
    #[serde(default)]
    pub restart: RestartConfig,
}

fn default_boards() -> u8 {
    4
}

fn default_triangles() -> u8 {
    16
}

fn default_rate() -> f64 {
    50.0
}

fn default_seed() -> u64 {
    7
}

fn default_priority() -> u8 {
    70
}

impl EmulatorConfig {
    /// Refuses values no MTB bus has, and a table without exactly one link.
    pub(super) fn check(&self) -> Result<()> {
        skinware::shm::validate_name("emulator", &self.name)?;
        if !(1..=15).contains(&self.boards) || !(1..=16).contains(&self.triangles) {
            bail!("`boards` must be 1 to 15 and `triangles` 1 to 16 (an MTB bus addresses 15 boards of 16 triangles)");
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 1000.0) {
            bail!("`rate_hz` {} must be above 0 and at most 1000", self.rate_hz);
        }
        if self.fifo_priority > 99 {
            bail!("`fifo_priority` is 0 (normal scheduler) or 1 to 99");
        }
        if self.error_nibble.is_some_and(|e| e > 15) {
            bail!("`error_nibble` is 0 to 15");
        }
        if self.silence_after_s.is_some_and(|s| !(s.is_finite() && s >= 0.0)) {
            bail!("`silence_after_s` must be 0 or more seconds");
        }
        match (&self.link, &self.cannelloni, &self.peer) {
            (Some(_), None, None) | (None, Some(_), Some(_)) => {}
            _ => bail!(
                "give either `link` (SLCAN on a pseudo-terminal, e.g. \"/tmp/skinware-bus0\") or both `cannelloni` and `peer` (UDP addresses)"
            ),
        }
        self.restart.check()
    }

    /// What `skin emulator` runs for this table.
    pub fn emulation(&self) -> MtbEmulation {
        let EmulatorKind::IcubMtb = self.kind;
        let transport = match (&self.cannelloni, &self.peer) {
            (Some(local), Some(peer)) => Transport::Cannelloni { local: local.clone(), peer: peer.clone() },
            _ => Transport::Slcan { link: self.link.clone() },
        };
        MtbEmulation {
            boards: self.boards,
            triangles: self.triangles,
            rate_hz: self.rate_hz,
            transport,
            candump: self.candump.clone(),
            faults: MtbFaults {
                drop_tails: self.drop_tails,
                error_nibble: self.error_nibble,
                silence_after: self.silence_after_s.map(Duration::from_secs_f64),
            },
            seed: self.seed,
            fifo_priority: (self.fifo_priority > 0).then_some(self.fifo_priority),
        }
    }
}
