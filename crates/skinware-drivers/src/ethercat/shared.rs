//! What the EtherCAT bus thread shares with the layers: each segment's
//! newest inputs and status, the bus's fault, and where each layer's writer
//! is (so that the bus can time its cycles to the writer's acquisitions).
//! Below both the bus thread ([`super::bus`]) and the driver's layers
//! ([`super::driver`]).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};

/// What the driver knows of one segment, for status displays.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SegmentStatus {
    /// Vendor ID, product code, revision and serial it reported, once seen.
    pub identity: Option<[u32; 4]>,
    /// Its name (the SII's order code).
    pub name: String,
    /// Its AL state as last seen (`INIT`, `PRE-OP`, `SAFE-OP`, `OP`, …).
    pub state: String,
    /// Why its layer is faulted, if it is.
    pub fault: Option<String>,
    /// Cycles whose data it delivered.
    pub cycles: u64,
    /// Its last sample counter.
    pub counter: u16,
    /// Faults it has had: lost frames, wrong working counters, states
    /// other than OP (a fault lasting several cycles counts once).
    pub faults: u64,
    /// When its newest good sample arrived, CLOCK_MONOTONIC ns; 0 before
    /// the first. A bus that has stopped cycling shows here, whatever the
    /// state last seen says.
    pub newest_sample_ns: u64,
}

/// One segment's newest inputs.
pub(super) struct SegmentImage {
    pub(super) values: Vec<u16>,
    /// When they arrived, CLOCK_MONOTONIC ns (0: never).
    pub(super) acquired_ns: u64,
    pub(super) status: SegmentStatus,
    /// Faults begun so far, and the newest one's reason: a fault that is
    /// over before the layer's writer looks (one cycle long, with the writer
    /// not scheduled in that period) is still reported, once.
    pub(super) faults_begun: u64,
    pub(super) newest_fault: String,
}

/// What the bus thread shares with the layers.
pub(super) struct Shared {
    pub(super) segments: Vec<Mutex<SegmentImage>>,
    /// One per segment: notified when its image has a new cycle or a new
    /// fault, or the bus a new fault.
    pub(super) news: Vec<Condvar>,
    /// Why the whole bus is down, while it is.
    pub(super) bus_fault: Mutex<Option<String>>,
    /// One per segment: where its layer writer is, for the schedule of the
    /// segment's cycles.
    pub(super) writers: Vec<WriterFollow>,
}

/// What a segment's layer writer tells the bus thread, so that each cycle
/// ends just before the acquisition that takes its sample.
#[derive(Debug, Default)]
pub(super) struct WriterFollow {
    /// Period deadline of its newest acquisition, CLOCK_MONOTONIC ns; 0
    /// before the first.
    pub(super) deadline_ns: AtomicU64,
    /// Whether it is in an acquisition now.
    pub(super) acquiring: AtomicBool,
    /// The cycle whose sample it took last.
    pub(super) taken_cycle: AtomicU64,
}

impl WriterFollow {
    pub(super) fn view(&self) -> WriterView {
        // Acquire: pairs with the Release stores of `acquiring`, so that the
        // deadline read is at least the one stored before it.
        let acquiring = self.acquiring.load(Ordering::Acquire);
        WriterView {
            deadline_ns: self.deadline_ns.load(Ordering::Relaxed),
            acquiring,
            taken_cycle: self.taken_cycle.load(Ordering::Relaxed),
        }
    }
}

/// A look at a [`WriterFollow`] (the three may be from moments a few
/// nanoseconds apart: a mistimed cycle is the worst that comes of it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct WriterView {
    pub(super) deadline_ns: u64,
    pub(super) acquiring: bool,
    pub(super) taken_cycle: u64,
}

impl Shared {
    pub(super) fn segment(&self, position: usize) -> std::sync::MutexGuard<'_, SegmentImage> {
        skinware::lock(&self.segments[position])
    }

    pub(super) fn set_bus_fault(&self, fault: Option<String>) {
        let mut bus = skinware::lock(&self.bus_fault);
        if *bus != fault {
            match &fault {
                Some(why) => tracing::warn!(error = %why, "EtherCAT bus down"),
                None => tracing::info!("EtherCAT bus up"),
            }
            *bus = fault;
            drop(bus);
            self.news.iter().for_each(Condvar::notify_all);
        }
    }

    pub(super) fn set_fault(&self, position: usize, fault: Option<String>) {
        let mut image = self.segment(position);
        if image.status.fault != fault {
            match &fault {
                Some(why) => tracing::warn!(segment = position, error = %why, "segment faulted"),
                None => tracing::info!(segment = position, "segment running"),
            }
            if let Some(why) = &fault {
                image.faults_begun += 1;
                image.newest_fault.clone_from(why);
            }
            image.status.fault = fault;
            drop(image);
            self.news[position].notify_all();
        }
    }
}
