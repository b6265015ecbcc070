//! `skin bench bridge`: the paper's skin across a link between two network
//! namespaces, and the probe that reads it on the far side.
//!
//! The bench makes two "hosts" (network namespaces joined by a veth pair),
//! runs `skin run` (the paper's 30,848-taxel skin and its services) and
//! `skin bridge` in the first, and `skin bridge-probe` in the second; a
//! second probe reads the same layers through the local exchange at the same
//! time. Then it shapes the link with `tc` to 100, 10 and 1 Mbit/s, and cuts
//! it (`ip link set down`) and restores it, timing detection and recovery.
//!
//! Both namespaces share the machine's clocks (and its `/dev/shm`, which the
//! probe uses to check every remote frame against the local exchange's frame
//! of the same sequence number), so latencies are from acquisition to the
//! remote reader's copy, on one clock.
//!
//! The bridge is zenoh's (feature `zenoh`); without it, the bench and its
//! probe say how to get it.

use anyhow::{Result, bail};

use crate::run_options::RunOptions;

/// Arguments of the hidden `bridge-probe` role.
#[derive(Clone, Debug, clap::Args)]
pub struct ProbeArgs {
    /// Read through this bridge endpoint (else through the local exchange).
    #[arg(long)]
    pub remote: Option<String>,
    /// The skin.
    #[arg(long, default_value = "default")]
    pub skin: String,
    /// How long to read, seconds.
    #[arg(long, default_value_t = 5.0)]
    pub seconds: f64,
    /// Check every remote frame against the local exchange's frame of the
    /// same sequence number (the same machine's shared memory).
    #[arg(long)]
    pub verify: bool,
}

/// Runs the probe: says how to get the bridge, which this build has not.
#[cfg(not(feature = "zenoh"))]
pub fn probe(_: &ProbeArgs) -> Result<()> {
    bail!("this `skin` was built without the zenoh bridge; rebuild it with `--features zenoh`")
}

/// Runs `skin bench bridge`: says how to get the bridge, which this build has not.
#[cfg(not(feature = "zenoh"))]
pub fn bench(_: &RunOptions) -> Result<()> {
    bail!(
        "`skin bench bridge` needs the zenoh bridge; rebuild with `cargo build --release -p skin --features zenoh` \
         (the engine takes a few minutes to build)"
    )
}

#[cfg(feature = "zenoh")]
pub use with_zenoh::{bench, probe};

#[cfg(feature = "zenoh")]
mod with_zenoh {
    use std::collections::BTreeMap;
    use std::path::{Path, PathBuf};
    use std::process::{Child, Command, Stdio};
    use std::sync::{Arc, Mutex};
    use std::thread::JoinHandle;
    use std::time::{Duration, Instant};

    use anyhow::Context;
    use skinware::{ChannelKind, Reader, ReaderOptions, Stop};
    use skinware_bridge::link::LinkOptions;
    use skinware_bridge::remote::{Reader as RemoteReader, RemoteSkin, RemoteState};

    use super::*;

    /// The skin the bench runs: the demo's (the paper's skin and its services).
    const DEMO_CONFIG: &str = include_str!("../../../examples/demo.toml");

    /// Percentiles of a sample, in µs.
    fn quantiles_us(samples: &mut [u64]) -> serde_json::Value {
        samples.sort_unstable();
        let at = |q: f64| {
            samples.get(((samples.len() as f64 - 1.0) * q).round() as usize).map_or(0.0, |&ns| ns as f64 / 1e3)
        };
        serde_json::json!({ "p50": at(0.5), "p99": at(0.99), "max": at(1.0), "samples": samples.len() })
    }

    /// What a probe thread counted of one layer.
    #[derive(Default)]
    struct LayerFigures {
        received: u64,
        skipped: u64,
        bytes: u64,
        latencies: Vec<u64>,
        verified: u64,
        mismatched: u64,
        unverifiable: u64,
        bridge_dropped: u64,
        /// Of `skipped`, the frames the bridge had handed to zenoh: lost on
        /// the link, or dropped by zenoh on a full link.
        lost: u64,
    }

    fn unix_now_ns(offset: i64) -> u64 {
        (skinware::os::monotonic_ns() as i64 + offset).max(0) as u64
    }

    /// Reads every layer as soon as available for `--seconds`, and prints
    /// one JSON object: per layer frames, gaps, bytes and latency; and the
    /// state changes, with their times (Unix ns).
    pub fn probe(args: &ProbeArgs) -> Result<()> {
        let offset = skinware_ros2::clock_offset_ns();
        let stop = Stop::new();
        let events = Arc::new(Mutex::new(Vec::<serde_json::Value>::new()));
        let until = Instant::now() + Duration::from_secs_f64(args.seconds.max(0.1));
        let mut threads = Vec::new();
        let remote = connect(args)?;
        for layer in layers_to_read(remote.as_ref(), &args.skin)? {
            let watch = Watch { until, stop: stop.clone(), events: Arc::clone(&events), offset };
            let verify = args.verify;
            let mut local =
                Reader::open_with(&args.skin, &layer, &ReaderOptions { allow_gone: true, ..Default::default() }).ok();
            if let Some(remote) = &remote {
                let reader = remote.reader(&layer)?;
                threads.push(std::thread::spawn(move || read_remote(reader, layer, local, verify, watch)));
            } else {
                let Some(reader) = local.take() else { continue };
                threads.push(std::thread::spawn(move || read_local(reader, layer, &watch)));
            }
        }
        print_probe_report(args, threads, &events)
    }

    /// The remote skin at `--remote`, if given.
    fn connect(args: &ProbeArgs) -> Result<Option<RemoteSkin>> {
        let Some(endpoint) = &args.remote else { return Ok(None) };
        let endpoint = if endpoint.contains('/') { endpoint.clone() } else { format!("tcp/{endpoint}") };
        let link = LinkOptions { connect: vec![endpoint], ..LinkOptions::default() };
        Ok(Some(RemoteSkin::connect(&link, &args.skin, Duration::from_secs(20))?))
    }

    /// The layers of `skin`: the remote skin's, or the local exchange's.
    fn layers_to_read(remote: Option<&RemoteSkin>, skin: &str) -> Result<Vec<String>> {
        let layers: Vec<String> = match remote {
            Some(remote) => {
                remote.channels().iter().filter(|c| c.kind == ChannelKind::Layer).map(|c| c.name.clone()).collect()
            }
            None => skinware::list_skin_channels(&skinware::shm::segment_dir(), skin)?
                .into_iter()
                .filter(|c| c.skin == skin && c.kind == Some(ChannelKind::Layer))
                .map(|c| c.channel)
                .collect(),
        };
        if layers.is_empty() {
            bail!("skin {skin} has no layer to read");
        }
        Ok(layers)
    }

    /// What every probe thread shares: when to stop, and where the remote
    /// readers' state changes go (with their times, Unix ns).
    struct Watch {
        until: Instant,
        stop: Stop,
        events: Arc<Mutex<Vec<serde_json::Value>>>,
        /// CLOCK_REALTIME minus CLOCK_MONOTONIC, ns.
        offset: i64,
    }

    /// Reads one remote layer until the probe ends; with `verify`, checks
    /// each frame against `local`'s of the same sequence number.
    fn read_remote(
        mut reader: RemoteReader,
        layer: String,
        mut local: Option<Reader>,
        verify: bool,
        watch: Watch,
    ) -> (String, LayerFigures) {
        let Watch { until, stop, events, offset } = watch;
        let mut figures = LayerFigures::default();
        let mut shown = "running";
        let mut gap_since: Option<u64> = None;
        while Instant::now() < until && !stop.is_stopped() {
            let state = reader.state();
            if state.name() != shown {
                shown = state.name();
                if state == RemoteState::Unreachable {
                    gap_since = Some(unix_now_ns(offset));
                }
                events
                    .lock()
                    .unwrap()
                    .push(serde_json::json!({"t": unix_now_ns(offset), "layer": layer, "state": shown}));
            }
            let Ok(frame) = reader.wait_newer(Duration::from_millis(20)) else { continue };
            let now = unix_now_ns(offset);
            figures.received += 1;
            figures.skipped += frame.skipped;
            figures.bytes += frame.bytes.len() as u64;
            figures.latencies.push(now.saturating_sub(frame.acquired_unix_ns));
            if gap_since.take().is_some() {
                events.lock().unwrap().push(serde_json::json!({"t": now, "layer": layer, "state": "frame"}));
            }
            if verify {
                match local.as_mut().and_then(|l| l.read_seq(frame.seq).map(|f| f.bytes() == frame.bytes.as_slice())) {
                    Some(true) => figures.verified += 1,
                    Some(false) => figures.mismatched += 1,
                    None => figures.unverifiable += 1,
                }
            }
        }
        figures.bridge_dropped = reader.bridge_state().map_or(0, |s| s.dropped);
        figures.lost = reader.stats().lost;
        // The reader reports once a second: one more report, with these
        // final figures, so that the bridge's match them.
        let report_until = Instant::now() + Duration::from_millis(1_500);
        while Instant::now() < report_until && !stop.is_stopped() {
            let _ = reader.state();
            std::thread::sleep(Duration::from_millis(20));
        }
        (layer, figures)
    }

    /// Reads one layer of the local exchange until the probe ends.
    fn read_local(mut reader: Reader, layer: String, watch: &Watch) -> (String, LayerFigures) {
        let mut figures = LayerFigures::default();
        while Instant::now() < watch.until && !watch.stop.is_stopped() {
            let Ok(frame) = reader.wait_newer(Duration::from_millis(100)) else { continue };
            let now = skinware::os::monotonic_ns();
            figures.received += 1;
            figures.skipped += frame.skipped();
            figures.bytes += frame.bytes().len() as u64;
            figures.latencies.push(now.saturating_sub(frame.acquired_ns()));
        }
        (layer, figures)
    }

    /// Joins the probe's threads and prints its JSON object.
    fn print_probe_report(
        args: &ProbeArgs,
        threads: Vec<JoinHandle<(String, LayerFigures)>>,
        events: &Mutex<Vec<serde_json::Value>>,
    ) -> Result<()> {
        let mut report = BTreeMap::new();
        let mut all_latencies = Vec::new();
        let (mut received, mut skipped, mut bytes, mut lost) = (0, 0, 0, 0);
        for thread in threads {
            let (layer, mut figures) = thread.join().map_err(|_| anyhow::anyhow!("a probe thread panicked"))?;
            received += figures.received;
            skipped += figures.skipped;
            bytes += figures.bytes;
            lost += figures.lost;
            all_latencies.extend_from_slice(&figures.latencies);
            report.insert(
                layer,
                serde_json::json!({
                    "received": figures.received, "skipped": figures.skipped, "bytes": figures.bytes,
                    "latency_us": quantiles_us(&mut figures.latencies),
                    "verified": figures.verified, "mismatched": figures.mismatched, "unverifiable": figures.unverifiable,
                    "bridge_dropped": figures.bridge_dropped, "lost": figures.lost,
                }),
            );
        }
        let seconds = args.seconds.max(0.1);
        let out = serde_json::json!({
            "mode": if args.remote.is_some() { "remote" } else { "local" },
            "seconds": seconds,
            "frames_per_s": received as f64 / seconds,
            "mb_per_s": bytes as f64 / seconds / 1e6,
            "received": received,
            "skipped": skipped,
            "lost": lost,
            "latency_us": quantiles_us(&mut all_latencies),
            "layers": report,
            "events": *events.lock().unwrap(),
        });
        println!("{out}");
        Ok(())
    }

    /// Two network namespaces joined by a veth pair; removed when dropped.
    struct TwoHosts {
        a: String,
        b: String,
        veth_a: String,
        veth_b: String,
    }

    const ADDRESS_A: &str = "10.231.7.1";
    const ADDRESS_B: &str = "10.231.7.2";

    fn ip(args: &[&str]) -> Result<()> {
        let output = Command::new("ip").args(args).output().context("cannot run `ip` (iproute2)")?;
        if !output.status.success() {
            bail!("ip {}: {}", args.join(" "), String::from_utf8_lossy(&output.stderr).trim());
        }
        Ok(())
    }

    impl TwoHosts {
        fn create() -> Result<TwoHosts> {
            let id = std::process::id();
            let hosts = TwoHosts {
                a: format!("skbr-a-{id}"),
                b: format!("skbr-b-{id}"),
                veth_a: format!("skbra{}", id % 100_000),
                veth_b: format!("skbrb{}", id % 100_000),
            };
            ip(&["netns", "add", &hosts.a]).context(
                "cannot create a network namespace (the bench needs root, or CAP_SYS_ADMIN and CAP_NET_ADMIN)",
            )?;
            ip(&["netns", "add", &hosts.b])?;
            ip(&[
                "link",
                "add",
                &hosts.veth_a,
                "netns",
                &hosts.a,
                "type",
                "veth",
                "peer",
                "name",
                &hosts.veth_b,
                "netns",
                &hosts.b,
            ])?;
            for (ns, dev, address) in [(&hosts.a, &hosts.veth_a, ADDRESS_A), (&hosts.b, &hosts.veth_b, ADDRESS_B)] {
                ip(&["-n", ns, "addr", "add", &format!("{address}/24"), "dev", dev])?;
                ip(&["-n", ns, "link", "set", dev, "up"])?;
                ip(&["-n", ns, "link", "set", "lo", "up"])?;
            }
            Ok(hosts)
        }

        fn command(&self, ns: &str, exe: &Path, dir: &Path) -> Command {
            let mut command = Command::new("ip");
            command.args(["netns", "exec", ns]).arg(exe).env("SKINWARE_SHM_DIR", dir).env("RUST_LOG", "warn");
            command
        }

        /// Shapes the bridge's side of the link (what it sends) to `mbit` Mbit/s; `None` removes the shaping.
        fn shape(&self, mbit: Option<u32>) -> Result<()> {
            let _ = ip(&["netns", "exec", &self.a, "tc", "qdisc", "del", "dev", &self.veth_a, "root"]);
            if let Some(mbit) = mbit {
                let status = Command::new("ip")
                    .args(["netns", "exec", &self.a, "tc", "qdisc", "add", "dev", &self.veth_a, "root", "tbf"])
                    .args(["rate", &format!("{mbit}mbit"), "burst", "64kb", "latency", "100ms"])
                    .status()
                    .context("cannot run tc (iproute2)")?;
                if !status.success() {
                    bail!("tc could not shape {} to {mbit} Mbit/s", self.veth_a);
                }
            }
            Ok(())
        }

        fn link(&self, up: bool) -> Result<()> {
            ip(&["-n", &self.b, "link", "set", &self.veth_b, if up { "up" } else { "down" }])
        }
    }

    impl Drop for TwoHosts {
        fn drop(&mut self) {
            let _ = ip(&["netns", "del", &self.a]);
            let _ = ip(&["netns", "del", &self.b]);
        }
    }

    struct Stopping(Child);

    impl Drop for Stopping {
        fn drop(&mut self) {
            let _ = Command::new("kill").args(["-INT", &self.0.id().to_string()]).status();
            let deadline = Instant::now() + Duration::from_secs(10);
            while Instant::now() < deadline {
                if let Ok(Some(_)) = self.0.try_wait() {
                    return;
                }
                std::thread::sleep(Duration::from_millis(50));
            }
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }

    fn run_probe(mut command: Command) -> Result<serde_json::Value> {
        let output = command.stderr(Stdio::inherit()).output().context("cannot run the probe")?;
        if !output.status.success() {
            bail!("the probe failed ({})", output.status);
        }
        serde_json::from_slice(&output.stdout).context("the probe's output is not JSON")
    }

    fn us(value: &serde_json::Value) -> f64 {
        value.as_f64().unwrap_or(f64::NAN)
    }

    /// Runs `skin bench bridge`.
    pub fn bench(options: &RunOptions) -> Result<()> {
        let exe = options.exe.as_path();
        let seconds = options.seconds_or(3.0, 10.0);
        std::fs::create_dir_all(&options.out)?;
        let dir = PathBuf::from("/dev/shm").join(format!("skin-bench-bridge-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        let _cleanup = RemoveDir(dir.clone());
        let config = dir.join("skin.toml");
        std::fs::write(&config, DEMO_CONFIG)?;
        let hosts = TwoHosts::create()?;
        let _skin = Stopping(hosts.command(&hosts.a, exe, &dir).arg("run").arg(&config).stdout(Stdio::null()).spawn()?);
        let endpoint = format!("tcp/{ADDRESS_A}:7447");
        // Wait for the skin's channels and geometry.
        let deadline = Instant::now() + Duration::from_secs(120);
        while skinware::list_channels(&dir).map(|c| c.len()).unwrap_or(0) < 8 {
            if Instant::now() > deadline {
                bail!("`skin run` did not create the skin's 8 channels within 120 s");
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        // The bridge's own figures, a JSON line a second: what it sent and
        // dropped, and what its remote readers report they did not get.
        let stats_path = options.out.join("bridge-stats.jsonl");
        let _bridge = Stopping(
            hosts
                .command(&hosts.a, exe, &dir)
                .args(["bridge", "--listen", &endpoint, "--stats", "--json"])
                .stdout(std::fs::File::create(&stats_path)?)
                .spawn()?,
        );
        let lab = Lab { hosts: &hosts, exe, dir: &dir, endpoint: &endpoint, stats_path: &stats_path };
        println!(
            "skin bench bridge: the paper's skin (5 layers, 30,848 taxels) across a veth link, {seconds} s per phase"
        );
        let mut results = serde_json::Map::new();
        lab.unshaped(seconds, &mut results)?;
        lab.shaped(seconds, &mut results)?;
        lab.cut(seconds, &mut results)?;
        let out = options.out.join("bridge.json");
        std::fs::write(&out, serde_json::to_string_pretty(&serde_json::Value::Object(results))?)?;
        println!("written: {}", out.display());
        Ok(())
    }

    /// The bench's two hosts, with the skin and its bridge running on the first.
    struct Lab<'a> {
        /// The two namespaces.
        hosts: &'a TwoHosts,
        /// The `skin` executable.
        exe: &'a Path,
        /// The skin's segment directory.
        dir: &'a Path,
        /// Where the bridge listens.
        endpoint: &'a str,
        /// The bridge's figures, a JSON line a second.
        stats_path: &'a Path,
    }

    /// The bench's results, by phase.
    type Results = serde_json::Map<String, serde_json::Value>;

    impl Lab<'_> {
        /// A probe in namespace `ns` for `seconds`: across the link
        /// (`remote`, checking each frame with `verify`) or through the
        /// local exchange.
        fn probe(&self, ns: &str, remote: bool, verify: bool, seconds: f64) -> Command {
            let mut command = self.hosts.command(ns, self.exe, self.dir);
            command.arg("bridge-probe").args(["--seconds", &seconds.to_string()]);
            if remote {
                command.args(["--remote", self.endpoint]);
            }
            if verify {
                command.arg("--verify");
            }
            command
        }

        /// The bridge's newest figures, a second from now.
        fn bridge_figures(&self) -> serde_json::Value {
            std::thread::sleep(Duration::from_millis(1100));
            std::fs::read_to_string(self.stats_path)
                .ok()
                .and_then(|text| text.lines().rev().find_map(|line| serde_json::from_str(line).ok()))
                .unwrap_or(serde_json::Value::Null)
        }

        /// Across the link and through the local exchange, at the same time.
        fn unshaped(&self, seconds: f64, results: &mut Results) -> Result<()> {
            let local = self.probe(&self.hosts.a, false, false, seconds).stdout(Stdio::piped()).spawn()?;
            let remote = run_probe(self.probe(&self.hosts.b, true, true, seconds))?;
            let local = local.wait_with_output()?;
            let local: serde_json::Value = serde_json::from_slice(&local.stdout).context("the local probe's output")?;
            println!(
                "{:<22} {:>10} {:>8} {:>9} {:>10} {:>10} {:>10}",
                "link", "frames/s", "MB/s", "skipped", "p50 µs", "p99 µs", "max µs"
            );
            row("local exchange", &local);
            row("veth, unshaped", &remote);
            results.insert("local".into(), local);
            results.insert("unshaped".into(), remote);
            Ok(())
        }

        /// The link shaped to 100, 10 and 1 Mbit/s.
        fn shaped(&self, seconds: f64, results: &mut Results) -> Result<()> {
            for mbit in [100, 10, 1] {
                self.hosts.shape(Some(mbit))?;
                // The first second fills the link's buffers; a slow link needs longer than that to show its rate.
                let mut shaped = run_probe(self.probe(&self.hosts.b, true, false, seconds.max(6.0)))?;
                shaped["bridge"] = self.bridge_figures();
                row(&format!("veth, {mbit} Mbit/s"), &shaped);
                results.insert(format!("{mbit}mbit"), shaped);
            }
            self.hosts.shape(None)
        }

        /// Cuts the link for 3 s (longer than zenoh's 1 s lease: the session
        /// closes and reconnects), with a probe reading across the cut. The
        /// probe reads long enough after the link returns (8 s) for a slow,
        /// loaded machine to reconnect and say so.
        fn cut(&self, seconds: f64, results: &mut Results) -> Result<()> {
            let cut_probe =
                self.probe(&self.hosts.b, true, false, seconds.max(3.0) + 3.0 + 8.0).stdout(Stdio::piped()).spawn()?;
            std::thread::sleep(Duration::from_secs_f64(seconds.max(3.0)));
            let offset = skinware_ros2::clock_offset_ns();
            let cut_at = unix_now_ns(offset);
            self.hosts.link(false)?;
            std::thread::sleep(Duration::from_secs(3));
            let restored_at = unix_now_ns(offset);
            self.hosts.link(true)?;
            let cut = cut_probe.wait_with_output()?;
            let cut: serde_json::Value = serde_json::from_slice(&cut.stdout).context("the link-cut probe's output")?;
            let events = cut["events"].as_array().cloned().unwrap_or_default();
            let first = |state: &str, after: u64| {
                events
                    .iter()
                    .filter(|e| e["state"] == state && e["t"].as_u64().unwrap_or(0) >= after)
                    .filter_map(|e| e["t"].as_u64())
                    .min()
            };
            let detected = first("unreachable", cut_at).map(|t| (t - cut_at) as f64 / 1e6);
            let recovered = first("frame", restored_at).map(|t| (t - restored_at) as f64 / 1e6);
            println!(
                "link cut for 3 s: unreachable after {} ms; frames again {} ms after the link came back",
                detected.map_or("(never)".into(), |ms| format!("{ms:.0}")),
                recovered.map_or("(never)".into(), |ms| format!("{ms:.0}"))
            );
            results.insert(
                "cut".into(),
                serde_json::json!({ "seconds_down": 3.0, "detected_ms": detected, "recovered_ms": recovered, "probe": cut }),
            );
            Ok(())
        }
    }

    /// One row of the bench's table: a probe's figures.
    fn row(name: &str, v: &serde_json::Value) {
        println!(
            "{:<22} {:>10.1} {:>8.2} {:>9} {:>10.0} {:>10.0} {:>10.0}",
            name,
            us(&v["frames_per_s"]),
            us(&v["mb_per_s"]),
            v["skipped"],
            us(&v["latency_us"]["p50"]),
            us(&v["latency_us"]["p99"]),
            us(&v["latency_us"]["max"])
        );
    }

    struct RemoveDir(PathBuf);

    impl Drop for RemoveDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}
