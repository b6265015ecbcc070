//! When a periodic writer's next frame is due, as seen by a reader that wants
//! to be spinning just before it ([`crate::ReaderOptions::anticipate`]), or
//! by the writer's lookout ([`crate::ReaderWake::Lookout`]).
//!
//! The writer publishes on an absolute-time grid, each frame some wake-up
//! latency and write time after its tick. The earliest publication phase seen
//! recently is the best estimate of "tick + write time": a frame is never
//! published earlier than that, while later ones are the writer's jitter. The
//! phase is a rolling minimum over two windows of frames, so that a writer
//! that changes its grid (a restart) is followed within two windows.

#![forbid(unsafe_code)]

/// Frames per window of the rolling minimum.
const WINDOW_FRAMES: u32 = 256;

/// The publication grid of one periodic writer, as observed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Anticipation {
    /// How long before the earliest expected publication to start spinning, ns.
    pub window_ns: u64,
    /// Publication time of the first frame observed: the grid's origin.
    origin_ns: u64,
    period_ns: u64,
    /// Earliest phase (publication time minus grid point) in the current and
    /// the previous window, ns.
    earliest_now: i64,
    earliest_before: i64,
    frames_in_window: u32,
    seeded: bool,
}

impl Anticipation {
    pub(crate) fn new(window_ns: u64) -> Anticipation {
        Anticipation { window_ns, ..Anticipation::default() }
    }

    /// The phase of `published_ns` on the grid, in (-period/2, period/2].
    /// In i128: the times are the writer's numbers (a reader takes them from
    /// shared memory), and `observe` keeps the period in (0, MAX_PERIOD_NS],
    /// so nothing here can overflow whatever the times are.
    fn phase(&self, published_ns: u64) -> i64 {
        let period = i128::from(self.period_ns.max(1));
        let offset = (i128::from(published_ns) - i128::from(self.origin_ns)).rem_euclid(period);
        let phase = if offset > period / 2 { offset - period } else { offset };
        // |phase| <= period / 2 <= MAX_PERIOD_NS / 2, far inside i64.
        phase as i64
    }

    /// Takes note of a frame published at `published_ns` by a writer of period `period_ns`.
    pub(crate) fn observe(&mut self, published_ns: u64, period_ns: u64) {
        if period_ns == 0 || period_ns > MAX_PERIOD_NS {
            // A sporadic writer (e.g. revived as one) has no grid to
            // anticipate, and a period beyond an hour is no writer's: a
            // forged header's. Neither is anticipated.
            self.seeded = false;
            return;
        }
        if !self.seeded || period_ns != self.period_ns {
            *self = Anticipation {
                window_ns: self.window_ns,
                origin_ns: published_ns,
                period_ns,
                seeded: true,
                ..Anticipation::default()
            };
            return;
        }
        let phase = self.phase(published_ns);
        self.earliest_now = self.earliest_now.min(phase);
        self.frames_in_window += 1;
        if self.frames_in_window >= WINDOW_FRAMES {
            self.earliest_before = self.earliest_now;
            self.earliest_now = phase;
            self.frames_in_window = 0;
        }
    }

    /// The earliest time the frame after the one published at `last_published_ns` is expected.
    pub(crate) fn next_expected(&self, last_published_ns: u64) -> Option<u64> {
        if !self.seeded {
            return None;
        }
        let earliest = i128::from(self.earliest_now.min(self.earliest_before));
        // The grid point of the last frame, then the next one.
        let grid = i128::from(last_published_ns) - i128::from(self.phase(last_published_ns));
        let expected = grid + i128::from(self.period_ns) + earliest;
        u64::try_from(expected).ok()
    }
}

/// The longest period anticipated: an hour. A writer's period comes from
/// shared memory, where a fake writer can put any number.
const MAX_PERIOD_NS: u64 = 3_600_000_000_000;

/// Samples per window of [`RecentQuantile`].
const QUANTILE_WINDOW: usize = 128;

/// A high quantile of a delay over the last window of samples, plus a
/// margin: how early a writer's lookout sets its timer and how long it spins
/// past the earliest expected frame. Recomputed once per window, so that a
/// stall or two move nothing (above the quantile) and a machine that turns
/// slower is followed within a window.
#[derive(Clone, Debug)]
pub(crate) struct RecentQuantile {
    samples: [u32; QUANTILE_WINDOW],
    filled: usize,
    /// Index of the quantile in a sorted window.
    rank: usize,
    value_ns: u64,
    margin_ns: u64,
}

impl RecentQuantile {
    /// The `per_mille` quantile (e.g. 970), `initial_ns` until a window is full.
    pub(crate) fn new(per_mille: usize, initial_ns: u64, margin_ns: u64) -> RecentQuantile {
        let rank = (QUANTILE_WINDOW * per_mille.min(1000) / 1000).min(QUANTILE_WINDOW - 1);
        RecentQuantile { samples: [0; QUANTILE_WINDOW], filled: 0, rank, value_ns: initial_ns, margin_ns }
    }

    /// Takes note of one delay.
    pub(crate) fn observe(&mut self, delay_ns: u64) {
        self.samples[self.filled] = u32::try_from(delay_ns).unwrap_or(u32::MAX);
        self.filled += 1;
        if self.filled == QUANTILE_WINDOW {
            let mut sorted = self.samples;
            sorted.sort_unstable();
            self.value_ns = u64::from(sorted[self.rank]) + self.margin_ns;
            self.filled = 0;
        }
    }

    /// The quantile of the last full window plus the margin, ns.
    pub(crate) fn value_ns(&self) -> u64 {
        self.value_ns
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_recent_quantile_ignores_stalls_and_follows_a_slower_machine() {
        let mut lead = RecentQuantile::new(970, 100_000, 10_000);
        assert_eq!(lead.value_ns(), 100_000);
        // 60 µs wake-ups with three 20 ms stalls: above the 97th percentile.
        for k in 0..QUANTILE_WINDOW {
            lead.observe(if k % 50 == 7 { 20_000_000 } else { 60_000 });
        }
        assert_eq!(lead.value_ns(), 70_000);
        // Slower wake-ups for a whole window are followed.
        for _ in 0..QUANTILE_WINDOW {
            lead.observe(150_000);
        }
        assert_eq!(lead.value_ns(), 160_000);
        // A delay beyond u32 nanoseconds saturates instead of wrapping.
        for _ in 0..QUANTILE_WINDOW {
            lead.observe(u64::MAX);
        }
        assert_eq!(lead.value_ns(), u64::from(u32::MAX) + 10_000);
        // The quantile's rank stays inside the window whatever is asked.
        assert_eq!(RecentQuantile::new(5000, 0, 0).rank, QUANTILE_WINDOW - 1);
    }

    const PERIOD: u64 = 5_000_000;

    /// The regression of issue #36: a forged period of `u64::MAX` and two
    /// frames 2^63 ns apart made `phase` compute `i64::MIN.rem_euclid(-1)`,
    /// which panics in release builds too.
    #[test]
    fn a_forged_period_and_times_do_not_panic() {
        let mut a = Anticipation::new(100_000);
        a.observe(0, u64::MAX);
        a.observe(1 << 63, u64::MAX);
        assert_eq!(a.next_expected(1 << 63), None, "a period beyond an hour is not anticipated");
        // The largest period accepted, with times at both ends of u64.
        a.observe(u64::MAX, MAX_PERIOD_NS);
        a.observe(0, MAX_PERIOD_NS);
        a.observe(u64::MAX, MAX_PERIOD_NS);
        let _ = a.next_expected(0);
        let _ = a.next_expected(u64::MAX);
    }

    // Not under Miri: proptest's failure files need the file system, which
    // Miri isolates (the test above runs there).
    #[cfg(not(miri))]
    proptest::proptest! {
        /// Whatever periods and times a writer's memory holds, observing and
        /// predicting never panics (debug builds check every overflow).
        #[test]
        fn any_period_and_times_are_taken_without_panic(
            frames in proptest::collection::vec((proptest::prelude::any::<u64>(), proptest::prelude::any::<u64>()), 1..40),
            period_choice in 0usize..4,
        ) {
            let mut a = Anticipation::new(100_000);
            for &(published, period) in &frames {
                let period = match period_choice {
                    0 => period,
                    1 => period % (MAX_PERIOD_NS + 2),
                    2 => u64::MAX - period % 4,
                    _ => MAX_PERIOD_NS,
                };
                a.observe(published, period);
                let _ = a.next_expected(published);
            }
        }

        /// For a real grid, the frame after the last is predicted within one
        /// period after it.
        #[test]
        fn a_real_grid_is_predicted_within_a_period(
            start in 0u64..(1 << 62),
            period in 1_000u64..1_000_000_000,
            jitters in proptest::collection::vec(0u64..1_000, 2..50),
        ) {
            let mut a = Anticipation::new(100_000);
            let mut last = start;
            for (k, jitter) in jitters.iter().enumerate() {
                last = start + k as u64 * period + jitter % (period / 4 + 1);
                a.observe(last, period);
            }
            let expected = a.next_expected(last).expect("seeded");
            proptest::prop_assert!(expected + period / 2 > last && expected <= last + period + period / 2,
                "expected {} after a frame at {} with period {}", expected, last, period);
        }
    }

    #[test]
    fn the_earliest_phase_predicts_the_next_frame() {
        let mut a = Anticipation::new(100_000);
        let start = 1_000_000_000;
        // Published 20-80 µs after each tick; the grid starts at `start`.
        let jitter = [30_000, 20_000, 80_000, 45_000, 25_000];
        for (k, j) in jitter.iter().enumerate() {
            a.observe(start + k as u64 * PERIOD + j, PERIOD);
        }
        // Relative to the first frame (at +30 µs), the earliest was 10 µs sooner.
        let last = start + 4 * PERIOD + 25_000;
        assert_eq!(a.next_expected(last), Some(start + 5 * PERIOD + 20_000));
    }

    #[test]
    fn a_late_frame_does_not_shift_the_grid() {
        let mut a = Anticipation::new(100_000);
        a.observe(10 * PERIOD, PERIOD);
        a.observe(11 * PERIOD, PERIOD);
        // Published 2 ms late: the next is still expected on the grid.
        a.observe(12 * PERIOD + 2_000_000, PERIOD);
        assert_eq!(a.next_expected(12 * PERIOD + 2_000_000), Some(13 * PERIOD));
    }

    #[test]
    fn a_new_grid_is_followed_within_two_windows() {
        let mut a = Anticipation::new(100_000);
        for k in 0..10 {
            a.observe(k * PERIOD, PERIOD);
        }
        // The writer restarts on a grid shifted by 1 ms.
        let shift = 1_000_000;
        for k in 10..10 + 2 * u64::from(WINDOW_FRAMES) + 1 {
            a.observe(k * PERIOD + shift, PERIOD);
        }
        let last = 1000 * PERIOD + shift;
        assert_eq!(a.next_expected(last), Some(1001 * PERIOD + shift));
        // A new period re-seeds at once.
        a.observe(7, 2 * PERIOD);
        assert_eq!(a.next_expected(7), Some(7 + 2 * PERIOD));
    }
}
