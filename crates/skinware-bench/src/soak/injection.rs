//! What a fault is made of: its kind, its record as it is injected, and
//! the soak's steps that begin and end one and pick its driver. The faults
//! ([`super::faults`]) and the squats ([`super::squats`]) are built from
//! these.

use std::time::{Duration, Instant};

use anyhow::{Result, bail};

use super::Soak;
use super::report::FaultRecord;
use crate::procs;

/// A kind of fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaultKind {
    /// SIGKILL a driver process (the supervisor restarts it).
    DriverKill,
    /// SIGSTOP a driver process for 0.2-2.5 s, then SIGCONT (a stop over
    /// 1 s is a hang to the supervisor, which kills it).
    DriverStop,
    /// SIGKILL a verifying reader (the soak starts another).
    ReaderKill,
    /// SIGSTOP a verifying reader for 0.3-3 s, then SIGCONT.
    ReaderStop,
    /// Pull a layer's cable for 0.5-3 s (`skin pull`'s control file).
    CablePull,
    /// Ten writers of an unrelated skin, stopped with SIGSTOP; 0.5 s later
    /// a driver is SIGKILLed beside them. They are resumed and stopped once
    /// every layer runs again.
    ForeignStoppedWriters,
    /// Unlink a live layer's socket and name lock: its writer must put them back.
    UnlinkLiveName,
    /// A regular file at the socket and lock paths of a channel of a skin
    /// that does not run, for 1-3 s.
    SquatFile,
    /// FIFOs there, for 1-3 s (opening one may block).
    SquatFifo,
    /// Symlinks there, to paths that do not exist, for 1-3 s (nothing may
    /// create their targets).
    SquatSymlink,
    /// Two busy threads per CPU at the normal priority for 2-5 s.
    CpuHog,
    /// A stale socket and a FIFO name lock at a channel of a skin that does
    /// not run (whoever lists the skins may block opening that FIFO); 0.5 s
    /// later a driver is SIGKILLed beside them. They are removed once every
    /// layer runs again, or 5 s after the kill.
    FifoSquatDriverKill,
}

/// Every kind: each round of faults is a shuffle of them all.
pub const KINDS: [FaultKind; 12] = [
    FaultKind::DriverKill,
    FaultKind::DriverStop,
    FaultKind::ReaderKill,
    FaultKind::ReaderStop,
    FaultKind::CablePull,
    FaultKind::ForeignStoppedWriters,
    FaultKind::UnlinkLiveName,
    FaultKind::SquatFile,
    FaultKind::SquatFifo,
    FaultKind::SquatSymlink,
    FaultKind::CpuHog,
    FaultKind::FifoSquatDriverKill,
];

impl FaultKind {
    /// Its name in the log, the table and the JSON.
    pub fn name(self) -> &'static str {
        match self {
            FaultKind::DriverKill => "driver_sigkill",
            FaultKind::DriverStop => "driver_sigstop",
            FaultKind::ReaderKill => "reader_sigkill",
            FaultKind::ReaderStop => "reader_sigstop",
            FaultKind::CablePull => "cable_pull",
            FaultKind::ForeignStoppedWriters => "foreign_stopped_writers",
            FaultKind::UnlinkLiveName => "unlink_live_name",
            FaultKind::SquatFile => "squat_file",
            FaultKind::SquatFifo => "squat_fifo",
            FaultKind::SquatSymlink => "squat_symlink",
            FaultKind::CpuHog => "cpu_hog",
            FaultKind::FifoSquatDriverKill => "fifo_squat_driver_kill",
        }
    }
}

/// A fault as injected: its record and its two moments (CLOCK_MONOTONIC ns).
pub(super) struct Injected {
    pub(super) record: FaultRecord,
    pub(super) injected_ns: u64,
    pub(super) ended_ns: u64,
}

fn unix_now_s() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

impl Soak<'_> {
    pub(super) fn begin(&self, kind: FaultKind, index: usize, target: String) -> Injected {
        let injected_ns = skinware::os::monotonic_ns();
        let at = self.elapsed_s();
        let unix = unix_now_s();
        Injected {
            record: FaultRecord {
                index,
                kind: kind.name().to_owned(),
                target,
                injected_s: at,
                injected_monotonic_ns: injected_ns,
                injected_unix_s: unix,
                ended_s: at,
                ended_monotonic_ns: injected_ns,
                ended_unix_s: unix,
                ..FaultRecord::default()
            },
            injected_ns,
            ended_ns: injected_ns,
        }
    }

    pub(super) fn end(&self, injected: &mut Injected) {
        injected.ended_ns = skinware::os::monotonic_ns();
        injected.record.ended_monotonic_ns = injected.ended_ns;
        injected.record.ended_s = self.elapsed_s();
        injected.record.ended_unix_s = unix_now_s();
        injected.record.held_s = (injected.ended_ns - injected.injected_ns) as f64 / 1e9;
    }

    /// A driver process, waiting (up to 10 s) for one to run.
    pub(super) fn driver(&mut self) -> Result<(String, u32)> {
        let deadline = Instant::now() + Duration::from_secs(10);
        loop {
            let drivers: Vec<(String, u32)> = procs::supervised_pids(self.monitor.skin_pid)
                .into_iter()
                .filter(|(name, pid)| name.starts_with("driver ") && !matches!(procs::state_of(*pid), Some('Z') | None))
                .collect();
            if !drivers.is_empty() {
                let pick = self.chaos.below(drivers.len() as u64) as usize;
                return Ok(drivers[pick].clone());
            }
            if Instant::now() > deadline || !self.idle(Duration::from_millis(20)) {
                bail!("no driver process of `skin run` ran for 10 s");
            }
        }
    }
}
