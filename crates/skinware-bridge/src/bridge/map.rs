//! The map thread: the skin's 2-D map as a `sensor_msgs/Image` for ROS
//! nodes, a few times a second, drawn only while a subscriber listens.

use std::sync::Arc;

use skinware::{Reader, WriterState};
use skinware_geometry::SkinGeometry;
use skinware_ros2::{Header, HeatMap, IMAGE, LayerLook, Time};

use super::Shared;
use super::ros::RosPublisher;
use crate::BridgeError;

/// The 2-D map as a `sensor_msgs/Image`, a few times a second.
pub(super) fn publish_map(shared: &Arc<Shared>) -> Result<(), BridgeError> {
    let skin = &shared.options.skin;
    let geometry = SkinGeometry::open_in(&shared.dir, skin).map_err(|source| BridgeError::Geometry {
        context: format!("skin {skin} publishes no geometry to draw"),
        source: Box::new(source),
    })?;
    let ros = RosPublisher::declare(shared, &skinware_ros2::map_topic(skin), IMAGE)?;
    let mut heatmap = HeatMap::new(&geometry, shared.options.map_width);
    let mut readers: Vec<Option<Reader>> = geometry.layers.iter().map(|_| None).collect();
    let mut ticker = skinware::Ticker::from_hz(shared.options.map_hz);
    while ticker.wait(&shared.stop).is_some() {
        if !ros.wanted() {
            continue;
        }
        let newest = read_layers(shared, &geometry, &mut readers);
        let layers: Vec<(Option<&[u16]>, LayerLook)> = newest.iter().map(|(r, look)| (r.as_deref(), *look)).collect();
        let pixels = heatmap.render(&layers);
        let now = shared.wall_now_ns();
        let header = Header { stamp: Time::from_ns(now.max(0) as u64), frame_id: format!("{skin}/map") };
        let image = heatmap.image(pixels, header);
        let sent = skinware_ros2::encode(&image, 64 + image.data.len())
            .map_err(BridgeError::from)
            .and_then(|bytes| ros.put(bytes, now));
        if let Err(e) = sent {
            tracing::warn!("map: {e}");
        }
    }
    Ok(())
}

/// Every layer's newest responses and how to draw them, opening the layers
/// not open yet (`None`: not readable now, drawn as gone).
fn read_layers(
    shared: &Shared,
    geometry: &SkinGeometry,
    readers: &mut [Option<Reader>],
) -> Vec<(Option<Vec<u16>>, LayerLook)> {
    let mut newest = Vec::with_capacity(readers.len());
    for (slot, layer) in readers.iter_mut().zip(&geometry.layers) {
        if slot.is_none() {
            *slot = Reader::open_with(&shared.options.skin, &layer.name, &shared.reader_options()).ok();
        }
        let read = slot.as_mut().map(|reader| {
            reader.follow_recreated();
            let look = match reader.writer_state() {
                WriterState::Gone => LayerLook::Gone,
                WriterState::Faulted => LayerLook::Faulted,
                _ => LayerLook::Live,
            };
            (reader.latest().ok().map(|f| f.responses().to_vec()), look)
        });
        newest.push(read.unwrap_or((None, LayerLook::Gone)));
    }
    newest
}
