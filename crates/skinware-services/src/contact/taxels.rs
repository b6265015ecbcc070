//! The per-taxel half of contact detection: each taxel's baseline, noise and
//! dead/stuck run lengths, and its state each frame.
//!
//! This is the loop over every taxel of the skin, so it is laid out for
//! speed: one vector per quantity (dense streams), a loop body without
//! branches (the compiler vectorises it), and run lengths stored in the
//! narrowest integer that still holds the thresholds they are compared with.

use std::ops::Range;

use super::TaxelState;
use super::memory::{Layout, Placed, TaxelMemory};

/// The parameters of one frame's classification.
pub(super) struct Limits {
    pub threshold_sigma: f32,
    pub min_threshold: f32,
    pub saturation: u16,
    pub stuck_frames: u32,
    pub dead_frames: u32,
    /// The baseline and noise estimates' step towards this frame.
    pub alpha: f32,
}

/// Where every taxel's tracked quantities are, in global order, in the
/// detector's [`TaxelMemory`].
pub(super) struct TaxelTracks {
    baseline: Placed<f32>,
    variance: Placed<f32>,
    last: Placed<u16>,
    runs: RunLengths,
    /// The widest vector instructions this CPU has, found once.
    arch: pulp::Arch,
}

/// How many fresh frames in a row each taxel's response has not changed
/// (`unchanged`) and has been saturated (`saturated`). Counts stop at the
/// integer's maximum, which is at least both thresholds, so every comparison
/// with a threshold gives what an unbounded count would; a narrower integer
/// is less memory to stream through every frame.
#[derive(Clone, Copy)]
enum RunLengths {
    Byte { unchanged: Placed<u8>, saturated: Placed<u8> },
    Short { unchanged: Placed<u16>, saturated: Placed<u16> },
    Word { unchanged: Placed<u32>, saturated: Placed<u32> },
}

impl TaxelTracks {
    /// Places the tracks of `taxels` taxels, whose run lengths are compared
    /// with `dead_frames` and `stuck_frames`, in `layout`; the taxels'
    /// `states` are placed right after them (the classification writes
    /// them in the same pass).
    pub fn place(
        layout: &mut Layout,
        taxels: usize,
        dead_frames: u32,
        stuck_frames: u32,
    ) -> (TaxelTracks, Placed<TaxelState>) {
        let (baseline, variance, last) = (layout.place(taxels), layout.place(taxels), layout.place(taxels));
        let longest = dead_frames.max(stuck_frames);
        let runs = if longest <= u32::from(u8::MAX) {
            RunLengths::Byte { unchanged: layout.place(taxels), saturated: layout.place(taxels) }
        } else if longest <= u32::from(u16::MAX) {
            RunLengths::Short { unchanged: layout.place(taxels), saturated: layout.place(taxels) }
        } else {
            RunLengths::Word { unchanged: layout.place(taxels), saturated: layout.place(taxels) }
        };
        let tracks = TaxelTracks { baseline, variance, last, runs, arch: pulp::Arch::new() };
        (tracks, layout.place(taxels))
    }

    /// Starts the baselines of taxels `range` at their first `responses`.
    pub fn initialize(&self, memory: &mut TaxelMemory, range: Range<usize>, responses: &[u16]) {
        for (baseline, &r) in memory.get_mut(self.baseline)[range.clone()].iter_mut().zip(responses) {
            *baseline = f32::from(r);
        }
        memory.get_mut(self.last)[range].copy_from_slice(responses);
    }

    /// The response above baseline of a taxel whose baseline this frame's
    /// [`classify`](Self::classify) did not move (a touched one).
    pub fn residual(&self, memory: &TaxelMemory, taxel: usize, response: u16) -> f32 {
        f32::from(response) - memory.get(self.baseline)[taxel]
    }

    /// Follows the baselines and noise of taxels `range`, whose `responses`
    /// are new (`fresh`: a new frame, which counts towards dead and stuck)
    /// or read again, and writes their states into `states` (what
    /// [`place`](Self::place) placed).
    pub fn classify(
        &self,
        memory: &mut TaxelMemory,
        states: Placed<TaxelState>,
        range: Range<usize>,
        responses: &[u16],
        fresh: bool,
        limits: &Limits,
    ) {
        macro_rules! classify_with {
            ($unchanged:expr, $saturated:expr) => {{
                let [baseline, variance, last, unchanged, saturated, states_words] = memory.words_of_mut([
                    self.baseline.words(),
                    self.variance.words(),
                    self.last.words(),
                    $unchanged.words(),
                    $saturated.words(),
                    states.words(),
                ]);
                let layer = Layer {
                    responses,
                    baseline: &mut self.baseline.view_mut(baseline)[range.clone()],
                    variance: &mut self.variance.view_mut(variance)[range.clone()],
                    last: &mut self.last.view_mut(last)[range.clone()],
                    unchanged: &mut $unchanged.view_mut(unchanged)[range.clone()],
                    saturated: &mut $saturated.view_mut(saturated)[range.clone()],
                    states: &mut states.view_mut(states_words)[range.clone()],
                };
                self.arch.dispatch(ClassifyLayer { layer, limits, fresh })
            }};
        }
        match self.runs {
            RunLengths::Byte { unchanged, saturated } => classify_with!(unchanged, saturated),
            RunLengths::Short { unchanged, saturated } => classify_with!(unchanged, saturated),
            RunLengths::Word { unchanged, saturated } => classify_with!(unchanged, saturated),
        }
    }
}

/// A run length's integer.
trait RunLength: Copy + PartialOrd {
    /// `count` + 1 (at most the integer's maximum) while `holds`, else 0.
    fn count_while(holds: bool, count: Self) -> Self;
    /// `frames` as this integer: its maximum if larger (which the choice of
    /// integer rules out for the thresholds).
    fn frames(frames: u32) -> Self;
}

// Written with masks rather than `saturating_add` under a condition, which
// the compiler does not vectorise.
macro_rules! run_length {
    ($t:ty) => {
        impl RunLength for $t {
            #[inline(always)]
            fn count_while(holds: bool, count: $t) -> $t {
                let incremented = count + <$t>::from(count != <$t>::MAX);
                incremented & <$t>::from(holds).wrapping_neg()
            }

            #[inline(always)]
            fn frames(frames: u32) -> $t {
                <$t>::try_from(frames).unwrap_or(<$t>::MAX)
            }
        }
    };
}
run_length!(u8);
run_length!(u16);
run_length!(u32);

/// One layer's slice of every per-taxel array, all of the same length.
struct Layer<'a, C> {
    responses: &'a [u16],
    baseline: &'a mut [f32],
    variance: &'a mut [f32],
    last: &'a mut [u16],
    unchanged: &'a mut [C],
    saturated: &'a mut [C],
    states: &'a mut [TaxelState],
}

// `classify_layer` ranks the states by their codes.
const _: () = assert!(
    TaxelState::IDLE.0 == 0
        && TaxelState::STUCK.0 > TaxelState::DEAD.0
        && TaxelState::DEAD.0 > TaxelState::TOUCHED.0
        && TaxelState::TOUCHED.0 > TaxelState::IDLE.0
);

/// One layer's classification, compiled once for each instruction set that
/// [`pulp::Arch`] can choose at run time (AVX2 doubles the vectors' width
/// over the SSE2 that every x86-64 has, and this loop is bound by arithmetic,
/// not memory). The results are the same bits on every instruction set: the
/// compiler does not fuse or reorder floating-point operations.
struct ClassifyLayer<'a, C> {
    layer: Layer<'a, C>,
    limits: &'a Limits,
    fresh: bool,
}

impl<C: RunLength> pulp::WithSimd for ClassifyLayer<'_, C> {
    type Output = ();

    // Inlined into pulp's function for each instruction set, so that the
    // loop is vectorised with it.
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        // Two copies of the loop, so that neither tests freshness per taxel.
        if self.fresh {
            classify_layer::<_, true>(self.layer, self.limits)
        } else {
            classify_layer::<_, false>(self.layer, self.limits)
        }
    }
}

/// Classifies one layer's taxels. The loop body has no branch and no early
/// exit (every choice is a select), so that the compiler vectorises it.
#[inline(always)]
fn classify_layer<C: RunLength, const FRESH: bool>(layer: Layer<'_, C>, limits: &Limits) {
    // Compared in the run lengths' own integer: narrow lanes, no widening.
    let (stuck_frames, dead_frames) = (C::frames(limits.stuck_frames), C::frames(limits.dead_frames));
    let n = layer.responses.len();
    // Equal lengths, stated once, so that the loop has no bounds checks.
    let (baseline, variance, last) = (&mut layer.baseline[..n], &mut layer.variance[..n], &mut layer.last[..n]);
    let (unchanged, saturated, states) = (&mut layer.unchanged[..n], &mut layer.saturated[..n], &mut layer.states[..n]);
    for i in 0..n {
        let r = layer.responses[i];
        if FRESH {
            unchanged[i] = C::count_while(r == last[i], unchanged[i]);
            last[i] = r;
            saturated[i] = C::count_while(r >= limits.saturation, saturated[i]);
        }
        let residual = f32::from(r) - baseline[i];
        let threshold = (limits.threshold_sigma * variance[i].sqrt()).max(limits.min_threshold);
        // Stuck before dead before touched (saturated also means unchanged):
        // the states' codes rank them, so the largest code that applies wins.
        let stuck = u8::from(saturated[i] >= stuck_frames) * TaxelState::STUCK.0;
        let dead = u8::from(unchanged[i] >= dead_frames) * TaxelState::DEAD.0;
        let touched = u8::from(residual > threshold) * TaxelState::TOUCHED.0;
        let state = stuck.max(dead).max(touched);
        states[i] = TaxelState(state);
        // Drift compensation and noise estimate, only while untouched.
        let step = if state == TaxelState::IDLE.0 { limits.alpha } else { 0.0 };
        baseline[i] += step * residual;
        variance[i] += step * (residual * residual - variance[i]);
    }
}

/// Appends the global index (`first` + position) of each touched taxel of
/// `states` to `touched`, and of each dead or stuck one to `dead_or_stuck`.
pub(super) fn list_non_idle(states: &[TaxelState], first: usize, touched: &mut Vec<u32>, dead_or_stuck: &mut Vec<u32>) {
    const CHUNK: usize = 16;
    let mut chunks = states.chunks_exact(CHUNK);
    let mut at = first;
    for chunk in &mut chunks {
        // Mostly idle (0): one test per 16 taxels.
        let codes: [u8; CHUNK] = bytemuck::cast_slice(chunk).try_into().expect("chunks of CHUNK");
        if u128::from_ne_bytes(codes) != 0 {
            list_non_idle_one_by_one(chunk, at, touched, dead_or_stuck);
        }
        at += CHUNK;
    }
    list_non_idle_one_by_one(chunks.remainder(), at, touched, dead_or_stuck);
}

fn list_non_idle_one_by_one(states: &[TaxelState], first: usize, touched: &mut Vec<u32>, dead_or_stuck: &mut Vec<u32>) {
    for (k, state) in states.iter().enumerate() {
        match *state {
            TaxelState::TOUCHED => touched.push((first + k) as u32),
            TaxelState::DEAD | TaxelState::STUCK => dead_or_stuck.push((first + k) as u32),
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Tracks of `taxels` taxels, their states, and the memory they are in.
    fn tracks(taxels: usize, dead_frames: u32, stuck_frames: u32) -> (TaxelTracks, Placed<TaxelState>, TaxelMemory) {
        let mut layout = Layout::default();
        let (tracks, states) = TaxelTracks::place(&mut layout, taxels, dead_frames, stuck_frames);
        (tracks, states, TaxelMemory::new(&layout))
    }

    /// Everything a classification leaves behind, as bits.
    fn snapshot(tracks: &TaxelTracks, states: Placed<TaxelState>, memory: &TaxelMemory) -> Vec<u32> {
        let floats = memory.get(tracks.baseline).iter().chain(memory.get(tracks.variance));
        let mut bits: Vec<u32> = floats.map(|v| v.to_bits()).collect();
        bits.extend(memory.get(tracks.last).iter().map(|&r| u32::from(r)));
        match tracks.runs {
            RunLengths::Byte { unchanged, saturated } => {
                bits.extend(memory.get(unchanged).iter().chain(memory.get(saturated)).map(|&c| u32::from(c)))
            }
            RunLengths::Short { unchanged, saturated } => {
                bits.extend(memory.get(unchanged).iter().chain(memory.get(saturated)).map(|&c| u32::from(c)))
            }
            RunLengths::Word { unchanged, saturated } => {
                bits.extend(memory.get(unchanged).iter().chain(memory.get(saturated)))
            }
        }
        bits.extend(memory.get(states).iter().map(|s| u32::from(s.0)));
        bits
    }

    /// Whether this CPU has what pulp's AVX2 level (`pulp::x86::V3`) needs.
    fn has_x86_64_v3() -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            has!("sse4.2")
                && has!("popcnt")
                && has!("avx")
                && has!("avx2")
                && has!("fma")
                && has!("bmi1")
                && has!("bmi2")
                && has!("lzcnt")
        }
        #[cfg(not(target_arch = "x86_64"))]
        false
    }

    #[test]
    fn the_widest_instruction_set_is_chosen_where_the_cpu_has_it() {
        let (tracks, _, _) = tracks(1, 100, 50);
        if has_x86_64_v3() {
            assert!(matches!(tracks.arch, pulp::Arch::V3(_)), "AVX2 CPU, but {:?} chosen", tracks.arch);
        } else {
            eprintln!("skipped: this CPU has no AVX2 (x86-64-v3), so only the baseline loop runs here");
        }
    }

    proptest! {
        /// The loop compiled for the widest vectors this CPU has (AVX2 where
        /// there is one) and the baseline one give the same bits, frame after
        /// frame: the detector's outputs do not depend on the machine. Up to
        /// 300 taxels (several passes of the vector loop and a remainder), and
        /// thresholds that pick each width of run-length counter.
        #[test]
        fn every_instruction_set_classifies_to_the_same_bits(
            taxels in 1usize..300,
            frames in proptest::collection::vec(
                (proptest::collection::vec(prop_oneof![0u16..2000, 64_990u16..=u16::MAX, Just(1000u16)], 300), any::<bool>()),
                1..30,
            ),
            (dead_frames, stuck_frames) in prop_oneof![Just((5u32, 3u32)), Just((300, 3)), Just((70_000, 3))],
        ) {
            let limits = Limits {
                threshold_sigma: 6.0,
                min_threshold: 60.0,
                saturation: 65_000,
                stuck_frames,
                dead_frames,
                alpha: 0.05,
            };
            let (widest, states_a, mut memory_a) = tracks(taxels, dead_frames, stuck_frames);
            let (mut baseline_isa, states_b, mut memory_b) = tracks(taxels, dead_frames, stuck_frames);
            baseline_isa.arch = pulp::Arch::Scalar;
            widest.initialize(&mut memory_a, 0..taxels, &frames[0].0[..taxels]);
            baseline_isa.initialize(&mut memory_b, 0..taxels, &frames[0].0[..taxels]);
            for (responses, fresh) in &frames {
                widest.classify(&mut memory_a, states_a, 0..taxels, &responses[..taxels], *fresh, &limits);
                baseline_isa.classify(&mut memory_b, states_b, 0..taxels, &responses[..taxels], *fresh, &limits);
                prop_assert_eq!(snapshot(&widest, states_a, &memory_a), snapshot(&baseline_isa, states_b, &memory_b));
            }
        }
    }

    #[test]
    fn run_lengths_count_stop_at_the_maximum_and_restart() {
        assert_eq!(u8::count_while(true, 7), 8);
        assert_eq!(u8::count_while(true, u8::MAX), u8::MAX);
        assert_eq!(u16::count_while(false, 300), 0);
        assert_eq!(u32::count_while(true, u32::MAX), u32::MAX);
        assert_eq!(u8::frames(300), u8::MAX);
    }
}
