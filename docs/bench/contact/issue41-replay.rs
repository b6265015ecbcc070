//! The replay harness of docs/bench/contact.md (issue #41, second pass): not
//! part of the build. Copy it to crates/skinware-services/examples/ and build
//! it with `cargo build --release -p skinware-services --example issue41-replay`.
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
use std::io::{Read, Write};
use std::time::{Duration, Instant};

use skinware_geometry::SkinGeometry;
use skinware_services::{ContactDetector, ContactParams, RegionContacts, SkinInputs};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    match args[1].as_str() {
        "record" => record(&args[2], &args[3], args[4].parse().unwrap()),
        "replay" => replay(&args[2], args[3].parse().unwrap()),
        _ => panic!("record DIR FILE N | replay FILE ROUNDS"),
    }
}

fn record(dir: &str, file: &str, frames: usize) {
    let geometry = SkinGeometry::open_in(std::path::Path::new(dir), "default").unwrap();
    let mut inputs = SkinInputs::new("default", &geometry);
    let mut out = Vec::new();
    let bytes = geometry.encode();
    out.extend_from_slice(&(bytes.len() as u64).to_le_bytes());
    out.extend_from_slice(&bytes);
    out.extend_from_slice(&(frames as u64).to_le_bytes());
    let layers = geometry.layers.len();
    let n = geometry.sensor_count();
    for _ in 0..frames {
        std::thread::sleep(Duration::from_millis(20));
        inputs.update();
        let mut all = vec![0u16; n];
        for l in 0..layers {
            out.push(inputs.layer_ok[l] as u8);
            out.push(inputs.layer_fresh[l] as u8);
            if let Some(r) = inputs.layer_responses(l) {
                all[geometry.layer_starts[l]..geometry.layer_starts[l + 1]].copy_from_slice(r);
            }
        }
        out.extend_from_slice(bytemuck::cast_slice(&all));
    }
    std::fs::File::create(file).unwrap().write_all(&out).unwrap();
}

fn replay(file: &str, rounds: usize) {
    let mut bytes = Vec::new();
    std::fs::File::open(file).unwrap().read_to_end(&mut bytes).unwrap();
    let glen = u64::from_le_bytes(bytes[0..8].try_into().unwrap()) as usize;
    let geometry = SkinGeometry::decode(&bytes[8..8 + glen]).unwrap();
    let mut at = 8 + glen;
    let frames = u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()) as usize;
    at += 8;
    let layers = geometry.layers.len();
    let n = geometry.sensor_count();
    let mut recorded = Vec::new();
    for _ in 0..frames {
        let mut ok = vec![false; layers];
        let mut fresh = vec![false; layers];
        for l in 0..layers {
            ok[l] = bytes[at] != 0;
            fresh[l] = bytes[at + 1] != 0;
            at += 2;
        }
        let responses: Vec<u16> =
            bytes[at..at + 2 * n].chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
        at += 2 * n;
        recorded.push((ok, fresh, responses));
    }
    let mut sweep = vec![1u64; 64 << 17]; // 64 MB
    if std::env::var("STATS").is_ok() {
        let nb: usize = (0..n).map(|i| geometry.neighbours_of(i).len()).sum();
        let mx = (0..n).map(|i| geometry.neighbours_of(i).len()).max().unwrap();
        let mut per = vec![0usize; n];
        for set in &geometry.regions.sensors {
            for &s in set {
                per[s as usize] += 1;
            }
        }
        let hist: Vec<usize> = (0..4).map(|k| per.iter().filter(|&&c| c == k).count()).collect();
        println!(
            "neighbours mean {:.2} max {mx}; regions per taxel histogram {hist:?}; regions {:?}",
            nb as f64 / n as f64,
            geometry.regions.names
        );
    }
    let modes: Vec<String> = std::env::var("MODES").unwrap_or("hot cold".into()).split(" ").map(String::from).collect();
    for mode in modes.iter().map(String::as_str) {
        let mut all = Vec::new();
        let mut digest = 0xcbf2_9ce4_8422_2325u64;
        let mut touched = 0usize;
        for _ in 0..rounds {
            let mut detector = ContactDetector::new(&geometry, ContactParams::default());
            let mut records = vec![RegionContacts::default(); detector.region_names().len()];
            for (ok, fresh, responses) in &recorded {
                if mode == "cold" {
                    for (k, v) in sweep.iter_mut().enumerate().step_by(8) {
                        *v = v.wrapping_add(k as u64);
                    }
                }
                let started = Instant::now();
                detector.update(&geometry, responses, ok, fresh, 0.02, &mut records);
                all.push(started.elapsed().as_nanos() as u64);
                for b in
                    bytemuck::cast_slice::<_, u8>(&records).iter().chain(bytemuck::cast_slice(detector.taxel_states()))
                {
                    digest = (digest ^ u64::from(*b)).wrapping_mul(0x0000_0100_0000_01b3);
                }
                touched += detector.taxel_states().iter().filter(|s| s.0 == 1).count();
            }
        }
        std::hint::black_box(&sweep);
        let mean = all.iter().sum::<u64>() as f64 / all.len() as f64 / 1e3;
        all.sort_unstable();
        let med = all[all.len() / 2] as f64 / 1e3;
        println!(
            "{mode}: frames {} mean {mean:.1} us median {med:.1} us p90 {:.1} us; touched/frame {:.0}; digest {digest:016x}",
            all.len(),
            all[all.len() * 9 / 10] as f64 / 1e3,
            touched as f64 / all.len() as f64
        );
    }
}
