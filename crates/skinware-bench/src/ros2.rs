//! `skin bench ros2`: the skin's ROS 2 topics delivered to stock ROS 2
//! nodes, side by side in one run, on the paper's skin (30,848 taxels, 5
//! layers, the contact service) under `skin run`:
//!
//! - **ours, DDS** (`DdsBridge`, feature `dds`) to an rclpy subscriber with
//!   Fast DDS's default settings: at the default rates, then with clouds at
//!   30 Hz, then the same with the shipped Fast DDS profile (4 MiB receive
//!   buffer, `docs/ros2/fastdds-large.xml`);
//! - **baseline, rclpy → rclpy** over Fast DDS UDP (`FASTDDS_BUILTIN_TRANSPORTS=UDPv4`):
//!   the same message sizes at the same rates, reliable (rclpy's default);
//! - **ours, rmw_zenoh** (the zenoh bridge, feature `zenoh`): each layer's
//!   `TactileState` to an `eclipse-zenoh` subscriber of the rmw_zenoh keys.
//!
//! Per topic: messages a second sent and delivered, loss, age at delivery
//! (callback wall time minus the stamp: a cloud's stamp is its frame's
//! acquisition, so its age includes the wait for its rate's tick; the
//! baseline's stamp is its publication), and the publisher's CPU.
//! Everything runs on this machine: the figures are ratios side by side.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use serde_json::Value;

use crate::measure::RunningSkin;
use crate::run_options::RunOptions;

const SCRIPT: &str = include_str!("ros2_bench.py");
#[cfg_attr(not(any(feature = "dds", feature = "zenoh")), allow(dead_code))]
const SKIN: &str = "ros2bench";
/// The paper's skin at fixed rates, with the contact service (its markers).
const CONFIG: &str = r#"
skin = "ros2bench"

[[driver]]
name = "virtual"
kind = "virtual"
sensors = 30848
layers = 5
sensors_per_module = 12
modules_per_patch = [4, 16]
rate_hz = 50
seed = 1

[[service]]
name = "contact"
kind = "contact"
rate_hz = 50
"#;

/// The Fast DDS profile for large messages that `docs/ros2.md` ships.
pub const FASTDDS_LARGE_PROFILE: &str = include_str!("../../../docs/ros2/fastdds-large.xml");

/// Options of `skin bench ros2`.
#[derive(Clone, Debug)]
pub struct Ros2BenchOptions {
    /// Quick: 3 s windows; `ros2.json` goes to `out`; `exe` runs the skin.
    pub run: RunOptions,
    /// A Python with rclpy and the standard messages (the first of `SKINWARE_ROS2_PYTHONS`).
    pub ros_python: String,
    /// A Python with `eclipse-zenoh` (`SKINWARE_PYTHON`), for the rmw_zenoh row.
    pub zenoh_python: String,
}

/// One topic of one scenario.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// Which publisher, subscriber and settings.
    pub scenario: String,
    /// The topic (or rmw_zenoh key).
    pub topic: String,
    /// Mean bytes of a message's data (a cloud's points, an image's pixels; 0 for others).
    pub bytes: f64,
    /// Messages a second the publisher sent in the window.
    pub sent_per_s: f64,
    /// Messages a second the subscriber received in the window.
    pub delivered_per_s: f64,
    /// `1 - delivered / sent`, percent (the window's edges give ±1 message).
    pub lost_pct: f64,
    /// Age at delivery, median, ms.
    pub age_p50_ms: Option<f64>,
    /// Age at delivery, 99th percentile, ms.
    pub age_p99_ms: Option<f64>,
    /// The publisher's CPU over the window, percent of one core (all its topics).
    pub publisher_cpu_pct: f64,
}

/// What `skin bench ros2` measured.
#[derive(Clone, Debug, Serialize)]
pub struct Ros2Report {
    /// Seconds each subscriber counted.
    pub window_s: f64,
    /// The kernel's `net.core.rmem_max` (a socket's largest receive buffer).
    pub rmem_max: u64,
    /// Every row.
    pub rows: Vec<Row>,
    /// Scenarios that could not run here, and why.
    pub skipped: Vec<String>,
}

/// Runs the benchmark, prints its table and writes `ros2.json`.
pub fn bench(options: &Ros2BenchOptions) -> Result<Ros2Report> {
    let window = options.run.seconds_or(3.0, 10.0);
    if !(window.is_finite() && window > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    let probe = Command::new(&options.ros_python).args(["-c", "import rclpy, sensor_msgs.msg"]).output();
    if !probe.as_ref().is_ok_and(|o| o.status.success()) {
        bail!(
            "{} cannot import rclpy and sensor_msgs; set SKINWARE_ROS2_PYTHONS to a venv with \
             `pip install 'ros-kilted-rclpy[fastrtps]' ros-kilted-sensor-msgs ros-kilted-std-msgs \
             ros-kilted-visualization-msgs ros-kilted-diagnostic-msgs` (docs/ros2.md)",
            options.ros_python
        );
    }
    let dir = skinware::shm::segment_dir().join(format!("skinware-bench-ros2-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let result = start_skin(options, &dir).and_then(|_skin| measure(options, &dir, window));
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    print(&report);
    std::fs::create_dir_all(&options.run.out)
        .with_context(|| format!("cannot create {}", options.run.out.display()))?;
    let path = options.run.out.join("ros2.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("  written: {}", path.display());
    Ok(report)
}

fn start_skin(options: &Ros2BenchOptions, dir: &Path) -> Result<RunningSkin> {
    RunningSkin::start_until(&options.run.exe, CONFIG, dir, "the paper's skin", |channels| {
        channels.iter().filter(|c| c.state == skinware::WriterState::Running && c.stats.frames > 5).count() >= 6
    })
}

fn measure(options: &Ros2BenchOptions, dir: &Path, window: f64) -> Result<Ros2Report> {
    let profile = dir.join("fastdds-large.xml");
    std::fs::write(&profile, FASTDDS_LARGE_PROFILE)?;
    let mut rows = Vec::new();
    let mut skipped = Vec::new();
    dds_rows(options, dir, window, &profile, &mut rows, &mut skipped)?;
    let sizes: Vec<usize> = rows
        .iter()
        .filter(|r| r.scenario.starts_with("ours DDS, defaults") && r.topic.contains("/cloud/"))
        .map(|r| r.bytes.round() as usize)
        .collect();
    for hz in [10.0, 30.0] {
        rows.extend(baseline(options, &sizes, hz, window)?);
    }
    zenoh_rows(options, dir, window, &mut rows, &mut skipped)?;
    let rmem_max =
        std::fs::read_to_string("/proc/sys/net/core/rmem_max").ok().and_then(|s| s.trim().parse().ok()).unwrap_or(0);
    Ok(Ros2Report { window_s: window, rmem_max, rows, skipped })
}

/// A process's CPU seconds so far (user + system), from `/proc`.
fn process_cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command's closing parenthesis: utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let field = |k: usize| fields.get(k).and_then(|f| f.parse::<u64>().ok()).unwrap_or(0);
    let ticks = rustix::param::clock_ticks_per_second() as f64;
    // After the state (index 0): utime at 11, stime at 12.
    (field(11) + field(12)) as f64 / ticks
}

/// A subscriber process: started, then its window's start and its JSON.
struct Listener {
    child: Child,
    lines: std::io::Lines<BufReader<std::process::ChildStdout>>,
}

impl Listener {
    fn start(python: &str, args: &[String], env: &[(&str, String)]) -> Result<Listener> {
        let mut command = Command::new(python);
        command.args(["-c", SCRIPT]).args(args).stdout(Stdio::piped()).stderr(Stdio::null());
        for (key, value) in env {
            command.env(key, value);
        }
        let mut child = command.spawn().with_context(|| format!("cannot run {python}"))?;
        let stdout = child.stdout.take().context("the subscriber's output")?;
        Ok(Listener { child, lines: BufReader::new(stdout).lines() })
    }

    /// Waits for the line `counting`.
    fn counting(&mut self) -> Result<()> {
        match self.lines.next() {
            Some(Ok(line)) if line.trim() == "counting" => Ok(()),
            other => bail!("the ROS 2 subscriber did not start counting: {other:?}"),
        }
    }

    /// Waits for the line `stopped`, the end of its window.
    fn stopped(&mut self) -> Result<()> {
        match self.lines.next() {
            Some(Ok(line)) if line.trim() == "stopped" => Ok(()),
            other => bail!("the ROS 2 subscriber did not stop counting: {other:?}"),
        }
    }

    /// Its JSON, after its window.
    fn result(mut self) -> Result<Value> {
        let line = self.lines.next().context("the subscriber's result")??;
        let _ = self.child.wait();
        serde_json::from_str(&line).context("the subscriber's JSON")
    }
}

impl Drop for Listener {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn row(scenario: &str, topic: &str, got: &Value, sent: f64, window: f64, cpu_pct: f64) -> Row {
    let count = got["count"].as_f64().unwrap_or(0.0);
    let bytes = if count > 0.0 { got["bytes"].as_f64().unwrap_or(0.0) / count } else { 0.0 };
    Row {
        scenario: scenario.to_owned(),
        topic: topic.to_owned(),
        bytes,
        sent_per_s: sent / window,
        delivered_per_s: count / window,
        lost_pct: if sent > 0.0 { (100.0 * (1.0 - count / sent)).max(0.0) } else { 0.0 },
        age_p50_ms: got["p50_ms"].as_f64(),
        age_p99_ms: got["p99_ms"].as_f64(),
        publisher_cpu_pct: cpu_pct,
    }
}

#[cfg(not(feature = "dds"))]
fn dds_rows(
    _: &Ros2BenchOptions,
    _: &Path,
    _: f64,
    _: &Path,
    _: &mut Vec<Row>,
    skipped: &mut Vec<String>,
) -> Result<()> {
    skipped.push("ours DDS: skin was built without --features dds".into());
    Ok(())
}

#[cfg(feature = "dds")]
fn dds_rows(
    options: &Ros2BenchOptions,
    dir: &Path,
    window: f64,
    profile: &Path,
    rows: &mut Vec<Row>,
    _: &mut Vec<String>,
) -> Result<()> {
    let defaults = skinware_dds::Rates::default();
    let fast = skinware_dds::Rates { cloud_hz: 30.0, ..defaults };
    let scenarios: [(&str, skinware_dds::Rates, Option<&Path>); 3] = [
        ("ours DDS, defaults (clouds 10 Hz)", defaults, None),
        ("ours DDS, clouds 30 Hz", fast, None),
        ("ours DDS, clouds 30 Hz, 4 MiB profile", fast, Some(profile)),
    ];
    for (k, (scenario, rates, profile)) in scenarios.into_iter().enumerate() {
        let domain = 60 + k as u16;
        let mut dds = skinware_dds::DdsOptions::new(SKIN);
        dds.domain = domain;
        dds.view.dir = Some(dir.to_owned());
        dds.view.rates = rates;
        let bridge = skinware_dds::DdsBridge::start(dds)?;
        // What rclpy has types for: not the tactile stack's, nor tf2_msgs.
        let topics: Vec<String> = bridge
            .report()
            .into_iter()
            .filter(|t| !t.type_name.starts_with("tactile_msgs/") && !t.type_name.starts_with("tf2_msgs/"))
            .map(|t| t.topic)
            .collect();
        let mut env = vec![("ROS_DOMAIN_ID", domain.to_string())];
        if let Some(profile) = profile {
            env.push(("FASTDDS_DEFAULT_PROFILES_FILE", profile.display().to_string()));
        }
        let mut args = vec!["listen".to_owned(), window.to_string()];
        args.extend(topics.iter().cloned());
        let mut listener = Listener::start(&options.ros_python, &args, &env)?;
        listener.counting()?;
        let (before, cpu_before, started) = (bridge.report(), process_cpu_s(std::process::id()), Instant::now());
        listener.stopped()?;
        let (after, cpu_after, wall) =
            (bridge.report(), process_cpu_s(std::process::id()), started.elapsed().as_secs_f64());
        let got = listener.result()?;
        let cpu_pct = 100.0 * (cpu_after - cpu_before) / wall;
        for topic in &topics {
            let sent = |report: &[skinware_dds::TopicReport]| {
                report.iter().find(|t| &t.topic == topic).map_or(0, |t| t.sent) as f64
            };
            rows.push(row(scenario, topic, &got[topic], sent(&after) - sent(&before), wall, cpu_pct));
        }
        bridge.stop();
    }
    Ok(())
}

/// rclpy to rclpy over Fast DDS UDP: one topic per size, at `hz`.
fn baseline(options: &Ros2BenchOptions, sizes: &[usize], hz: f64, window: f64) -> Result<Vec<Row>> {
    if sizes.is_empty() {
        return Ok(Vec::new());
    }
    let domain = if hz > 20.0 { 71 } else { 70 };
    let env = [("ROS_DOMAIN_ID", domain.to_string()), ("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4".to_owned())];
    let mut talk = vec!["talk".to_owned(), hz.to_string(), (window + 8.0).to_string()];
    talk.extend(sizes.iter().map(usize::to_string));
    let mut talker = Command::new(&options.ros_python);
    talker.args(["-c", SCRIPT]).args(&talk).stdout(Stdio::null()).stderr(Stdio::null());
    for (key, value) in &env {
        talker.env(key, value);
    }
    let mut talker = KillOnDrop(talker.spawn().context("cannot start the baseline publisher")?);
    let topics: Vec<String> = (0..sizes.len()).map(|i| format!("/baseline/cloud_{i}")).collect();
    let mut args = vec!["listen".to_owned(), window.to_string()];
    args.extend(topics.iter().cloned());
    let mut listener = Listener::start(&options.ros_python, &args, &env)?;
    listener.counting()?;
    let (cpu_before, started) = (process_cpu_s(talker.0.id()), Instant::now());
    listener.stopped()?;
    let (cpu_after, wall) = (process_cpu_s(talker.0.id()), started.elapsed().as_secs_f64());
    let got = listener.result()?;
    let _ = talker.0.kill();
    let cpu_pct = 100.0 * (cpu_after - cpu_before) / wall;
    let scenario = format!("baseline rclpy -> rclpy, UDP, reliable, {hz:.0} Hz");
    Ok(topics
        .iter()
        .map(|topic| {
            let got = &got[topic];
            let sent = got["sent_by_seq"].as_f64().unwrap_or(0.0);
            row(&scenario, topic, got, sent, wall, cpu_pct)
        })
        .collect())
}

struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[cfg(not(feature = "zenoh"))]
fn zenoh_rows(_: &Ros2BenchOptions, _: &Path, _: f64, _: &mut Vec<Row>, skipped: &mut Vec<String>) -> Result<()> {
    skipped.push("ours rmw_zenoh: skin was built without --features zenoh".into());
    Ok(())
}

#[cfg(feature = "zenoh")]
fn zenoh_rows(
    options: &Ros2BenchOptions,
    dir: &Path,
    window: f64,
    rows: &mut Vec<Row>,
    skipped: &mut Vec<String>,
) -> Result<()> {
    use skinware_bridge::bridge::{Bridge, BridgeOptions};
    use skinware_bridge::link::LinkOptions;

    let probe = Command::new(&options.zenoh_python).args(["-c", "import zenoh"]).output();
    if !probe.as_ref().is_ok_and(|o| o.status.success()) {
        skipped.push(format!("ours rmw_zenoh: {} cannot import zenoh (SKINWARE_PYTHON)", options.zenoh_python));
        return Ok(());
    }
    let endpoint = format!("tcp/127.0.0.1:{}", 17_000 + std::process::id() % 2_000);
    let mut bridge_options = BridgeOptions::new(SKIN);
    bridge_options.dir = Some(dir.to_owned());
    bridge_options.services = false;
    bridge_options.map_hz = 0.0;
    bridge_options.link = LinkOptions { listen: vec![endpoint.clone()], ..LinkOptions::default() };
    let bridge = Bridge::start(bridge_options)?;
    // Each layer's TactileState: its channel counts what it sent (the
    // clouds and markers beside it are the view's, which counts per topic).
    let args = ["zlisten".to_owned(), endpoint, window.to_string(), format!("0/skin/{SKIN}/*/state/**")];
    let mut listener = Listener::start(&options.zenoh_python, &args, &[])?;
    listener.counting()?;
    let (before, cpu_before, started) = (bridge.report(), process_cpu_s(std::process::id()), Instant::now());
    listener.stopped()?;
    let (after, cpu_after, wall) =
        (bridge.report(), process_cpu_s(std::process::id()), started.elapsed().as_secs_f64());
    let got = listener.result()?;
    let cpu_pct = 100.0 * (cpu_after - cpu_before) / wall;
    for (key, figures) in got.as_object().into_iter().flatten() {
        // The key's topic names the channel as ROS names it (`virtual_0`).
        let channel = key.split('/').nth(3).unwrap_or_default();
        let sent = |report: &[skinware_bridge::bridge::ChannelReport]| {
            report.iter().find(|c| skinware_ros2::ros_name(&c.channel) == channel).map_or(0, |c| c.ros_sent) as f64
        };
        let topic = key.split('/').take(5).collect::<Vec<_>>().join("/");
        rows.push(row("ours rmw_zenoh, every frame", &topic, figures, sent(&after) - sent(&before), wall, cpu_pct));
    }
    bridge.stop();
    Ok(())
}

fn print(report: &Ros2Report) {
    println!(
        "\nROS 2 to stock subscribers, the paper's skin (30,848 taxels, 5 layers at 50 Hz), {:.0} s windows; \
         net.core.rmem_max {} B",
        report.window_s, report.rmem_max
    );
    let mut scenario = "";
    for row in &report.rows {
        if row.scenario != scenario {
            scenario = &row.scenario;
            println!("  {scenario}: publisher CPU {:.1}% of a core", row.publisher_cpu_pct);
            println!(
                "    {:<44} {:>9} {:>8} {:>10} {:>7} {:>9} {:>9}",
                "topic", "bytes", "sent/s", "deliv./s", "lost %", "age p50", "age p99"
            );
        }
        let ms = |v: Option<f64>| v.map_or("-".to_owned(), |v| format!("{v:.1} ms"));
        println!(
            "    {:<44} {:>9.0} {:>8.1} {:>10.1} {:>7.1} {:>9} {:>9}",
            row.topic,
            row.bytes,
            row.sent_per_s,
            row.delivered_per_s,
            row.lost_pct,
            ms(row.age_p50_ms),
            ms(row.age_p99_ms)
        );
    }
    for why in &report.skipped {
        println!("  skipped: {why}");
    }
}

/// The default Python for the rclpy side: the first of `SKINWARE_ROS2_PYTHONS`.
pub fn default_ros_python() -> Option<PathBuf> {
    let list = std::env::var("SKINWARE_ROS2_PYTHONS").ok()?;
    list.split(':').find(|p| !p.is_empty()).map(PathBuf::from)
}
