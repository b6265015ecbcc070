//! The standard ROS 2 topics on rmw_zenoh: the skin's view
//! (`skinware_ros2::view`: a `PointCloud2` per layer and link, the contacts
//! as a `MarkerArray`, every channel's health on `/diagnostics`) with the
//! bridge's node and publishers as transport. The tactile messages and the
//! map are the channel threads' and the map thread's, so the view leaves
//! them out, and `/tf_static` too: rmw_zenoh serves a transient-local topic
//! from a publisher cache this bridge does not keep, so tf2's static
//! listener would not match it.

use std::marker::PhantomData;
use std::sync::Arc;

use serde::Serialize;
use skinware_ros2::qos::QosClass;
use skinware_ros2::view::{Sink, SinkError, Transport, View, ViewError, ViewOptions};

use super::Shared;
use super::ros::RosPublisher;
use crate::BridgeError;

/// The bridge's ROS node as a view's transport.
struct ZenohTransport {
    shared: Arc<Shared>,
}

impl Transport for ZenohTransport {
    fn declare<M: Serialize + Send + 'static>(
        &mut self,
        topic: &str,
        type_name: &'static str,
        // rmw_zenoh's keep-last with congestion control "drop" is what every
        // topic of the bridge offers (reliable, volatile, keep last 10),
        // which best-effort and reliable subscribers alike accept.
        _class: QosClass,
    ) -> Result<Box<dyn Sink<M>>, ViewError> {
        let publisher =
            RosPublisher::declare(&self.shared, topic, type_name).map_err(|e| ViewError::Transport(e.to_string()))?;
        Ok(Box::new(ZenohSink { publisher, shared: Arc::clone(&self.shared), message: PhantomData }))
    }
}

/// One topic's rmw_zenoh publisher.
struct ZenohSink<M> {
    publisher: RosPublisher,
    shared: Arc<Shared>,
    message: PhantomData<fn(M)>,
}

impl<M: Serialize + Send> Sink<M> for ZenohSink<M> {
    fn publish(&mut self, message: M) -> Result<(), SinkError> {
        let bytes = skinware_ros2::encode(&message, 4096).map_err(|e| SinkError(e.to_string()))?;
        self.publisher.put(bytes, self.shared.wall_now_ns()).map_err(|e| SinkError(e.to_string()))
    }

    fn subscribers(&self) -> usize {
        usize::from(self.publisher.wanted())
    }
}

/// Publishes the view until the bridge stops; retried each second until
/// the skin's channels are there to declare.
pub(super) fn publish_standard(shared: &Arc<Shared>) -> Result<(), BridgeError> {
    let bridge = &shared.options;
    let mut options = ViewOptions::new(&bridge.skin);
    options.dir = Some(shared.dir.clone());
    options.layers = bridge.layers.clone();
    options.services = bridge.services;
    options.root_frame = None;
    options.rates = bridge.standard;
    options.topic_hz = bridge.topic_hz.clone();
    // The channel threads publish the tactile messages, the map thread the map.
    options.tactile_and_map = false;
    let mut ticker = skinware::Ticker::new(std::time::Duration::from_secs(1));
    loop {
        match View::declare(options.clone(), ZenohTransport { shared: Arc::clone(shared) }) {
            Ok(mut view) => {
                view.run(&shared.stop);
                return Ok(());
            }
            // Options that name what cannot be will not get better.
            Err(e @ ViewError::Invalid(_)) => {
                return Err(BridgeError::Invalid(format!("the standard ROS 2 topics: {e}")));
            }
            Err(e) => tracing::debug!("the standard ROS 2 topics, not yet: {e}"),
        }
        if ticker.wait(&shared.stop).is_none() {
            return Ok(());
        }
    }
}
