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
use skinware_ros2::standard::{
    FLOAT32_MULTI_ARRAY, Float32MultiArray, MultiArrayLayout, POINT_CLOUD2, PointCloud2, UINT16_MULTI_ARRAY,
    UInt16MultiArray,
};

use crate::DdsError;

/// What a `ros2` layer's topic carries.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Ros2Input {
    /// `sensor_msgs/PointCloud2`, the response in the named field.
    PointCloud2 {
        /// The field holding each point's response.
        field: String,
    },
    /// `std_msgs/UInt16MultiArray`: raw responses.
    UInt16MultiArray,
    /// `std_msgs/Float32MultiArray`: responses at full scale 0..1.
    Float32MultiArray,
}

impl Ros2Input {
    /// The input of a config's `message` (a full type name, or its short
    /// name) and `field` (a `PointCloud2`'s, default `response`).
    pub fn parse(message: &str, field: Option<&str>) -> Result<Ros2Input, DdsError> {
        let short = message.rsplit('/').next().unwrap_or(message);
        let package = message.split('/').next().filter(|_| message.contains('/'));
        let expected = if short == "PointCloud2" { "sensor_msgs" } else { "std_msgs" };
        if package.is_some_and(|package| package != expected) {
            return Err(DdsError::Invalid(format!(
                "message = {message:?}: a ros2 layer reads {expected}'s {short}, not another package's"
            )));
        }
        let input = match short {
            "PointCloud2" => Ros2Input::PointCloud2 { field: field.unwrap_or("response").to_owned() },
            "UInt16MultiArray" => Ros2Input::UInt16MultiArray,
            "Float32MultiArray" => Ros2Input::Float32MultiArray,
            _ => {
                return Err(DdsError::Invalid(format!(
                    "message = {message:?}: a ros2 layer reads {POINT_CLOUD2}, {UINT16_MULTI_ARRAY} or {FLOAT32_MULTI_ARRAY}"
                )));
            }
        };
        if field.is_some() && !matches!(input, Ros2Input::PointCloud2 { .. }) {
            return Err(DdsError::Invalid(format!(
                "field = {:?} is a setting of a PointCloud2 topic, not of {message}",
                field.unwrap_or_default()
            )));
        }
        Ok(input)
    }

    /// Its full type name.
    pub fn type_name(&self) -> &'static str {
        match self {
            Ros2Input::PointCloud2 { .. } => POINT_CLOUD2,
            Ros2Input::UInt16MultiArray => UINT16_MULTI_ARRAY,
            Ros2Input::Float32MultiArray => FLOAT32_MULTI_ARRAY,
        }
    }
}

/// Why a message gave no frame.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InputError {
    /// The bytes are not a CDR message of the type.
    #[error("{0}")]
    Cdr(String),
    /// The message has another number of responses than the layer has sensors.
    #[error(
        "{what} holds {got} responses, but the layer has {want} sensors; publish one per sensor, in topology order"
    )]
    Count {
        /// The message type.
        what: &'static str,
        /// Responses in the message.
        got: usize,
        /// Sensors in the layer.
        want: usize,
    },
    /// The `PointCloud2` has no usable field of that name.
    #[error(
        "the PointCloud2 has no numeric field {field:?} inside its points (its fields: {fields:?}); set `field` to one of them"
    )]
    NoField {
        /// The field asked for.
        field: String,
        /// The fields it has.
        fields: Vec<String>,
    },
    /// The `PointCloud2`'s sizes disagree with its data.
    #[error("the PointCloud2's layout is inconsistent: {0}")]
    Layout(String),
}

/// Decodes `bytes`, a CDR message of `input`'s type, into `out` (one
/// response per sensor of the layer). Any bytes give `Ok` or an error.
pub fn decode(bytes: &[u8], input: &Ros2Input, out: &mut [u16]) -> Result<(), InputError> {
    let cdr = |e: skinware_ros2::DecodeError| InputError::Cdr(e.to_string());
    match input {
        Ros2Input::PointCloud2 { field } => {
            let cloud: PointCloud2 = skinware_ros2::decode(bytes, POINT_CLOUD2).map_err(cdr)?;
            from_cloud(&cloud, field, out)
        }
        Ros2Input::UInt16MultiArray => {
            let array: UInt16MultiArray = skinware_ros2::decode(bytes, UINT16_MULTI_ARRAY).map_err(cdr)?;
            from_u16(&array, out)
        }
        Ros2Input::Float32MultiArray => {
            let array: Float32MultiArray = skinware_ros2::decode(bytes, FLOAT32_MULTI_ARRAY).map_err(cdr)?;
            from_f32(&array, out)
        }
    }
}

/// The elements of an array message from its `data_offset`, if exactly `want`.
fn elements<'a, T>(
    layout: &MultiArrayLayout,
    data: &'a [T],
    what: &'static str,
    want: usize,
) -> Result<&'a [T], InputError> {
    let rest = data.get(layout.data_offset as usize..).unwrap_or_default();
    if rest.len() != want {
        return Err(InputError::Count { what, got: rest.len(), want });
    }
    Ok(rest)
}

/// A `UInt16MultiArray`'s responses.
pub fn from_u16(array: &UInt16MultiArray, out: &mut [u16]) -> Result<(), InputError> {
    out.copy_from_slice(elements(&array.layout, &array.data, UINT16_MULTI_ARRAY, out.len())?);
    Ok(())
}

/// A `Float32MultiArray`'s responses (full scale 0..1).
pub fn from_f32(array: &Float32MultiArray, out: &mut [u16]) -> Result<(), InputError> {
    let values = elements(&array.layout, &array.data, FLOAT32_MULTI_ARRAY, out.len())?;
    for (response, value) in out.iter_mut().zip(values) {
        *response = saturate(f64::from(*value) * f64::from(skinware_ros2::RESPONSE_FULL_SCALE));
    }
    Ok(())
}

/// A response from any number: rounded, clamped to 0..=65535, NaN as 0.
fn saturate(value: f64) -> u16 {
    if value.is_nan() { 0 } else { value.round().clamp(0.0, 65535.0) as u16 }
}

/// A `PointCloud2`'s responses, from its field `field`.
pub fn from_cloud(cloud: &PointCloud2, field: &str, out: &mut [u16]) -> Result<(), InputError> {
    let points = u64::from(cloud.width) * u64::from(cloud.height);
    if points != out.len() as u64 {
        return Err(InputError::Count { what: POINT_CLOUD2, got: points as usize, want: out.len() });
    }
    let step = cloud.point_step as usize;
    let fields = || cloud.fields.iter().map(|f| f.name.clone()).collect::<Vec<_>>();
    let found = cloud.fields.iter().find(|f| f.name == field);
    let Some((offset, size)) = found.and_then(|f| Some((f.offset as usize, datatype_size(f.datatype)?))) else {
        return Err(InputError::NoField { field: field.to_owned(), fields: fields() });
    };
    if offset.checked_add(size).is_none_or(|end| end > step) {
        return Err(InputError::NoField { field: field.to_owned(), fields: fields() });
    }
    let rows = cloud.height as usize;
    let row_step = cloud.row_step as usize;
    let width = cloud.width as usize;
    // Every point's bytes must be in the data: the last row's last point ends the need.
    let needed = rows
        .checked_sub(1)
        .and_then(|last_row| last_row.checked_mul(row_step))
        .and_then(|start| start.checked_add(width.checked_mul(step)?));
    if row_step < width.saturating_mul(step) || needed.is_none_or(|needed| needed > cloud.data.len()) {
        return Err(InputError::Layout(format!(
            "{} × {} points of {step} bytes, rows of {row_step} bytes, in {} bytes of data",
            cloud.width,
            cloud.height,
            cloud.data.len()
        )));
    }
    let datatype = found.map_or(0, |f| f.datatype);
    let mut next = out.iter_mut();
    for row in 0..rows {
        for column in 0..width {
            let at = row * row_step + column * step + offset;
            let bytes = &cloud.data[at..at + size];
            if let Some(response) = next.next() {
                *response = saturate(read_number(bytes, datatype, cloud.is_bigendian));
            }
        }
    }
    Ok(())
}

/// The size of a `sensor_msgs/PointField` datatype (1..=8), if it is one.
fn datatype_size(datatype: u8) -> Option<usize> {
    match datatype {
        1 | 2 => Some(1),
        3 | 4 => Some(2),
        5..=7 => Some(4),
        8 => Some(8),
        _ => None,
    }
}

/// A number of `datatype` from its bytes (`bytes.len()` is its size).
fn read_number(bytes: &[u8], datatype: u8, big_endian: bool) -> f64 {
    let mut raw = [0u8; 8];
    raw[..bytes.len()].copy_from_slice(bytes);
    if big_endian {
        raw[..bytes.len()].reverse();
    }
    let [a, b, c, d, ..] = raw;
    match datatype {
        1 => f64::from(a as i8),
        2 => f64::from(a),
        3 => f64::from(i16::from_le_bytes([a, b])),
        4 => f64::from(u16::from_le_bytes([a, b])),
        5 => f64::from(i32::from_le_bytes([a, b, c, d])),
        6 => f64::from(u32::from_le_bytes([a, b, c, d])),
        7 => f64::from(f32::from_le_bytes([a, b, c, d])),
        _ => f64::from_le_bytes(raw),
    }
}

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

#[cfg(test)]
mod tests {
    use proptest::prelude::*;
    use skinware_ros2::Header;
    use skinware_ros2::standard::PointField;

    use super::*;

    fn cloud(values: &[f32], extra_field: bool) -> PointCloud2 {
        let step = if extra_field { 20 } else { 16 };
        let mut data = Vec::new();
        for (k, value) in values.iter().enumerate() {
            for coordinate in [k as f32, 0.0, 0.0, *value] {
                data.extend_from_slice(&coordinate.to_le_bytes());
            }
            if extra_field {
                data.extend_from_slice(&[0; 4]);
            }
        }
        let field = |name: &str, offset| PointField { name: name.into(), offset, datatype: 7, count: 1 };
        PointCloud2 {
            header: Header { stamp: skinware_ros2::Time::default(), frame_id: String::new() },
            height: 1,
            width: values.len() as u32,
            fields: vec![field("x", 0), field("y", 4), field("z", 8), field("response", 12)],
            is_bigendian: false,
            point_step: step,
            row_step: step * values.len() as u32,
            data,
            is_dense: true,
        }
    }

    #[test]
    fn skinwares_own_clouds_read_back() {
        let mut out = [0u16; 4];
        from_cloud(&cloud(&[0.0, 1.4, 65535.0, 70000.0], true), "response", &mut out).unwrap();
        assert_eq!(out, [0, 1, 65535, 65535]);
        let bytes = skinware_ros2::encode(&cloud(&[5.0, 6.0, 7.0, f32::NAN], false), 128).unwrap();
        decode(&bytes, &Ros2Input::PointCloud2 { field: "response".into() }, &mut out).unwrap();
        assert_eq!(out, [5, 6, 7, 0]);
    }

    #[test]
    fn misfits_are_named() {
        let mut out = [0u16; 3];
        let wrong_count = from_cloud(&cloud(&[1.0, 2.0], false), "response", &mut out).unwrap_err();
        assert!(wrong_count.to_string().contains("2 responses, but the layer has 3 sensors"), "{wrong_count}");
        let no_field = from_cloud(&cloud(&[1.0, 2.0, 3.0], false), "pressure", &mut out).unwrap_err();
        assert!(no_field.to_string().contains("\"response\""), "{no_field}");
        let mut short = cloud(&[1.0, 2.0, 3.0], false);
        short.data.truncate(40);
        assert!(matches!(from_cloud(&short, "response", &mut out), Err(InputError::Layout(_))));
        let array =
            UInt16MultiArray { layout: MultiArrayLayout { dim: Vec::new(), data_offset: 1 }, data: vec![9, 1, 2, 3] };
        from_u16(&array, &mut out).unwrap();
        assert_eq!(out, [1, 2, 3], "data_offset skips the first");
        let full = Float32MultiArray { layout: MultiArrayLayout::default(), data: vec![0.0, 0.5, 2.0] };
        from_f32(&full, &mut out).unwrap();
        assert_eq!(out, [0, 32768, 65535]);
        assert!(Ros2Input::parse("std_msgs/msg/String", None).unwrap_err().to_string().contains("PointCloud2"));
        assert!(Ros2Input::parse("UInt16MultiArray", Some("x")).is_err());
    }

    /// The fuzz target's seeds (`fuzz/corpus/ros2_input`) are real messages
    /// of each type: a first byte picking the type and 4 sensors, then CDR.
    #[test]
    fn the_fuzz_seeds_decode() {
        let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/corpus/ros2_input");
        let expected: [(&str, Ros2Input, [u16; 4]); 3] = [
            ("cloud", Ros2Input::PointCloud2 { field: "response".into() }, [0, 100, 200, 300]),
            ("uint16", Ros2Input::UInt16MultiArray, [1, 2, 3, 4]),
            ("float32", Ros2Input::Float32MultiArray, [0, 16384, 32768, 65535]),
        ];
        for (name, input, responses) in expected {
            let seed = std::fs::read(corpus.join(name)).unwrap();
            let mut out = [0u16; 4];
            decode(&seed[1..], &input, &mut out).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(out, responses, "{name}");
        }
    }

    proptest! {
        #[test]
        fn any_bytes_give_a_frame_or_an_error(bytes in proptest::collection::vec(any::<u8>(), 0..512), sensors in 0usize..16) {
            let mut out = vec![0u16; sensors];
            for input in [Ros2Input::PointCloud2 { field: "response".into() }, Ros2Input::UInt16MultiArray, Ros2Input::Float32MultiArray] {
                let _ = decode(&bytes, &input, &mut out);
            }
        }

        #[test]
        fn any_cloud_layout_gives_a_frame_or_an_error(
            width in 0u32..8, height in 0u32..4, step in 0u32..40, row_step in 0u32..200,
            offset in 0u32..40, datatype in 0u8..10, data_len in 0usize..600, big in any::<bool>(),
        ) {
            let cloud = PointCloud2 {
                header: Header { stamp: skinware_ros2::Time::default(), frame_id: String::new() },
                height,
                width,
                fields: vec![PointField { name: "response".into(), offset, datatype, count: 1 }],
                is_bigendian: big,
                point_step: step,
                row_step,
                data: vec![7; data_len],
                is_dense: true,
            };
            let mut out = vec![0u16; (width * height) as usize];
            let _ = from_cloud(&cloud, "response", &mut out);
        }
    }
}
