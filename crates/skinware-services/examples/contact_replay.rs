//! The contact detector on recorded frames of a running skin, timed per
//! call: the replay harness of docs/bench/contact.md (issue #41). Run it
//! with `cargo run --release -p skinware-services --example contact_replay`.
//!
//! * `record DIR FILE N`: with `skin run examples/demo.toml` running and its
//!   channels in DIR (`SKINWARE_SHM_DIR=DIR` for both), stores the geometry
//!   and N frames of every layer, one each 20 ms, in FILE.
//! * `replay FILE ROUNDS`: runs a new detector over the frames ROUNDS times,
//!   hot (frame after frame) and cold (64 MB written between frames), and
//!   prints each mode's per-call mean, median and p90, the touched taxels a
//!   frame and an FNV-1a digest of every output (compare builds at the same
//!   ROUNDS). `MODES="cold"` runs one mode; `STATS=1` prints the neighbour
//!   and region counts of the skin.
use std::error::Error;
use std::time::{Duration, Instant};

use skinware_geometry::SkinGeometry;
use skinware_services::{ContactDetector, ContactParams, RegionContacts, SkinInputs};

type Result<T> = std::result::Result<T, Box<dyn Error>>;

const USAGE: &str = "usage: contact_replay record DIR FILE FRAMES | contact_replay replay FILE ROUNDS";

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let number = |text: &str, what: &str| -> Result<usize> {
        text.parse().map_err(|_| format!("{what} must be a whole number, not {text:?}; {USAGE}").into())
    };
    match args.iter().map(String::as_str).collect::<Vec<_>>().as_slice() {
        ["record", dir, file, frames] => record(dir, file, number(frames, "FRAMES")?),
        ["replay", file, rounds] => replay(file, number(rounds, "ROUNDS")?),
        _ => Err(USAGE.into()),
    }
}

/// Stores the geometry of skin `default` in `dir` and `frames` frames of
/// every layer, one each 20 ms, in `file`.
fn record(dir: &str, file: &str, frames: usize) -> Result<()> {
    let geometry = SkinGeometry::open_in(std::path::Path::new(dir), "default")
        .map_err(|e| format!("no geometry of skin `default` in {dir} (is `skin run` running there?): {e}"))?;
    let mut inputs = SkinInputs::new("default", &geometry);
    let bytes = geometry.encode();
    let mut out = Vec::new();
    out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
    out.extend_from_slice(&bytes);
    out.extend_from_slice(&(frames as u64).to_le_bytes());
    let mut all = vec![0u16; geometry.sensor_count()];
    for _ in 0..frames {
        std::thread::sleep(Duration::from_millis(20));
        inputs.update();
        all.fill(0);
        for l in 0..geometry.layers.len() {
            out.push(u8::from(inputs.layer_ok[l]));
            out.push(u8::from(inputs.layer_fresh[l]));
            if let Some(responses) = inputs.layer_responses(l) {
                all[geometry.layer_starts[l]..geometry.layer_starts[l + 1]].copy_from_slice(responses);
            }
        }
        out.extend(all.iter().flat_map(|r| r.to_le_bytes()));
    }
    std::fs::write(file, &out).map_err(|e| format!("cannot write {file}: {e}"))?;
    Ok(())
}

/// One recorded frame: per layer whether it was up and new, and every response.
struct Frame {
    ok: Vec<bool>,
    fresh: Vec<bool>,
    responses: Vec<u16>,
}

/// The bytes of a recording not read yet.
struct Cursor<'a> {
    rest: &'a [u8],
    file: &'a str,
}

impl<'a> Cursor<'a> {
    /// The next `count` bytes, or an error if fewer are left.
    fn take(&mut self, count: usize) -> Result<&'a [u8]> {
        let (taken, rest) =
            self.rest.split_at_checked(count).ok_or(format!("{} is cut short: not a recording", self.file))?;
        self.rest = rest;
        Ok(taken)
    }

    /// The next little-endian u64, as a length.
    fn length(&mut self) -> Result<usize> {
        Ok(usize::try_from(u64::from_le_bytes(self.take(8)?.try_into()?))?)
    }
}

/// Reads what [`record`] wrote, checking every length against what is there.
fn load(file: &str) -> Result<(SkinGeometry, Vec<Frame>)> {
    let bytes = std::fs::read(file).map_err(|e| format!("cannot read {file}: {e}"))?;
    let mut cursor = Cursor { rest: &bytes, file };
    let geometry_bytes = cursor.length()?;
    let geometry =
        SkinGeometry::decode(cursor.take(geometry_bytes)?).map_err(|e| format!("{file}: its geometry: {e}"))?;
    let count = cursor.length()?;
    let (layers, n) = (geometry.layers.len(), geometry.sensor_count());
    // A frame of no bytes (a skin of no layers), or more frames than the
    // file holds: refused before any is read.
    let frame_bytes = 2 * layers + 2 * n;
    if frame_bytes == 0 || count > cursor.rest.len() / frame_bytes {
        return Err(
            format!("{file} says {count} frames of {frame_bytes} bytes; it holds fewer: not a recording").into()
        );
    }
    let mut frames = Vec::new();
    for _ in 0..count {
        let flags = cursor.take(2 * layers)?;
        let responses = cursor.take(2 * n)?.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
        let ok = flags.iter().step_by(2).map(|&b| b != 0).collect();
        let fresh = flags.iter().skip(1).step_by(2).map(|&b| b != 0).collect();
        frames.push(Frame { ok, fresh, responses });
    }
    Ok((geometry, frames))
}

/// Runs a new detector over the frames `rounds` times in each mode, and
/// prints each mode's per-call times, touched taxels and outputs digest.
fn replay(file: &str, rounds: usize) -> Result<()> {
    let (geometry, frames) = load(file)?;
    if frames.is_empty() || rounds == 0 {
        return Err(format!("{file} holds {} frames and ROUNDS is {rounds}: nothing to time", frames.len()).into());
    }
    if std::env::var("STATS").is_ok() {
        print_stats(&geometry);
    }
    let modes = std::env::var("MODES").unwrap_or_else(|_| "hot cold".into());
    // Written between frames in the cold mode: 64 MB, so that no line of the
    // detector's stays in the caches.
    let mut sweep = vec![1u64; 64 << 17];
    for mode in modes.split_whitespace() {
        if mode != "hot" && mode != "cold" {
            return Err(format!("MODES: {mode:?} is neither hot nor cold").into());
        }
        let (mut times, mut digest, mut touched) = (Vec::new(), 0xcbf2_9ce4_8422_2325u64, 0usize);
        for _ in 0..rounds {
            let mut detector = ContactDetector::new(&geometry, ContactParams::default());
            let mut records = vec![RegionContacts::default(); detector.region_names().len()];
            for frame in &frames {
                if mode == "cold" {
                    for (k, word) in sweep.iter_mut().enumerate().step_by(8) {
                        *word = word.wrapping_add(k as u64);
                    }
                }
                let started = Instant::now();
                detector.update(&geometry, &frame.responses, &frame.ok, &frame.fresh, 0.02, &mut records);
                times.push(started.elapsed().as_nanos() as u64);
                let states = detector.taxel_states();
                for &byte in bytemuck::cast_slice::<_, u8>(&records).iter().chain(bytemuck::cast_slice(states)) {
                    digest = (digest ^ u64::from(byte)).wrapping_mul(0x0000_0100_0000_01b3);
                }
                touched += states.iter().filter(|s| s.0 == 1).count();
            }
        }
        std::hint::black_box(&sweep);
        times.sort_unstable();
        let us = |ns: u64| ns as f64 / 1e3;
        println!(
            "{mode}: frames {} mean {:.1} us median {:.1} us p90 {:.1} us; touched/frame {:.0}; digest {digest:016x}",
            times.len(),
            times.iter().sum::<u64>() as f64 / times.len() as f64 / 1e3,
            us(times[times.len() / 2]),
            us(times[times.len() * 9 / 10]),
            touched as f64 / times.len() as f64
        );
    }
    Ok(())
}

/// The skin's neighbour and region counts.
fn print_stats(geometry: &SkinGeometry) {
    let n = geometry.sensor_count().max(1);
    let neighbours: Vec<usize> = (0..geometry.sensor_count()).map(|i| geometry.neighbours_of(i).len()).collect();
    let mut regions_per_taxel = vec![0usize; n];
    for set in &geometry.regions.sensors {
        for &s in set {
            if let Some(count) = regions_per_taxel.get_mut(s as usize) {
                *count += 1;
            }
        }
    }
    let histogram: Vec<usize> = (0..4).map(|k| regions_per_taxel.iter().filter(|&&c| c == k).count()).collect();
    println!(
        "neighbours mean {:.2} max {}; regions per taxel histogram {histogram:?}; regions {:?}",
        neighbours.iter().sum::<usize>() as f64 / n as f64,
        neighbours.iter().max().unwrap_or(&0),
        geometry.regions.names
    );
}
