//! A service's view of the skin's layers: the newest responses of every
//! layer (each layer a contiguous range of the geometry's sensor order), and
//! which layers are healthy.

use skinware::{Reader, ReaderOptions, WriterState};
use skinware_geometry::SkinGeometry;

/// Readers of every layer of a skin.
pub struct SkinInputs {
    skin: String,
    names: Vec<String>,
    readers: Vec<Option<Reader>>,
    starts: Vec<usize>,
    /// Whether each layer's responses are current (running, not faulted, not stale).
    pub layer_ok: Vec<bool>,
    /// Whether each layer published a new frame since the previous update.
    pub layer_fresh: Vec<bool>,
    /// Whether each layer's newest frame was new at the previous update or
    /// published within one period of its writer.
    layer_recent: Vec<bool>,
    /// The newest acquisition time over the layers, monotonic ns.
    pub acquired_ns: u64,
}

impl SkinInputs {
    /// Readers for the layers of `geometry`. Layers that do not exist yet are
    /// retried on every [`update`](Self::update), and count as down meanwhile.
    pub fn new(skin: &str, geometry: &SkinGeometry) -> SkinInputs {
        let names: Vec<String> = geometry.layers.iter().map(|l| l.name.clone()).collect();
        SkinInputs {
            skin: skin.to_owned(),
            readers: names.iter().map(|_| None).collect(),
            names,
            starts: geometry.layer_starts.clone(),
            layer_ok: vec![false; geometry.layers.len()],
            layer_fresh: vec![false; geometry.layers.len()],
            layer_recent: vec![false; geometry.layers.len()],
            acquired_ns: 0,
        }
    }

    /// The layer names.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Reads the newest frame of every layer. A layer is down when it cannot
    /// be opened, its writer is not running, its frame is faulted or of the
    /// wrong size, or its newest frame is stale; it then has no responses
    /// until it is up again. Returns whether every layer is up.
    ///
    /// A writer that dies is seen as gone within one of its periods (at most
    /// a second): while its newest frame is younger than that, the state it
    /// stored stands in for asking the kernel.
    ///
    /// Each frame stays in its reader's own copy, where
    /// [`layer_responses`](Self::layer_responses) shows it: copying all the
    /// layers once more into one array would cost the contact service about
    /// 10 µs a frame on the paper's skin, most of it cache misses on an
    /// array last written a period before.
    pub fn update(&mut self) -> bool {
        for l in 0..self.names.len() {
            if self.readers[l].is_none() {
                let options = ReaderOptions { allow_gone: true, ..ReaderOptions::default() };
                self.readers[l] = Reader::open_with(&self.skin, &self.names[l], &options).ok();
            }
            let Some(reader) = &mut self.readers[l] else {
                self.layer_ok[l] = false;
                self.layer_fresh[l] = false;
                continue;
            };
            // A re-created channel matters only once the old one has stopped
            // giving new frames; asking costs a system call per layer.
            if !self.layer_recent[l] {
                reader.follow_recreated();
            }
            self.layer_fresh[l] = false;
            self.layer_recent[l] = false;
            let range = self.starts[l]..self.starts[l + 1];
            let period = reader.writer_period();
            let current = match reader.latest() {
                Ok(frame) if !frame.status().is_fault() && frame.responses().len() == range.len() => {
                    // The reader's own freshness: a successor writer's frames
                    // start again at 1, and its first is new whatever its number.
                    self.layer_fresh[l] = frame.is_fresh();
                    self.acquired_ns = self.acquired_ns.max(frame.acquired_ns());
                    let now = skinware::os::monotonic_ns();
                    self.layer_recent[l] = self.layer_fresh[l] || is_recent(frame.published_ns(), period, now);
                    !crate::is_stale(frame.published_ns(), period)
                }
                _ => false,
            };
            // A writer that published within its period was alive a period
            // ago: the state it stored will do, whether or not this frame is
            // new here (a layer slower than the service is read again between
            // its frames). Otherwise ask the kernel whether it lives (a system
            // call per layer).
            let state = if self.layer_recent[l] { reader.stored_writer_state() } else { reader.writer_state() };
            self.layer_ok[l] = current && state == WriterState::Running;
        }
        self.layer_ok.iter().all(|&ok| ok)
    }

    /// The layer of global sensor `sensor`.
    pub fn layer_of(&self, sensor: usize) -> usize {
        self.starts.partition_point(|&s| s <= sensor) - 1
    }

    /// The responses of layer `layer` from the last [`update`](Self::update)
    /// (its sensors' global indices start at the geometry's
    /// `layer_starts[layer]`), or `None` if the layer is down.
    pub fn layer_responses(&self, layer: usize) -> Option<&[u16]> {
        if !self.layer_ok.get(layer).copied().unwrap_or(false) {
            return None;
        }
        let frame = self.readers.get(layer)?.as_ref()?.last_frame()?;
        let responses = frame.responses();
        (responses.len() == self.starts[layer + 1] - self.starts[layer]).then_some(responses)
    }

    /// The response of global sensor `sensor` from the last
    /// [`update`](Self::update), or `None` if its layer is down (or there is
    /// no such sensor).
    pub fn response(&self, sensor: usize) -> Option<u16> {
        if sensor >= *self.starts.last()? {
            return None;
        }
        let layer = self.layer_of(sensor);
        self.layer_responses(layer)?.get(sensor - self.starts[layer]).copied()
    }
}

/// Whether a frame published at `published_ns` by a writer of `period` is
/// younger than one period, and than a second: a period and a time read
/// from shared memory may be forged, and a writer that died must not pass
/// for alive for longer than that. A time from the future is not recent.
fn is_recent(published_ns: u64, period: Option<std::time::Duration>, now: u64) -> bool {
    let longest = period.map_or(0, |period| period.min(std::time::Duration::from_secs(1)).as_nanos());
    published_ns <= now && u128::from(now - published_ns) < longest
}

#[cfg(test)]
mod tests {
    use super::is_recent;
    use std::time::Duration;

    #[test]
    fn recent_is_within_one_period_at_most_a_second_and_never_from_the_future() {
        let now = 100_000_000_000;
        let ms = |n: u64| Duration::from_millis(n);
        assert!(is_recent(now - 19_000_000, Some(ms(20)), now));
        assert!(!is_recent(now - 21_000_000, Some(ms(20)), now), "older than one period");
        assert!(!is_recent(now - 2_000_000_000, Some(ms(3_600_000)), now), "a forged hour-long period counts as 1 s");
        assert!(is_recent(now - 900_000_000, Some(ms(3_600_000)), now));
        assert!(!is_recent(now + 1, Some(ms(20)), now), "a time from the future");
        assert!(!is_recent(now, None, now), "a sporadic writer's frame is as fresh as its request");
    }
}
