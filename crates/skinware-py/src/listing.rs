//! What channels exist: `skinware.channels()`, and through it
//! `skinware.layers()` and `skinware.services()`.

use pyo3::prelude::*;
use skinware::ChannelKind;

use crate::errors;

/// One channel of a skin, as `skin ls` sees it.
#[pyclass(module = "skinware", frozen, get_all)]
pub struct ChannelInfo {
    /// The skin's name.
    skin: String,
    /// The channel's name (the layer or service).
    name: String,
    /// "layer", "service", or `None` if the channel cannot be read (see `problem`).
    kind: Option<&'static str>,
    /// "running", "paused", "faulted" or "gone".
    state: &'static str,
    /// A layer's sensors (responses per frame); 0 for services.
    sensors: usize,
    /// Bytes per frame.
    payload_bytes: u64,
    /// Frames published by the current writer.
    frames: u64,
    /// The current (or last) writer's process id.
    writer_pid: u32,
    /// How many writers the channel has had.
    generation: u64,
    /// Why the channel cannot be read, if it cannot.
    problem: Option<String>,
}

#[pymethods]
impl ChannelInfo {
    fn __repr__(&self) -> String {
        format!(
            "ChannelInfo({}/{}, {}, {}, {} frames)",
            self.skin,
            self.name,
            self.kind.unwrap_or("unreadable"),
            self.state,
            self.frames
        )
    }
}

/// The channels of skin `skin` (every skin if `None`), sorted by skin and name.
#[pyfunction]
#[pyo3(signature = (skin = None))]
pub fn channels(py: Python<'_>, skin: Option<&str>) -> PyResult<Vec<ChannelInfo>> {
    let dir = skinware::shm::segment_dir();
    let listed =
        py.detach(|| skinware::list_channels_where(&dir, skin, |_| true)).map_err(|e| errors::exchange(py, e))?;
    Ok(listed
        .into_iter()
        .filter(|c| skin.is_none_or(|s| s == c.skin))
        .map(|c| ChannelInfo {
            kind: c.kind.map(ChannelKind::as_str),
            sensors: if c.kind == Some(ChannelKind::Layer) { (c.payload_bytes / 2) as usize } else { 0 },
            state: c.state.as_str(),
            payload_bytes: c.payload_bytes,
            frames: c.stats.frames,
            writer_pid: c.writer_pid,
            generation: c.generation,
            problem: c.problem,
            skin: c.skin,
            name: c.channel,
        })
        .collect())
}

/// The directory holding the channels' sockets (`SKINWARE_SHM_DIR`, else `/dev/shm`).
#[pyfunction]
pub fn segment_dir() -> String {
    skinware::shm::segment_dir().display().to_string()
}
