//! From skinware's clock to ROS time. skinware stamps frames with
//! CLOCK_MONOTONIC, which never jumps, so that periods and latencies stay
//! true; ROS 2 messages carry wall-clock time (CLOCK_REALTIME, since the Unix
//! epoch). A transport measures the offset between the two once, when it
//! starts, and converts every stamp with that one offset: the stamps of one
//! recording or one bridge then keep their spacing even if the wall clock is
//! stepped while it runs.

use crate::messages::Time;

/// CLOCK_REALTIME minus CLOCK_MONOTONIC, ns: what turns a frame's monotonic
/// times into wall-clock ones. Of five readings, the one taken in the
/// shortest window, so that a preemption between the two clock reads does
/// not skew it.
pub fn clock_offset_ns() -> i64 {
    let mut best = (u64::MAX, 0i64);
    for _ in 0..5 {
        let before = skinware::os::monotonic_ns();
        let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos() as i64);
        let after = skinware::os::monotonic_ns();
        if after - before < best.0 {
            best = (after - before, now - (before / 2 + after / 2) as i64);
        }
    }
    best.1
}

/// A CLOCK_MONOTONIC time as ns since the Unix epoch, given the
/// [`clock_offset_ns`] measured at the start (0 for a time before the epoch).
pub fn unix_ns(monotonic_ns: u64, clock_offset_ns: i64) -> u64 {
    (monotonic_ns as i64).saturating_add(clock_offset_ns).max(0) as u64
}

/// A CLOCK_MONOTONIC time (a frame's acquisition or publication) as ROS time.
pub fn ros_time(monotonic_ns: u64, clock_offset_ns: i64) -> Time {
    Time::from_ns(unix_ns(monotonic_ns, clock_offset_ns))
}

/// Now, as ns since the Unix epoch on the clock that [`unix_ns`] converts to.
pub fn now_unix_ns(clock_offset_ns: i64) -> u64 {
    unix_ns(skinware::os::monotonic_ns(), clock_offset_ns)
}

/// The inverse of [`unix_ns`]: ns since the Unix epoch as a CLOCK_MONOTONIC
/// time of this machine (0 for a time before its boot), for frames that come
/// back from ROS time (a remote skin mirrored into local channels).
pub fn monotonic_ns(unix_ns: u64, clock_offset_ns: i64) -> u64 {
    (unix_ns as i64).saturating_sub(clock_offset_ns).max(0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_offset_puts_monotonic_time_at_the_wall_clock() {
        let offset = clock_offset_ns();
        let wall = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() as u64;
        let converted = now_unix_ns(offset);
        // Two clock reads apart, on a loaded machine.
        assert!(converted.abs_diff(wall) < 1_000_000_000, "{converted} vs {wall}");
    }

    #[test]
    fn conversions_saturate_and_invert() {
        assert_eq!(unix_ns(5, -10), 0);
        assert_eq!(unix_ns(5, 10), 15);
        assert_eq!(monotonic_ns(15, 10), 5);
        assert_eq!(monotonic_ns(5, 10), 0);
        assert_eq!(monotonic_ns(unix_ns(1_000, 1_700_000_000_000_000_000), 1_700_000_000_000_000_000), 1_000);
        assert_eq!(ros_time(2_500_000_000, 1_000_000_000), Time { sec: 3, nanosec: 500_000_000 });
    }
}
