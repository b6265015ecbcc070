//! `skin bridge --ros2 dds` (or `both`): the skin's standard ROS 2 topics
//! on DDS, ROS 2's default RMW, for Fast DDS and Cyclone DDS nodes
//! (`skinware-dds`; feature `dds`).

#[cfg(not(feature = "dds"))]
use anyhow::Result;

use super::bridge::Args;

#[cfg(not(feature = "dds"))]
fn without_dds() -> anyhow::Error {
    anyhow::anyhow!(
        "this `skin` was built without DDS; rebuild it with `cargo build --release -p skin --features dds` \
         (add zenoh for --ros2 both: --features dds,zenoh)"
    )
}

/// `skin bridge --ros2 dds`: DDS alone, until Ctrl-C or `--seconds`.
#[cfg(not(feature = "dds"))]
pub fn run_alone(_: &Args) -> Result<()> {
    Err(without_dds())
}

/// The DDS side of `--ros2 both`, running.
#[cfg(all(feature = "zenoh", not(feature = "dds")))]
pub struct Running;

/// Starts the DDS side of `--ros2 both`.
#[cfg(all(feature = "zenoh", not(feature = "dds")))]
pub fn start(_: &Args) -> Result<Running> {
    Err(without_dds())
}

/// Stops the DDS side and prints its topics' figures.
#[cfg(all(feature = "zenoh", not(feature = "dds")))]
pub fn finish(_: Running, _: &Args, _: &mut impl std::io::Write, _: f64) -> Result<()> {
    Ok(())
}

#[cfg(feature = "dds")]
pub use with_dds::run_alone;
#[cfg(all(feature = "dds", feature = "zenoh"))]
pub use with_dds::{finish, start};

#[cfg(feature = "dds")]
mod with_dds {
    use std::io::Write;
    use std::sync::atomic::Ordering;
    use std::time::{Duration, Instant};

    use anyhow::{Result, bail};
    use skinware_dds::{DdsBridge, DdsOptions, TopicReport};

    use super::Args;

    /// The DDS side, running.
    pub struct Running(pub(super) DdsBridge);

    /// The DDS bridge's options from the command line.
    pub(super) fn options(args: &Args) -> Result<DdsOptions> {
        let mut dds = DdsOptions::new(&args.skin);
        dds.domain = match args.domain {
            Some(domain) => skinware_dds::check_domain(domain)?,
            None => skinware_dds::domain_from_env()?,
        };
        let options = &mut dds.view;
        options.layers = args.layers.clone();
        options.services = !args.no_services;
        (options.rates, options.topic_hz) = args.standard_rates()?;
        options.map_width = args.map_width.map_or(skinware_dds::DEFAULT_MAP_WIDTH, |w| w as usize);
        options.root_frame = match args.root_frame.as_deref().map(str::trim) {
            None => Some("base_link".to_owned()),
            Some("none") => None,
            Some("") => bail!("--root-frame is empty: name the robot's root frame (base_link), or give `none`"),
            Some(frame) => Some(frame.to_owned()),
        };
        Ok(dds)
    }

    /// Starts the DDS side and says so.
    pub fn start(args: &Args) -> Result<Running> {
        let options = options(args)?;
        let bridge = DdsBridge::start(options.clone())?;
        let topics = bridge.report();
        eprintln!(
            "skin bridge: skin {} on DDS, ROS 2 domain {}, as node /{}: {} topics ({}); QoS and rates in docs/ros2.md",
            args.skin,
            options.domain,
            bridge.node_name(),
            topics.len(),
            topics.iter().map(|t| t.topic.as_str()).take(6).collect::<Vec<_>>().join(", ")
                + if topics.len() > 6 { ", ..." } else { "" },
        );
        Ok(Running(bridge))
    }

    /// Stops the DDS side and prints its topics' figures.
    pub fn finish(running: Running, args: &Args, out: &mut impl Write, seconds: f64) -> Result<()> {
        let report = running.0.stop();
        print(out, &report, args.json, seconds)
    }

    /// `skin bridge --ros2 dds`: DDS alone, until Ctrl-C or `--seconds`.
    pub fn run_alone(args: &Args) -> Result<()> {
        let shutdown = super::super::run::shutdown_on_signals()?;
        let running = start(args)?;
        let started = Instant::now();
        let until = args.seconds.map(|s| started + Duration::from_secs_f64(s.max(0.0)));
        let mut out = std::io::stdout().lock();
        let going = || !shutdown.load(Ordering::Relaxed) && until.is_none_or(|until| Instant::now() < until);
        while going() {
            let tick = Instant::now() + Duration::from_secs(1);
            while Instant::now() < tick && going() {
                std::thread::sleep(Duration::from_millis(50));
            }
            if args.stats {
                print(&mut out, &running.0.report(), args.json, started.elapsed().as_secs_f64())?;
            }
        }
        finish(running, args, &mut out, started.elapsed().as_secs_f64())
    }

    fn print(out: &mut impl Write, report: &[TopicReport], json: bool, seconds: f64) -> Result<()> {
        if json {
            let topics: Vec<_> = report
                .iter()
                .map(|t| {
                    serde_json::json!({
                        "topic": t.topic, "type": t.type_name, "qos": t.class.as_str(), "hz": t.hz,
                        "sent": t.sent, "failed": t.failed, "subscribers": t.subscribers,
                    })
                })
                .collect();
            serde_json::to_writer(&mut *out, &serde_json::json!({ "seconds": seconds, "dds_topics": topics }))?;
            writeln!(out)?;
            return Ok(());
        }
        writeln!(out, "DDS after {seconds:.1} s:")?;
        writeln!(
            out,
            "  {:<44} {:<36} {:<38} {:>6} {:>8} {:>6} {:>5}",
            "topic", "type", "QoS", "Hz", "sent", "failed", "subs"
        )?;
        for t in report {
            writeln!(
                out,
                "  {:<44} {:<36} {:<38} {:>6.1} {:>8} {:>6} {:>5}",
                t.topic,
                t.type_name,
                t.class.as_str(),
                t.hz,
                t.sent,
                t.failed,
                t.subscribers
            )?;
        }
        Ok(())
    }
}
