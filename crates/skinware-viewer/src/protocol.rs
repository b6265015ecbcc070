//! The viewer's wire format: binary WebSocket messages from the server, small
//! JSON text messages from the browser (decoded by [`crate::message`]).
//! `docs/viewer.md` documents it byte by byte; `page.js` decodes it. Everything is little-endian, and every array
//! starts at an offset aligned to its element size, so that the browser can
//! view it in place with a typed array.

#![forbid(unsafe_code)]

use skinware::WriterState;
use skinware_geometry::{SensorRef, SkinGeometry};

use crate::compact;
use crate::labels;
use crate::message::ReadMode;
use crate::overlays::Overlays;
use crate::sampler::LayerSlot;

/// Bumped on any change of the layout below; the page refuses other
/// versions, and the server refuses pages that do not ask for this one
/// ([`WEBSOCKET_PATH`]). 2: connecting state, colour ranges, piece labels
/// and places. 3: the responses in updates in the compact encoding of
/// [`crate::compact`] (43 % of the raw bytes on `skin demo`'s skin).
pub const PROTOCOL_VERSION: u8 = 3;
/// Where a page of this version opens its WebSocket: the version it speaks
/// is in the query, so that a page of another version (open in a tab from
/// before an upgrade) gets a message asking for a reload instead of bytes it
/// cannot read.
pub const WEBSOCKET_PATH: &str = "/ws?protocol=3";
/// First byte of the geometry message.
pub const KIND_GEOMETRY: u8 = 1;
/// First byte of an update message.
pub const KIND_UPDATE: u8 = 2;
/// Bytes of the geometry header, before the layer table.
pub const GEOMETRY_HEADER_BYTES: usize = 32;
/// Bytes of the update header.
pub const UPDATE_HEADER_BYTES: usize = 16;
/// Bytes of one layer's record in an update.
pub const LAYER_RECORD_BYTES: usize = 32;
/// Where a layer's record holds the sequence number (u64) of its newest frame.
pub const LAYER_SEQ_OFFSET: usize = 16;
/// Bytes of one arrow or one marker.
pub const OVERLAY_RECORD_BYTES: usize = 16;
/// Flag of a layer record: its responses follow in this update.
pub const FLAG_RESPONSES: u8 = 1;
/// Flag of a layer record: its newest frame carries the fault status.
pub const FLAG_FAULT_FRAME: u8 = 2;
/// The state code of a layer not read yet (connecting).
pub const STATE_CONNECTING: u8 = 0;

/// The code of a reader mode in update headers.
pub fn mode_code(mode: ReadMode) -> u8 {
    match mode {
        ReadMode::Periodic { .. } => 0,
        ReadMode::Asap => 1,
        ReadMode::Request => 2,
    }
}

/// The code of a writer state in layer records: the state's one number
/// ([`WriterState::code`]: 1 running, 2 paused, 3 faulted, 4 gone), as in
/// shared memory, recordings and the bridge; [`STATE_CONNECTING`] (0)
/// before the layer was read.
pub fn state_code(state: Option<WriterState>) -> u8 {
    // The codes are 1 to 4.
    state.map_or(STATE_CONNECTING, |state| state.code() as u8)
}

/// One layer in an update: its newest state as sampled, and whether its
/// responses go along (only when they changed since the last update sent).
/// A session keeps one per layer and refreshes it in place for each update.
#[derive(Clone, Debug)]
pub struct LayerUpdate {
    /// The layer's slot as taken from the board (its responses shared with it).
    pub slot: LayerSlot,
    /// Send its responses.
    pub with_responses: bool,
}

impl LayerUpdate {
    /// The responses this update carries of this layer, if any.
    pub fn responses(&self) -> Option<&[u16]> {
        self.with_responses.then_some(self.slot.responses.as_slice())
    }

    /// The same, in the compact encoding: encoded by the first session
    /// that sends this frame, and shared with the others.
    pub fn compact_responses(&self) -> Option<&[u8]> {
        self.with_responses.then(|| self.slot.compact_responses())
    }
}

fn pad_to_4(out: &mut Vec<u8>) {
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
}

/// One line of the geometry's names: a newline in a name would split it.
fn one_line(name: &str) -> std::borrow::Cow<'_, str> {
    if name.contains('\n') { name.replace('\n', " ").into() } else { name.into() }
}

/// The message sent once at connect: layers, the labels of the map's
/// pieces, map positions and, per sensor, uid, module id, patch id and
/// place (a sensor's layer follows from the layer ranges).
pub fn encode_geometry(geometry: &SkinGeometry) -> Vec<u8> {
    let sensors = geometry.sensor_count();
    let layers = geometry.layers.len().min(usize::from(u16::MAX));
    let labels = labels::piece_labels(geometry);
    let places = labels::places(geometry);
    let mut bounds = [f32::INFINITY, f32::INFINITY, f32::NEG_INFINITY, f32::NEG_INFINITY];
    for &[x, y] in &geometry.map.positions {
        bounds = [bounds[0].min(x), bounds[1].min(y), bounds[2].max(x), bounds[3].max(y)];
    }
    if sensors == 0 {
        bounds = [0.0, 0.0, 1.0, 1.0];
    }
    let mut out = Vec::with_capacity(64 + layers * 12 + labels.len() * 16 + sensors * 24);
    out.push(KIND_GEOMETRY);
    out.push(PROTOCOL_VERSION);
    out.extend_from_slice(&(layers as u16).to_le_bytes());
    out.extend_from_slice(&(sensors as u32).to_le_bytes());
    for value in bounds {
        out.extend_from_slice(&value.to_le_bytes());
    }
    out.extend_from_slice(&(places.texts.len() as u32).to_le_bytes());
    out.extend_from_slice(&(labels.len() as u32).to_le_bytes());
    for (index, layer) in geometry.layers.iter().take(layers).enumerate() {
        out.extend_from_slice(&(geometry.layer_starts[index] as u32).to_le_bytes());
        out.extend_from_slice(&(layer.sensors.len() as u32).to_le_bytes());
        out.extend_from_slice(&(layer.rate_hz as f32).to_le_bytes());
    }
    let layer_list = &geometry.layers[..layers];
    let names: Vec<std::borrow::Cow<'_, str>> = std::iter::once(geometry.skin.as_str())
        .chain(layer_list.iter().map(|l| l.name.as_str()))
        .chain(layer_list.iter().map(|l| l.sensor_type.as_str()))
        .chain(places.texts.iter().map(String::as_str))
        .chain(labels.iter().map(|label| label.text.as_str()))
        .map(one_line)
        .collect();
    let names = names.join("\n");
    out.extend_from_slice(&(names.len() as u32).to_le_bytes());
    out.extend_from_slice(names.as_bytes());
    pad_to_4(&mut out);
    for label in &labels {
        for value in label.bounds {
            out.extend_from_slice(&value.to_le_bytes());
        }
    }
    for index in 0..sensors {
        let [x, y] = geometry.map.positions.get(index).copied().unwrap_or([0.0, 0.0]);
        out.extend_from_slice(&x.to_le_bytes());
        out.extend_from_slice(&y.to_le_bytes());
    }
    let located: Vec<Option<SensorRef>> = (0..sensors).map(|index| geometry.locate(index)).collect();
    let fields: [fn(&SensorRef) -> u32; 3] = [|s| s.uid, |s| s.module_id, |s| s.patch_id];
    for field in fields {
        for sensor in &located {
            out.extend_from_slice(&sensor.as_ref().map_or(0, field).to_le_bytes());
        }
    }
    for &place in &places.place_of {
        out.extend_from_slice(&place.to_le_bytes());
    }
    out
}

/// Encodes into `out` (cleared first, and reused between updates: no
/// allocation once it has grown to an update's size) a whole update: the
/// header, the layer records, the overlays, then the responses of the
/// layers sent `with_responses`, in layer order, each in the compact
/// encoding ([`compact::encode`]), which each frame gets once, shared by
/// every session that sends it ([`LayerUpdate::compact_responses`]). The
/// part before the responses is a multiple of 4 bytes long, and so is each
/// layer's encoding, so that their words start aligned.
pub fn encode_update(out: &mut Vec<u8>, number: u32, mode: ReadMode, layers: &[LayerUpdate], overlays: &Overlays) {
    encode_update_head(out, number, mode, layers, overlays);
    let sent = || layers.iter().take(usize::from(u16::MAX));
    // The most any responses can take: the buffer grows once, whatever comes.
    out.reserve(sent().filter_map(LayerUpdate::responses).map(|r| compact::max_encoded_bytes(r.len())).sum());
    for encoded in sent().filter_map(LayerUpdate::compact_responses) {
        out.extend_from_slice(encoded);
    }
}

/// Everything of an update that precedes the responses.
fn encode_update_head(out: &mut Vec<u8>, number: u32, mode: ReadMode, layers: &[LayerUpdate], overlays: &Overlays) {
    out.clear();
    let arrows = overlays.arrows.len().min(usize::from(u16::MAX));
    let markers = overlays.markers.len().min(usize::from(u16::MAX));
    out.reserve(UPDATE_HEADER_BYTES + layers.len() * LAYER_RECORD_BYTES + (arrows + markers) * OVERLAY_RECORD_BYTES);
    out.push(KIND_UPDATE);
    out.push(mode_code(mode));
    out.extend_from_slice(&(layers.len().min(usize::from(u16::MAX)) as u16).to_le_bytes());
    out.extend_from_slice(&number.to_le_bytes());
    out.extend_from_slice(&(arrows as u16).to_le_bytes());
    out.extend_from_slice(&(markers as u16).to_le_bytes());
    out.extend_from_slice(&[0; 4]);
    for layer in layers.iter().take(usize::from(u16::MAX)) {
        let mut flags = 0;
        let slot = &layer.slot;
        if layer.with_responses {
            flags |= FLAG_RESPONSES;
        }
        if slot.fault_frame {
            flags |= FLAG_FAULT_FRAME;
        }
        let full_scale = slot.range.map_or(0, |range| range.full_scale());
        out.extend_from_slice(&[state_code(slot.state), flags]);
        out.extend_from_slice(&full_scale.to_le_bytes());
        out.extend_from_slice(&slot.writer_rate_hz.to_le_bytes());
        out.extend_from_slice(&slot.read_rate_hz.to_le_bytes());
        out.extend_from_slice(&slot.latency_ms.to_le_bytes());
        out.extend_from_slice(&slot.seq.to_le_bytes());
        let range = slot.range.map_or([0, 0], |range| [range.resting, range.highest]);
        out.extend_from_slice(&range[0].to_le_bytes());
        out.extend_from_slice(&range[1].to_le_bytes());
        out.extend_from_slice(&[0; 4]);
    }
    for arrow in &overlays.arrows[..arrows] {
        for value in [arrow.from[0], arrow.from[1], arrow.to[0], arrow.to[1]] {
            out.extend_from_slice(&value.to_le_bytes());
        }
    }
    for marker in &overlays.markers[..markers] {
        for value in [marker.at[0], marker.at[1], marker.radius, marker.pressure] {
            out.extend_from_slice(&value.to_le_bytes());
        }
    }
}

/// `values` as raw little-endian bytes, as protocol 2 sent them (and as
/// the bench's floor server still sends a board, from where the readers
/// left it): on a little-endian machine the values themselves, not a copy;
/// elsewhere converted into `scratch`.
pub fn responses_le<'a>(values: &'a [u16], scratch: &'a mut Vec<u8>) -> &'a [u8] {
    if cfg!(target_endian = "little") {
        bytemuck::cast_slice(values)
    } else {
        scratch.clear();
        scratch.extend(values.iter().flat_map(|value| value.to_le_bytes()));
        scratch
    }
}

/// Why bytes are not an update of a skin of the given layers.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum UpdateError {
    /// Shorter than its header, layer records and overlays, or not of kind 2.
    #[error("not an update message ({bytes} bytes, kind {kind})")]
    NotAnUpdate {
        /// The message's length.
        bytes: usize,
        /// Its first byte.
        kind: u8,
    },
    /// Of another number of layers than the geometry's.
    #[error("an update of {found} layers, the geometry has {expected}")]
    Layers {
        /// Layers in the update.
        found: usize,
        /// Layers in the geometry.
        expected: usize,
    },
    /// A layer's responses do not decode.
    #[error("layer {layer}'s responses: {source}")]
    Responses {
        /// The layer (from 0).
        layer: usize,
        /// What is wrong with them.
        source: compact::CompactError,
    },
    /// Bytes left after the last layer's responses.
    #[error("{left} bytes after the last layer's responses")]
    Trailing {
        /// How many.
        left: usize,
    },
}

/// The responses an update carries, decoded, for a skin whose layers have
/// `layer_sensors` sensors each: per layer, `Some` if its flag 1 is set.
/// What the browser test checks the page's decoder against (the page has
/// its own, in `page.js`).
pub fn decode_update_responses(message: &[u8], layer_sensors: &[usize]) -> Result<Vec<Option<Vec<u16>>>, UpdateError> {
    let u16_at = |at: usize| message.get(at..at + 2).map_or(0, |b| u16::from_le_bytes([b[0], b[1]]));
    let layers = usize::from(u16_at(2));
    let arrows_and_markers = usize::from(u16_at(8)) + usize::from(u16_at(10));
    let head = UPDATE_HEADER_BYTES + layers * LAYER_RECORD_BYTES + arrows_and_markers * OVERLAY_RECORD_BYTES;
    if message.first() != Some(&KIND_UPDATE) || message.len() < head {
        return Err(UpdateError::NotAnUpdate { bytes: message.len(), kind: message.first().copied().unwrap_or(0) });
    }
    if layers != layer_sensors.len() {
        return Err(UpdateError::Layers { found: layers, expected: layer_sensors.len() });
    }
    let mut at = head;
    let mut decoded = Vec::with_capacity(layers);
    for (layer, &sensors) in layer_sensors.iter().enumerate() {
        let flags = message[UPDATE_HEADER_BYTES + layer * LAYER_RECORD_BYTES + 1];
        if flags & FLAG_RESPONSES == 0 {
            decoded.push(None);
            continue;
        }
        let mut values = vec![0; sensors];
        at +=
            compact::decode(&message[at..], &mut values).map_err(|source| UpdateError::Responses { layer, source })?;
        decoded.push(Some(values));
    }
    match message.len() - at {
        0 => Ok(decoded),
        left => Err(UpdateError::Trailing { left }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::overlays::{Arrow, Marker};
    use crate::range::ResponseRange;

    fn f32_at(bytes: &[u8], offset: usize) -> f32 {
        f32::from_le_bytes(bytes[offset..offset + 4].try_into().unwrap())
    }

    fn u16_at(bytes: &[u8], offset: usize) -> u16 {
        u16::from_le_bytes(bytes[offset..offset + 2].try_into().unwrap())
    }

    fn u32_at(bytes: &[u8], offset: usize) -> u32 {
        u32::from_le_bytes(bytes[offset..offset + 4].try_into().unwrap())
    }

    fn slot(state: Option<WriterState>, rates: [f32; 3], seq: u64, fault_frame: bool, responses: &[u16]) -> LayerSlot {
        LayerSlot {
            state,
            writer_rate_hz: rates[0],
            read_rate_hz: rates[1],
            latency_ms: rates[2],
            seq,
            fault_frame,
            range: None,
            responses: std::sync::Arc::new(responses.to_vec()),
            compact: std::sync::Arc::default(),
        }
    }

    #[test]
    fn update_carries_states_ranges_changed_responses_and_synthetic_overlays_where_documented() {
        let overlays = Overlays {
            arrows: vec![Arrow { from: [0.1, 0.2], to: [0.3, -0.4] }],
            markers: vec![
                Marker { at: [0.5, 0.6], radius: 0.02, pressure: 1234.0 },
                Marker { at: [-1.0, 2.0], radius: 0.05, pressure: 7.5 },
            ],
        };
        let mut running = slot(Some(WriterState::Running), [41.5, 40.0, 0.25], 77, false, &[10, 20, 30]);
        running.range = Some(ResponseRange { resting: 15, highest: 255 });
        let layers = [
            LayerUpdate { slot: running, with_responses: true },
            LayerUpdate { slot: slot(Some(WriterState::Faulted), [0.0; 3], 5, true, &[9, 9]), with_responses: false },
            LayerUpdate { slot: slot(Some(WriterState::Gone), [0.0; 3], 0, false, &[65535, 1]), with_responses: true },
            LayerUpdate { slot: slot(None, [0.0; 3], 0, false, &[0]), with_responses: false },
        ];
        let mut out = vec![0xAA; 3];
        encode_update(&mut out, 9, ReadMode::Periodic { rate_hz: 30.0 }, &layers, &overlays);
        let overlays_at = UPDATE_HEADER_BYTES + 4 * LAYER_RECORD_BYTES;
        let responses_at = overlays_at + 3 * OVERLAY_RECORD_BYTES;
        // Two layers' responses, one block each: a head and a word per lane.
        // 10, 20, 30: first 10, differences 0, 10, 10, zigzag 0, 20, 20: 5 bits.
        // 65535, 1: first 65535, differences 0, 2 (modulo 2^16), zigzag 0, 4: 3 bits.
        assert_eq!(out.len(), responses_at + 20 + 20, "only the responses of changed layers are sent");
        assert_eq!(&out[..4], &[KIND_UPDATE, 0, 4, 0]);
        assert_eq!(u32_at(&out, 4), 9);
        assert_eq!((u16_at(&out, 8), u16_at(&out, 10)), (1, 2));
        let record = |i: usize| &out[UPDATE_HEADER_BYTES + i * LAYER_RECORD_BYTES..][..LAYER_RECORD_BYTES];
        // WriterState::code: 1 running, 3 faulted, 4 gone; 0 connecting.
        assert_eq!(&record(0)[..2], &[1, FLAG_RESPONSES]);
        assert_eq!(&record(1)[..2], &[3, FLAG_FAULT_FRAME]);
        assert_eq!(&record(2)[..2], &[4, FLAG_RESPONSES]);
        assert_eq!(&record(3)[..2], &[STATE_CONNECTING, 0]);
        assert_eq!(u16_at(record(0), 2), 240, "full colour at the range learnt: 255 - 15");
        assert_eq!((u16_at(record(0), 24), u16_at(record(0), 26)), (15, 255));
        assert_eq!((u16_at(record(1), 2), u16_at(record(1), 24), u16_at(record(1), 26)), (0, 0, 0), "no range yet");
        assert_eq!(f32_at(record(0), 4), 41.5);
        assert_eq!(f32_at(record(0), 8), 40.0);
        assert_eq!(f32_at(record(0), 12), 0.25);
        assert_eq!(u64::from_le_bytes(record(0)[LAYER_SEQ_OFFSET..][..8].try_into().unwrap()), 77);
        let arrow: Vec<f32> = (0..4).map(|i| f32_at(&out, overlays_at + 4 * i)).collect();
        assert_eq!(arrow, [0.1, 0.2, 0.3, -0.4]);
        let second_marker: Vec<f32> = (0..4).map(|i| f32_at(&out, overlays_at + 32 + 4 * i)).collect();
        assert_eq!(second_marker, [-1.0, 2.0, 0.05, 7.5]);
        assert_eq!(u32_at(&out, responses_at), 10 | 5 << 16, "the first block's first value and width");
        let words = |at: usize| [0, 4, 8, 12].map(|offset| u32_at(&out, at + offset));
        assert_eq!(words(responses_at + 4), [0, 20, 20, 0], "one lane each");
        assert_eq!(u32_at(&out, responses_at + 20), 65535 | 3 << 16);
        assert_eq!(words(responses_at + 24), [0, 4, 0, 0]);
        let decoded = decode_update_responses(&out, &[3, 2, 2, 1]).unwrap();
        assert_eq!(decoded, [Some(vec![10, 20, 30]), None, Some(vec![65535, 1]), None]);
        assert_eq!(responses_at % 4, 0, "the responses' words must be viewable as a Uint32Array in place");
        assert_eq!(decode_update_responses(&out, &[3, 2, 2]), Err(UpdateError::Layers { found: 4, expected: 3 }));
        let cut = decode_update_responses(&out[..out.len() - 4], &[3, 2, 2, 1]);
        assert!(matches!(cut, Err(UpdateError::Responses { layer: 2, .. })), "{cut:?}");
        let mut longer = out.clone();
        longer.extend_from_slice(&[0; 4]);
        assert_eq!(decode_update_responses(&longer, &[3, 2, 2, 1]), Err(UpdateError::Trailing { left: 4 }));
        assert!(matches!(decode_update_responses(&out[..40], &[3, 2, 2, 1]), Err(UpdateError::NotAnUpdate { .. })));
    }

    /// A session's buffer, once grown to an update's size, is reused: the
    /// next updates (of any responses) encode into it without allocating.
    #[test]
    fn updates_encode_into_the_reused_buffer_without_allocating() {
        let layer = |values: Vec<u16>| LayerUpdate {
            slot: slot(Some(WriterState::Running), [0.0; 3], 1, false, &values),
            with_responses: true,
        };
        let quiet: Vec<LayerUpdate> = (0..5).map(|_| layer(vec![1000; 6_170])).collect();
        let noisy: Vec<LayerUpdate> = (0..5)
            .map(|l| layer((0..6_170u32).map(|i| ((i + l).wrapping_mul(2_654_435_761) >> 16) as u16).collect()))
            .collect();
        let mut out = Vec::new();
        encode_update(&mut out, 0, ReadMode::Asap, &quiet, &Overlays::default());
        let (capacity, address) = (out.capacity(), out.as_ptr());
        for (number, layers) in [&noisy, &quiet, &noisy].into_iter().enumerate() {
            encode_update(&mut out, number as u32, ReadMode::Asap, layers, &Overlays::default());
            assert_eq!((out.capacity(), out.as_ptr()), (capacity, address), "update {number} allocated");
        }
        assert!(out.len() > 5 * 2 * 6_170, "the noisy responses do not pack: {} bytes", out.len());
    }

    #[test]
    fn geometry_message_holds_layers_names_labels_positions_ids_and_places_where_documented() {
        let geometry = crate::virtual_geometry("small", 240);
        let out = encode_geometry(&geometry);
        let u32_at = |offset: usize| u32_at(&out, offset);
        assert_eq!(&out[..4], &[KIND_GEOMETRY, PROTOCOL_VERSION, 2, 0]);
        assert_eq!(u32_at(4), 240);
        let [min_x, min_y, max_x, max_y] = [8, 12, 16, 20].map(|offset| f32_at(&out, offset));
        assert!(
            geometry.map.positions.iter().all(|&[x, y]| (min_x..=max_x).contains(&x) && (min_y..=max_y).contains(&y))
        );
        let places = labels::places(&geometry);
        let labels = labels::piece_labels(&geometry);
        assert!(!labels.is_empty());
        assert_eq!((u32_at(24) as usize, u32_at(28) as usize), (places.texts.len(), labels.len()));
        let table = GEOMETRY_HEADER_BYTES;
        assert_eq!((u32_at(table), u32_at(table + 4)), (0, 120));
        assert_eq!((u32_at(table + 12), u32_at(table + 16)), (120, 120));
        assert_eq!(f32_at(&out, table + 20), geometry.layers[1].rate_hz as f32);
        let text_bytes = u32_at(table + 24) as usize;
        let text = std::str::from_utf8(&out[table + 28..table + 28 + text_bytes]).unwrap();
        let lines: Vec<&str> = text.split('\n').collect();
        assert_eq!(&lines[..5], ["small", "v-0", "v-1", "pressure", "pressure"]);
        assert_eq!(lines[5..5 + places.texts.len()], places.texts);
        let label_texts: Vec<&str> = labels.iter().map(|l| l.text.as_str()).collect();
        assert_eq!(lines[5 + places.texts.len()..], label_texts);
        let labels_at = (table + 28 + text_bytes).next_multiple_of(4);
        assert_eq!([0, 4, 8, 12].map(|d| f32_at(&out, labels_at + d)), labels[0].bounds);
        let positions_at = labels_at + 16 * labels.len();
        assert_eq!(out.len(), positions_at + 240 * 8 + 4 * 240 * 4);
        let sensor = 157;
        let at = positions_at + 8 * sensor;
        assert_eq!([f32_at(&out, at), f32_at(&out, at + 4)], geometry.map.positions[sensor]);
        let ids_at = positions_at + 240 * 8;
        let expected = geometry.locate(sensor).unwrap();
        assert_eq!(
            [u32_at(ids_at + 4 * sensor), u32_at(ids_at + 960 + 4 * sensor), u32_at(ids_at + 1920 + 4 * sensor)],
            [expected.uid, expected.module_id, expected.patch_id]
        );
        let place = u32_at(ids_at + 2880 + 4 * sensor) as usize;
        let link = &geometry.links[usize::from(geometry.link_of[sensor])];
        assert_eq!(places.texts[place], format!("link {link}"));
    }

    #[test]
    fn the_websocket_path_asks_for_this_version() {
        assert_eq!(WEBSOCKET_PATH, format!("/ws?protocol={PROTOCOL_VERSION}"));
    }
}
