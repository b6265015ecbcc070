//! The heartbeat thread: every channel's state, ten times a second. Its
//! absence tells a remote reader that the link is cut.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use skinware::{Reader, lock};
use zenoh::Wait;
use zenoh::pubsub::Publisher;
use zenoh::qos::{CongestionControl, Priority};

use super::Shared;
use super::channel::Channel;
use crate::protocol::{self, ChannelState};

/// Every channel's state, 10 times a second; new channels every second.
pub(super) fn heartbeat(shared: &Arc<Shared>) {
    let mut publishers: BTreeMap<String, (Publisher<'static>, Reader)> = BTreeMap::new();
    let mut ticker = skinware::Ticker::new(HEARTBEAT);
    while ticker.wait(&shared.stop).is_some() {
        let channels: Vec<Arc<Channel>> = lock(&shared.channels).values().cloned().collect();
        for channel in channels {
            let name = &channel.info.name;
            if !publishers.contains_key(name) {
                let publisher = shared
                    .session
                    .declare_publisher(protocol::state_key(&shared.options.skin, name))
                    .congestion_control(CongestionControl::Drop)
                    .priority(Priority::DataHigh)
                    .express(true)
                    .wait();
                let reader = Reader::open_with(&shared.options.skin, name, &shared.reader_options());
                match (publisher, reader) {
                    (Ok(publisher), Ok(reader)) => {
                        publishers.insert(name.clone(), (publisher, reader));
                    }
                    (Err(e), _) => channel.counters.error(format!("cannot declare the state of {name}: {e}")),
                    (_, Err(e)) => channel.counters.error(format!("cannot watch the state of {name}: {e}")),
                }
            }
            let Some((publisher, reader)) = publishers.get_mut(name) else { continue };
            reader.follow_recreated();
            let state = reader.writer_state();
            channel.counters.state.store(state.code(), Ordering::Relaxed);
            channel.counters.published_seq.store(reader.published_seq(), Ordering::Relaxed);
            let message = ChannelState {
                state,
                published_seq: reader.published_seq(),
                sent: channel.counters.sent.load(Ordering::Relaxed),
                dropped: channel.counters.dropped.load(Ordering::Relaxed),
                latency_ns: channel.counters.mean_latency_ns(),
                period_ns: reader.writer_period().map_or(0, |p| p.as_nanos() as u64),
            };
            if let Err(e) = publisher.put(message.encode()).wait() {
                channel.counters.error(format!("sending the state of {name}: {e}"));
            }
        }
    }
}

/// How often every channel's state is sent.
pub const HEARTBEAT: Duration = Duration::from_millis(100);
