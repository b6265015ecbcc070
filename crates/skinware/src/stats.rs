//! Statistics: the writer's (in shared memory, readable by any process) and a
//! reader's (local to it).

#![forbid(unsafe_code)]

use crate::sync::AtomicU64;
use crate::sync::Ordering::Relaxed;

use crate::channel::layout::{HISTOGRAM_BUCKETS, SharedStats};

/// What a reader can tell about a channel's writer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WriterState {
    /// The writer is alive and publishing.
    Running,
    /// The writer is alive but has paused publishing on purpose.
    Paused,
    /// The writer is alive but its source failed (driver error, cable pulled);
    /// frames, if any, carry [`FrameStatus::FAULT`](crate::FrameStatus::FAULT).
    Faulted,
    /// No live process owns the channel: its writer stopped or died.
    Gone,
}

impl WriterState {
    pub(crate) const RUNNING: u32 = 1;
    pub(crate) const PAUSED: u32 = 2;
    pub(crate) const FAULTED: u32 = 3;
    pub(crate) const STOPPED: u32 = 4;

    /// Every state, in the order of their codes.
    pub const ALL: [WriterState; 4] =
        [WriterState::Running, WriterState::Paused, WriterState::Faulted, WriterState::Gone];

    /// Combines the state code a writer left in the header with whether its
    /// liveness lock is still held: a dead writer is gone whatever it last said.
    pub(crate) fn from_code(code: u32, alive: bool) -> WriterState {
        match (alive, code) {
            (false, _) | (true, WriterState::STOPPED) => WriterState::Gone,
            (true, WriterState::PAUSED) => WriterState::Paused,
            (true, WriterState::FAULTED) => WriterState::Faulted,
            (true, _) => WriterState::Running,
        }
    }

    /// The state's number: 1 running, 2 paused, 3 faulted, 4 gone. The same
    /// number the writer stores in shared memory, and the one every encoding
    /// of a state uses (recordings, the bridge, the viewer), so that there is
    /// one table.
    pub const fn code(self) -> u32 {
        match self {
            WriterState::Running => WriterState::RUNNING,
            WriterState::Paused => WriterState::PAUSED,
            WriterState::Faulted => WriterState::FAULTED,
            WriterState::Gone => WriterState::STOPPED,
        }
    }

    /// The state numbered `code` (see [`code`](Self::code)); `None` for a
    /// number that is none of them (from a file or a peer: hostile input).
    pub const fn from_number(code: u32) -> Option<WriterState> {
        match code {
            WriterState::RUNNING => Some(WriterState::Running),
            WriterState::PAUSED => Some(WriterState::Paused),
            WriterState::FAULTED => Some(WriterState::Faulted),
            WriterState::STOPPED => Some(WriterState::Gone),
            _ => None,
        }
    }

    /// The lower-case name used by the CLI, its JSON and Python: `running|paused|faulted|gone`.
    pub const fn as_str(self) -> &'static str {
        match self {
            WriterState::Running => "running",
            WriterState::Paused => "paused",
            WriterState::Faulted => "faulted",
            WriterState::Gone => "gone",
        }
    }
}

impl std::fmt::Display for WriterState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A name that is not a writer state's ([`WriterState::as_str`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{given:?} is not a writer state: give one of running, paused, faulted, gone")]
pub struct UnknownWriterState {
    /// The name given.
    pub given: String,
}

impl std::str::FromStr for WriterState {
    type Err = UnknownWriterState;

    fn from_str(name: &str) -> Result<WriterState, UnknownWriterState> {
        WriterState::ALL
            .into_iter()
            .find(|state| state.as_str() == name)
            .ok_or_else(|| UnknownWriterState { given: name.to_owned() })
    }
}

/// A snapshot of a writer's statistics, read from shared memory.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// Frames published since the channel was created.
    pub frames: u64,
    /// Periods whose work did not finish before the next deadline.
    pub overruns: u64,
    /// Deadlines skipped because of overruns.
    pub missed_periods: u64,
    /// Frames published with the FAULT status, or acquisitions that failed.
    pub faults: u64,
    /// Shortest time to fill and publish one frame, ns (0 before the first).
    pub write_ns_min: u64,
    /// Longest time to fill and publish one frame, ns.
    pub write_ns_max: u64,
    /// Mean time to fill and publish one frame, ns.
    pub write_ns_mean: u64,
    /// Time of the latest frame, ns.
    pub write_ns_last: u64,
    /// Worst lateness of a periodic writer's wake-up after its deadline, ns.
    pub lateness_ns_max: u64,
    /// Mean lateness of a periodic writer's wake-up, ns.
    pub lateness_ns_mean: u64,
    /// Histogram of write times: bucket `i` counts `[2^i, 2^(i+1))` ns.
    pub write_histogram: [u64; HISTOGRAM_BUCKETS],
    /// Histogram of wake-up lateness, same buckets.
    pub lateness_histogram: [u64; HISTOGRAM_BUCKETS],
}

impl WriterStats {
    pub(crate) fn load(shared: &SharedStats) -> WriterStats {
        let frames = shared.frames.load(Relaxed);
        let lateness_samples = shared.lateness_samples.load(Relaxed);
        let min = shared.write_ns_min.load(Relaxed);
        WriterStats {
            frames,
            overruns: shared.overruns.load(Relaxed),
            missed_periods: shared.missed_periods.load(Relaxed),
            faults: shared.faults.load(Relaxed),
            write_ns_min: if min == u64::MAX { 0 } else { min },
            write_ns_max: shared.write_ns_max.load(Relaxed),
            write_ns_mean: shared.write_ns_sum.load(Relaxed).checked_div(frames).unwrap_or(0),
            write_ns_last: shared.write_ns_last.load(Relaxed),
            lateness_ns_max: shared.lateness_ns_max.load(Relaxed),
            lateness_ns_mean: shared.lateness_ns_sum.load(Relaxed).checked_div(lateness_samples).unwrap_or(0),
            write_histogram: std::array::from_fn(|i| shared.write_histogram[i].load(Relaxed)),
            lateness_histogram: std::array::from_fn(|i| shared.lateness_histogram[i].load(Relaxed)),
        }
    }

    /// An upper bound of the `q`-quantile (0..=1) of write times, from the histogram.
    pub fn write_ns_quantile(&self, q: f64) -> u64 {
        histogram_quantile(&self.write_histogram, q)
    }
}

/// The upper edge of the histogram bucket holding the `q`-quantile.
pub fn histogram_quantile(histogram: &[u64; HISTOGRAM_BUCKETS], q: f64) -> u64 {
    // u128 sums: the counts are the writer's numbers, read from shared
    // memory, and a fake writer's need not add up within u64.
    let total: u128 = histogram.iter().map(|&count| u128::from(count)).sum();
    if total == 0 {
        return 0;
    }
    let rank = ((q.clamp(0.0, 1.0) * total as f64).ceil() as u128).max(1);
    let mut seen: u128 = 0;
    for (bucket, &count) in histogram.iter().enumerate() {
        seen += u128::from(count);
        if seen >= rank {
            return 1u64 << (bucket + 1);
        }
    }
    1u64 << HISTOGRAM_BUCKETS
}

/// The histogram bucket of a duration in ns.
pub(crate) fn bucket_of(ns: u64) -> usize {
    (63 - ns.max(1).leading_zeros() as usize).min(HISTOGRAM_BUCKETS - 1)
}

/// Adds one to a single-writer counter without a locked instruction.
pub(crate) fn bump(counter: &AtomicU64, by: u64) {
    counter.store(counter.load(Relaxed).wrapping_add(by), Relaxed);
}

/// Records one write time into the shared statistics. Only the writer calls it.
pub(crate) fn record_write(shared: &SharedStats, write_ns: u64, faulted: bool) {
    bump(&shared.frames, 1);
    if faulted {
        bump(&shared.faults, 1);
    }
    if write_ns < shared.write_ns_min.load(Relaxed) {
        shared.write_ns_min.store(write_ns, Relaxed);
    }
    if write_ns > shared.write_ns_max.load(Relaxed) {
        shared.write_ns_max.store(write_ns, Relaxed);
    }
    bump(&shared.write_ns_sum, write_ns);
    shared.write_ns_last.store(write_ns, Relaxed);
    bump(&shared.write_histogram[bucket_of(write_ns)], 1);
}

/// Records a periodic wake-up: its lateness, and any overrun. Only the writer calls it.
pub(crate) fn record_tick(shared: &SharedStats, lateness_ns: u64, missed: u64) {
    if lateness_ns > shared.lateness_ns_max.load(Relaxed) {
        shared.lateness_ns_max.store(lateness_ns, Relaxed);
    }
    bump(&shared.lateness_ns_sum, lateness_ns);
    bump(&shared.lateness_samples, 1);
    bump(&shared.lateness_histogram[bucket_of(lateness_ns)], 1);
    if missed > 0 {
        bump(&shared.overruns, 1);
        bump(&shared.missed_periods, missed);
    }
}

/// A reader's own statistics.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReaderStats {
    /// Frames obtained.
    pub reads: u64,
    /// Copies thrown away because the writer lapped the reader.
    pub retries: u64,
    /// Frames published that this reader never saw.
    pub skipped: u64,
    /// Shortest time to obtain one frame, ns.
    pub read_ns_min: u64,
    /// Longest time to obtain one frame, ns.
    pub read_ns_max: u64,
    /// Sum of the times to obtain frames, ns (for the mean).
    pub read_ns_sum: u64,
    /// Time to obtain the latest frame, ns.
    pub read_ns_last: u64,
}

impl ReaderStats {
    /// Mean time to obtain one frame, ns.
    pub fn read_ns_mean(&self) -> u64 {
        self.read_ns_sum.checked_div(self.reads).unwrap_or(0)
    }

    pub(crate) fn record(&mut self, read_ns: u64, retries: u32, skipped: u64) {
        if self.reads == 0 || read_ns < self.read_ns_min {
            self.read_ns_min = read_ns;
        }
        self.read_ns_max = self.read_ns_max.max(read_ns);
        self.read_ns_sum += read_ns;
        self.read_ns_last = read_ns;
        self.reads += 1;
        self.retries += u64::from(retries);
        self.skipped += skipped;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_writer_state_has_one_number_and_one_name() {
        for state in WriterState::ALL {
            assert_eq!(WriterState::from_number(state.code()), Some(state));
            assert_eq!(state.as_str().parse::<WriterState>(), Ok(state));
            assert_eq!(WriterState::from_code(state.code(), true), state);
        }
        assert_eq!(WriterState::from_number(0), None);
        assert_eq!(WriterState::from_number(u32::MAX), None);
        let refused = "stopped".parse::<WriterState>().unwrap_err();
        assert!(refused.to_string().contains("running, paused, faulted, gone"), "{refused}");
    }

    #[test]
    fn buckets_are_powers_of_two() {
        assert_eq!(bucket_of(0), 0);
        assert_eq!(bucket_of(1), 0);
        assert_eq!(bucket_of(2), 1);
        assert_eq!(bucket_of(1023), 9);
        assert_eq!(bucket_of(1024), 10);
        assert_eq!(bucket_of(u64::MAX), HISTOGRAM_BUCKETS - 1);
    }

    #[test]
    fn quantile_reads_the_upper_bucket_edge() {
        let mut histogram = [0; HISTOGRAM_BUCKETS];
        histogram[3] = 98; // [8, 16) ns
        histogram[10] = 2; // [1024, 2048) ns
        assert_eq!(histogram_quantile(&histogram, 0.5), 16);
        assert_eq!(histogram_quantile(&histogram, 0.99), 2048);
        assert_eq!(histogram_quantile(&[0; HISTOGRAM_BUCKETS], 0.5), 0);
    }

    /// A fake writer's counts that do not add up within u64 (they come from
    /// shared memory) give an answer, not an overflow panic.
    #[test]
    fn forged_histogram_counts_do_not_overflow() {
        let histogram = [u64::MAX; HISTOGRAM_BUCKETS];
        assert_eq!(histogram_quantile(&histogram, 0.0), 2);
        assert_eq!(histogram_quantile(&histogram, 1.0), 1u64 << HISTOGRAM_BUCKETS);
    }

    #[test]
    fn a_dead_writer_is_gone_whatever_it_said() {
        assert_eq!(WriterState::from_code(WriterState::RUNNING, false), WriterState::Gone);
        assert_eq!(WriterState::from_code(WriterState::FAULTED, true), WriterState::Faulted);
        assert_eq!(WriterState::from_code(WriterState::STOPPED, true), WriterState::Gone);
    }

    #[test]
    fn reader_stats_track_min_max_mean() {
        let mut stats = ReaderStats::default();
        stats.record(300, 1, 0);
        stats.record(100, 0, 4);
        assert_eq!((stats.read_ns_min, stats.read_ns_max, stats.read_ns_mean()), (100, 300, 200));
        assert_eq!((stats.retries, stats.skipped, stats.reads), (1, 4, 2));
    }
}
