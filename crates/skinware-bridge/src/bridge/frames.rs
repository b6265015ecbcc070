//! One thread per channel: its newest frame, each time it is published (or
//! at most `max_hz` times a second), to remote skinware readers and, as a
//! ROS message, to ROS nodes. A frame the thread did not send is counted as
//! dropped, never lost silently.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use skinware::{Error, Reader};
use zenoh::Wait;
use zenoh::pubsub::Publisher;
use zenoh::qos::{CongestionControl, Priority};

use super::Shared;
use super::channel::Channel;
use super::ros::ChannelRos;
use crate::BridgeError;
use crate::protocol;

/// One channel: its newest frame, each time (or at most `max_hz` a second).
pub(super) fn send_channel(shared: &Arc<Shared>, channel: &Channel, mut reader: Reader) -> Result<(), BridgeError> {
    let name = &channel.info.name;
    reader.set_stop(&shared.stop);
    let frames = shared
        .session
        .declare_publisher(protocol::frame_key(&shared.options.skin, name))
        .congestion_control(CongestionControl::Drop)
        .priority(Priority::Data)
        .wait()
        .map_err(|e| BridgeError::Zenoh(format!("cannot declare the publisher of {name}: {e}")))?;
    let ros = ChannelRos::declare(shared, channel)?;
    let min_interval_ns = shared.max_hz(name).map(|hz| (1e9 / hz) as u64);
    let mut next_allowed_ns = 0u64;
    let mut last_sent_seq: Option<u64> = None;
    while !shared.stop.is_stopped() {
        if min_interval_ns.is_some() && !shared.stop.sleep_until(next_allowed_ns) {
            break;
        }
        let frame = match reader.wait_newer(Duration::from_millis(100)) {
            Ok(frame) => frame,
            Err(Error::Timeout { .. } | Error::WriterGone { .. } | Error::NoFrameYet { .. }) => continue,
            Err(Error::Stopped { .. }) => break,
            Err(e) => {
                channel.counters.error(format!("reading {name}: {e}"));
                if !shared.stop.sleep_until(skinware::os::monotonic_ns() + 100_000_000) {
                    break;
                }
                continue;
            }
        };
        count_dropped(channel, &mut last_sent_seq, frame.seq());
        send_frame(shared, channel, &frames, &frame);
        ros.send(shared, channel, &frame);
        if let Some(interval) = min_interval_ns {
            next_allowed_ns = skinware::os::monotonic_ns().max(next_allowed_ns.saturating_add(interval));
            next_allowed_ns = next_allowed_ns.max(skinware::os::monotonic_ns() + interval / 2);
        }
    }
    Ok(())
}

/// Counts the frames published since the last one sent as dropped: skipped
/// by this reader, or (after a writer's restart) everything the new writer
/// published first.
fn count_dropped(channel: &Channel, last_sent_seq: &mut Option<u64>, seq: u64) {
    let missed = match *last_sent_seq {
        Some(last) if seq > last => seq - last - 1,
        // A restarted writer counts from 1 again: what it published before this one.
        Some(_) => seq.saturating_sub(1),
        // What was published before the bridge started is not its to send.
        None => 0,
    };
    channel.counters.dropped.fetch_add(missed, Ordering::Relaxed);
    *last_sent_seq = Some(seq);
}

/// Hands `frame` to zenoh for remote skinware readers.
fn send_frame(shared: &Shared, channel: &Channel, frames: &Publisher<'_>, frame: &skinware::Frame<'_>) {
    let name = &channel.info.name;
    let acquired_ns = frame.acquired_ns();
    match protocol::encode_frame(channel.info.kind, frame, shared.clock_offset_ns) {
        Ok(bytes) => match frames.put(bytes).wait() {
            Ok(()) => {
                channel.counters.sent.fetch_add(1, Ordering::Relaxed);
                channel.counters.latency(skinware::os::monotonic_ns().saturating_sub(acquired_ns));
            }
            Err(e) => channel.counters.error(format!("sending a frame of {name}: {e}")),
        },
        Err(e) => channel.counters.error(format!("encoding a frame of {name}: {e}")),
    }
}
