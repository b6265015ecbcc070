//! What a recording holds for ROS tools, beside skinware's own frames: the
//! standard messages that Foxglove's 3-D and diagnostics panels draw with no
//! schema of ours.
//!
//! | topic | message | when |
//! |---|---|---|
//! | `/skin/<skin>/<layer>/cloud/<link>` | `sensor_msgs/PointCloud2` | `ros2_hz` times a second, each layer's newest frame |
//! | `/skin/<skin>/<service>/markers` | `visualization_msgs/MarkerArray` | `ros2_hz`, a recorded contact service's newest frame |
//! | `/diagnostics` | `diagnostic_msgs/DiagnosticArray` | every statistics interval, every recorded channel |
//! | `/tf_static` | `tf2_msgs/TFMessage` | once, at the start: every link at the root frame |
//!
//! Each channel carries the QoS its ROS publisher offers, as rosbag2 records
//! it (`offered_qos_profiles`: sensor best-effort, `/diagnostics` reliable,
//! `/tf_static` reliable and transient-local), so `ros2 bag play` offers the
//! same and tf2's static listener matches `/tf_static`.
//!
//! They are copies at a bounded rate, not every frame: a cloud is 8 times
//! the bytes of the frame it shows. The frames themselves are in
//! `skinware_msgs/SkinFrame` (every one), which is what `skin replay` uses;
//! it ignores these.

use std::collections::BTreeMap;
use std::io::{Seek, Write};
use std::path::PathBuf;
use std::time::Duration;

use mcap::records::MessageHeader;
use skinware::{Reader, ReaderOptions, WriterState};
use skinware_geometry::SkinGeometry;
use skinware_ros2::cloud::{LayerClouds, static_links};
use skinware_ros2::diagnostics::{ChannelHealth, diagnostics};
use skinware_ros2::markers::ContactMarkers;
use skinware_ros2::qos::QosClass;
use skinware_ros2::standard::{DIAGNOSTIC_ARRAY, MARKER_ARRAY, POINT_CLOUD2, TF_MESSAGE};
use skinware_ros2::{Time, unix_ns};
use skinware_services::RegionContacts;

use super::discovery::Sources;
use super::queue::QueueSender;
use super::{Item, RecordOptions, add_schema};
use crate::MESSAGE_ENCODING;

/// One layer's clouds and where they go.
struct LayerTopics {
    /// The layer's index in the geometry (and in the watcher's newest frames).
    layer: usize,
    clouds: LayerClouds,
    /// Each cloud's MCAP channel.
    channels: Vec<u16>,
    /// The newest frame drawn: each frame once, whatever the ticks.
    last_seq: u64,
}

/// A recorded contact service, drawn as markers.
struct ContactSource {
    name: String,
    channel_id: u16,
    /// Opened by the watcher (its own reader), once it can be.
    reader: Option<Reader>,
    /// The newest frame drawn.
    last_seq: u64,
}

/// The ROS tools' view of a recording: its channels, and the watcher's own
/// readers for what it draws.
pub(super) struct RosView {
    /// `/tf_static`'s channel and its one message, until written.
    tf_static: Option<(u16, Vec<u8>)>,
    /// The layers drawn as clouds.
    clouds: Vec<LayerTopics>,
    contacts: Vec<ContactSource>,
    diagnostics_channel: u16,
    /// Per recorded channel, in the recording's order: its name and the
    /// watcher's reader of it (for its writer's counters and period).
    health: Vec<(String, Option<Reader>)>,
    root_frame: String,
    /// How long a marker lives without an update.
    marker_lifetime: Duration,
    skin: String,
    reader_options: ReaderOptions,
}

/// Adds the view's schemas and channels to `writer` (its `/tf_static`
/// message is written by [`RosView::write_static`]); `None` if the view is
/// not wanted (`ros2_hz` 0).
pub(super) fn add_view<W: Write + Seek>(
    writer: &mut mcap::Writer<W>,
    options: &RecordOptions,
    sources: &Sources,
    dir: PathBuf,
    started_unix_ns: u64,
) -> Result<Option<RosView>, mcap::McapError> {
    // Also a NaN: `RecordOptions` is public, and only the CLI checks it.
    if !(options.ros2_hz > 0.0 && options.ros2_hz.is_finite()) {
        return Ok(None);
    }
    // Each with the QoS a ROS publisher of it offers, as rosbag2 records it.
    let channel = |writer: &mut mcap::Writer<W>, schema: u16, topic: &str, qos: QosClass| {
        let metadata = BTreeMap::from([("offered_qos_profiles".to_owned(), qos.offered_qos_profiles())]);
        writer.add_channel(schema, topic, MESSAGE_ENCODING, &metadata)
    };
    let skin = &options.skin;
    let mut clouds = Vec::new();
    let mut tf_static = None;
    if let Some(geometry) = &sources.geometry {
        let cloud_schema = add_schema(writer, POINT_CLOUD2)?;
        let mut topics = std::collections::BTreeSet::new();
        for layer in 0..geometry.layers.len() {
            let Some(layer_clouds) = LayerClouds::new(geometry, layer) else { continue };
            let mut channels = Vec::new();
            for cloud in &layer_clouds.clouds {
                let topic =
                    unique_topic(&mut topics, skinware_ros2::cloud_topic(skin, &layer_clouds.layer, &cloud.link));
                channels.push(channel(writer, cloud_schema, &topic, QosClass::Sensor)?);
            }
            clouds.push(LayerTopics { layer, clouds: layer_clouds, channels, last_seq: 0 });
        }
        let tf_schema = add_schema(writer, TF_MESSAGE)?;
        let tf_channel = channel(writer, tf_schema, skinware_ros2::TF_STATIC_TOPIC, QosClass::Static)?;
        if let Ok(data) = static_links(geometry, &options.root_frame, Time::from_ns(started_unix_ns)) {
            tf_static = Some((tf_channel, data));
        }
    }
    let mut contacts = Vec::new();
    let mut marker_schema = None;
    for recorded in sources.facts.iter().filter(|c| c.is_contacts) {
        let schema_id = match marker_schema {
            Some(id) => id,
            None => *marker_schema.insert(add_schema(writer, MARKER_ARRAY)?),
        };
        let name = recorded.name.clone();
        let channel_id = channel(writer, schema_id, &skinware_ros2::markers_topic(skin, &name), QosClass::Sensor)?;
        contacts.push(ContactSource { name, channel_id, reader: None, last_seq: 0 });
    }
    let diagnostics_schema = add_schema(writer, DIAGNOSTIC_ARRAY)?;
    let diagnostics_channel = channel(writer, diagnostics_schema, skinware_ros2::DIAGNOSTICS_TOPIC, QosClass::Status)?;
    let period = Duration::from_secs_f64(1.0 / options.ros2_hz.clamp(0.1, 60.0));
    Ok(Some(RosView {
        tf_static,
        clouds,
        contacts,
        diagnostics_channel,
        health: sources.facts.iter().map(|c| (c.name.clone(), None)).collect(),
        root_frame: options.root_frame.clone(),
        marker_lifetime: (period * 3).max(Duration::from_millis(200)),
        skin: skin.clone(),
        reader_options: ReaderOptions { dir: Some(dir), allow_gone: true, ..ReaderOptions::default() },
    }))
}

impl RosView {
    /// Every MCAP channel id the view sends to, in a fixed order.
    pub(super) fn channel_ids(&self) -> Vec<u16> {
        let mut ids: Vec<u16> = self.tf_static.iter().map(|(id, _)| *id).collect();
        for layer in &self.clouds {
            ids.extend_from_slice(&layer.channels);
        }
        ids.extend(self.contacts.iter().map(|c| c.channel_id));
        ids.push(self.diagnostics_channel);
        ids
    }

    /// Writes `/tf_static`'s one message. Last in the file's start: readers
    /// of a recording's start (skinware's own) stop at its first message,
    /// and must have seen every channel, the metadata and the attachments.
    pub(super) fn write_static<W: Write + Seek>(
        &mut self,
        writer: &mut mcap::Writer<W>,
        started_unix_ns: u64,
    ) -> Result<(), mcap::McapError> {
        let Some((channel_id, data)) = self.tf_static.take() else { return Ok(()) };
        let header =
            MessageHeader { channel_id, sequence: 0, log_time: started_unix_ns, publish_time: started_unix_ns };
        writer.write_to_known_channel(&header, &data)
    }

    /// Sends the clouds of every layer whose newest frame was not drawn yet;
    /// `newest[l]` is geometry layer `l`'s newest frame (responses, sequence
    /// number, acquisition time in Unix ns), if read. `false` once the file
    /// is gone.
    pub(super) fn send_clouds(&mut self, newest: &[Option<(&[u16], u64, u64)>], sender: &QueueSender<Item>) -> bool {
        for layer in &mut self.clouds {
            let Some(Some((responses, seq, acquired_unix_ns))) = newest.get(layer.layer) else { continue };
            if *seq == layer.last_seq {
                continue;
            }
            layer.last_seq = *seq;
            for (cloud, &channel_id) in layer.clouds.clouds.iter().zip(&layer.channels) {
                let Ok(data) = cloud.encode(responses, Time::from_ns(*acquired_unix_ns)) else { continue };
                let item = Item {
                    channel_id,
                    sequence: 0,
                    log_time: *acquired_unix_ns,
                    publish_time: *acquired_unix_ns,
                    data,
                };
                if sender.send(item).is_err() {
                    return false;
                }
            }
        }
        true
    }

    /// Sends each contact service's newest frame as markers, if it is new.
    pub(super) fn send_markers(
        &mut self,
        geometry: Option<&SkinGeometry>,
        clock_offset_ns: i64,
        sender: &QueueSender<Item>,
    ) -> bool {
        let drawing = ContactMarkers { geometry, root: &self.root_frame, lifetime: self.marker_lifetime };
        for source in &mut self.contacts {
            if source.reader.is_none() {
                source.reader = Reader::open_with(&self.skin, &source.name, &self.reader_options).ok();
            }
            let Some(reader) = &mut source.reader else { continue };
            let Ok(frame) = reader.latest() else { continue };
            if frame.seq() == source.last_seq {
                continue;
            }
            source.last_seq = frame.seq();
            // A service's frame is its writer's bytes: whole records only.
            let stamp_ns = unix_ns(frame.acquired_ns(), clock_offset_ns);
            let Ok(data) = drawing.encode(&frame.records::<RegionContacts>(), Time::from_ns(stamp_ns)) else {
                continue;
            };
            let item =
                Item { channel_id: source.channel_id, sequence: 0, log_time: stamp_ns, publish_time: stamp_ns, data };
            if sender.send(item).is_err() {
                return false;
            }
        }
        true
    }

    /// Sends every recorded channel's health: `states` and `rates_hz` are
    /// the recording's, per channel, over the last statistics interval.
    pub(super) fn send_diagnostics(
        &mut self,
        states: &[WriterState],
        rates_hz: &[f64],
        now_ns: u64,
        sender: &QueueSender<Item>,
    ) -> bool {
        let mut channels = Vec::new();
        for (((name, reader), &state), &rate_hz) in self.health.iter_mut().zip(states).zip(rates_hz) {
            if reader.is_none() {
                *reader = Reader::open_with(&self.skin, name, &self.reader_options).ok();
            }
            let (stats, nominal_hz) = match reader {
                // The period is the writer's number: one under a microsecond
                // (or none) is no nominal rate to judge by.
                Some(reader) => (
                    reader.writer_stats(),
                    reader
                        .writer_period()
                        .filter(|p| *p >= Duration::from_micros(1))
                        .map_or(0.0, |p| 1.0 / p.as_secs_f64()),
                ),
                None => (Default::default(), 0.0),
            };
            channels.push(ChannelHealth {
                channel: name.clone(),
                // The recorder knows the channel, not the process writing it.
                writer: format!("skinware {}", self.skin),
                state,
                rate_hz,
                nominal_hz,
                stats,
                restarts: None,
            });
        }
        let Ok(data) = diagnostics(&self.skin, &channels, Time::from_ns(now_ns)) else { return true };
        let item =
            Item { channel_id: self.diagnostics_channel, sequence: 0, log_time: now_ns, publish_time: now_ns, data };
        sender.send(item).is_ok()
    }
}

/// `topic`, or, if another topic of the view took that name already (two
/// links whose names differ only in characters ROS forbids), it with `_2`,
/// `_3`, ... appended.
fn unique_topic(taken: &mut std::collections::BTreeSet<String>, topic: String) -> String {
    let mut unique = topic.clone();
    let mut n = 2;
    while !taken.insert(unique.clone()) {
        unique = format!("{topic}_{n}");
        n += 1;
    }
    unique
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_links_never_share_a_topic() {
        let mut taken = std::collections::BTreeSet::new();
        assert_eq!(unique_topic(&mut taken, "/skin/s/l/cloud/a_b".into()), "/skin/s/l/cloud/a_b");
        assert_eq!(unique_topic(&mut taken, "/skin/s/l/cloud/a_b".into()), "/skin/s/l/cloud/a_b_2");
        assert_eq!(unique_topic(&mut taken, "/skin/s/l/cloud/a_b".into()), "/skin/s/l/cloud/a_b_3");
    }
}
