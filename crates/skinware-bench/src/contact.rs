//! `skin bench contact`: the contact service's cost per frame on the paper's
//! 30,848-taxel virtual skin (5 layers at 50 Hz), pressed by the scripted
//! contacts of the services' accuracy test (a press held on the torso, a
//! slide over the left forearm). Two figures:
//!
//! * detector: `ContactDetector::update` alone, in this thread, on frames of
//!   that skin computed between the timed calls (no skin running, no other
//!   thread): the algorithm's own cost, repeatable from run to run.
//! * service: the contact service beside the virtual skin's five writers in
//!   this process, from its channel's write-time statistics (reading the
//!   layers, detecting, publishing contacts and taxel states): the figure
//!   `skin services` prints, with the writers competing for the cores. Twice:
//!   skin and service at the paper's 50 Hz, then both at 1 kHz. At 50 Hz
//!   each frame finds the service's memory gone from the caches (20 ms of
//!   other work, and on a VM the hypervisor, in between); at 1 kHz less of
//!   it is.

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{Driver, DriverHandler, HandlerOptions, Stop, WriterOptions};
use skinware_drivers::{PressureField, Rate, ScriptedContact, VirtualSkin, VirtualSkinConfig};
use skinware_geometry::{RegionSpec, Selector, SkinGeometry};
use skinware_services::framework::{ServiceMode, ServiceReader};
use skinware_services::{ContactDetector, ContactParams, ContactServiceConfig, RegionContacts, run_contact_service};

use crate::measure::Percentiles;
use crate::run_options::RunOptions;

/// What `skin bench contact` measured, per frame, ns.
#[derive(Clone, Debug, Serialize)]
pub struct ContactReport {
    /// Taxels of the skin.
    pub taxels: usize,
    /// `ContactDetector::update` alone.
    pub detector_ns: Percentiles,
    /// FNV-1a of every frame's region records and taxel states from the
    /// detector: the same frames give the same digest, so a change that
    /// should not change the outputs can be checked with it.
    pub detector_outputs_digest: String,
    /// Frames the contact service published.
    pub service_frames: u64,
    /// The service's mean write time (its channel's statistics).
    pub service_ns_mean: u64,
    /// The service's longest write time.
    pub service_ns_max: u64,
    /// The same service, with the skin and the service at 1 kHz.
    pub service_at_1khz: ServiceRun,
    /// The service as users run it: `skin run` of `skin demo`'s skin (its
    /// random contacts all over the body, its 7 regions, layers at 30–50 Hz
    /// and the service at 50 Hz), in the service's own process, read from
    /// its channel's statistics as `skin services` prints them, over the
    /// measured window only.
    pub service_in_demo: ServiceRun,
}

/// One run of the contact service beside the skin's writers.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ServiceRun {
    /// The skin's and the service's rate.
    pub rate_hz: f64,
    /// Frames the service published.
    pub frames: u64,
    /// Its mean write time, ns.
    pub ns_mean: u64,
    /// Its longest write time, ns.
    pub ns_max: u64,
}

const FRAME_PERIOD_S: f64 = 0.02;
const LAYERS: usize = 5;

/// The scripted contacts of the services' accuracy test
/// (`skinware-services/tests/integration/scripted.rs`).
fn scripted_contacts() -> Vec<ScriptedContact> {
    let contact = |part: &str, at_s, angle_deg, height, velocity, slide_s, peak, sigma| ScriptedContact {
        part: part.into(),
        at_s,
        angle_deg,
        height,
        velocity,
        press_s: 0.3,
        slide_s,
        release_s: 0.3,
        peak,
        sigma,
    };
    vec![
        contact("torso", 0.3, 100.0, 0.3, [0.0, 0.0], 30.0, 20_000.0, 0.015),
        contact("left_forearm", 0.5, 30.0, 0.06, [0.03, 0.04], 4.0, 25_000.0, 0.012),
    ]
}

/// The rate of the second service run.
const KILOHERTZ: f64 = 1000.0;

fn skin_config(rate_hz: f64) -> VirtualSkinConfig {
    VirtualSkinConfig {
        layers: LAYERS,
        rate: Rate::Fixed(rate_hz),
        random_contacts: false,
        contacts: scripted_contacts(),
        ..VirtualSkinConfig::default()
    }
}

fn geometry_of(skin: &str, driver: &VirtualSkin) -> Result<SkinGeometry> {
    let layers: Vec<_> = driver.layers().into_iter().map(|l| l.topology).collect();
    let regions = ["torso", "left_forearm", "right_shin"]
        .map(|link| RegionSpec { name: link.into(), selectors: vec![Selector::Link(link.into())] });
    Ok(SkinGeometry::build(skin, &layers, &driver.calibration(), &regions)?)
}

/// Runs both measurements, prints them and writes `contact.json`.
pub fn run(options: &RunOptions) -> Result<ContactReport> {
    let seconds = options.seconds_or(4.0, 20.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let skin = format!("bench-contact-{}", std::process::id());
    let config = skin_config(1.0 / FRAME_PERIOD_S);
    let driver = VirtualSkin::new(config.clone()).map_err(anyhow::Error::msg)?;
    let driver_1khz = VirtualSkin::new(skin_config(KILOHERTZ)).map_err(anyhow::Error::msg)?;
    let geometry = Arc::new(geometry_of(&skin, &driver)?);
    let taxels = geometry.sensor_count();

    let (mut detector_ns, digest) = time_detector(&config, &geometry, seconds);
    let at_paper_rate = time_service(&skin, driver, &geometry, 1.0 / FRAME_PERIOD_S, seconds)?;
    let at_1khz = time_service(&format!("{skin}-khz"), driver_1khz, &geometry, KILOHERTZ, seconds)?;
    let in_demo = time_demo(&options.exe, seconds)?;
    let report = ContactReport {
        taxels,
        detector_ns: Percentiles::of(&mut detector_ns),
        detector_outputs_digest: format!("{digest:016x}"),
        service_frames: at_paper_rate.frames,
        service_ns_mean: at_paper_rate.ns_mean,
        service_ns_max: at_paper_rate.ns_max,
        service_at_1khz: at_1khz,
        service_in_demo: in_demo,
    };
    let us = |ns: f64| ns / 1e3;
    println!(
        "skin bench contact: {taxels} taxels, {LAYERS} layers, scripted contacts, {seconds} s per run (the detector on \
         {:.0} Hz frames; skin and service at 50 Hz, then at 1 kHz)",
        1.0 / FRAME_PERIOD_S
    );
    println!("  {:<14} {:>7} {:>9} {:>9} {:>9} {:>9}", "", "frames", "mean µs", "p50 µs", "p99 µs", "max µs");
    let d = &report.detector_ns;
    println!(
        "  {:<14} {:>7} {:>9.1} {:>9.1} {:>9.1} {:>9.1}",
        "detector",
        d.samples,
        us(d.avg),
        us(d.p50 as f64),
        us(d.p99 as f64),
        us(d.max as f64)
    );
    for (name, run) in [("service 50 Hz", at_paper_rate), ("service 1 kHz", at_1khz), ("skin demo", in_demo)] {
        println!(
            "  {:<14} {:>7} {:>9.1} {:>9} {:>9} {:>9.1}",
            name,
            run.frames,
            us(run.ns_mean as f64),
            "-",
            "-",
            us(run.ns_max as f64)
        );
    }
    println!("  detector outputs digest {}", report.detector_outputs_digest);
    let json = options.out.join("contact.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&report)?)?;
    println!("wrote {}", json.display());
    Ok(report)
}

/// `skin demo`'s skin, which `skin run` starts as users start it.
const DEMO_SKIN: &str = include_str!("../../../examples/demo.toml");

/// Runs `skin run` of the demo's skin in its own processes, waits until its
/// contact service has published for a while, and reads the service's
/// statistics over `seconds`: what `skin services` reports, for the
/// frames of that window (the mean from the statistics' running mean and
/// frame count at both ends).
fn time_demo(exe: &std::path::Path, seconds: f64) -> Result<ServiceRun> {
    let dir = skinware::shm::segment_dir().join(format!("skcd{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let result = (|| {
        let skin = crate::measure::RunningSkin::start_until(exe, DEMO_SKIN, &dir, "skin demo's skin", |channels| {
            channels.iter().any(|c| c.channel == "contact" && c.stats.frames > 100)
        })?;
        let options = skinware::ReaderOptions { dir: Some(dir.clone()), ..Default::default() };
        let reader = skinware::Reader::open_with("default", "contact", &options)?;
        let before = reader.writer_stats();
        std::thread::sleep(Duration::from_secs_f64(seconds));
        let after = reader.writer_stats();
        drop(skin);
        let (frames, ns_mean) = crate::measure::write_ns_between(&before, &after);
        Ok(ServiceRun { rate_hz: 50.0, frames, ns_mean, ns_max: after.write_ns_max })
    })();
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// Times `ContactDetector::update` on `seconds` of frames of the scripted
/// skin, with the virtual skin's noise; returns each update's time, ns, and
/// the digest of its outputs. So that the digest covers every path of the
/// detector, one taxel is dead and one stuck (those of the accuracy test), the
/// second layer has a new frame only every other update (the others read
/// its frame again, which the detector does not classify again), and the
/// last layer is down for half a second and comes back with the frame it
/// had (not fresh, and not classified since: classified without counting
/// towards dead and stuck).
fn time_detector(config: &VirtualSkinConfig, geometry: &SkinGeometry, seconds: f64) -> (Vec<u64>, u64) {
    const DEAD_TAXEL: usize = 4;
    const STUCK_TAXEL: usize = 16;
    let taxels = geometry.sensor_count();
    let field = PressureField::with_contacts(taxels, config.seed, seconds + 1.0, &config.contacts, false);
    let mut detector = ContactDetector::new(geometry, ContactParams::default());
    let mut records = vec![RegionContacts::default(); detector.region_names().len()];
    let mut responses = vec![0u16; taxels];
    let mut next = vec![0u16; taxels];
    let layers = geometry.layers.len();
    let (mut layer_ok, mut layer_fresh) = (vec![true; layers], vec![true; layers]);
    let slow_layer = geometry.layer_starts[1]..geometry.layer_starts[2];
    let last_layer = geometry.layer_starts[layers - 1]..geometry.layer_starts[layers];
    // The virtual skin's noise: uniform in -8..=8.
    let mut noise_state = config.seed;
    let frames = (seconds / FRAME_PERIOD_S).round() as usize;
    let down = frames / 3..frames / 3 + 25;
    let mut times = Vec::with_capacity(frames);
    let mut digest = Fnv1a::default();
    for frame in 0..frames {
        field.responses(frame as f64 * FRAME_PERIOD_S, 0, &mut next);
        for response in &mut next {
            noise_state ^= noise_state << 13;
            noise_state ^= noise_state >> 7;
            noise_state ^= noise_state << 17;
            let noise = (noise_state % 17) as i32 - 8;
            *response = (i32::from(*response) + noise).clamp(0, i32::from(u16::MAX)) as u16;
        }
        if frame > 0 {
            next[DEAD_TAXEL] = responses[DEAD_TAXEL];
        }
        next[STUCK_TAXEL] = u16::MAX;
        layer_fresh[1] = frame % 2 == 0;
        if !layer_fresh[1] {
            next[slow_layer.clone()].copy_from_slice(&responses[slow_layer.clone()]);
        }
        layer_ok[layers - 1] = !down.contains(&frame);
        let back_with_its_old_frame = frame == down.end;
        layer_fresh[layers - 1] = layer_ok[layers - 1] && !back_with_its_old_frame;
        if back_with_its_old_frame {
            next[last_layer.clone()].copy_from_slice(&responses[last_layer.clone()]);
        }
        std::mem::swap(&mut responses, &mut next);
        let started = Instant::now();
        detector.update(geometry, &responses, &layer_ok, &layer_fresh, FRAME_PERIOD_S as f32, &mut records);
        times.push(started.elapsed().as_nanos() as u64);
        digest.add(bytemuck::cast_slice(&records));
        digest.add(bytemuck::cast_slice(detector.taxel_states()));
    }
    (times, digest.0)
}

/// The 64-bit FNV-1a hash: simple, and the same on every platform and run.
struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Fnv1a(0xcbf2_9ce4_8422_2325)
    }
}

impl Fnv1a {
    fn add(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
}

/// Runs the virtual skin (`driver`, at `rate_hz`) and the contact service at
/// the same rate for `seconds`.
fn time_service(
    skin: &str,
    driver: VirtualSkin,
    geometry: &Arc<SkinGeometry>,
    rate_hz: f64,
    seconds: f64,
) -> Result<ServiceRun> {
    let handler = DriverHandler::start(skin, Box::new(driver), &HandlerOptions::default())?;
    let stop = Stop::new();
    let service = {
        let (skin, geometry, stop) = (skin.to_owned(), geometry.clone(), stop.clone());
        std::thread::spawn(move || {
            let config = ContactServiceConfig {
                name: "contact".into(),
                mode: ServiceMode::Periodic { hz: rate_hz },
                params: ContactParams::default(),
            };
            run_contact_service(&skin, &config, &geometry, &WriterOptions::default(), &stop)
        })
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut contacts = loop {
        match ServiceReader::<RegionContacts>::open(skin, "contact") {
            Ok(reader) => break reader,
            Err(_) if Instant::now() < deadline && !service.is_finished() => {
                std::thread::sleep(Duration::from_millis(20))
            }
            Err(e) => {
                stop.stop();
                handler.stop();
                bail!("the contact service did not start: {e}");
            }
        }
    };
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let stats = contacts.reader().writer_stats();
    stop.stop();
    let outcome = service.join();
    handler.stop();
    match outcome {
        Ok(Ok(())) => {
            Ok(ServiceRun { rate_hz, frames: stats.frames, ns_mean: stats.write_ns_mean, ns_max: stats.write_ns_max })
        }
        Ok(Err(e)) => Err(anyhow::Error::new(e).context("the contact service failed")),
        Err(_) => bail!("the contact service panicked"),
    }
}
