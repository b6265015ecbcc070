//! What an EtherCAT skin driver is told: the segments to expect, in ring
//! order, and how each maps onto a layer.

use std::time::Duration;

use skinware::{LayerTopology, RtOptions, TopologyBuilder, TopologyError};

use super::{INPUTS_HEADER_BYTES, MAX_SEGMENTS, MAX_TAXELS};

/// One tactile segment (one SubDevice), at its position on the ring.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SegmentConfig {
    /// The layer it publishes (one layer per segment).
    pub layer: String,
    /// The vendor ID it must report.
    pub vendor_id: u32,
    /// The product code it must report.
    pub product_code: u32,
    /// Its taxels: `taxel[N]` of its inputs.
    pub taxels: usize,
    /// Taxels of each module, in order; they add up to `taxels`. Empty: one
    /// module of every taxel.
    pub modules: Vec<usize>,
    /// The id of the patch it is (the segment's microcontroller).
    pub patch: u32,
    /// Ask for baseline-subtracted taxels instead of raw ones.
    pub baseline: bool,
}

/// What is wrong with an EtherCAT driver's settings; each message names
/// the setting and the fix.
#[derive(Debug, thiserror::Error)]
pub enum EthercatConfigError {
    /// The rate is not above 0 and at most 10 kHz.
    #[error("rate {rate_hz} Hz: give a rate above 0 and at most 10 kHz")]
    Rate {
        /// The rate given.
        rate_hz: f64,
    },
    /// No segments, or more than the ring can have.
    #[error("{segments} segments: list 1 to {MAX_SEGMENTS} `[[driver.segment]]` tables, in ring order")]
    Segments {
        /// How many were given.
        segments: usize,
    },
    /// A segment with no taxels or too many.
    #[error("segment {position}: {taxels} taxels; a segment has 1 to {MAX_TAXELS}")]
    Taxels {
        /// The segment's position on the ring.
        position: usize,
        /// Its taxels.
        taxels: usize,
    },
    /// A segment whose modules do not add up to its taxels.
    #[error("segment {position}: its modules hold {in_modules} taxels but it has {taxels}; make them add up")]
    ModulesDisagree {
        /// The segment's position on the ring.
        position: usize,
        /// The taxels its modules hold.
        in_modules: usize,
        /// Its taxels.
        taxels: usize,
    },
    /// A module of no taxels.
    #[error("segment {position}: a module of 0 taxels; drop it")]
    EmptyModule {
        /// The segment's position on the ring.
        position: usize,
    },
    /// Two segments publishing one layer.
    #[error("segments {first} and {position} both publish layer {layer:?}; give each its own layer")]
    SharedLayer {
        /// The earlier segment.
        first: usize,
        /// The later one.
        position: usize,
        /// The layer.
        layer: String,
    },
    /// A segment position past the last segment.
    #[error("no segment {position}: the ring has {segments}")]
    NoSegment {
        /// The position asked for.
        position: usize,
        /// The segments there are.
        segments: usize,
    },
    /// A segment's layer topology was refused.
    #[error("segment {position}: {source}")]
    Topology {
        /// The segment's position on the ring.
        position: usize,
        /// Why.
        #[source]
        source: TopologyError,
    },
}

/// An EtherCAT skin driver's settings.
#[derive(Clone, Debug)]
pub struct EthercatDriverConfig {
    /// Driver name, for logs.
    pub name: String,
    /// The segments in ring order: position 0 is nearest the MainDevice.
    pub segments: Vec<SegmentConfig>,
    /// Cycles (and frames per layer) per second.
    pub rate_hz: f64,
    /// How long a frame may take to come back before it counts as lost
    /// (and how long each step of the bring-up may take); `None`: 2 periods,
    /// at least 10 ms. A lost frame stalls only its own segment's cycles,
    /// and its layer faults after 2 periods without new data whatever this is.
    pub frame_timeout: Option<Duration>,
    /// Real-time settings of the writer threads and of the bus thread.
    pub rt: RtOptions,
}

impl EthercatDriverConfig {
    /// Checks the settings; the explanation names the setting and the fix.
    pub fn check(&self) -> Result<(), EthercatConfigError> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 10_000.0) {
            return Err(EthercatConfigError::Rate { rate_hz: self.rate_hz });
        }
        if self.segments.is_empty() || self.segments.len() > MAX_SEGMENTS {
            return Err(EthercatConfigError::Segments { segments: self.segments.len() });
        }
        for (position, segment) in self.segments.iter().enumerate() {
            if segment.taxels == 0 || segment.taxels > MAX_TAXELS {
                return Err(EthercatConfigError::Taxels { position, taxels: segment.taxels });
            }
            // Saturating: module sizes come from a file, and their sum must not overflow.
            let in_modules = segment.modules.iter().fold(0usize, |sum, &m| sum.saturating_add(m));
            if !segment.modules.is_empty() && in_modules != segment.taxels {
                return Err(EthercatConfigError::ModulesDisagree { position, in_modules, taxels: segment.taxels });
            }
            if segment.modules.contains(&0) {
                return Err(EthercatConfigError::EmptyModule { position });
            }
            if let Some(first) = self.segments[..position].iter().position(|s| s.layer == segment.layer) {
                return Err(EthercatConfigError::SharedLayer { first, position, layer: segment.layer.clone() });
            }
        }
        Ok(())
    }

    /// The cycle period.
    pub fn period(&self) -> Duration {
        Duration::from_secs_f64(1.0 / self.rate_hz)
    }

    /// How long a frame may take before it counts as lost.
    pub fn frame_timeout(&self) -> Duration {
        self.frame_timeout.unwrap_or_else(|| (self.period() * 2).max(Duration::from_millis(10)))
    }

    /// The topology of segment `position`'s layer: one patch, its modules,
    /// taxel uids `(position + 1) << 16 | taxel`.
    pub fn topology(&self, position: usize) -> Result<LayerTopology, EthercatConfigError> {
        let segment = self
            .segments
            .get(position)
            .ok_or(EthercatConfigError::NoSegment { position, segments: self.segments.len() })?;
        let mut builder = TopologyBuilder::new(&segment.layer, "pressure", self.rate_hz);
        builder.patch(segment.patch);
        let modules = if segment.modules.is_empty() { vec![segment.taxels] } else { segment.modules.clone() };
        let base = (position as u32 + 1) << 16;
        let mut first = 0u32;
        for (module, &taxels) in modules.iter().enumerate() {
            let taxels = taxels as u32;
            builder.module(module as u32 + 1, (first..first + taxels).map(|k| base | k));
            first += taxels;
        }
        builder.build().map_err(|source| EthercatConfigError::Topology { position, source })
    }
}

/// The working counter ethercrab reports for one cycle of a group of one
/// segment with `taxels` taxels, when frames carry at most `chunk` bytes of
/// process data each. Its process image is the inputs then the outputs; it
/// sends it as one LRW per frame and adds up their working counters, in
/// each of which the segment counts +1 if the LRW reads some of its inputs
/// and +2 if it writes some of its outputs. Within one frame that is 3.
pub fn expected_working_counter(taxels: usize, chunk: usize) -> u16 {
    let inputs = INPUTS_HEADER_BYTES + 2 * taxels;
    let total = inputs + super::OUTPUTS_BYTES;
    let chunk = chunk.max(1);
    (0..total)
        .step_by(chunk)
        .map(|start| {
            let end = (start + chunk).min(total);
            u16::from(start < inputs) + 2 * u16::from(end > inputs)
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn segment(layer: &str, taxels: usize, modules: Vec<usize>) -> SegmentConfig {
        SegmentConfig { layer: layer.into(), vendor_id: 1, product_code: 2, taxels, modules, patch: 7, baseline: false }
    }

    fn config(segments: Vec<SegmentConfig>) -> EthercatDriverConfig {
        EthercatDriverConfig {
            name: "ecat".into(),
            segments,
            rate_hz: 1000.0,
            frame_timeout: None,
            rt: RtOptions::default(),
        }
    }

    #[test]
    fn topology_is_one_patch_of_the_configured_modules() {
        let config = config(vec![segment("a", 4, vec![]), segment("b", 36, vec![12, 12, 12])]);
        config.check().unwrap();
        let topology = config.topology(1).unwrap();
        assert_eq!(topology.patches.len(), 1);
        assert_eq!(topology.patches[0].id, 7);
        assert_eq!(topology.modules.iter().map(|m| m.sensors.len()).collect::<Vec<_>>(), [12, 12, 12]);
        assert_eq!(topology.sensors[13].uid, 2 << 16 | 13);
        assert_eq!(config.topology(0).unwrap().modules.len(), 1);
    }

    #[test]
    fn bad_settings_are_explained() {
        let err = |segments| config(segments).check().unwrap_err().to_string();
        assert!(err(vec![]).contains("1 to 16"));
        assert!(err(vec![segment("a", 0, vec![])]).contains("1 to 2048"));
        assert!(err(vec![segment("a", 24, vec![12, 10])]).contains("add up"));
        assert!(err(vec![segment("a", 4, vec![]), segment("a", 4, vec![])]).contains("its own layer"));
        let mut slow = config(vec![segment("a", 4, vec![])]);
        slow.rate_hz = 0.0;
        assert!(slow.check().unwrap_err().to_string().contains("rate"));
    }

    #[test]
    fn working_counter_counts_each_frame_of_the_image() {
        // 708 taxels: 1,424 bytes fit one frame of 1,486.
        assert_eq!(expected_working_counter(708, 1486), 3);
        // 740 taxels: 1,484 bytes of inputs and 4 of outputs straddle two
        // frames: inputs and half the outputs in the first (3), the rest of
        // the outputs in the second (2).
        assert_eq!(expected_working_counter(740, 1486), 3 + 2);
        // 741: the inputs fill the first frame exactly; outputs alone after.
        assert_eq!(expected_working_counter(741, 1486), 1 + 2);
        assert_eq!(expected_working_counter(2048, 1486), 1 + 1 + 3);
    }
}
