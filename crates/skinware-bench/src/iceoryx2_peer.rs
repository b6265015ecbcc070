//! The iceoryx2 peer of `skin bench peers` (cargo feature `iceoryx2`):
//! publish-subscribe with a one-sample subscriber buffer and safe overflow
//! (latest-value semantics), plus an event service to wake waiting readers.
//! The publish timestamp travels in the first four elements of the frame.

use anyhow::{Result, anyhow};
use iceoryx2::prelude::*;

type Publisher = iceoryx2::port::publisher::Publisher<ipc::Service, [u16], ()>;
type Subscriber = iceoryx2::port::subscriber::Subscriber<ipc::Service, [u16], ()>;

fn e<E: std::fmt::Debug>(what: &'static str) -> impl FnOnce(E) -> anyhow::Error {
    move |error| anyhow!("iceoryx2 {what}: {error:?}")
}

/// The writer side.
pub struct IceoryxWriter {
    _node: Node<ipc::Service>,
    publisher: Publisher,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
    sensors: usize,
}

fn names(name: &str) -> Result<(ServiceName, ServiceName)> {
    let data: ServiceName = format!("skinware-bench/{name}/frame").as_str().try_into().map_err(e("service name"))?;
    let event: ServiceName = format!("skinware-bench/{name}/event").as_str().try_into().map_err(e("service name"))?;
    Ok((data, event))
}

type FrameService = iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [u16], ()>;
type EventService = iceoryx2::service::port_factory::event::PortFactory<ipc::Service>;

/// Opens (or creates) the frame and event services with the same settings on
/// both sides: a one-sample subscriber buffer with safe overflow, so that a
/// reader always gets the newest frame.
fn services(name: &str) -> Result<(Node<ipc::Service>, FrameService, EventService)> {
    // Its default configuration is what we want; say so only on errors
    // (IOX2_LOG_LEVEL still overrides).
    set_log_level_from_env_or(LogLevel::Error);
    let node = NodeBuilder::new().create::<ipc::Service>().map_err(e("node"))?;
    let (data, event) = names(name)?;
    let frames = node
        .service_builder(&data)
        .publish_subscribe::<[u16]>()
        .subscriber_max_buffer_size(1)
        .history_size(1)
        .enable_safe_overflow(true)
        .max_subscribers(32)
        .open_or_create()
        .map_err(e("publish-subscribe service"))?;
    let events = node.service_builder(&event).event().max_listeners(32).open_or_create().map_err(e("event service"))?;
    Ok((node, frames, events))
}

impl IceoryxWriter {
    /// Creates the services.
    pub fn create(name: &str, sensors: usize) -> Result<IceoryxWriter> {
        let (node, service, event) = services(name)?;
        let publisher = service.publisher_builder().initial_max_slice_len(sensors).create().map_err(e("publisher"))?;
        let notifier = event.notifier_builder().create().map_err(e("notifier"))?;
        Ok(IceoryxWriter { _node: node, publisher, notifier, sensors })
    }

    /// Publishes one frame (copied into a loaned sample) and wakes listeners.
    pub fn publish(&self, frame: &[u16]) -> Result<()> {
        let sample = self.publisher.loan_slice_uninit(self.sensors).map_err(e("loan"))?;
        let now = skinware::os::monotonic_ns();
        let mut sample = sample.write_from_slice(&frame[..self.sensors]);
        for (i, word) in sample.payload_mut()[..4].iter_mut().enumerate() {
            *word = (now >> (16 * i)) as u16;
        }
        sample.send().map_err(e("send"))?;
        self.notifier.notify().map_err(e("notify"))?;
        Ok(())
    }
}

/// The reader side.
pub struct IceoryxReader {
    _node: Node<ipc::Service>,
    subscriber: Subscriber,
    listener: iceoryx2::port::listener::Listener<ipc::Service>,
}

impl IceoryxReader {
    /// Opens the services.
    pub fn open(name: &str) -> Result<IceoryxReader> {
        let (node, service, event) = services(name)?;
        let subscriber = service.subscriber_builder().create().map_err(e("subscriber"))?;
        let listener = event.listener_builder().create().map_err(e("listener"))?;
        Ok(IceoryxReader { _node: node, subscriber, listener })
    }

    /// Waits (up to `timeout`) for a frame, copies the newest into `out` and
    /// returns (its publish timestamp, ns spent receiving and copying).
    pub fn wait_newer(&self, out: &mut [u16], timeout: std::time::Duration) -> Result<Option<(u64, u64)>> {
        self.listener.timed_wait(|_| {}, timeout).map_err(e("wait"))?;
        let started = skinware::os::monotonic_ns();
        let mut newest = None;
        while let Some(sample) = self.subscriber.receive().map_err(e("receive"))? {
            newest = Some(sample);
        }
        let Some(sample) = newest else { return Ok(None) };
        let payload = sample.payload();
        let n = out.len().min(payload.len());
        out[..n].copy_from_slice(&payload[..n]);
        std::hint::black_box(&mut *out);
        let published = (0..4).fold(0u64, |acc, i| acc | (u64::from(payload[i]) << (16 * i)));
        Ok(Some((published, skinware::os::monotonic_ns() - started)))
    }
}
