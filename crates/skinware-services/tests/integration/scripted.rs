//! The services on the 30,848-sensor virtual skin with scripted contacts of
//! known place, direction and speed: a contact held on the torso, one sliding
//! over the left forearm, dead and stuck taxels, and a pulled cable.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use skinware::{Driver, DriverHandler, FrameStatus, HandlerOptions, Stop, WriterOptions};
use skinware_drivers::{Rate, ScriptedContact, VirtualBody, VirtualSkin, VirtualSkinConfig};
use skinware_geometry::{RegionSpec, Selector, SkinGeometry};
use skinware_services::framework::{ServiceMode, ServiceReader};
use skinware_services::{
    ContactParams, ContactServiceConfig, MotionParams, MotionRecord, MotionServiceConfig, RegionContacts, TaxelState,
    contact_flags, motion_flags, run_contact_service, run_motion_service, taxel_channel,
};

const FOREARM_RADIUS: f64 = 0.042;
/// The slide: around the forearm at 0.03 m/s and along it at 0.04 m/s.
const SLIDE_VELOCITY: [f64; 2] = [0.03, 0.04];

fn contacts() -> Vec<ScriptedContact> {
    vec![
        ScriptedContact {
            part: "torso".into(),
            at_s: 0.3,
            angle_deg: 100.0,
            height: 0.3,
            velocity: [0.0, 0.0],
            press_s: 0.3,
            slide_s: 30.0,
            release_s: 0.3,
            peak: 20_000.0,
            sigma: 0.015,
        },
        ScriptedContact {
            part: "left_forearm".into(),
            at_s: 0.5,
            angle_deg: 30.0,
            height: 0.06,
            velocity: SLIDE_VELOCITY,
            press_s: 0.3,
            slide_s: 4.0,
            release_s: 0.3,
            peak: 25_000.0,
            sigma: 0.012,
        },
    ]
}

struct Running {
    stop: Stop,
    handler: Option<DriverHandler>,
    threads: Vec<std::thread::JoinHandle<()>>,
    pull_files: Vec<PathBuf>,
}

impl Drop for Running {
    fn drop(&mut self) {
        self.stop.stop();
        for thread in self.threads.drain(..) {
            let _ = thread.join();
        }
        if let Some(handler) = self.handler.take() {
            handler.stop();
        }
        for file in &self.pull_files {
            let _ = std::fs::remove_file(file);
        }
    }
}

/// Starts the skin, its geometry and both services in this process.
fn start(skin: &str, dead: Vec<u32>, stuck: Vec<u32>) -> (Running, Arc<SkinGeometry>) {
    let pull_files: Vec<PathBuf> = (0..5).map(|l| std::env::temp_dir().join(format!("{skin}-pull-{l}"))).collect();
    let config = VirtualSkinConfig {
        layers: 5,
        rate: Rate::Fixed(50.0),
        random_contacts: false,
        contacts: contacts(),
        dead_taxels: dead,
        stuck_taxels: stuck,
        pull_files: Some(pull_files.clone()),
        ..VirtualSkinConfig::default()
    };
    let driver = VirtualSkin::new(config).unwrap();
    let layers: Vec<_> = driver.layers().into_iter().map(|l| l.topology).collect();
    let regions = vec![
        RegionSpec { name: "torso".into(), selectors: vec![Selector::Link("torso".into())] },
        RegionSpec { name: "left_forearm".into(), selectors: vec![Selector::Link("left_forearm".into())] },
        RegionSpec { name: "right_shin".into(), selectors: vec![Selector::Link("right_shin".into())] },
    ];
    let geometry = Arc::new(SkinGeometry::build(skin, &layers, &driver.calibration(), &regions).unwrap());
    let handler = DriverHandler::start(skin, Box::new(driver), &HandlerOptions::default()).unwrap();
    let stop = Stop::new();
    let mut threads = Vec::new();
    {
        let (skin, geometry, stop) = (skin.to_owned(), geometry.clone(), stop.clone());
        threads.push(std::thread::spawn(move || {
            let config = ContactServiceConfig {
                name: "contact".into(),
                mode: ServiceMode::Periodic { hz: 50.0 },
                params: ContactParams::default(),
            };
            run_contact_service(&skin, &config, &geometry, &WriterOptions::default(), &stop).unwrap();
        }));
    }
    {
        let (skin, stop) = (skin.to_owned(), stop.clone());
        threads.push(std::thread::spawn(move || {
            let config = MotionServiceConfig {
                name: "motion".into(),
                mode: ServiceMode::Periodic { hz: 50.0 },
                input: "contact".into(),
                params: MotionParams::default(),
            };
            run_motion_service(&skin, &config, &WriterOptions::default(), &stop).unwrap();
        }));
    }
    (Running { stop, handler: Some(handler), threads, pull_files }, geometry)
}

fn open<T: skinware_services::framework::ServicePayload>(skin: &str, name: &str) -> ServiceReader<T> {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match ServiceReader::<T>::open(skin, name) {
            Ok(reader) => return reader,
            Err(_) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
            Err(e) => panic!("service {name} did not appear: {e}"),
        }
    }
}

fn angle_between(a: [f64; 2], b: [f64; 2]) -> f64 {
    let d = (a[1].atan2(a[0]) - b[1].atan2(b[0])).to_degrees().rem_euclid(360.0);
    d.min(360.0 - d)
}

fn nearest_sensor(geometry: &SkinGeometry, point: [f64; 3]) -> usize {
    (0..geometry.sensor_count())
        .min_by(|&a, &b| {
            let da: f64 = (0..3).map(|c| (f64::from(geometry.positions[a][c]) - point[c]).powi(2)).sum();
            let db: f64 = (0..3).map(|c| (f64::from(geometry.positions[b][c]) - point[c]).powi(2)).sum();
            da.total_cmp(&db)
        })
        .unwrap()
}

/// Errors of the motion service's slide estimates against the script, one per sample.
#[derive(Default)]
struct SlideErrors {
    direction: Vec<f64>,
    speed: Vec<f64>,
    map_direction: Vec<f64>,
    map_speed: Vec<f64>,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn worst(v: &[f64]) -> f64 {
    v.iter().copied().fold(0.0, f64::max)
}

/// Samples the left forearm's slide once it is well under way: the errors
/// of at least 40 samples, and where the service says the slide started.
fn sample_slide(motion: &mut ServiceReader<MotionRecord>, geometry: &SkinGeometry) -> (SlideErrors, [f32; 3]) {
    let mut errors = SlideErrors::default();
    let mut started: Option<[f32; 3]> = None;
    let deadline = Instant::now() + Duration::from_secs(20);
    while errors.direction.len() < 40 && Instant::now() < deadline {
        let frame = motion.wait_newer(Duration::from_secs(2)).unwrap();
        let record = frame.records[1];
        if record.flags & motion_flags::SLIDING == 0 || record.duration_s < 1.0 {
            continue;
        }
        assert_eq!(record.flags & motion_flags::INPUT_FAULTED, 0);
        started.get_or_insert(record.start_3d);
        add_slide_errors(&record, geometry, &mut errors);
    }
    assert!(errors.direction.len() >= 40, "the slide was not reported as sliding often enough");
    (errors, started.unwrap())
}

/// Compares one sliding record with the script's truth at the measured place.
fn add_slide_errors(record: &MotionRecord, geometry: &SkinGeometry, errors: &mut SlideErrors) {
    // Truth at the measured place: the tangent around the axis and the axis.
    let now = record.now_3d.map(f64::from);
    let angle = (now[1] - 0.0).atan2(now[0] - 0.24);
    let truth = [-angle.sin() * SLIDE_VELOCITY[0], angle.cos() * SLIDE_VELOCITY[0], SLIDE_VELOCITY[1]];
    let truth_speed = SLIDE_VELOCITY[0].hypot(SLIDE_VELOCITY[1]);
    let measured = record.velocity_3d.map(f64::from);
    let cos = (0..3).map(|c| measured[c] * truth[c]).sum::<f64>()
        / (measured.iter().map(|v| v * v).sum::<f64>().sqrt() * truth_speed);
    errors.direction.push(cos.clamp(-1.0, 1.0).acos().to_degrees());
    errors.speed.push((f64::from(record.speed_3d) - truth_speed).abs() / truth_speed);
    // On the map: where the truth moves the contact, through the map.
    let height = now[2] - 0.85;
    let ahead_angle = angle + 0.02 * SLIDE_VELOCITY[0] / truth_speed / FOREARM_RADIUS;
    let ahead_height = height + 0.02 * SLIDE_VELOCITY[1] / truth_speed;
    let (ahead, _) = VirtualBody::surface_point("left_forearm", ahead_angle, ahead_height).unwrap();
    let (here, _) = VirtualBody::surface_point("left_forearm", angle, height).unwrap();
    let (a, b) = (
        geometry.map.positions[nearest_sensor(geometry, here)],
        geometry.map.positions[nearest_sensor(geometry, ahead)],
    );
    let map_truth = [f64::from(b[0] - a[0]), f64::from(b[1] - a[1])];
    errors.map_direction.push(angle_between(record.velocity_map.map(f64::from), map_truth));
    errors.map_speed.push((f64::from(record.speed_map) - truth_speed).abs() / truth_speed);
}

/// Prints the slide's errors and checks the worst of each.
fn check_slide_errors(mut errors: SlideErrors) {
    eprintln!(
        "3-D direction error median {:.1}° worst {:.1}°; speed error median {:.1}% worst {:.1}%",
        median(&mut errors.direction),
        worst(&errors.direction),
        100.0 * median(&mut errors.speed),
        100.0 * worst(&errors.speed)
    );
    eprintln!(
        "map direction error median {:.1}° worst {:.1}°; map speed error median {:.1}% worst {:.1}%",
        median(&mut errors.map_direction),
        worst(&errors.map_direction),
        100.0 * median(&mut errors.map_speed),
        100.0 * worst(&errors.map_speed)
    );
    assert!(worst(&errors.direction) < 20.0, "{:?}", errors.direction);
    assert!(worst(&errors.speed) < 0.25, "{:?}", errors.speed);
    assert!(worst(&errors.map_direction) < 20.0, "{:?}", errors.map_direction);
    assert!(worst(&errors.map_speed) < 0.25, "{:?}", errors.map_speed);
}

/// The slide started where the script pressed.
fn check_slide_start(started: [f32; 3], pitch: f64) {
    let (start_truth, _) = VirtualBody::surface_point("left_forearm", 30f64.to_radians(), 0.06).unwrap();
    let start = started.map(f64::from);
    let start_error = (0..3).map(|c| (start[c] - start_truth[c]).powi(2)).sum::<f64>().sqrt();
    eprintln!("start error {:.1} mm (pitch {:.1} mm)", start_error * 1e3, pitch * 1e3);
    assert!(start_error < 2.0 * pitch, "started {start:?}, truth {start_truth:?}");
}

/// The contact held on the torso: its centroid, normal and map centroid; and
/// no contact on the right shin.
fn check_held_contact(contact: &mut ServiceReader<RegionContacts>, geometry: &SkinGeometry, pitch: f64) {
    let (truth, truth_normal) = VirtualBody::surface_point("torso", 100f64.to_radians(), 0.3).unwrap();
    let frame = contact.wait_newer(Duration::from_secs(2)).unwrap();
    let torso = frame.records[0];
    assert_eq!(torso.count, 1, "{torso:?}");
    let c = torso.contacts()[0];
    let error = (0..3).map(|k| (f64::from(c.centroid[k]) - truth[k]).powi(2)).sum::<f64>().sqrt();
    let normal_cos: f64 = (0..3).map(|k| f64::from(c.normal[k]) * truth_normal[k]).sum();
    eprintln!(
        "torso contact: centroid error {:.2} mm (pitch {:.1} mm), {} taxels, area {:.1} cm², total {:.0}, peak {:.0}, normal error {:.1}°",
        error * 1e3,
        pitch * 1e3,
        c.taxels,
        c.area_m2 * 1e4,
        c.total,
        c.peak,
        normal_cos.clamp(-1.0, 1.0).acos().to_degrees()
    );
    assert!(error < 2.0 * pitch);
    assert!(normal_cos > 0.99);
    assert!(c.taxels > 10 && c.peak > 15_000.0);
    // The map centroid sits at the map position of the taxel nearest the truth.
    let m = geometry.map.positions[nearest_sensor(geometry, truth)];
    let map_error = f64::from((c.map[0] - m[0]).hypot(c.map[1] - m[1]));
    assert!(map_error < 2.0 * pitch, "map centroid {:?} vs {m:?}", c.map);
    // No contact where there is none.
    assert_eq!(frame.records[2].count, 0);
}

/// Prints the services' own cost per frame, from their channels' statistics.
fn print_service_costs(contact: &mut ServiceReader<RegionContacts>, motion: &mut ServiceReader<MotionRecord>) {
    for (name, stats) in [("contact", contact.reader().writer_stats()), ("motion", motion.reader().writer_stats())] {
        eprintln!(
            "{name}: {} frames, per-frame cost p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs",
            stats.frames,
            stats.write_ns_quantile(0.5) as f64 / 1e3,
            stats.write_ns_quantile(0.99) as f64 / 1e3,
            stats.write_ns_max as f64 / 1e3
        );
    }
}

#[test]
fn motion_direction_speed_and_contact_centroid_match_the_script() {
    let skin = format!("svc{}", std::process::id());
    let (running, geometry) = start(&skin, Vec::new(), Vec::new());
    let mut motion = open::<MotionRecord>(&skin, "motion");
    let mut contact = open::<RegionContacts>(&skin, "contact");
    assert_eq!(motion.labels(), ["torso", "left_forearm", "right_shin"]);
    let pitch = geometry.neighbour_stats.mean_edge_m;

    let (errors, started) = sample_slide(&mut motion, &geometry);
    check_slide_errors(errors);
    check_slide_start(started, pitch);
    check_held_contact(&mut contact, &geometry, pitch);
    print_service_costs(&mut contact, &mut motion);
    drop(running);
}

#[test]
fn a_pulled_layer_is_reported_and_dead_and_stuck_taxels_are_found() {
    let skin = format!("svcpull{}", std::process::id());
    // Two uids on the torso (layer 0): one dead, one stuck.
    let (running, geometry) = start(&skin, vec![5], vec![17]);
    let mut contact = open::<RegionContacts>(&skin, "contact");
    let mut taxels = open::<TaxelState>(&skin, &taxel_channel("contact"));
    let mut motion = open::<MotionRecord>(&skin, "motion");
    // Dead after 100 unchanged frames at 50 Hz: about 2 s.
    let deadline = Instant::now() + Duration::from_secs(15);
    loop {
        let frame = contact.wait_newer(Duration::from_secs(2)).unwrap();
        if frame.records[0].dead == 1 && frame.records[0].stuck == 1 {
            break;
        }
        assert!(Instant::now() < deadline, "dead/stuck not found: {:?}", frame.records[0]);
    }
    let states = taxels.latest().unwrap();
    assert_eq!(states.records[4], TaxelState::DEAD);
    assert_eq!(states.records[16], TaxelState::STUCK);
    assert_eq!(states.records.iter().filter(|s| **s == TaxelState::DEAD).count(), 1);

    // Pull the cable of the last layer (the legs: the right shin).
    let last = geometry.layers.len() - 1;
    let shin_layer = geometry.locate(geometry.link("right_shin").unwrap()[0] as usize).unwrap().layer;
    assert_eq!(shin_layer, last);
    std::fs::write(&running.pull_files[last], b"").unwrap();
    let pulled = Instant::now();
    let deadline = pulled + Duration::from_secs(5);
    loop {
        let frame = contact.wait_newer(Duration::from_secs(2)).unwrap();
        if frame.status.contains(FrameStatus::INPUT_FAULTED) {
            assert_ne!(frame.records[2].flags & contact_flags::INPUT_FAULTED, 0, "right_shin not flagged");
            assert_eq!(frame.records[0].flags & contact_flags::INPUT_FAULTED, 0, "torso flagged");
            break;
        }
        assert!(Instant::now() < deadline, "the pulled layer was not reported");
    }
    eprintln!("contact service reported the pulled layer after {:?}", pulled.elapsed());
    let states = taxels.latest().unwrap();
    let shin = geometry.link("right_shin").unwrap()[0] as usize;
    assert_eq!(states.records[shin], TaxelState::NO_INPUT);
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let frame = motion.wait_newer(Duration::from_secs(2)).unwrap();
        if frame.status.contains(FrameStatus::INPUT_FAULTED) {
            assert_ne!(frame.records[2].flags & motion_flags::INPUT_FAULTED, 0);
            assert_eq!(frame.records[0].flags & motion_flags::INPUT_FAULTED, 0);
            break;
        }
        assert!(Instant::now() < deadline, "the motion service did not report the pulled layer");
    }
    // Plugged back: the reports clear.
    std::fs::remove_file(&running.pull_files[last]).unwrap();
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let frame = contact.wait_newer(Duration::from_secs(2)).unwrap();
        if !frame.status.contains(FrameStatus::INPUT_FAULTED) {
            assert_eq!(frame.records[2].flags & contact_flags::INPUT_FAULTED, 0);
            break;
        }
        assert!(Instant::now() < deadline, "the report did not clear after the cable came back");
    }
    drop(running);
}

#[test]
fn readers_with_the_wrong_type_get_typed_errors() {
    let skin = format!("svctype{}", std::process::id());
    let (running, _geometry) = start(&skin, Vec::new(), Vec::new());
    open::<MotionRecord>(&skin, "motion");
    match ServiceReader::<RegionContacts>::open(&skin, "motion") {
        Err(skinware::Error::SchemaMismatch { found, expected, .. }) => {
            assert_eq!((found.as_str(), expected.as_str()), ("skinware.motion", "skinware.contacts"));
        }
        other => panic!("expected a schema mismatch, got {:?}", other.err()),
    }
    match ServiceReader::<MotionRecord>::open(&skin, "virtual-0") {
        Err(e @ skinware::Error::NotThisService { .. }) => assert!(e.to_string().contains("it is a layer"), "{e}"),
        other => panic!("expected NotThisService, got {:?}", other.err()),
    }
    drop(running);
}
