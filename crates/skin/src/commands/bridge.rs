//! `skin bridge`: the skin on zenoh, for remote skinware readers and ROS 2
//! (rmw_zenoh), and on DDS for ROS 2's default RMW (`--ros2 dds`, see
//! `bridge_dds`); and the remote side of `skin ls`, `skin echo` and `skin
//! view`.
//!
//! The zenoh side needs the `zenoh` feature, and the DDS side the `dds`
//! feature; a `skin` built without one says how to rebuild instead.

use std::path::PathBuf;

#[cfg(not(feature = "zenoh"))]
use anyhow::Result;

/// Arguments of `skin bridge`.
#[derive(clap::Args)]
pub struct Args {
    /// The skin to bridge.
    #[arg(long, default_value = "default")]
    pub(super) skin: String,
    /// Only these layers (comma-separated; default: every layer).
    #[arg(long, value_delimiter = ',')]
    pub(super) layers: Option<Vec<String>>,
    /// Leave the services out.
    #[arg(long)]
    pub(super) no_services: bool,
    /// Rate limit for slow links: `HZ` for every channel, or `CHANNEL=HZ`
    /// (repeatable). The newest frame is sent; what is left out is counted.
    #[arg(long)]
    max_hz: Vec<String>,
    /// Map images a second for ROS 2 (`/skin/<skin>/map`); 0 for none.
    #[arg(long, default_value_t = 5.0)]
    pub(super) map_hz: f64,
    /// The map's width in pixels, 16 to 4096 (default: 480 on zenoh, 200 on
    /// DDS, where 480 is a 580 KB message that a default socket buffer drops).
    #[arg(long, value_parser = clap::value_parser!(u32).range(16..=4096))]
    pub(super) map_width: Option<u32>,
    /// Publish only for skinware readers, not for ROS 2 (`--ros2 none`).
    #[arg(long)]
    no_ros: bool,
    /// Where the ROS 2 topics go: `zenoh` (rmw_zenoh nodes, beside the
    /// remote readers), `dds` (the default RMW: Fast DDS or Cyclone DDS
    /// nodes; no zenoh), `both`, or `none`.
    #[arg(long, value_enum, default_value_t = Ros2Mode::Zenoh)]
    pub(super) ros2: Ros2Mode,
    /// ROS domain id (default: $ROS_DOMAIN_ID, else 0).
    #[arg(long)]
    pub(super) domain: Option<u32>,
    /// Point clouds a second, per layer and link (0: none).
    #[arg(long, default_value_t = skinware_ros2_rates::CLOUD_HZ)]
    pub(super) cloud_hz: f64,
    /// DDS: `TactileState` messages a second, per layer (0: none; default
    /// 30). On rmw_zenoh every frame is sent, or --max-hz.
    #[arg(long)]
    pub(super) state_hz: Option<f64>,
    /// Contact markers a second (and on DDS `TactileContacts`), per contact service (0: none).
    #[arg(long, default_value_t = skinware_ros2_rates::CONTACTS_HZ)]
    pub(super) contacts_hz: f64,
    /// One standard topic's own rate, `TOPIC=HZ` (repeatable), over its kind's.
    #[arg(long)]
    pub(super) topic_hz: Vec<String>,
    /// DDS: the frame every link hangs from on `/tf_static` (`none`: no
    /// `/tf_static`; default `base_link`).
    #[arg(long)]
    pub(super) root_frame: Option<String>,
    /// Endpoint to listen on (repeatable); `tcp/127.0.0.1:7447` unless
    /// --connect or a --zenoh-config says otherwise. `tcp/0.0.0.0:7447`
    /// opens the bridge to the network.
    #[arg(long)]
    listen: Vec<String>,
    /// Endpoint to connect to (repeatable), such as a `rmw_zenohd` router.
    #[arg(long)]
    connect: Vec<String>,
    /// A zenoh configuration file (JSON5): TLS, access control, anything
    /// zenoh offers (see docs/remote.md).
    #[arg(long)]
    zenoh_config: Option<PathBuf>,
    /// The TCP send buffer of each link, bytes: what a slow link may hold
    /// back before the bridge sends only the newest frames (0: the kernel's
    /// autotuning, which holds seconds on a slow link).
    #[arg(long, default_value_t = skinware_bridge::protocol::BRIDGE_SEND_BUFFER)]
    send_buffer: usize,
    /// Print every channel's figures each second.
    #[arg(long)]
    pub(super) stats: bool,
    /// Print JSON: a line each second with --stats, and the summary at the end.
    #[arg(long)]
    pub(super) json: bool,
    /// Stop after this many seconds (default: at Ctrl-C).
    #[arg(long)]
    pub(super) seconds: Option<f64>,
}

/// The default rates of the standard topics (as `skinware_ros2::view::Rates` gives them).
mod skinware_ros2_rates {
    pub const CLOUD_HZ: f64 = 10.0;
    pub const STATE_HZ: f64 = 30.0;
    pub const CONTACTS_HZ: f64 = 30.0;
}

/// Where `skin bridge` sends the ROS 2 topics.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Ros2Mode {
    /// rmw_zenoh, beside the remote readers (feature `zenoh`).
    Zenoh,
    /// DDS, ROS 2's default RMW (feature `dds`); no zenoh.
    Dds,
    /// Both.
    Both,
    /// No ROS 2 topics: zenoh for skinware's remote readers only.
    None,
}

/// A rate option: 0 (none) or a positive number of messages a second.
#[cfg_attr(not(any(feature = "zenoh", feature = "dds")), allow(dead_code))]
fn rate(flag: &str, hz: f64) -> anyhow::Result<f64> {
    use skinware_ros2::view::{MAX_HZ, MIN_HZ};
    if !(hz == 0.0 || (MIN_HZ..=MAX_HZ).contains(&hz)) {
        anyhow::bail!("{flag} {hz}: give messages a second, 0 (none) or {MIN_HZ} to {MAX_HZ}");
    }
    Ok(hz)
}

impl Args {
    /// The standard ROS 2 topics' rates (`--state-hz`, `--cloud-hz`,
    /// `--contacts-hz`, `--map-hz`) and per-topic rates (`--topic-hz`).
    #[cfg_attr(not(any(feature = "zenoh", feature = "dds")), allow(dead_code))]
    pub(super) fn standard_rates(
        &self,
    ) -> anyhow::Result<(skinware_ros2::view::Rates, std::collections::BTreeMap<String, f64>)> {
        use anyhow::Context as _;
        let contacts_hz = rate("--contacts-hz", self.contacts_hz)?;
        let rates = skinware_ros2::view::Rates {
            state_hz: rate("--state-hz", self.state_hz.unwrap_or(skinware_ros2_rates::STATE_HZ))?,
            cloud_hz: rate("--cloud-hz", self.cloud_hz)?,
            markers_hz: contacts_hz,
            contacts_hz,
            map_hz: rate("--map-hz", self.map_hz)?,
            ..skinware_ros2::view::Rates::default()
        };
        let mut topic_hz = std::collections::BTreeMap::new();
        for spec in &self.topic_hz {
            let (topic, hz) = spec
                .split_once('=')
                .with_context(|| format!("--topic-hz {spec:?}: give TOPIC=HZ, such as /skin/default/map=1"))?;
            let topic = topic.trim();
            if !topic.starts_with('/') {
                anyhow::bail!("--topic-hz {spec:?}: {topic:?} is not a topic; give its full name, from `/`");
            }
            let hz: f64 = hz.trim().parse().with_context(|| format!("--topic-hz {spec:?}: {hz:?} is not a number"))?;
            topic_hz.insert(topic.to_owned(), rate("--topic-hz", hz)?);
        }
        Ok((rates, topic_hz))
    }

    /// The ROS 2 side asked for, `--no-ros` included.
    fn ros2_mode(&self) -> Result<Ros2Mode, anyhow::Error> {
        match (self.no_ros, self.ros2) {
            (false, mode) => Ok(mode),
            (true, Ros2Mode::Zenoh | Ros2Mode::None) => Ok(Ros2Mode::None),
            (true, mode) => {
                Err(anyhow::anyhow!("--no-ros and --ros2 {mode:?} disagree; give one (--ros2 none is --no-ros)"))
            }
        }
    }
}

/// Runs `skin bridge`: zenoh, DDS, or both.
pub fn run(args: &Args) -> anyhow::Result<()> {
    if let Some(seconds) = args.seconds
        && !(seconds.is_finite() && (0.0..=1e9).contains(&seconds))
    {
        anyhow::bail!("--seconds {seconds}: give the seconds to run, 0 to 1e9 (or leave it out: until Ctrl-C)");
    }
    let mode = args.ros2_mode()?;
    refuse_other_modes_options(args, mode)?;
    match mode {
        Ros2Mode::Dds => super::bridge_dds::run_alone(args),
        mode => run_zenoh(args, mode == Ros2Mode::Both),
    }
}

/// Refuses an option that the chosen `--ros2` mode would ignore.
fn refuse_other_modes_options(args: &Args, mode: Ros2Mode) -> anyhow::Result<()> {
    if mode == Ros2Mode::Dds {
        let zenoh_only = [
            ("--max-hz", !args.max_hz.is_empty()),
            ("--listen", !args.listen.is_empty()),
            ("--connect", !args.connect.is_empty()),
            ("--zenoh-config", args.zenoh_config.is_some()),
        ];
        if let Some((flag, _)) = zenoh_only.iter().find(|(_, given)| *given) {
            anyhow::bail!(
                "{flag} is a zenoh option, and --ros2 dds sends nothing over zenoh; give --ros2 both for both"
            );
        }
        return Ok(());
    }
    if mode == Ros2Mode::Both {
        return Ok(());
    }
    let dds_only = [("--state-hz", args.state_hz.is_some()), ("--root-frame", args.root_frame.is_some())];
    if let Some((flag, _)) = dds_only.iter().find(|(_, given)| *given) {
        anyhow::bail!(
            "{flag} is a DDS option (on rmw_zenoh every frame's TactileState is sent, or --max-hz; /tf_static is DDS's only); \
             give --ros2 dds or --ros2 both"
        );
    }
    let map = skinware_ros2::map_topic(&args.skin);
    if let Some(topic) = args
        .topic_hz
        .iter()
        .filter_map(|spec| spec.split_once('=').map(|(topic, _)| topic.trim()))
        .find(|topic| *topic == map || topic.ends_with("/state") || topic.ends_with("/contacts"))
    {
        anyhow::bail!(
            "--topic-hz {topic}=...: on rmw_zenoh the tactile messages follow --max-hz and the map --map-hz; \
             --topic-hz sets the clouds, markers and /diagnostics there (or give --ros2 both for DDS)"
        );
    }
    Ok(())
}

/// The `--remote` option of `skin ls`, `echo` and `view`, and how to link.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct RemoteArgs {
    /// Read a skin on another machine through its `skin bridge`: the
    /// bridge's endpoint (`tcp/robot-pc:7447`, or `robot-pc:7447`).
    #[arg(long)]
    pub remote: Option<String>,
    /// A zenoh configuration file for the remote link (TLS, credentials).
    #[arg(long, requires = "remote")]
    pub zenoh_config: Option<PathBuf>,
}

#[cfg(not(feature = "zenoh"))]
fn without_zenoh() -> anyhow::Error {
    anyhow::anyhow!(
        "this `skin` was built without the zenoh bridge; rebuild it with `cargo build --release -p skin --features \
         zenoh` (the engine takes a few minutes to build)"
    )
}

/// Runs the zenoh side of `skin bridge`.
#[cfg(not(feature = "zenoh"))]
fn run_zenoh(_: &Args, _: bool) -> Result<()> {
    Err(anyhow::anyhow!("{}; or publish for ROS 2 on DDS alone with --ros2 dds (feature dds)", without_zenoh()))
}

/// `skin ls --remote`.
#[cfg(not(feature = "zenoh"))]
pub fn ls(_: &RemoteArgs, _: Option<&str>, _: bool) -> Result<()> {
    Err(without_zenoh())
}

/// `skin echo --remote`.
#[cfg(not(feature = "zenoh"))]
pub fn echo(_: &RemoteArgs, _: &RemoteEcho) -> Result<()> {
    Err(without_zenoh())
}

/// `skin view --remote`.
#[cfg(not(feature = "zenoh"))]
pub fn view(_: &RemoteArgs, _: &str, _: &str) -> Result<()> {
    Err(without_zenoh())
}

/// What `skin echo --remote` prints.
#[derive(Clone, Debug)]
// Without zenoh, `echo` only says how to rebuild.
#[cfg_attr(not(feature = "zenoh"), allow(dead_code))]
pub struct RemoteEcho {
    /// The skin.
    pub skin: String,
    /// The channel.
    pub channel: String,
    /// Reader mode.
    pub mode: EchoMode,
    /// Rate of the periodic and request modes, Hz.
    pub rate: f64,
    /// Stop after this many frames.
    pub count: Option<u64>,
    /// Print every response.
    pub full: bool,
    /// Seconds to wait for a frame before reporting the state.
    pub timeout: f64,
}

/// The reader modes of `skin echo --remote`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EchoMode {
    /// At a fixed rate.
    Periodic,
    /// As soon as available.
    Asap,
    /// On request.
    Request,
}

#[cfg(feature = "zenoh")]
use with_zenoh::run_zenoh;
#[cfg(feature = "zenoh")]
pub use with_zenoh::{echo, ls, view};

#[cfg(feature = "zenoh")]
mod with_zenoh {
    use std::io::Write;
    use std::sync::atomic::Ordering;
    use std::time::{Duration, Instant};

    use anyhow::{Context, Result};
    use skinware_bridge::BridgeError;
    use skinware_bridge::bridge::{Bridge, BridgeOptions, ChannelReport};
    use skinware_bridge::link::{DEFAULT_LISTEN, LinkOptions};
    use skinware_bridge::remote::{Mirror, RemoteSkin};

    use super::{Args, EchoMode, RemoteArgs, RemoteEcho};
    use skinware_viewer::{self as view, Site};

    fn rate_limits(options: &mut BridgeOptions, specs: &[String]) -> Result<()> {
        for spec in specs {
            let (channel, hz) = match spec.split_once('=') {
                Some((channel, _)) if channel.trim().is_empty() => {
                    anyhow::bail!(
                        "--max-hz {spec:?}: name the channel before `=` (`virtual-0=10`), or give only the rate"
                    )
                }
                Some((channel, hz)) => (Some(channel.trim()), hz),
                None => (None, spec.as_str()),
            };
            let hz: f64 = hz.trim().parse().ok().filter(|hz: &f64| hz.is_finite() && *hz > 0.0).with_context(|| {
                format!(
                    "--max-hz {spec:?}: give frames a second (`10`) or a channel's (`virtual-0=10`), a positive number"
                )
            })?;
            match channel {
                Some(channel) => {
                    options.max_hz_per_channel.insert(channel.to_owned(), hz);
                }
                None => options.max_hz = Some(hz),
            }
        }
        Ok(())
    }

    /// Runs `skin bridge` on zenoh (and on DDS too with `with_dds`) until
    /// Ctrl-C or `--seconds`.
    pub fn run_zenoh(args: &Args, with_dds: bool) -> Result<()> {
        let mut options = BridgeOptions::new(&args.skin);
        options.layers = args.layers.clone();
        options.services = !args.no_services;
        options.ros = !args.no_ros && args.ros2 != super::Ros2Mode::None;
        options.map_hz = args.map_hz.max(0.0);
        (options.standard, options.topic_hz) = args.standard_rates()?;
        if let Some(width) = args.map_width {
            options.map_width = width as usize;
        }
        options.domain = match args.domain {
            Some(domain) => domain,
            None => match std::env::var("ROS_DOMAIN_ID") {
                Ok(text) if !text.trim().is_empty() => text
                    .trim()
                    .parse()
                    .with_context(|| format!("ROS_DOMAIN_ID={text:?} is not a domain id (0 to 232)"))?,
                _ => 0,
            },
        };
        if options.domain > 232 {
            anyhow::bail!("ROS domain {} is beyond 232, the largest ROS 2 allows; pick 0 to 232", options.domain);
        }
        rate_limits(&mut options, &args.max_hz)?;
        let mut listen = args.listen.clone();
        if listen.is_empty() && args.connect.is_empty() && args.zenoh_config.is_none() {
            listen.push(DEFAULT_LISTEN.to_owned());
        }
        options.link = LinkOptions {
            listen: listen.clone(),
            connect: args.connect.clone(),
            config_file: args.zenoh_config.clone(),
            lease: None,
            send_buffer: (args.send_buffer > 0).then_some(args.send_buffer),
        };
        let shutdown = super::super::run::shutdown_on_signals()?;
        let bridge = Bridge::start(options.clone())?;
        let dds = if with_dds { Some(super::super::bridge_dds::start(args)?) } else { None };
        eprintln!(
            "skin bridge: skin {} ({} channels: {}) on zenoh {}{}{}; Ctrl-C to stop",
            args.skin,
            bridge.channels().len(),
            bridge.channels().join(", "),
            bridge.zid(),
            if listen.is_empty() { String::new() } else { format!(", listening on {}", listen.join(", ")) },
            if options.ros { format!(", ROS 2 domain {}", options.domain) } else { String::new() },
        );
        let started = Instant::now();
        let until = args.seconds.map(|s| started + Duration::from_secs_f64(s.max(0.0)));
        let mut out = std::io::stdout().lock();
        let _ = bridge.report();
        while !shutdown.load(Ordering::Relaxed) && until.is_none_or(|until| Instant::now() < until) {
            let tick = Instant::now() + Duration::from_secs(1);
            while Instant::now() < tick && !shutdown.load(Ordering::Relaxed) && until.is_none_or(|u| Instant::now() < u)
            {
                std::thread::sleep(Duration::from_millis(50));
            }
            if args.stats {
                let report = bridge.report();
                if args.json {
                    serde_json::to_writer(&mut out, &json(&report, started.elapsed().as_secs_f64()))?;
                    writeln!(out)?;
                } else {
                    print_table(&mut out, &report, started.elapsed().as_secs_f64())?;
                }
            }
        }
        let report = bridge.stop();
        if args.json {
            serde_json::to_writer_pretty(&mut out, &json(&report, started.elapsed().as_secs_f64()))?;
            writeln!(out)?;
        } else {
            print_table(&mut out, &report, started.elapsed().as_secs_f64())?;
        }
        if let Some(dds) = dds {
            super::super::bridge_dds::finish(dds, args, &mut out, started.elapsed().as_secs_f64())?;
        }
        Ok(())
    }

    fn json(report: &[ChannelReport], seconds: f64) -> serde_json::Value {
        let channels: Vec<_> = report
            .iter()
            .map(|c| {
                serde_json::json!({
                    "channel": c.channel, "kind": c.kind, "state": c.state, "sent": c.sent, "dropped": c.dropped,
                    "ros_sent": c.ros_sent, "rate_hz": c.rate_hz, "latency_p50_us": c.latency_p50_us,
                    "latency_p99_us": c.latency_p99_us, "remote_readers": c.remote_readers,
                    "remote_lost": c.remote_lost, "remote_latency_us": c.remote_latency_us,
                    "errors": c.errors, "last_error": c.last_error,
                })
            })
            .collect();
        serde_json::json!({ "seconds": seconds, "channels": channels })
    }

    fn print_table(out: &mut impl Write, report: &[ChannelReport], seconds: f64) -> std::io::Result<()> {
        writeln!(out, "after {seconds:.1} s:")?;
        writeln!(
            out,
            "  {:<16} {:<8} {:<8} {:>9} {:>8} {:>8} {:>8} {:>10} {:>10} {:>7} {:>9} {:>10} {:>6}",
            "channel",
            "kind",
            "state",
            "sent",
            "dropped",
            "ros",
            "rate Hz",
            "p50 µs",
            "p99 µs",
            "readers",
            "link lost",
            "remote µs",
            "errors"
        )?;
        for c in report {
            writeln!(
                out,
                "  {:<16} {:<8} {:<8} {:>9} {:>8} {:>8} {:>8.1} {:>10.0} {:>10.0} {:>7} {:>9} {:>10.0} {:>6}",
                c.channel,
                c.kind,
                c.state,
                c.sent,
                c.dropped,
                c.ros_sent,
                c.rate_hz,
                c.latency_p50_us,
                c.latency_p99_us,
                c.remote_readers,
                c.remote_lost,
                c.remote_latency_us,
                c.errors
            )?;
            if let Some(error) = &c.last_error {
                writeln!(out, "    last error: {error}")?;
            }
        }
        Ok(())
    }

    fn link(remote: &RemoteArgs) -> Result<LinkOptions> {
        let endpoint = remote.remote.clone().context("--remote ENDPOINT is needed")?;
        let endpoint = if endpoint.contains('/') { endpoint } else { format!("tcp/{endpoint}") };
        Ok(LinkOptions { connect: vec![endpoint], config_file: remote.zenoh_config.clone(), ..LinkOptions::default() })
    }

    const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

    /// `skin ls --remote`: the skins and channels a bridge serves.
    pub fn ls(remote: &RemoteArgs, skin: Option<&str>, as_json: bool) -> Result<()> {
        let link = link(remote)?;
        let skins = RemoteSkin::list(&link, CONNECT_TIMEOUT)?;
        let skins: Vec<_> = skins.into_iter().filter(|s| skin.is_none_or(|name| s.skin == name)).collect();
        let mut out = std::io::stdout().lock();
        if skins.is_empty() {
            anyhow::bail!(
                "no bridge answered at {} within {CONNECT_TIMEOUT:?}; is `skin bridge` running there and listening on that endpoint?",
                link.connect.join(", ")
            );
        }
        let mut layers = Vec::new();
        for list in &skins {
            let remote = RemoteSkin::connect(&link, &list.skin, CONNECT_TIMEOUT)?;
            for channel in remote.channels() {
                let mut reader = remote.reader(&channel.name)?;
                // A heartbeat comes every 100 ms; wait for one to tell the state.
                let deadline = Instant::now() + Duration::from_millis(400);
                while reader.bridge_state().is_none() && Instant::now() < deadline {
                    std::thread::sleep(Duration::from_millis(20));
                }
                let state = reader.state().name();
                let figures = reader.bridge_state();
                let topology = reader.topology().ok();
                layers.push(serde_json::json!({
                    "skin": list.skin,
                    "name": channel.name,
                    "kind": channel.kind.as_str(),
                    "state": state,
                    "sensors": topology.as_ref().map(|t| t.sensors.len()),
                    "modules": topology.as_ref().map(|t| t.modules.len()),
                    "patches": topology.as_ref().map(|t| t.patches.len()),
                    "sensor_type": topology.as_ref().map(|t| t.sensor_type.clone()),
                    "nominal_rate_hz": channel.period.map(|p| 1.0 / p.as_secs_f64()),
                    "schema": channel.schema.0,
                    "published_seq": figures.map(|f| f.published_seq),
                    "bridge_sent": figures.map(|f| f.sent),
                    "bridge_dropped": figures.map(|f| f.dropped),
                    "bridge_latency_us": figures.map(|f| f.latency_ns as f64 / 1e3),
                }));
            }
        }
        if as_json {
            serde_json::to_writer_pretty(&mut out, &serde_json::json!({ "remote": link.connect, "channels": layers }))?;
            writeln!(out)?;
            return Ok(());
        }
        for l in &layers {
            let text = |key: &str| l[key].as_str().unwrap_or("").to_owned();
            let number = |key: &str| l[key].as_u64().map_or("?".to_owned(), |n| n.to_string());
            match text("kind").as_str() {
                "layer" => writeln!(
                    out,
                    "{}/{}  [{}]  {} sensors ({}), {} modules, {} patches, {:.1} Hz nominal; bridge sent {}, dropped {}",
                    text("skin"),
                    text("name"),
                    text("state"),
                    number("sensors"),
                    text("sensor_type"),
                    number("modules"),
                    number("patches"),
                    l["nominal_rate_hz"].as_f64().unwrap_or(0.0),
                    number("bridge_sent"),
                    number("bridge_dropped"),
                )?,
                _ => writeln!(
                    out,
                    "{}/{}  [{}]  service {}; bridge sent {}, dropped {}",
                    text("skin"),
                    text("name"),
                    text("state"),
                    text("schema"),
                    number("bridge_sent"),
                    number("bridge_dropped"),
                )?,
            }
        }
        Ok(())
    }

    /// `skin echo --remote`: a remote channel's frames, in any mode.
    pub fn echo(remote: &RemoteArgs, echo: &RemoteEcho) -> Result<()> {
        let RemoteEcho { skin, channel, mode, rate, count, full, timeout } = echo.clone();
        let link = link(remote)?;
        let remote = RemoteSkin::connect(&link, &skin, CONNECT_TIMEOUT)?;
        let mut reader = remote.reader(&channel)?;
        let is_layer = reader.channel().kind == skinware::ChannelKind::Layer;
        let timeout = Duration::from_secs_f64(timeout.clamp(0.001, 86_400.0));
        let mut ticker = skinware::Ticker::from_hz(rate.clamp(0.001, 100_000.0));
        let stop = skinware::Stop::new();
        let mut out = std::io::stdout().lock();
        let mut printed = 0;
        let offset = skinware_ros2::clock_offset_ns();
        while count.is_none_or(|count| printed < count) {
            let result = match mode {
                EchoMode::Periodic => reader.next_periodic(&mut ticker, &stop),
                EchoMode::Asap => reader.wait_newer(timeout),
                EchoMode::Request => {
                    let _ = ticker.wait(&stop);
                    reader.request(timeout)
                }
            };
            match result {
                Ok(frame) => {
                    let now_unix = (skinware::os::monotonic_ns() as i64 + offset).max(0) as u64;
                    let latency_us = now_unix.saturating_sub(frame.acquired_unix_ns) as f64 / 1e3;
                    write!(
                        out,
                        "seq {} acquired {} ns (unix) status {:#x} skipped {} latency {latency_us:.0} µs",
                        frame.seq, frame.acquired_unix_ns, frame.status.0, frame.skipped
                    )?;
                    if is_layer {
                        let responses = frame.responses();
                        let (min, max) = responses.iter().fold((u16::MAX, 0), |(lo, hi), &r| (lo.min(r), hi.max(r)));
                        let mean = responses.iter().map(|&r| f64::from(r)).sum::<f64>() / responses.len().max(1) as f64;
                        write!(out, " sensors {} min {min} mean {mean:.1} max {max}", responses.len())?;
                        if full {
                            write!(out, " responses {responses:?}")?;
                        }
                    } else {
                        write!(out, " {} bytes", frame.bytes.len())?;
                    }
                    writeln!(out)?;
                    printed += 1;
                }
                Err(BridgeError::Timeout(_)) => {
                    writeln!(out, "no new frame; channel is {}", reader.state().name())?;
                }
                Err(e @ BridgeError::Malformed { .. }) => {
                    writeln!(out, "refused a message: {e}")?;
                }
                Err(e) => return Err(e.into()),
            }
        }
        let stats = reader.stats();
        eprintln!(
            "received {}, skipped {}, malformed {}, unreachable {} times",
            stats.received, stats.skipped, stats.malformed, stats.unreachable
        );
        Ok(())
    }

    /// `skin view --remote`: the remote skin mirrored into private local
    /// channels, and the ordinary viewer on them.
    pub fn view(remote: &RemoteArgs, skin: &str, listen: &str) -> Result<()> {
        let link = link(remote)?;
        let remote_skin = RemoteSkin::connect(&link, skin, CONNECT_TIMEOUT)?;
        let dir = skinware::shm::segment_dir().join(format!("remote-{}", std::process::id()));
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        let cleanup = RemoveDir(dir.clone());
        let mirror = Mirror::start(&remote_skin, skin, &dir)?;
        let listener = view::bind(listen)?;
        let shutdown = super::super::run::shutdown_on_signals()?;
        println!(
            "skin view: remote skin {skin} at {} ({} channels) on http://{}/ ; Ctrl-C to stop",
            link.connect.join(", "),
            mirror.channels().len(),
            listener.local_addr()?
        );
        let served = view::serve(listener, &Site::new(skin, Some(dir), shutdown));
        drop(mirror);
        drop(cleanup);
        served
    }

    struct RemoveDir(std::path::PathBuf);

    impl Drop for RemoveDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}
