//! A verifying reader process of the soak (`skin bench-soak-reader`): one
//! thread per layer, all in one reader mode, checking every frame it gets
//! against the virtual skin's verification pattern, its sequence number
//! against the last one, and every gap against [`skinware::Frame::skipped`].
//! It writes its counts to a report file four times a second, atomically
//! (a temporary file renamed over it), so that a reader killed with SIGKILL
//! keeps what it counted up to its last report. It stops, writing a last
//! report, when its standard input closes.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use skinware::{Error, Frame, Reader, ReaderOptions, Stop, Ticker};
use skinware_drivers::virtual_skin::pattern::pattern_mismatch;

/// How a verifying reader reads (the library's reader modes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// `next_periodic` at [`PERIODIC_HZ`], whatever the writer's rate.
    Periodic,
    /// As soon as available: `wait_newer`.
    Asap,
    /// On request: `request`, then a random pause of up to 30 ms.
    Request,
    /// As soon as available with `ReaderOptions::anticipate`.
    Anticipate,
}

/// Every mode, in the order the soak starts them.
pub const MODES: [Mode; 4] = [Mode::Periodic, Mode::Asap, Mode::Request, Mode::Anticipate];

/// The rate of the periodic readers: faster than any layer of the paper's
/// skin, so that they see frames again (repeats) as well as skip none.
pub const PERIODIC_HZ: f64 = 100.0;

/// How early an anticipating reader wakes before a frame is due. Small,
/// because it spins that long (up to three times) per frame and per layer
/// on a machine the soak shares with the skin.
const ANTICIPATE: Duration = Duration::from_micros(200);

impl Mode {
    /// Its name on the command line and in the report.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Periodic => "periodic",
            Mode::Asap => "asap",
            Mode::Request => "request",
            Mode::Anticipate => "anticipate",
        }
    }

    /// The mode named `name`.
    pub fn parse(name: &str) -> Result<Mode> {
        MODES
            .into_iter()
            .find(|m| m.name() == name)
            .with_context(|| format!("unknown reader mode {name:?}: give one of periodic, asap, request, anticipate"))
    }
}

/// A pause between two fresh frames longer than this is kept in the
/// tally ([`LayerTally::long_gaps`]): the reader's own record of when it got
/// nothing, which the soak holds against when the layer published.
pub const LONG_GAP_NS: u64 = 1_000_000_000;

/// How many long gaps a tally keeps (the first ones; a reader with more is
/// far past failing the soak).
const MAX_LONG_GAPS: usize = 256;

/// A long pause between two fresh frames of one layer, as the reader saw it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Gap {
    /// When the frame before it was obtained (CLOCK_MONOTONIC ns).
    pub from_ns: u64,
    /// When the frame after it was obtained.
    pub to_ns: u64,
    /// Whether the frame after it came from a successor writer.
    pub followed: bool,
}

/// One reader's counts of one layer.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LayerTally {
    /// Frames whose content matched the pattern of their sequence number.
    pub verified: u64,
    /// Frames whose content did not: a mix of frames, or mislabelled.
    pub torn: u64,
    /// Fresh frames whose sequence number was not above the last one's
    /// within the same writer (the reader followed no successor in between).
    pub backwards: u64,
    /// Frames of the writer never obtained, that `Frame::skipped` reported.
    pub lost_counted: u64,
    /// Frames of the writer never obtained, that `Frame::skipped` did not
    /// report: a gap in the sequence wider than it said.
    pub lost_silently: u64,
    /// `Frame::skipped` above the gap in the sequence (frames reported lost
    /// that were not).
    pub over_counted: u64,
    /// Frames of a successor writer published before this reader's first
    /// frame of it (`seq - 1` at that frame): lost at a writer change, where
    /// `Frame::skipped` starts again at 0 by design.
    pub lost_at_follow: u64,
    /// Reads that returned the frame already obtained (a periodic reader
    /// faster than the writer).
    pub repeats: u64,
    /// Successors followed.
    pub follows: u64,
    /// Reads that failed with an unexpected error.
    pub errors: u64,
    /// Attaching attempts that failed (writer gone, name missing).
    pub open_failures: u64,
    /// Whether the layer's reader is attached.
    pub attached: bool,
    /// When this reader last obtained a fresh frame (CLOCK_MONOTONIC ns; 0: never).
    pub last_new_ns: u64,
    /// The sequence number of that frame.
    pub last_seq: u64,
    /// The first torn frame's description, for the log.
    pub first_torn: Option<String>,
    /// Pauses between fresh frames longer than [`LONG_GAP_NS`], oldest first.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub long_gaps: Vec<Gap>,
}

impl LayerTally {
    /// Adds `other`'s counts (not its times or flags).
    pub fn add(&mut self, other: &LayerTally) {
        self.verified += other.verified;
        self.torn += other.torn;
        self.backwards += other.backwards;
        self.lost_counted += other.lost_counted;
        self.lost_silently += other.lost_silently;
        self.over_counted += other.over_counted;
        self.lost_at_follow += other.lost_at_follow;
        self.repeats += other.repeats;
        self.follows += other.follows;
        self.errors += other.errors;
        self.open_failures += other.open_failures;
        if self.first_torn.is_none() {
            self.first_torn.clone_from(&other.first_torn);
        }
    }

    /// Counts one frame, `seen` at `now_ns` by a reader that has followed
    /// `follows` successors so far.
    pub fn observe(&mut self, seen: &Seen, follows: u64, now_ns: u64) {
        if !seen.fresh {
            self.repeats += 1;
            return;
        }
        let seq = seen.seq;
        if self.last_new_ns != 0
            && now_ns.saturating_sub(self.last_new_ns) > LONG_GAP_NS
            && self.long_gaps.len() < MAX_LONG_GAPS
        {
            self.long_gaps.push(Gap { from_ns: self.last_new_ns, to_ns: now_ns, followed: follows != self.follows });
        }
        if follows != self.follows {
            // A new writer: its numbers start again from 1, and the frames
            // it published before this one are lost to this reader, uncounted.
            self.follows = follows;
            self.lost_at_follow += seq.saturating_sub(1);
        } else if self.last_seq != 0 {
            if seq <= self.last_seq {
                self.backwards += 1;
            } else {
                let gap = seq - self.last_seq - 1;
                self.lost_counted += seen.skipped.min(gap);
                self.lost_silently += gap.saturating_sub(seen.skipped);
                self.over_counted += seen.skipped.saturating_sub(gap);
            }
        }
        match seen.mismatch {
            None => self.verified += 1,
            Some(index) => {
                self.torn += 1;
                if self.first_torn.is_none() {
                    self.first_torn =
                        Some(format!("frame {seq} differs from its pattern at response {index} of {}", seen.responses));
                }
            }
        }
        self.last_seq = seq;
        self.last_new_ns = now_ns;
    }
}

/// What a reader saw of one frame, taken from it while the reader lends it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Seen {
    /// Its sequence number.
    pub seq: u64,
    /// `Frame::skipped`.
    pub skipped: u64,
    /// `Frame::is_fresh`.
    pub fresh: bool,
    /// Where it differs from its pattern, if it does (checked only if fresh).
    pub mismatch: Option<usize>,
    /// Its responses.
    pub responses: usize,
}

impl Seen {
    /// Checks `frame` against the pattern of its sequence number.
    pub fn of(frame: &Frame<'_>) -> Seen {
        let fresh = frame.is_fresh();
        Seen {
            seq: frame.seq(),
            skipped: frame.skipped(),
            fresh,
            mismatch: if fresh { pattern_mismatch(frame.seq(), frame.responses()) } else { None },
            responses: frame.responses().len(),
        }
    }
}

/// What a reader process reports.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ReaderReport {
    /// Its reader mode.
    pub mode: Option<Mode>,
    /// Its process id.
    pub pid: u32,
    /// When the report was written (CLOCK_MONOTONIC ns).
    pub written_ns: u64,
    /// Whether this is its last report (it stopped cleanly).
    pub done: bool,
    /// Counts by layer.
    pub layers: BTreeMap<String, LayerTally>,
}

impl ReaderReport {
    /// Writes the report to `path` atomically: a reader killed while writing
    /// leaves the previous report whole.
    pub fn write(&self, path: &Path) -> Result<()> {
        let temp = path.with_extension("tmp");
        std::fs::write(&temp, serde_json::to_vec(self)?).with_context(|| format!("cannot write {}", temp.display()))?;
        std::fs::rename(&temp, path).with_context(|| format!("cannot rename {} to {}", temp.display(), path.display()))
    }

    /// The report at `path`, if one was written.
    pub fn read(path: &Path) -> Option<ReaderReport> {
        serde_json::from_slice(&std::fs::read(path).ok()?).ok()
    }
}

/// What `skin bench-soak-reader` is told.
#[derive(Clone, Debug, clap::Args)]
pub struct ReaderArgs {
    /// The skin.
    #[arg(long)]
    pub skin: String,
    /// Its layers to read.
    #[arg(long, value_delimiter = ',')]
    pub layers: Vec<String>,
    /// How: periodic, asap, request or anticipate.
    #[arg(long, value_parser = Mode::parse)]
    pub mode: Mode,
    /// Where to write the report.
    #[arg(long)]
    pub report: PathBuf,
}

/// Runs a verifying reader process until its standard input closes.
pub fn run(args: &ReaderArgs) -> Result<()> {
    if args.layers.is_empty() {
        bail!("give the layers to read with --layers");
    }
    let stop = Stop::new();
    let tallies: Vec<(String, Arc<Mutex<LayerTally>>)> =
        args.layers.iter().map(|layer| (layer.clone(), Arc::new(Mutex::new(LayerTally::default())))).collect();
    let mut threads = Vec::new();
    for (index, (layer, tally)) in tallies.iter().enumerate() {
        let (skin, layer, tally, stop, mode) =
            (args.skin.clone(), layer.clone(), tally.clone(), stop.clone(), args.mode);
        let seed = u64::from(std::process::id()) << 8 | index as u64;
        threads.push(
            std::thread::Builder::new()
                .name(format!("verify-{layer}"))
                .spawn(move || read_layer(&skin, &layer, mode, &tally, &stop, seed))
                .context("cannot start a reader thread")?,
        );
    }
    let stopper = stop.clone();
    std::thread::spawn(move || {
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
        stopper.stop();
    });
    let report = |done: bool| ReaderReport {
        mode: Some(args.mode),
        pid: std::process::id(),
        written_ns: skinware::os::monotonic_ns(),
        done,
        layers: tallies.iter().map(|(layer, tally)| (layer.clone(), skinware::lock(tally).clone())).collect(),
    };
    while stop.sleep_until(skinware::os::monotonic_ns() + 250_000_000) {
        report(false).write(&args.report)?;
    }
    for thread in threads {
        let _ = thread.join();
    }
    report(true).write(&args.report)
}

/// Reads one layer in `mode` until `stop`, counting into `tally`.
fn read_layer(skin: &str, layer: &str, mode: Mode, tally: &Mutex<LayerTally>, stop: &Stop, seed: u64) {
    let lock = || skinware::lock(tally);
    let options =
        ReaderOptions { anticipate: (mode == Mode::Anticipate).then_some(ANTICIPATE), ..ReaderOptions::default() };
    let mut reader = loop {
        match Reader::open_with(skin, layer, &options) {
            Ok(reader) => break reader,
            Err(_) => {
                lock().open_failures += 1;
                if !stop.sleep_until(skinware::os::monotonic_ns() + 50_000_000) {
                    return;
                }
            }
        }
    };
    reader.set_stop(stop);
    lock().attached = true;
    let mut ticker = Ticker::new(Duration::from_secs_f64(1.0 / PERIODIC_HZ));
    let mut random = seed | 1;
    let timeout = Duration::from_millis(200);
    // A periodic reader's writer that published nothing for this long may
    // be gone: time to look for a successor (what a periodic application
    // does today; a reader that follows on its own makes it a no-op).
    let stale_after =
        reader.writer_period().map_or(Duration::from_millis(100), |p| 2 * p).max(Duration::from_millis(20));
    let mut last_fresh = std::time::Instant::now();
    loop {
        let result = match mode {
            Mode::Periodic => reader.next_periodic(&mut ticker),
            Mode::Asap | Mode::Anticipate => reader.wait_newer(timeout),
            Mode::Request => reader.request(timeout),
        }
        .map(|frame| Seen::of(&frame));
        let now_ns = skinware::os::monotonic_ns();
        let follows = reader.follows();
        let mut stale = false;
        match result {
            Ok(seen) => {
                if seen.fresh {
                    last_fresh = std::time::Instant::now();
                } else {
                    stale = last_fresh.elapsed() > stale_after;
                }
                lock().observe(&seen, follows, now_ns);
            }
            Err(Error::Stopped { .. }) => return,
            Err(Error::Timeout { .. } | Error::NoFrameYet { .. } | Error::WriterGone { .. } | Error::Lapped { .. }) => {
                stale = true;
            }
            Err(e) => {
                let mut tally = lock();
                tally.errors += 1;
                if tally.errors <= 3 {
                    eprintln!("soak reader {} {layer}: {e}", mode.name());
                }
                stale = true;
            }
        }
        if stop.is_stopped() {
            return;
        }
        if stale {
            reader.follow_recreated();
        }
        if mode == Mode::Request {
            // An application that asks now and then, not in a tight loop.
            random ^= random << 13;
            random ^= random >> 7;
            random ^= random << 17;
            let pause = random % 30_000_000;
            if !stop.sleep_until(skinware::os::monotonic_ns() + pause) {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(seq: u64, skipped: u64) -> Seen {
        Seen { seq, skipped, fresh: true, mismatch: None, responses: 10 }
    }

    #[test]
    fn gaps_are_counted_against_what_skipped_said() {
        let mut tally = LayerTally::default();
        tally.observe(&seen(5, 4), 0, 1); // the first frame: nothing before it counts
        tally.observe(&seen(6, 0), 0, 2);
        tally.observe(&seen(9, 2), 0, 3); // 2 lost, both counted
        tally.observe(&seen(12, 1), 0, 4); // 2 lost, 1 counted
        tally.observe(&seen(13, 3), 0, 5); // none lost, 3 said
        tally.observe(&Seen { fresh: false, ..seen(13, 0) }, 0, 6);
        assert_eq!((tally.verified, tally.lost_counted, tally.lost_silently, tally.over_counted), (5, 3, 1, 3));
        assert_eq!((tally.repeats, tally.last_seq, tally.last_new_ns), (1, 13, 5));
    }

    #[test]
    fn a_successor_starts_again_and_a_step_back_without_one_is_caught() {
        let mut tally = LayerTally::default();
        tally.observe(&seen(40, 0), 0, 1);
        tally.observe(&seen(4, 0), 1, 2); // followed: the successor's frames 1-3 not seen
        assert_eq!((tally.backwards, tally.lost_at_follow, tally.lost_silently, tally.follows), (0, 3, 0, 1));
        tally.observe(&seen(3, 0), 1, 3);
        assert_eq!(tally.backwards, 1);
        tally.observe(&Seen { mismatch: Some(7), ..seen(5, 0) }, 1, 4);
        assert_eq!(tally.torn, 1);
        assert!(tally.first_torn.as_deref().unwrap().contains("frame 5"));
    }

    #[test]
    fn long_pauses_between_fresh_frames_are_kept() {
        const S: u64 = 1_000_000_000;
        let mut tally = LayerTally::default();
        tally.observe(&seen(1, 0), 0, 10 * S);
        tally.observe(&Seen { fresh: false, ..seen(1, 0) }, 0, 12 * S); // a repeat ends nothing
        tally.observe(&seen(2, 0), 0, 12 * S + 500); // 2 s without a fresh frame
        tally.observe(&seen(3, 0), 0, 13 * S); // under a second: not kept
        tally.observe(&seen(1, 0), 1, 15 * S); // from a successor
        assert_eq!(
            tally.long_gaps,
            vec![
                Gap { from_ns: 10 * S, to_ns: 12 * S + 500, followed: false },
                Gap { from_ns: 13 * S, to_ns: 15 * S, followed: true },
            ]
        );
    }
}
