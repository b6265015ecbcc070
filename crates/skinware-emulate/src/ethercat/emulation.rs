//! A whole emulated EtherCAT skin, as `skin emulate ethercat` runs it:
//! segments whose taxels feel the virtual body's moving contacts, on a
//! network interface, with fault switches, until stopped.

use std::io::BufWriter;
use std::num::NonZeroU64;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use skinware_drivers::PressureField;

use super::esc::{ConfigError, LeaveOp, TactileConfig, TactileSubDevice};
use super::interface::{FrameObserver, InterfaceError, InterfaceStats, serve_interface};
use super::pcapng::PcapngWriter;
use super::segment::Segment;

/// What the emulated skin does wrong, on purpose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EmulationFaults {
    /// Lose every Nth process-data frame (never one of the bring-up's).
    pub drop_every_nth_frame: Option<NonZeroU64>,
    /// Answer every Nth process-data frame `late_by` late (after the
    /// MainDevice's frame timeout, to be a late answer).
    pub late_every_nth_frame: Option<NonZeroU64>,
    /// How late those answers are.
    pub late_by: Duration,
    /// The segment that the per-segment faults below hit (from 0).
    pub segment: usize,
    /// That segment leaves the working counter of process data alone.
    pub wrong_working_counter: bool,
    /// That segment drops out of OP this long after entering it.
    pub leave_op_after: Option<Duration>,
    /// The whole segment stops answering (a pulled cable) this long after
    /// the emulator starts.
    pub link_down_after: Option<Duration>,
}

/// An emulated EtherCAT skin: `segments` tactile segments of `taxels` each.
#[derive(Clone, Debug)]
pub struct EthercatEmulation {
    /// Segments (SubDevices) in the line.
    pub segments: usize,
    /// Taxels per segment.
    pub taxels: usize,
    /// The network interface to answer on.
    pub interface: String,
    /// Seed of the virtual body's contacts.
    pub seed: u64,
    /// Fault switches.
    pub faults: EmulationFaults,
    /// SCHED_FIFO priority of the emulator's thread (refused without the
    /// privilege: warned).
    pub fifo_priority: Option<u8>,
    /// A pcapng capture of every frame taken and every answer sent (Wireshark
    /// reads it), as a record of exactly what the segments answered.
    pub capture: Option<PathBuf>,
}

/// Five minutes of contacts, repeated: drawing more would cost the start-up.
const CONTACTS_S: f64 = 300.0;

impl EthercatEmulation {
    /// The segments, their taxels pressed by the virtual body's contacts
    /// (segment `k` is taxels `k * taxels ..` of the body), faults set.
    pub fn segment(&self) -> Result<Segment, ConfigError> {
        let field = Arc::new(PressureField::new(self.segments * self.taxels, self.seed, CONTACTS_S));
        let started = Instant::now();
        let mut subdevices = Vec::with_capacity(self.segments);
        for position in 0..self.segments {
            let field = field.clone();
            let first = position * self.taxels;
            let source = move |_sample: u64, taxels: &mut [u16]| {
                field.responses(started.elapsed().as_secs_f64() % CONTACTS_S, first, taxels);
            };
            let mut subdevice = TactileSubDevice::new(TactileConfig::new(self.taxels, position as u32 + 1), source)?;
            if position == self.faults.segment {
                let faults = subdevice.faults_mut();
                faults.wrong_working_counter = self.faults.wrong_working_counter;
                faults.leave_op = self.faults.leave_op_after.map(LeaveOp::AfterTime);
            }
            subdevices.push(subdevice);
        }
        let mut segment = Segment::new(subdevices);
        let faults = segment.faults_mut();
        faults.drop_every_nth_frame = self.faults.drop_every_nth_frame;
        faults.late_every_nth_frame = self.faults.late_every_nth_frame;
        faults.late_by = self.faults.late_by;
        Ok(segment)
    }

    /// Opens the interface, calls `ready`, then answers frames until `stop`
    /// returns true.
    pub fn run(
        &self,
        ready: impl FnOnce(&str),
        stop: &(dyn Fn() -> bool + Sync),
    ) -> Result<InterfaceStats, EmulationError> {
        if self.faults.segment >= self.segments {
            return Err(EmulationError::FaultSegment { segment: self.faults.segment, segments: self.segments });
        }
        let segment = Mutex::new(self.segment()?);
        let mut capture = match &self.capture {
            Some(path) => {
                let failed = |source| EmulationError::Capture { path: path.clone(), source };
                let file = std::fs::File::create(path).map_err(failed)?;
                Some(PcapngWriter::new(BufWriter::new(file)).map_err(failed)?)
            }
            None => None,
        };
        let capturing = capture.is_some();
        let mut warned = false;
        // Dropped when serving ends, which flushes the capture.
        let mut record = move |request: &[u8], answer: Option<&[u8]>| {
            let Some(writer) = capture.as_mut() else { return };
            let now = skinware::os::monotonic_ns();
            let written = writer.write_frame(now, request).and_then(|()| match answer {
                Some(answer) => writer.write_frame(now, answer),
                None => Ok(()),
            });
            if let Err(e) = written
                && !warned
            {
                tracing::warn!(error = %e, "the capture cannot be written; the segments go on answering");
                warned = true;
            }
        };
        if let Some(priority) = self.fifo_priority
            && let Err(e) = skinware::os::set_fifo_priority(priority)
        {
            tracing::warn!(
                "SCHED_FIFO priority {priority} refused ({e}); the emulated segments run in the normal scheduler"
            );
        }
        ready(&self.interface);
        let started = Instant::now();
        let served = std::sync::atomic::AtomicBool::new(false);
        let stats = std::thread::scope(|scope| {
            if let Some(after) = self.faults.link_down_after {
                let (segment, served) = (&segment, &served);
                // A pulled cable at a given time, whatever the traffic.
                scope.spawn(move || {
                    while !stop() && !served.load(std::sync::atomic::Ordering::Relaxed) {
                        if started.elapsed() >= after {
                            skinware::lock(segment).faults_mut().link_down = true;
                            return;
                        }
                        std::thread::sleep(Duration::from_millis(5));
                    }
                });
            }
            let observer: Option<&mut FrameObserver<'_>> = if capturing { Some(&mut record) } else { None };
            let stats = serve_interface(&segment, &self.interface, stop, observer);
            served.store(true, std::sync::atomic::Ordering::Relaxed);
            stats
        })?;
        Ok(stats)
    }
}

/// Why an emulation cannot run.
#[derive(Debug, thiserror::Error)]
pub enum EmulationError {
    /// The segments cannot be built.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The interface cannot be served.
    #[error(transparent)]
    Interface(#[from] InterfaceError),
    /// The capture file cannot be written.
    #[error("cannot write the capture {}: {source} (give a path in a directory that exists and is writable)", path.display())]
    Capture {
        /// The capture asked for.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The faulty segment is not there.
    #[error("faults hit segment {segment}, but there are only {segments} (0 to {})", segments.saturating_sub(1))]
    FaultSegment {
        /// The segment asked for.
        segment: usize,
        /// Segments there are.
        segments: usize,
    },
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ethercat::wire::{Command, FrameBuilder};

    #[test]
    fn faults_hit_the_segment_they_name() {
        let emulation = EthercatEmulation {
            segments: 3,
            taxels: 24,
            interface: "none".into(),
            seed: 7,
            faults: EmulationFaults {
                segment: 1,
                wrong_working_counter: true,
                leave_op_after: Some(Duration::from_secs(2)),
                drop_every_nth_frame: NonZeroU64::new(9),
                ..EmulationFaults::default()
            },
            fifo_priority: None,
            capture: None,
        };
        let mut segment = emulation.segment().unwrap();
        assert_eq!(segment.subdevices().len(), 3);
        let faulty: Vec<bool> =
            (0..3).map(|k| segment.subdevice_mut(k).unwrap().faults_mut().wrong_working_counter).collect();
        assert_eq!(faulty, [false, true, false]);
        assert_eq!(segment.faults_mut().drop_every_nth_frame, NonZeroU64::new(9));
        let mut frame = FrameBuilder::new().datagram(Command::Brd, 0, 0, &[0]).build();
        segment.process(&mut frame).unwrap();
        let bad =
            EthercatEmulation { faults: EmulationFaults { segment: 3, ..EmulationFaults::default() }, ..emulation };
        assert!(matches!(bad.run(|_| {}, &|| true), Err(EmulationError::FaultSegment { segment: 3, segments: 3 })));
    }
}
