//! The colour range of each layer, found from what the layer reports. The
//! skin model carries no declared response range (a topology says a layer's
//! sensor type, not its units or resolution), so the viewer learns it from
//! the responses: an 8-bit iCub skin resting at 15 and pressed up to 255 and
//! the paper's virtual skin resting at 1,000 and pressed up to 65,535 each get
//! a scale on which their touches show.
//!
//! A [`RangeTracker`] watches a layer's frames and keeps its
//! [`ResponseRange`]: the resting level (the lowest median of its frames) and
//! the highest response seen. [`ResponseRange::full_scale`] is where the page
//! puts full colour, in response units above each taxel's baseline.

#![forbid(unsafe_code)]

/// The resolutions a layer's responses are taken to have, smallest first: a
/// layer whose responses never exceeded 255 is taken for an 8-bit sensor.
const RESOLUTIONS: [u16; 5] = [255, 1023, 4095, 16383, 65535];
/// Full colour is never below this fraction (1/N) of the resolution: before
/// the first touch the highest response seen is the resting level plus
/// noise, which must not fill the scale.
const FLOOR_DIVISOR: u16 = 8;

/// What one layer's responses spanned since the viewer started reading it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ResponseRange {
    /// The layer's resting response: the lowest median of the frames looked
    /// at (a median, so that dead taxels at 0 and a contact over less than
    /// half the layer do not move it).
    pub resting: u16,
    /// The highest response of any of its taxels in any frame seen.
    pub highest: u16,
}

impl ResponseRange {
    /// The resolution the responses seem to have: the smallest of 8, 10,
    /// 12, 14 and 16 bits that holds the highest one seen.
    pub fn resolution(&self) -> u16 {
        RESOLUTIONS.iter().copied().find(|&full| full >= self.highest).unwrap_or(u16::MAX)
    }

    /// Where full colour goes, above a taxel's baseline: how far the highest
    /// response rose above the resting level, and at least an eighth of the
    /// resolution (255 for an 8-bit skin: 31); never 0.
    ///
    /// ```
    /// use skinware_viewer::range::ResponseRange;
    ///
    /// // An iCub skin: resting at 15, pressed to 255.
    /// assert_eq!(ResponseRange { resting: 15, highest: 255 }.full_scale(), 240);
    /// // The same before any touch: noise must not fill the scale.
    /// assert_eq!(ResponseRange { resting: 15, highest: 17 }.full_scale(), 31);
    /// ```
    pub fn full_scale(&self) -> u16 {
        let floor = self.resolution() / FLOOR_DIVISOR;
        self.highest.saturating_sub(self.resting).max(floor).max(1)
    }
}

/// Every layer's range shared with the other layers of its sensor type
/// (`type_of`: each layer's type, as an index), so that one pressure looks
/// the same on each of them (the paper's virtual skin spreads five layers
/// of one type over the same body): the lowest resting level and the
/// highest response of them all. `scratch` holds the types' ranges, kept
/// between calls.
pub fn share_by_type(
    ranges: &mut [Option<ResponseRange>],
    type_of: &[usize],
    scratch: &mut Vec<Option<ResponseRange>>,
) {
    scratch.clear();
    for (range, &kind) in ranges.iter().zip(type_of) {
        if scratch.len() <= kind {
            scratch.resize(kind + 1, None);
        }
        scratch[kind] = match (scratch[kind], *range) {
            (Some(a), Some(b)) => {
                Some(ResponseRange { resting: a.resting.min(b.resting), highest: a.highest.max(b.highest) })
            }
            (a, b) => a.or(b),
        };
    }
    for (range, &kind) in ranges.iter_mut().zip(type_of) {
        *range = scratch[kind];
    }
}

/// Follows one layer's frames and keeps their [`ResponseRange`]. Looking at
/// a frame costs one pass for its highest response; its median (a selection
/// over a copy) only when asked for, which the sampler does twice a second.
#[derive(Clone, Debug, Default)]
pub struct RangeTracker {
    range: Option<ResponseRange>,
    /// The copy the median is selected in, kept between frames.
    scratch: Vec<u16>,
}

impl RangeTracker {
    /// A tracker that starts from `range` (what another reader of the same
    /// layer learnt), or from nothing.
    pub fn starting_from(range: Option<ResponseRange>) -> RangeTracker {
        RangeTracker { range, scratch: Vec::new() }
    }

    /// The range so far; `None` before the first frame.
    pub fn range(&self) -> Option<ResponseRange> {
        self.range
    }

    /// Takes one frame's `responses` into the range, and its median into the
    /// resting level if `with_median` (always for the first frame). An empty
    /// frame says nothing.
    pub fn observe(&mut self, responses: &[u16], with_median: bool) {
        let Some(highest) = responses.iter().copied().max() else {
            return;
        };
        let median = (with_median || self.range.is_none()).then(|| self.median(responses));
        let range = self.range.get_or_insert(ResponseRange { resting: u16::MAX, highest });
        range.highest = range.highest.max(highest);
        if let Some(median) = median {
            range.resting = range.resting.min(median);
        }
    }

    fn median(&mut self, responses: &[u16]) -> u16 {
        self.scratch.clear();
        self.scratch.extend_from_slice(responses);
        let middle = self.scratch.len() / 2;
        *self.scratch.select_nth_unstable(middle).1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame of `n` taxels at `resting`, `pressed` of them pressed to `peak`
    /// and `dead` of them at 0.
    fn frame(n: usize, resting: u16, pressed: usize, peak: u16, dead: usize) -> Vec<u16> {
        let mut responses = vec![resting; n];
        responses[..pressed].fill(peak);
        responses[n - dead..].fill(0);
        responses
    }

    #[test]
    fn an_8_bit_skin_gets_a_scale_its_touches_fill() {
        let mut tracker = RangeTracker::default();
        assert_eq!(tracker.range(), None);
        tracker.observe(&frame(768, 15, 0, 15, 0), false);
        let untouched = tracker.range().unwrap();
        assert_eq!((untouched.resting, untouched.highest), (15, 15));
        assert_eq!(untouched.resolution(), 255);
        assert_eq!(untouched.full_scale(), 31, "before a touch: an eighth of 8 bits, not the noise");
        tracker.observe(&frame(768, 16, 40, 255, 0), false);
        let touched = tracker.range().unwrap();
        assert_eq!(touched, ResponseRange { resting: 15, highest: 255 }, "the median is looked at when asked");
        assert_eq!(touched.full_scale(), 240, "a full press is full colour, not 1.2 % of 20,000");
    }

    #[test]
    fn a_16_bit_skin_ranges_up_to_its_highest_press() {
        let mut tracker = RangeTracker::default();
        tracker.observe(&frame(6000, 1000, 0, 0, 0), false);
        tracker.observe(&frame(6000, 1040, 0, 0, 0), true);
        let resting = tracker.range().unwrap();
        assert_eq!((resting.resting, resting.highest), (1000, 1040));
        assert_eq!(resting.resolution(), 4095);
        assert_eq!(resting.full_scale(), 511, "noise of 40 on 1,000 does not fill the scale");
        tracker.observe(&frame(6000, 1000, 30, 31_000, 0), true);
        assert_eq!(tracker.range().unwrap().full_scale(), 30_000);
        // A lighter press later does not shrink the scale: colours mean the same pressure all along.
        tracker.observe(&frame(6000, 1000, 30, 5_000, 0), true);
        assert_eq!(tracker.range().unwrap().full_scale(), 30_000);
    }

    #[test]
    fn dead_taxels_and_a_large_contact_leave_the_resting_level_alone() {
        let mut tracker = RangeTracker::default();
        // A fifth of the taxels dead at 0, a third pressed: the median is still resting.
        tracker.observe(&frame(900, 200, 300, 900, 180), true);
        assert_eq!(tracker.range().unwrap(), ResponseRange { resting: 200, highest: 900 });
        assert_eq!(tracker.range().unwrap().full_scale(), 700);
        // The resting level only falls (a drift down, a re-zeroed skin), never rises with a press.
        tracker.observe(&frame(900, 180, 600, 900, 0), true);
        tracker.observe(&frame(900, 180, 0, 0, 0), true);
        assert_eq!(tracker.range().unwrap().resting, 180);
        tracker.observe(&[], true);
        assert_eq!(tracker.range().unwrap().resting, 180, "an empty frame says nothing");
    }

    #[test]
    fn a_tracker_continues_what_another_reader_learnt() {
        let learnt = ResponseRange { resting: 15, highest: 255 };
        let mut tracker = RangeTracker::starting_from(Some(learnt));
        tracker.observe(&frame(100, 15, 0, 0, 0), false);
        assert_eq!(tracker.range(), Some(learnt), "a new mode's reader keeps the scale");
        assert_eq!(ResponseRange { resting: 65535, highest: 65535 }.full_scale(), 8191);
        assert_eq!(ResponseRange { resting: 0, highest: 0 }.full_scale(), 31);
    }

    #[test]
    fn layers_of_one_sensor_type_share_their_range() {
        let range = |resting, highest| Some(ResponseRange { resting, highest });
        let mut ranges = [range(1000, 17_000), range(990, 46_000), None, range(15, 255), None];
        let types = [0, 0, 0, 1, 2];
        let mut scratch = Vec::new();
        share_by_type(&mut ranges, &types, &mut scratch);
        assert_eq!(ranges, [range(990, 46_000), range(990, 46_000), range(990, 46_000), range(15, 255), None]);
        assert_eq!(ranges[0].unwrap().full_scale(), 45_010, "one pressure, one colour, on every pressure layer");
    }
}
