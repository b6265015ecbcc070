//! A whole emulated bus, as `skin emulate` runs it: boards, a link, what the
//! taxels feel, an optional log, until stopped.

use std::path::PathBuf;
use std::time::Duration;

use skinware_drivers::PressureField;

use crate::{DeviceLink, MtbBoards, MtbFaults, SlcanDevice, run_mtb};

/// How the emulated boards reach the host.
#[derive(Clone, Debug)]
pub enum Transport {
    /// An SLCAN adapter on a pseudo-terminal; `link`, if given, becomes a
    /// symbolic link to it (a stable name for configurations).
    Slcan {
        /// Where to put the symbolic link.
        link: Option<PathBuf>,
    },
    /// cannelloni datagrams from `local` to the host at `peer`.
    Cannelloni {
        /// The emulator's address.
        local: String,
        /// The host's address.
        peer: String,
    },
}

/// An emulated bus of MTB boards.
#[derive(Clone, Debug)]
pub struct MtbEmulation {
    /// Boards, addresses 1..=boards.
    pub boards: u8,
    /// Triangles per board.
    pub triangles: u8,
    /// Streaming rate until the host configures another period.
    pub rate_hz: f64,
    /// The link.
    pub transport: Transport,
    /// A `candump -l` log of every frame sent.
    pub candump: Option<PathBuf>,
    /// Fault switches.
    pub faults: MtbFaults,
    /// Seed of the virtual body's contacts.
    pub seed: u64,
    /// SCHED_FIFO priority of the boards' thread: emulated hardware should
    /// be as punctual as real boards (refused without the privilege: warned).
    pub fifo_priority: Option<u8>,
}

impl MtbEmulation {
    /// Opens the link and calls `ready` with the URL a host opens it with,
    /// then runs until `stop` returns true. Returns the frames sent.
    pub fn run(&self, ready: impl FnOnce(&str), stop: &dyn Fn() -> bool) -> std::io::Result<u64> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(std::io::Error::other(format!("rate {} Hz: give a positive rate", self.rate_hz)));
        }
        let mut boards = MtbBoards::new(
            self.boards,
            self.triangles,
            Duration::from_secs_f64(1.0 / self.rate_hz),
            self.faults.clone(),
        );
        // Five minutes of contacts, repeated: drawing a day's worth would cost
        // the start-up (and every period's look through them) far more.
        const CONTACTS_S: f64 = 300.0;
        let field = PressureField::new(boards.taxels(), self.seed, CONTACTS_S);
        let touch = |t: f64, responses: &mut [u16]| field.responses(t % CONTACTS_S, 0, responses);
        // Real time only once the set-up is done, so that it starves nobody.
        if let Some(priority) = self.fifo_priority
            && let Err(e) = skinware::os::set_fifo_priority(priority)
        {
            tracing::warn!(
                "SCHED_FIFO priority {priority} refused ({e}); the emulated boards run in the normal scheduler"
            );
        }
        let mut log = match &self.candump {
            Some(path) => Some(std::io::BufWriter::new(std::fs::File::create(path)?)),
            None => None,
        };
        let mut device_path = None;
        let mut link: Box<dyn DeviceLink> = match &self.transport {
            Transport::Slcan { link } => {
                let device = SlcanDevice::new()?;
                device_path = Some(PathBuf::from(device.path()));
                if let Some(link) = link {
                    let _ = std::fs::remove_file(link);
                    std::os::unix::fs::symlink(device.path(), link)?;
                    ready(&format!("slcan://{}?bitrate=1000000", link.display()));
                } else {
                    ready(&device.url());
                }
                Box::new(device)
            }
            Transport::Cannelloni { local, peer } => {
                let url = format!("cannelloni://{local}?peer={peer}");
                let bus = skinware_drivers::can::open(&url).map_err(|e| std::io::Error::other(e.to_string()))?;
                ready(&format!("cannelloni://{peer}?peer={local}"));
                Box::new(bus)
            }
        };
        let sent =
            run_mtb(&mut boards, link.as_mut(), &touch, log.as_mut().map(|w| w as &mut dyn std::io::Write), stop);
        // The link goes with the emulator, unless a newer one has taken it.
        if let (Transport::Slcan { link: Some(link) }, Some(device)) = (&self.transport, &device_path)
            && std::fs::read_link(link).is_ok_and(|target| &target == device)
        {
            let _ = std::fs::remove_file(link);
        }
        sent
    }
}
