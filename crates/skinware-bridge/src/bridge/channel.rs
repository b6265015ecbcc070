//! A bridged channel: its description for remote readers, what its threads
//! count, its queue of requests, and its line in the bridge's report.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::Duration;

use skinware::{WriterState, lock};

use super::ReaderReports;
use crate::protocol::RemoteChannel;

/// One channel's figures since the bridge started.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChannelReport {
    /// The channel.
    pub channel: String,
    /// `layer` or `service`.
    pub kind: String,
    /// The writer's state.
    pub state: String,
    /// Frames handed to zenoh for remote skinware readers.
    pub sent: u64,
    /// Frames the writer published that the bridge did not hand to zenoh
    /// (the rate limit, or it read too late). What zenoh then drops on a
    /// full link is in `remote_lost`, as the remote readers report it.
    pub dropped: u64,
    /// ROS messages sent (0 while no ROS subscriber listens).
    pub ros_sent: u64,
    /// Frames sent per second over the last interval.
    pub rate_hz: f64,
    /// Acquisition to hand-over to zenoh, over the last 1024 frames, µs.
    pub latency_p50_us: f64,
    /// The same, 99th percentile.
    pub latency_p99_us: f64,
    /// Remote skinware readers that reported in the last 5 s.
    pub remote_readers: u64,
    /// Frames those readers did not get although the bridge sent them
    /// (lost on the link, or dropped by zenoh's queue when the link was
    /// full), summed over the readers.
    pub remote_lost: u64,
    /// The slowest reader's mean acquisition-to-receipt time over its last second, µs.
    pub remote_latency_us: f64,
    /// Errors (encoding, zenoh).
    pub errors: u64,
    /// The last error.
    pub last_error: Option<String>,
}

/// What the threads of one channel count, for [`Bridge::report`](super::Bridge::report) and the heartbeat.
#[derive(Default)]
pub(super) struct Counters {
    pub(super) sent: AtomicU64,
    pub(super) dropped: AtomicU64,
    pub(super) ros_sent: AtomicU64,
    pub(super) errors: AtomicU64,
    /// The writer's state, by its number ([`WriterState::code`]; 0 until the heartbeat reads it).
    pub(super) state: AtomicU32,
    pub(super) published_seq: AtomicU64,
    /// Acquisition to hand-over to zenoh, ns, of the last [`LATENCY_WINDOW`] frames.
    latencies: Mutex<VecDeque<u64>>,
    last_error: Mutex<Option<String>>,
    /// When the rate was last computed (monotonic ns), `sent` then, and the rate.
    rate: Mutex<(u64, u64, f64)>,
}

impl Counters {
    pub(super) fn error(&self, message: String) {
        self.errors.fetch_add(1, Ordering::Relaxed);
        tracing::warn!("{message}");
        *lock(&self.last_error) = Some(message);
    }

    pub(super) fn latency(&self, ns: u64) {
        let mut latencies = lock(&self.latencies);
        if latencies.len() == LATENCY_WINDOW {
            latencies.pop_front();
        }
        latencies.push_back(ns);
    }

    pub(super) fn mean_latency_ns(&self) -> u64 {
        let latencies = lock(&self.latencies);
        if latencies.is_empty() { 0 } else { latencies.iter().sum::<u64>() / latencies.len() as u64 }
    }
}

const LATENCY_WINDOW: usize = 1024;

/// A bridged channel: what remote readers are told of it, and what its threads count.
pub(super) struct Channel {
    pub(super) info: RemoteChannel,
    pub(super) counters: Counters,
    pub(super) requests: RequestQueue,
}

/// Queries for a frame on request, waiting for this channel's request thread.
/// Filled from zenoh's thread, which must never wait: past
/// [`MAX_WAITING_REQUESTS`] a query is dropped (its asker times out).
#[derive(Default)]
pub(super) struct RequestQueue {
    queries: Mutex<VecDeque<zenoh::query::Query>>,
    arrived: std::sync::Condvar,
}

/// Requests one channel holds before it drops new ones.
const MAX_WAITING_REQUESTS: usize = 16;

impl RequestQueue {
    pub(super) fn push(&self, query: zenoh::query::Query) {
        let mut queries = lock(&self.queries);
        if queries.len() < MAX_WAITING_REQUESTS {
            queries.push_back(query);
            self.arrived.notify_one();
        }
    }

    pub(super) fn pop(&self, timeout: Duration) -> Option<zenoh::query::Query> {
        let mut queries = lock(&self.queries);
        if queries.is_empty() {
            queries = self.arrived.wait_timeout(queries, timeout).map(|(q, _)| q).unwrap_or_else(|p| p.into_inner().0);
        }
        queries.pop_front()
    }
}

impl Channel {
    /// The channel's figures now (`now`: monotonic ns), with what the remote
    /// readers reported in the last 5 s.
    pub(super) fn report(&self, now: u64, reader_reports: &Mutex<ReaderReports>) -> ChannelReport {
        let c = &self.counters;
        let sent = c.sent.load(Ordering::Relaxed);
        let rate_hz = {
            let mut rate = lock(&c.rate);
            let (at, count, hz) = &mut *rate;
            if *at == 0 {
                (*at, *count) = (now, sent);
            } else if now - *at >= 500_000_000 {
                *hz = (sent - *count) as f64 * 1e9 / (now - *at) as f64;
                (*at, *count) = (now, sent);
            }
            *hz
        };
        let (mut remote_readers, mut remote_lost, mut remote_latency_ns) = (0, 0, 0);
        {
            let mut reports = lock(reader_reports);
            reports.retain(|_, (_, at)| at.elapsed() < Duration::from_secs(60));
            for ((name, _), (report, at)) in reports.iter() {
                if *name == self.info.name && at.elapsed() < Duration::from_secs(5) {
                    remote_readers += 1;
                    remote_lost += report.lost;
                    remote_latency_ns = remote_latency_ns.max(report.latency_ns);
                }
            }
        }
        let mut latencies: Vec<u64> = lock(&c.latencies).iter().copied().collect();
        latencies.sort_unstable();
        let quantile = |q: f64| {
            latencies.get(((latencies.len() as f64 - 1.0) * q).round() as usize).map_or(0.0, |&ns| ns as f64 / 1e3)
        };
        ChannelReport {
            channel: self.info.name.clone(),
            kind: self.info.kind.as_str().to_owned(),
            state: WriterState::from_number(c.state.load(Ordering::Relaxed)).unwrap_or(WriterState::Gone).to_string(),
            sent,
            dropped: c.dropped.load(Ordering::Relaxed),
            ros_sent: c.ros_sent.load(Ordering::Relaxed),
            rate_hz,
            latency_p50_us: quantile(0.5),
            latency_p99_us: quantile(0.99),
            remote_readers,
            remote_lost,
            remote_latency_us: remote_latency_ns as f64 / 1e3,
            errors: c.errors.load(Ordering::Relaxed),
            last_error: lock(&c.last_error).clone(),
        }
    }
}
