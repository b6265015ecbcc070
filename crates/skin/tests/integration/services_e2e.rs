//! End to end: `skin run` with regions and services in their own processes;
//! `skin services`, `echo --service`, `ls --regions`, `geometry` and
//! `region record` against it; a SIGKILLed service reported by the service
//! built on it and restarted by the supervisor; a clean shutdown.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

use skinware::{FrameStatus, ReaderOptions};
use skinware_services::framework::ServiceReader;
use skinware_services::{MotionRecord, motion_flags};

use crate::util::{interrupt_and_wait, one_skin_at_a_time};

const CONFIG: &str = r#"
skin = "svc"

[[driver]]
name = "body"
kind = "virtual"
sensors = 6000
layers = 2
rate_hz = 50
random_contacts = false

[[driver.contact]]
part = "torso"
at_s = 4.0
angle_deg = 90
height = 0.3
slide_s = 60

[[driver.contact]]
part = "left_forearm"
at_s = 4.0
angle_deg = 0
height = 0.05
velocity = [0.03, 0.0]
slide_s = 60

[[region]]
name = "torso"
links = ["torso"]

[[region]]
name = "left_forearm"
links = ["left_forearm"]

[[service]]
name = "contact"
kind = "contact"
rate_hz = 50
restart = { min_backoff_s = 0.1, max_backoff_s = 0.5 }

[[service]]
name = "motion"
kind = "motion"
input = "contact"
rate_hz = 50
"#;

struct Skin {
    dir: PathBuf,
    config: PathBuf,
    supervisor: Option<Child>,
}

impl Drop for Skin {
    fn drop(&mut self) {
        if let Some(mut supervisor) = self.supervisor.take() {
            let _ = supervisor.kill();
            let _ = supervisor.wait();
        }
        crate::util::show_logs_if_failing(&self.dir);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

fn skin_command(dir: &Path) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
    command.env("SKINWARE_SHM_DIR", dir).env("SKINWARE_CACHE_DIR", dir.join("cache")).env("RUST_LOG", "warn");
    command
}

fn skin(dir: &Path, args: &[&str]) -> Output {
    let output = skin_command(dir).args(args).output().expect("run skin");
    assert!(output.status.success(), "skin {args:?} failed: {}", String::from_utf8_lossy(&output.stderr));
    output
}

fn json(dir: &Path, args: &[&str]) -> serde_json::Value {
    serde_json::from_slice(&skin(dir, args).stdout).expect("JSON output")
}

fn poll<T>(what: &str, within: Duration, mut check: impl FnMut() -> Option<T>) -> T {
    let started = Instant::now();
    loop {
        if let Some(value) = check() {
            return value;
        }
        assert!(started.elapsed() < within, "{what}: not within {within:?}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn services_run_supervised_and_report_through_the_cli() {
    let _alone = one_skin_at_a_time();
    let dir = PathBuf::from("/dev/shm").join(format!("skin-svc-e2e-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("config.toml");
    std::fs::write(&config, CONFIG).unwrap();
    let supervisor = skin_command(&dir)
        .arg("run")
        .arg(&config)
        .stdout(crate::util::log_file(&dir, "skin-run"))
        .stderr(crate::util::log_file(&dir, "skin-run"))
        .spawn()
        .expect("start skin run");
    let mut running = Skin { dir: dir.clone(), config, supervisor: Some(supervisor) };

    let services = services_are_listed(&dir);
    regions_and_geometry_are_listed(&dir);
    a_region_is_recorded(&dir, &running.config);
    let mut motion_reader = motion_sees_the_forearm_slide(&dir);
    let contact = services.iter().find(|s| s["name"] == "contact").unwrap();
    killed_contact_service_is_reported_and_restarted(contact, &mut motion_reader);
    ctrl_c_stops_everything(&dir, &mut running);
    drop(running);
}

/// Three service channels, running, reading the two layers.
fn services_are_listed(dir: &Path) -> Vec<serde_json::Value> {
    let services = poll("services running", Duration::from_secs(30), || {
        let listed = json(dir, &["services", "--skin", "svc", "--json"]);
        let services = listed["services"].as_array()?.clone();
        (services.len() == 3 && services.iter().all(|s| s["state"] == "running" && s["frames"].as_u64() > Some(10)))
            .then_some(services)
    });
    let contact = services.iter().find(|s| s["name"] == "contact").unwrap();
    assert_eq!(contact["schema"], "skinware.contacts");
    assert_eq!(contact["records"], 2);
    assert_eq!(contact["inputs"], serde_json::json!(["body-0", "body-1"]));
    let motion = services.iter().find(|s| s["name"] == "motion").unwrap();
    assert_eq!(motion["inputs"], serde_json::json!(["contact"]));
    services
}

/// Regions, sub-regions and the published geometry.
fn regions_and_geometry_are_listed(dir: &Path) {
    let regions = json(dir, &["ls", "--regions", "--skin", "svc", "--json"]);
    assert_eq!(regions["regions"].as_array().unwrap().len(), 2);
    let geometry = json(dir, &["geometry", "--skin", "svc", "--json"]);
    assert_eq!(geometry["sensors"], 6000);
    assert_eq!(geometry["source"], "published");
    assert!(geometry["map"]["mean_relative_error"].as_f64().unwrap() < 0.15);
}

/// Record a region while the scripted contacts press (from 4 s on).
fn a_region_is_recorded(dir: &Path, config: &Path) {
    let recorded = skin(
        dir,
        &[
            "region",
            "record",
            "touched",
            "--config",
            config.to_str().unwrap(),
            "--seconds",
            "5",
            "--baseline-seconds",
            "0.5",
        ],
    );
    assert!(String::from_utf8_lossy(&recorded.stdout).contains("region \"touched\""));
    let text = std::fs::read_to_string(config).unwrap();
    assert!(text.contains("name = \"touched\"") && text.contains("[[region.in_layer]]"), "{text}");
    let rebuilt = json(dir, &["geometry", config.to_str().unwrap(), "--json"]);
    assert_eq!(rebuilt["regions"], 3);
}

/// The motion service sees the forearm contact slide around the arm; returns
/// the reader that saw it.
fn motion_sees_the_forearm_slide(dir: &Path) -> ServiceReader<MotionRecord> {
    let options = ReaderOptions { dir: Some(dir.to_owned()), allow_gone: true, ..ReaderOptions::default() };
    let mut motion_reader = ServiceReader::<MotionRecord>::open_with("svc", "motion", &options).unwrap();
    poll("forearm sliding", Duration::from_secs(10), || {
        let frame = motion_reader.wait_newer(Duration::from_secs(1)).ok()?;
        let forearm = frame.records[1];
        (forearm.flags & motion_flags::SLIDING != 0 && forearm.speed_3d > 0.02).then_some(())
    });
    let echoed = skin(dir, &["echo", "--skin", "svc", "--service", "motion", "--count", "1"]);
    assert!(String::from_utf8_lossy(&echoed.stdout).contains("left_forearm: sliding"));
    motion_reader
}

/// SIGKILL the contact service: motion reports its input down, then the
/// supervisor's new contact process takes the channel's name, motion follows it and recovers.
fn killed_contact_service_is_reported_and_restarted(
    contact: &serde_json::Value,
    motion_reader: &mut ServiceReader<MotionRecord>,
) {
    let pid = contact["writer_pid"].as_u64().unwrap() as i32;
    rustix::process::kill_process(rustix::process::Pid::from_raw(pid).unwrap(), rustix::process::Signal::KILL).unwrap();
    let killed = Instant::now();
    poll("motion reports its input down", Duration::from_secs(5), || {
        let frame = motion_reader.wait_newer(Duration::from_secs(1)).ok()?;
        frame.status.contains(FrameStatus::INPUT_FAULTED).then_some(())
    });
    let reported = killed.elapsed();
    poll("motion recovers", Duration::from_secs(10), || {
        let frame = motion_reader.wait_newer(Duration::from_secs(1)).ok()?;
        (!frame.status.contains(FrameStatus::INPUT_FAULTED)).then_some(())
    });
    eprintln!("contact service killed: reported by motion after {reported:?}, recovered after {:?}", killed.elapsed());
}

/// Ctrl-C: everything stops and nothing is left behind.
fn ctrl_c_stops_everything(dir: &Path, running: &mut Skin) {
    let mut supervisor = running.supervisor.take().unwrap();
    let status = interrupt_and_wait(&mut supervisor, "skin run", Duration::from_secs(10));
    assert!(status.success());
    let left: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with("skinware"))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}
