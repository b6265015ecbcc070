//! What a recording reads: the chosen layers and services of the skin,
//! opened as ordinary readers, and the geometry the skin publishes.

use std::path::Path;

use skinware::{ChannelKind, Reader, ReaderOptions, WriterState};
use skinware_geometry::SkinGeometry;

use super::{RecordOptions, ServiceChoice};
use crate::RecordError;

/// The skin as the recording found it at its start.
pub(super) struct Sources {
    /// One reader per recorded channel, layers first.
    pub(super) readers: Vec<Reader>,
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
    Ok(Sources { readers, geometry_bytes, geometry })
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
