//! The DDS bridge: the skin's standard ROS 2 topics (`skinware_ros2::view`)
//! on DDS, for nodes on the default RMW, as node `skin_bridge_<skin>`.

use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use ros2_client::{Context, ContextOptions, Name, Node, NodeName, NodeOptions, Publisher};
use serde::Serialize;
use skinware::{Stop, lock};
use skinware_ros2::qos::QosClass;
use skinware_ros2::view::{Sink, SinkError, Transport, View, ViewError, ViewOptions};

use crate::DdsError;
use crate::qos::profile;

pub use skinware_ros2::view::{DEFAULT_MAP_WIDTH, Rates, TopicReport};

/// What to publish, and where.
#[derive(Clone, Debug)]
pub struct DdsOptions {
    /// The skin, its channels, topics and rates.
    pub view: ViewOptions,
    /// The ROS domain (`ROS_DOMAIN_ID`).
    pub domain: u16,
}

impl DdsOptions {
    /// Every layer and service of `skin`, domain 0, the default rates,
    /// links at `base_link`.
    pub fn new(skin: &str) -> DdsOptions {
        DdsOptions { view: ViewOptions::new(skin), domain: 0 }
    }
}

/// DDS as a view's transport: a node, and a publisher per topic.
pub struct DdsTransport {
    /// Dropped before the context: the node drops its context before its
    /// own writers, and a writer dropped after its participant logs errors.
    node: Node,
    context: Context,
}

impl DdsTransport {
    /// Joins DDS domain `domain` as node `node_name`.
    pub fn join(domain: u16, node_name: &str) -> Result<DdsTransport, DdsError> {
        let context = Context::with_options(ContextOptions::new().domain_id(domain))
            .map_err(|e| DdsError::Dds(format!("cannot join DDS domain {domain}: {e}")))?;
        let node = context
            .new_node(
                NodeName::new("/", node_name)
                    .map_err(|e| DdsError::Invalid(format!("node name {node_name}: {e:?}")))?,
                NodeOptions::new().enable_rosout(false).start_parameter_services(false),
            )
            .map_err(|e| DdsError::Dds(format!("cannot create the ROS 2 node {node_name}: {e:?}")))?;
        Ok(DdsTransport { node, context })
    }
}

impl Transport for DdsTransport {
    fn declare<M: Serialize + Send + 'static>(
        &mut self,
        topic: &str,
        type_name: &'static str,
        class: QosClass,
    ) -> Result<Box<dyn Sink<M>>, ViewError> {
        let dds =
            |e: &dyn std::fmt::Display| ViewError::Transport(format!("cannot declare the DDS topic {topic}: {e}"));
        let name = Name::parse(topic).map_err(|e| dds(&format!("{e:?}")))?;
        let qos = profile(class);
        let ros_topic = self.node.create_topic(&name, crate::type_name(type_name), &qos).map_err(|e| dds(&e))?;
        let offered = ros2_client::ros2::QosPolicies::from(&qos);
        let publisher = self.node.create_publisher::<M>(&ros_topic, Some(qos)).map_err(|e| dds(&e))?;
        Ok(Box::new(DdsSink {
            publisher,
            context: self.context.clone(),
            // As ros2-client names a ROS topic and its type in DDS.
            dds_name: format!("rt/{}", topic.trim_start_matches('/')),
            dds_type: crate::type_name(type_name).dds_msg_type(),
            offered,
        }))
    }
}

/// One topic's DDS writer.
struct DdsSink<M: Serialize> {
    publisher: Publisher<M>,
    context: Context,
    dds_name: String,
    dds_type: String,
    /// The QoS it offers, which a reader must accept to match.
    offered: ros2_client::ros2::QosPolicies,
}

impl<M: Serialize + Send> Sink<M> for DdsSink<M> {
    fn publish(&mut self, message: M) -> Result<(), SinkError> {
        self.publisher.publish(message).map_err(|e| SinkError(format!("DDS refused a write: {e}")))
    }

    /// The readers that match: of its topic and type, requesting no more
    /// than it offers (a reliable reader does not match a best-effort
    /// writer, and is not counted).
    fn subscribers(&self) -> usize {
        let readers = self.context.domain_participant().discovered_readers();
        readers
            .iter()
            .map(|reader| &reader.subscription_topic_data)
            .filter(|data| data.topic_name() == &self.dds_name && data.type_name() == &self.dds_type)
            .filter(|data| self.offered.compliance_failure_wrt(&data.qos()).is_none())
            .count()
    }
}

/// A running DDS bridge. Dropping it stops it.
pub struct DdsBridge {
    stop: Stop,
    thread: Option<JoinHandle<()>>,
    reports: Arc<Mutex<Vec<TopicReport>>>,
    node_name: String,
}

impl DdsBridge {
    /// Joins the DDS domain as node `skin_bridge_<skin>`, declares every
    /// topic of the chosen channels, sends `/tf_static`, and starts
    /// publishing.
    pub fn start(options: DdsOptions) -> Result<DdsBridge, DdsError> {
        skinware::shm::validate_name("skin", &options.view.skin)?;
        let node_name = format!("skin_bridge_{}", skinware_ros2::ros_name(&options.view.skin).trim_start_matches('_'));
        let transport = DdsTransport::join(options.domain, &node_name)?;
        let mut view = View::declare(options.view, transport)?;
        let stop = Stop::new();
        let reports = view.shared_reports();
        let stopping = stop.clone();
        let thread = std::thread::Builder::new()
            .name("dds-bridge".into())
            .spawn(move || view.run(&stopping))
            .map_err(|source| DdsError::Thread { thread: "the DDS bridge".into(), source })?;
        Ok(DdsBridge { stop, thread: Some(thread), reports, node_name })
    }

    /// The bridge's node name in the ROS graph.
    pub fn node_name(&self) -> &str {
        &self.node_name
    }

    /// Every topic's figures, as of the last tick.
    pub fn report(&self) -> Vec<TopicReport> {
        lock(&self.reports).clone()
    }

    /// Stops publishing and leaves the domain; the topics' figures.
    pub fn stop(mut self) -> Vec<TopicReport> {
        self.halt();
        self.report()
    }

    fn halt(&mut self) {
        self.stop.stop();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

impl Drop for DdsBridge {
    fn drop(&mut self) {
        self.halt();
    }
}
