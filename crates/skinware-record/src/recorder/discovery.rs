//! What a recording reads: the chosen layers and services of the skin,
//! opened as ordinary readers, and the geometry the skin publishes.

use std::collections::BTreeMap;
use std::path::Path;

use skinware::{ChannelKind, Reader, ReaderOptions, WriterState};
use skinware_geometry::SkinGeometry;
use skinware_services::{RegionContacts, ServicePayload};

use super::summary::channel_name;
use super::{RecordOptions, ServiceChoice};
use crate::{RecordError, channel_keys};

/// The skin as the recording found it at its start.
pub(super) struct Sources {
    /// One reader per recorded channel, layers first (none in the copy
    /// that starts the later parts of a split recording).
    pub(super) readers: Vec<Reader>,
    /// What a file's start says of each recorded channel, in the readers'
    /// order, taken from its reader once: every part of a split recording
    /// starts with the same channels, with the same ids.
    pub(super) facts: Vec<ChannelFacts>,
    /// The published geometry file, byte for byte (attached to the recording).
    pub(super) geometry_bytes: Option<Vec<u8>>,
    /// The same, decoded (the map image needs it).
    pub(super) geometry: Option<SkinGeometry>,
}

/// Opens a reader on every chosen channel of `options.skin`, and reads its geometry.
pub(super) fn open_sources(dir: &Path, options: &RecordOptions) -> Result<Sources, RecordError> {
    let chosen = choose_channels(dir, options)?;
    let reader_options = ReaderOptions { dir: Some(dir.to_owned()), ..ReaderOptions::default() };
    let mut readers = Vec::new();
    for name in &chosen {
        readers.push(Reader::open_with(&options.skin, name, &reader_options)?);
    }
    let geometry_path = SkinGeometry::published_path(dir, &options.skin);
    let geometry_bytes = skinware::shm::read_regular(&geometry_path, SkinGeometry::MAX_PUBLISHED_BYTES).ok();
    let geometry = geometry_bytes.as_deref().and_then(|bytes| match SkinGeometry::decode(bytes) {
        Ok(geometry) => Some(geometry),
        Err(e) => {
            tracing::warn!(skin = %options.skin, error = %e, "the published geometry does not decode; recording without it");
            None
        }
    });
    let facts = readers.iter().map(|reader| ChannelFacts::of(reader, &options.skin)).collect();
    Ok(Sources { readers, facts, geometry_bytes, geometry })
}

impl Sources {
    /// Everything but the readers: what starts the next part of a split recording.
    pub(super) fn without_readers(&self) -> Sources {
        Sources {
            readers: Vec::new(),
            facts: self.facts.clone(),
            geometry_bytes: self.geometry_bytes.clone(),
            geometry: self.geometry.clone(),
        }
    }
}

/// One recorded channel as a file's start describes it.
#[derive(Clone, Debug)]
pub(super) struct ChannelFacts {
    /// The channel's name within its skin.
    pub(super) name: String,
    /// Its frame topic's MCAP channel metadata: enough to recreate the channel on replay.
    pub(super) metadata: BTreeMap<String, String>,
    /// Its line in the `skin.layout` outline.
    pub(super) outline: String,
    /// Its description, byte for byte (attached).
    pub(super) description: Vec<u8>,
    /// Whether it is a contact service (drawn as markers for ROS tools).
    pub(super) is_contacts: bool,
}

impl ChannelFacts {
    fn of(reader: &Reader, skin: &str) -> ChannelFacts {
        let name = channel_name(reader);
        let topic = skinware_ros2::frame_topic(skin, &name);
        let contact_schema =
            (<RegionContacts as ServicePayload>::SCHEMA.to_owned(), <RegionContacts as ServicePayload>::VERSION);
        ChannelFacts {
            metadata: channel_metadata(reader),
            outline: describe(reader, &topic),
            description: reader.description(),
            is_contacts: reader.schema() == contact_schema,
            name,
        }
    }
}

/// A frame topic's channel metadata: enough to recreate the channel on replay.
fn channel_metadata(reader: &Reader) -> BTreeMap<String, String> {
    let (schema_name, schema_version) = reader.schema();
    let mut metadata = BTreeMap::new();
    metadata.insert(channel_keys::CHANNEL.to_owned(), channel_name(reader));
    metadata.insert(channel_keys::KIND.to_owned(), reader.kind().as_str().to_owned());
    metadata.insert(channel_keys::PAYLOAD_BYTES.to_owned(), reader.payload_bytes().to_string());
    metadata.insert(channel_keys::SLOTS.to_owned(), reader.slots().to_string());
    let period = reader.writer_period().map_or(0, |p| p.as_nanos() as u64);
    metadata.insert(channel_keys::PERIOD_NS.to_owned(), period.to_string());
    metadata.insert(channel_keys::SCHEMA_NAME.to_owned(), schema_name);
    metadata.insert(channel_keys::SCHEMA_VERSION.to_owned(), schema_version.to_string());
    metadata
}

/// The `skin.layout` entry of a channel: a readable outline.
fn describe(reader: &Reader, topic: &str) -> String {
    match (reader.kind(), reader.topology()) {
        (ChannelKind::Layer, Ok(t)) => format!(
            "layer {}: topic {topic}, {} sensors of type {} in {} modules on {} patches, {} Hz",
            t.name,
            t.sensors.len(),
            t.sensor_type,
            t.modules.len(),
            t.patches.len(),
            t.rate_hz
        ),
        (kind, _) => {
            let (schema, version) = reader.schema();
            format!(
                "{} {}: topic {topic}, {} bytes per frame, schema {schema} v{version}",
                kind.as_str(),
                reader.label(),
                reader.payload_bytes()
            )
        }
    }
}

/// The channels of `options.skin` to record, by name, layers first.
fn choose_channels(dir: &Path, options: &RecordOptions) -> Result<Vec<String>, RecordError> {
    let listed = skinware::list_skin_channels(dir, &options.skin)?;
    let live: Vec<_> = listed
        .iter()
        .filter(|c| c.skin == options.skin && c.state != WriterState::Gone && c.problem.is_none())
        .collect();
    let of_kind = |kind: ChannelKind| -> Vec<String> {
        live.iter().filter(|c| c.kind == Some(kind)).map(|c| c.channel.clone()).collect()
    };
    let (layers, services) = (of_kind(ChannelKind::Layer), of_kind(ChannelKind::Service));
    let pick = |wanted: &[String], available: &[String], what: &str| -> Result<Vec<String>, RecordError> {
        for name in wanted {
            if !available.contains(name) {
                return Err(RecordError::Nothing(format!(
                    "skin {} has no running {what} {name:?}; its {what}s: {}",
                    options.skin,
                    if available.is_empty() { "none".to_owned() } else { available.join(", ") }
                )));
            }
        }
        Ok(wanted.to_vec())
    };
    let mut chosen = match &options.layers {
        None => layers.clone(),
        Some(wanted) => pick(wanted, &layers, "layer")?,
    };
    chosen.extend(match &options.services {
        ServiceChoice::None => Vec::new(),
        ServiceChoice::All => services,
        ServiceChoice::Named(wanted) => pick(wanted, &services, "service")?,
    });
    if chosen.is_empty() {
        return Err(RecordError::Nothing(format!(
            "skin {} has no running channel to record in {}; start it first (`skin run`; `skin record --wait 60` waits for it), or name the skin with --skin",
            options.skin,
            dir.display()
        )));
    }
    Ok(chosen)
}
