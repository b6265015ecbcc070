//! `[[emulator]]` tables: software skin boards that `skin run` starts before
//! the drivers, so that a configuration can run a real driver path without
//! hardware.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Result, bail};
use serde::Deserialize;
use skinware_emulate::ethercat::{EmulationFaults, EthercatEmulation};
use skinware_emulate::{MtbEmulation, MtbFaults, Transport};

use super::process::RestartConfig;

/// The kinds of emulated boards.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum EmulatorKind {
    /// iCub MTB boards.
    IcubMtb,
    /// EtherCAT tactile segments on a network interface.
    Ethercat,
}

/// What `skin emulator` runs for a table.
pub enum Emulation {
    /// MTB boards.
    Mtb(MtbEmulation),
    /// EtherCAT segments.
    Ethercat(EthercatEmulation),
}

/// One `[[emulator]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct EmulatorConfig {
    /// Unique among the emulators.
    pub name: String,
    /// Which boards.
    pub kind: EmulatorKind,
    /// MTB: boards on the bus, addresses 1..=boards (default 4).
    pub boards: Option<u8>,
    /// MTB: triangles per board (default 16).
    pub triangles: Option<u8>,
    /// MTB: streaming rate until the host configures a period (default 50).
    pub rate_hz: Option<f64>,
    /// EtherCAT: the network interface to answer on.
    pub interface: Option<String>,
    /// EtherCAT: segments (SubDevices) in the line (default 1).
    pub segments: Option<u16>,
    /// EtherCAT: taxels per segment (default 708).
    pub taxels: Option<u16>,
    /// EtherCAT fault: lose every Nth process-data frame (never the bring-up's).
    pub drop_every: Option<std::num::NonZeroU64>,
    /// EtherCAT fault: answer every Nth process-data frame `late_by_ms` late.
    pub late_every: Option<std::num::NonZeroU64>,
    /// EtherCAT fault: how late those answers are, in milliseconds.
    pub late_by_ms: Option<u64>,
    /// EtherCAT: the segment the per-segment faults hit (default 0).
    pub fault_segment: Option<usize>,
    /// EtherCAT fault: that segment leaves the process data's working counter alone.
    #[serde(default)]
    pub wrong_wkc: bool,
    /// EtherCAT fault: that segment drops out of OP this many seconds after entering it.
    pub leave_op_after_s: Option<f64>,
    /// EtherCAT fault: no segment answers this many seconds after the start (a pulled cable).
    pub link_down_after_s: Option<f64>,
    /// EtherCAT: a pcapng capture of every frame taken and answer sent.
    pub capture: Option<PathBuf>,
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

const DEFAULT_BOARDS: u8 = 4;
const DEFAULT_TRIANGLES: u8 = 16;
const DEFAULT_RATE_HZ: f64 = 50.0;
const DEFAULT_SEGMENTS: u16 = 1;
const DEFAULT_TAXELS: u16 = 708;

fn default_seed() -> u64 {
    7
}

fn default_priority() -> u8 {
    70
}

/// Refuses a duration that is not 0 or more seconds.
fn check_seconds(key: &str, value: Option<f64>) -> Result<()> {
    match value {
        Some(s) if !(s.is_finite() && s >= 0.0) => bail!("`{key}` must be 0 or more seconds"),
        _ => Ok(()),
    }
}

impl EmulatorConfig {
    /// Refuses values no bus of its kind has, settings of the other kind,
    /// and an MTB table without exactly one link.
    pub(super) fn check(&self) -> Result<()> {
        skinware::shm::validate_name("emulator", &self.name)?;
        if self.fifo_priority > 99 {
            bail!("`fifo_priority` is 0 (normal scheduler) or 1 to 99");
        }
        match self.kind {
            EmulatorKind::IcubMtb => self.check_mtb()?,
            EmulatorKind::Ethercat => self.check_ethercat()?,
        }
        self.restart.check()
    }

    /// The checks of an `icub-mtb` table.
    fn check_mtb(&self) -> Result<()> {
        let ethercat_keys = [
            ("interface", self.interface.is_some()),
            ("segments", self.segments.is_some()),
            ("taxels", self.taxels.is_some()),
            ("drop_every", self.drop_every.is_some()),
            ("late_every", self.late_every.is_some()),
            ("late_by_ms", self.late_by_ms.is_some()),
            ("fault_segment", self.fault_segment.is_some()),
            ("wrong_wkc", self.wrong_wkc),
            ("leave_op_after_s", self.leave_op_after_s.is_some()),
            ("link_down_after_s", self.link_down_after_s.is_some()),
            ("capture", self.capture.is_some()),
        ];
        if let Some((key, _)) = ethercat_keys.iter().find(|(_, given)| *given) {
            bail!("`{key}` is a setting of kind = \"ethercat\", not of \"icub-mtb\"");
        }
        let boards = self.boards.unwrap_or(DEFAULT_BOARDS);
        let triangles = self.triangles.unwrap_or(DEFAULT_TRIANGLES);
        if !(1..=15).contains(&boards) || !(1..=16).contains(&triangles) {
            bail!("`boards` must be 1 to 15 and `triangles` 1 to 16 (an MTB bus addresses 15 boards of 16 triangles)");
        }
        let rate_hz = self.rate_hz.unwrap_or(DEFAULT_RATE_HZ);
        if !(rate_hz.is_finite() && rate_hz > 0.0 && rate_hz <= 1000.0) {
            bail!("`rate_hz` {rate_hz} must be above 0 and at most 1000");
        }
        if self.error_nibble.is_some_and(|e| e > 15) {
            bail!("`error_nibble` is 0 to 15");
        }
        check_seconds("silence_after_s", self.silence_after_s)?;
        match (&self.link, &self.cannelloni, &self.peer) {
            (Some(_), None, None) | (None, Some(_), Some(_)) => Ok(()),
            _ => bail!(
                "give either `link` (SLCAN on a pseudo-terminal, e.g. \"/tmp/skinware-bus0\") or both `cannelloni` and `peer` (UDP addresses)"
            ),
        }
    }

    /// The checks of an `ethercat` table.
    fn check_ethercat(&self) -> Result<()> {
        let mtb_keys = [
            ("boards", self.boards.is_some()),
            ("triangles", self.triangles.is_some()),
            ("rate_hz", self.rate_hz.is_some()),
            ("link", self.link.is_some()),
            ("cannelloni", self.cannelloni.is_some()),
            ("peer", self.peer.is_some()),
            ("candump", self.candump.is_some()),
            ("drop_tails", self.drop_tails),
            ("error_nibble", self.error_nibble.is_some()),
            ("silence_after_s", self.silence_after_s.is_some()),
        ];
        if let Some((key, _)) = mtb_keys.iter().find(|(_, given)| *given) {
            bail!("`{key}` is a setting of kind = \"icub-mtb\", not of \"ethercat\"");
        }
        if self.interface.as_deref().is_none_or(str::is_empty) {
            bail!("kind = \"ethercat\" needs `interface`, the network interface to answer on (one end of a veth pair)");
        }
        let segments = self.segments.unwrap_or(DEFAULT_SEGMENTS);
        let taxels = self.taxels.unwrap_or(DEFAULT_TAXELS);
        if !(1..=16).contains(&segments) || !(1..=2048).contains(&taxels) {
            bail!("`segments` must be 1 to 16 and `taxels` 1 to 2048");
        }
        if self.fault_segment.is_some_and(|k| k >= usize::from(segments)) {
            bail!("`fault_segment` must be one of the {segments} segments (0 to {})", segments - 1);
        }
        check_seconds("leave_op_after_s", self.leave_op_after_s)?;
        check_seconds("link_down_after_s", self.link_down_after_s)?;
        if self.late_every.is_some() != self.late_by_ms.is_some() {
            bail!(
                "`late_every` and `late_by_ms` go together: every Nth process-data frame is answered that many milliseconds late"
            );
        }
        Ok(())
    }

    /// What `skin emulator` runs for this table (checked by [`Self::check`]).
    pub fn emulation(&self) -> Emulation {
        let fifo_priority = (self.fifo_priority > 0).then_some(self.fifo_priority);
        match self.kind {
            EmulatorKind::IcubMtb => {
                let transport = match (&self.cannelloni, &self.peer) {
                    (Some(local), Some(peer)) => Transport::Cannelloni { local: local.clone(), peer: peer.clone() },
                    _ => Transport::Slcan { link: self.link.clone() },
                };
                Emulation::Mtb(MtbEmulation {
                    boards: self.boards.unwrap_or(DEFAULT_BOARDS),
                    triangles: self.triangles.unwrap_or(DEFAULT_TRIANGLES),
                    rate_hz: self.rate_hz.unwrap_or(DEFAULT_RATE_HZ),
                    transport,
                    candump: self.candump.clone(),
                    faults: MtbFaults {
                        drop_tails: self.drop_tails,
                        error_nibble: self.error_nibble,
                        silence_after: self.silence_after_s.map(Duration::from_secs_f64),
                    },
                    seed: self.seed,
                    fifo_priority,
                })
            }
            EmulatorKind::Ethercat => Emulation::Ethercat(EthercatEmulation {
                segments: usize::from(self.segments.unwrap_or(DEFAULT_SEGMENTS)),
                taxels: usize::from(self.taxels.unwrap_or(DEFAULT_TAXELS)),
                interface: self.interface.clone().unwrap_or_default(),
                seed: self.seed,
                faults: EmulationFaults {
                    drop_every_nth_frame: self.drop_every,
                    late_every_nth_frame: self.late_every,
                    late_by: Duration::from_millis(self.late_by_ms.unwrap_or(0)),
                    segment: self.fault_segment.unwrap_or(0),
                    wrong_working_counter: self.wrong_wkc,
                    leave_op_after: self.leave_op_after_s.map(Duration::from_secs_f64),
                    link_down_after: self.link_down_after_s.map(Duration::from_secs_f64),
                },
                fifo_priority,
                capture: self.capture.clone(),
            }),
        }
    }
}
