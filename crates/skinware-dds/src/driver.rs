//! The `ros2` driver kind: a ROS 2 topic as a skinware layer, so that a
//! tactile sensor's existing ROS 2 driver, or a simulator's contact
//! sensors, feed the viewer, the services and the recorder.
//!
//! The messages it reads, one per frame of the layer's `N` sensors:
//!
//! | message | layout | response |
//! |---|---|---|
//! | `sensor_msgs/PointCloud2` | `N` points (`width × height`), a numeric field named by `field` (default `response`) | the field's value, rounded and clamped to 0..=65535 (NaN: 0) |
//! | `std_msgs/UInt16MultiArray` | `N` elements after `layout.data_offset` | the element |
//! | `std_msgs/Float32MultiArray` | `N` elements after `layout.data_offset`, full scale 0..1 | `round(v × 65535)`, clamped (NaN: 0) |
//!
//! skinware's own clouds (`skin bridge --ros2`) are such `PointCloud2`s,
//! and its `TactileState` uses the same full scale.
//!
//! The layer runs at its configured rate. Each period it takes the newest
//! message that arrived (older ones are dropped, as a keep-last reader
//! would); with none new, it repeats the last responses marked
//! [`FrameStatus::PARTIAL`]. The layer is faulted until the first message,
//! and again after silence longer than the timeout, naming the topic; the
//! next message brings it back to running. A message
//! that does not fit the layout is counted and named in the layer's fault,
//! never a panic: [`decode`] takes any bytes.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use ros2_client::{Context, ContextOptions, Name, Node, NodeName, NodeOptions, Subscription};
use skinware::FrameWriter;
use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::rt::RtOptions;
use skinware::{FrameStatus, LayerTopology};
pub use skinware_ros2::input::{InputError, Ros2Input, UnknownInput, decode, from_cloud, from_f32, from_u16};
use skinware_ros2::standard::{Float32MultiArray, PointCloud2, UInt16MultiArray};

use crate::DdsError;

/// The subscription of one message type.
enum Inputs {
    Cloud(Subscription<PointCloud2>, String),
    U16(Subscription<UInt16MultiArray>),
    F32(Subscription<Float32MultiArray>),
}

/// What a `ros2` layer counts, readable while it runs.
#[derive(Debug, Default)]
pub struct Ros2Counters {
    /// Messages that became frames.
    pub received: AtomicU64,
    /// Messages that did not fit (each named in the layer's fault).
    pub rejected: AtomicU64,
    /// Messages dropped for a newer one in the same period.
    pub superseded: AtomicU64,
}

/// A `kind = "ros2"` driver: one layer from one topic.
pub struct Ros2Driver {
    topology: LayerTopology,
    rt: RtOptions,
    topic: String,
    input: Ros2Input,
    domain: u16,
    timeout: Duration,
    counters: Arc<Ros2Counters>,
}

impl Ros2Driver {
    /// A layer of `topology` from `topic` in ROS domain `domain`; faulted
    /// after `timeout` without a message.
    pub fn new(
        topology: LayerTopology,
        rt: RtOptions,
        topic: &str,
        input: Ros2Input,
        domain: u16,
        timeout: Duration,
    ) -> Result<Ros2Driver, DdsError> {
        Name::parse(topic).map_err(|e| {
            DdsError::Invalid(format!("topic = {topic:?} is not a ROS 2 topic name ({e:?}); write it as /a/b"))
        })?;
        if topology.rate_hz.is_nan() || topology.rate_hz <= 0.0 {
            return Err(DdsError::Invalid(format!(
                "layer {}: a ros2 layer needs rate_hz, the rate its topic is published at",
                topology.name
            )));
        }
        Ok(Ros2Driver { topology, rt, topic: topic.to_owned(), input, domain, timeout, counters: Arc::default() })
    }

    /// Its counters.
    pub fn counters(&self) -> Arc<Ros2Counters> {
        Arc::clone(&self.counters)
    }
}

impl Driver for Ros2Driver {
    fn name(&self) -> &str {
        "ros2"
    }

    fn layers(&self) -> Vec<LayerSpec> {
        vec![LayerSpec { topology: self.topology.clone(), rt: self.rt.clone() }]
    }

    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError> {
        let context = Context::with_options(ContextOptions::new().domain_id(self.domain))
            .map_err(|e| format!("cannot join DDS domain {}: {e}", self.domain))?;
        let node_name = format!("skin_driver_{}", skinware_ros2::ros_name(&self.topology.name).trim_start_matches('_'));
        let mut node = context
            .new_node(
                NodeName::new("/", &node_name).map_err(|e| format!("node name {node_name}: {e:?}"))?,
                NodeOptions::new().enable_rosout(false).start_parameter_services(false),
            )
            .map_err(|e| format!("cannot create the ROS 2 node {node_name}: {e:?}"))?;
        let qos = crate::qos::driver_subscription();
        let name = Name::parse(&self.topic).map_err(|e| format!("topic {}: {e:?}", self.topic))?;
        let topic = node
            .create_topic(&name, crate::type_name(self.input.type_name()), &qos)
            .map_err(|e| format!("cannot subscribe to {}: {e}", self.topic))?;
        let subscribe = |e: ros2_client::CreateError| format!("cannot subscribe to {}: {e}", self.topic);
        let inputs = match &self.input {
            Ros2Input::PointCloud2 { field } => {
                Inputs::Cloud(node.create_subscription(&topic, Some(qos)).map_err(subscribe)?, field.clone())
            }
            Ros2Input::UInt16MultiArray => Inputs::U16(node.create_subscription(&topic, Some(qos)).map_err(subscribe)?),
            Ros2Input::Float32MultiArray => {
                Inputs::F32(node.create_subscription(&topic, Some(qos)).map_err(subscribe)?)
            }
        };
        let source = TopicSource {
            inputs,
            _node: node,
            _context: context,
            topic: self.topic.clone(),
            timeout: self.timeout,
            responses: vec![0; self.topology.sensors.len()],
            scratch: vec![0; self.topology.sensors.len()],
            last_message: Instant::now(),
            ever: false,
            misfit: None,
            counters: Arc::clone(&self.counters),
        };
        Ok(vec![Box::new(source)])
    }
}

/// The layer's source: its subscription and the newest responses.
struct TopicSource {
    // Before the node: fields drop in order, and a subscription dropped
    // after its participant logs errors.
    inputs: Inputs,
    /// Kept alive: the subscription is the node's.
    _node: Node,
    /// After the node: a node's own writers dropped after their
    /// participant log errors, and the node drops its context first.
    _context: Context,
    topic: String,
    timeout: Duration,
    responses: Vec<u16>,
    /// Where a message is decoded before it is known to fit (kept: no
    /// allocation in a period).
    scratch: Vec<u16>,
    last_message: Instant,
    /// Whether any message came yet.
    ever: bool,
    /// Why the newest message did not fit, until one does.
    misfit: Option<String>,
    counters: Arc<Ros2Counters>,
}

impl TopicSource {
    /// Takes every message waiting, keeping the newest that fits: `Ok(true)`
    /// if one did, the last misfit's error if only misfits came.
    fn take_newest(&mut self) -> Result<bool, InputError> {
        let mut fresh = false;
        let mut misfit = None;
        let mut scratch = std::mem::take(&mut self.scratch);
        scratch.resize(self.responses.len(), 0);
        // At most a few subscriptions' worth a period: a flooding publisher
        // cannot keep the layer's thread draining.
        for _ in 0..MAX_TAKEN_PER_PERIOD {
            let fitted = match &self.inputs {
                Inputs::Cloud(sub, field) => match sub.take() {
                    Ok(Some((cloud, _))) => from_cloud(&cloud, field, &mut scratch),
                    Ok(None) => break,
                    Err(e) => Err(not_the_type(&e)),
                },
                Inputs::U16(sub) => match sub.take() {
                    Ok(Some((array, _))) => from_u16(&array, &mut scratch),
                    Ok(None) => break,
                    Err(e) => Err(not_the_type(&e)),
                },
                Inputs::F32(sub) => match sub.take() {
                    Ok(Some((array, _))) => from_f32(&array, &mut scratch),
                    Ok(None) => break,
                    Err(e) => Err(not_the_type(&e)),
                },
            };
            match fitted {
                Ok(()) => {
                    if fresh {
                        self.counters.superseded.fetch_add(1, Ordering::Relaxed);
                    }
                    std::mem::swap(&mut self.responses, &mut scratch);
                    fresh = true;
                }
                Err(e) => {
                    self.counters.rejected.fetch_add(1, Ordering::Relaxed);
                    misfit = Some(e);
                }
            }
        }
        self.scratch = scratch;
        match (fresh, misfit) {
            (false, Some(e)) => Err(e),
            _ => Ok(fresh),
        }
    }
}

/// Messages a layer takes in one period at most (its subscription keeps
/// the newest [`SENSOR_DEPTH`](crate::qos::SENSOR_DEPTH)).
const MAX_TAKEN_PER_PERIOD: usize = 4 * crate::qos::SENSOR_DEPTH;

/// A message the subscription could not decode as its type.
fn not_the_type(error: &ros2_client::ReadError) -> InputError {
    InputError::Cdr(format!(
        "a message that does not decode as the topic's type ({error}); does its publisher send the `message` the config names?"
    ))
}

impl LayerSource for TopicSource {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let fresh = match self.take_newest() {
            Ok(fresh) => fresh,
            Err(misfit) => {
                self.misfit = Some(format!("topic {}: {misfit}", self.topic));
                false
            }
        };
        if fresh {
            self.misfit = None;
        }
        // The newest message did not fit: faulted until one does.
        if let Some(misfit) = &self.misfit {
            return Err(misfit.clone().into());
        }
        let now = Instant::now();
        if fresh {
            self.counters.received.fetch_add(1, Ordering::Relaxed);
            self.last_message = now;
            self.ever = true;
        } else if !self.ever || now.duration_since(self.last_message) > self.timeout {
            // Responses no message gave are no frame: faulted until the first.
            let silent = if self.ever {
                format!(
                    "no message for {:.1} s (timeout {:.1} s)",
                    now.duration_since(self.last_message).as_secs_f64(),
                    self.timeout.as_secs_f64()
                )
            } else {
                "no message yet".to_owned()
            };
            return Err(format!(
                "topic {}: {silent}; is its publisher running, in the same ROS_DOMAIN_ID?",
                self.topic
            )
            .into());
        }
        frame.write_responses(0, &self.responses)?;
        if !fresh {
            // The previous responses again: no new message this period.
            frame.set_status(FrameStatus::PARTIAL);
        }
        Ok(())
    }
}
