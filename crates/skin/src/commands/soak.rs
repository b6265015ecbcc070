//! `skin bench soak CONFIG --minutes N`: the fault soak
//! ([`skinware_bench::soak`]), and its hidden helper roles. This file turns
//! the user's config into the soak's (every virtual driver publishing its
//! verification pattern; both services added if it has none) and runs the
//! browser-like client of the viewer, which speaks the viewer's protocol
//! and so lives beside it in this crate; the rest of the soak is in
//! `skinware-bench`.

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use skinware_bench::soak::{self, LayerPlan, SoakOptions};

use skin::config::{Config, ServiceKind};

/// Options of `skin bench soak`.
#[derive(clap::Args)]
pub struct SoakArgs {
    /// The skin to soak: a config of virtual drivers (e.g.
    /// examples/paper-virtual-skin.toml). Its drivers publish their
    /// verification pattern during the soak; the contact and motion
    /// services are added if it has no service.
    config: PathBuf,
    /// Minutes of faults (the start and the end take some seconds more; at
    /// least one round of every kind of fault, about 80 s, however short).
    #[arg(long, value_parser = parse_minutes)]
    minutes: Option<f64>,
    /// Two minutes, as CI runs it (unless --minutes says otherwise).
    #[arg(long)]
    quick: bool,
    /// The faults' seed, to run the same faults again (printed at the start).
    #[arg(long)]
    seed: Option<u64>,
    /// Directory for soak.json and the logs (soak-work/).
    #[arg(long, default_value = "target/bench")]
    out: PathBuf,
}

fn parse_minutes(text: &str) -> Result<f64, String> {
    let minutes: f64 = text.trim().parse().map_err(|_| format!("{text:?} is not a number of minutes"))?;
    if minutes.is_finite() && minutes > 0.0 && minutes <= 1440.0 {
        Ok(minutes)
    } else {
        Err(format!("{text} minutes: give more than 0 and at most 1440 (a day)"))
    }
}

/// Runs `skin bench soak`; fails if the soak found a correctness failure.
pub fn bench(args: &SoakArgs) -> Result<()> {
    let interrupted = super::run::shutdown_on_signals()?;
    let exe = std::env::current_exe().context("cannot find the skin executable")?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let dir = skinware::shm::segment_dir().join(format!("skin-soak-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)
        .with_context(|| format!("cannot create the soak's segment directory {}", dir.display()))?;
    let prepared = prepare(&args.config, &dir, &args.out);
    let prepared = match prepared {
        Ok(prepared) => prepared,
        Err(e) => {
            let _ = std::fs::remove_dir_all(&dir);
            return Err(e);
        }
    };
    let options = SoakOptions {
        exe,
        source_config: args.config.display().to_string(),
        config: prepared.path,
        skin: prepared.skin,
        layers: prepared.layers,
        services: prepared.services,
        dir,
        minutes: args.minutes.unwrap_or(if args.quick { 2.0 } else { 60.0 }),
        seed: args.seed,
        out: args.out.clone(),
        interrupted: interrupted.clone(),
    };
    let report = soak::run(&options)?;
    if interrupted.load(std::sync::atomic::Ordering::Relaxed) {
        bail!("interrupted: the report above covers the faults until then");
    }
    if !report.passed {
        bail!("the soak found {} correctness failure(s): {}", report.failures.len(), report.failures.join("; "));
    }
    Ok(())
}

/// The soak's config, written, and what it runs.
struct Prepared {
    path: PathBuf,
    skin: String,
    layers: Vec<LayerPlan>,
    services: Vec<String>,
}

/// Writes the soak's version of `config` into `out`: every driver must be
/// virtual (its frames are then checkable) and publishes its verification
/// pattern; relative paths are made absolute; the contact and motion
/// services are added to a config that has none.
fn prepare(config: &Path, dir: &Path, out: &Path) -> Result<Prepared> {
    let text = std::fs::read_to_string(config).with_context(|| format!("cannot read config {}", config.display()))?;
    // Checked as `skin run` would, first, for its clear messages.
    Config::parse(&text, config)?;
    let mut value: toml::Table = toml::from_str(&text).with_context(|| format!("cannot parse {}", config.display()))?;
    let base = config.parent().map(Path::to_path_buf).unwrap_or_default();
    let base = std::fs::canonicalize(if base.as_os_str().is_empty() { Path::new(".") } else { &base })?;
    if value.get("emulator").is_some() {
        bail!(
            "{}: the soak runs virtual drivers only (its readers check the virtual skin's pattern); remove the [[emulator]] tables",
            config.display()
        );
    }
    let drivers =
        value.get_mut("driver").and_then(toml::Value::as_array_mut).context("the config has no [[driver]]")?;
    for driver in drivers.iter_mut() {
        let table = driver.as_table_mut().context("a [[driver]] that is not a table")?;
        let name = table.get("name").and_then(toml::Value::as_str).unwrap_or("?").to_owned();
        if table.get("kind").and_then(toml::Value::as_str) != Some("virtual") {
            bail!(
                "{}: driver {name} is not kind = \"virtual\": the soak's readers verify every frame against the virtual skin's pattern, which only virtual drivers publish",
                config.display()
            );
        }
        table.insert("verify_pattern".into(), toml::Value::Boolean(true));
        if let Some(calibration) = table.get("calibration").and_then(toml::Value::as_str) {
            let absolute = base.join(calibration).display().to_string();
            table.insert("calibration".into(), toml::Value::String(absolute));
        }
    }
    if value.get("service").is_none() {
        let services: toml::Value = toml::from_str::<toml::Table>(
            "[[service]]\nname = \"contact\"\nkind = \"contact\"\nrate_hz = 50\n\n[[service]]\nname = \"motion\"\nkind = \"motion\"\ninput = \"contact\"\nrate_hz = 50\n",
        )?
        .remove("service")
        .context("the services")?;
        value.insert("service".into(), services);
    }
    let path = out.join("soak-config.toml");
    let text = format!(
        "# Written by `skin bench soak` from {}: its virtual drivers publish their\n# verification pattern.\n{}",
        config.display(),
        toml::to_string(&value)?
    );
    std::fs::write(&path, &text).with_context(|| format!("cannot write {}", path.display()))?;
    let parsed = Config::parse(&text, &path)?;
    let mut layers = Vec::new();
    for driver in &parsed.drivers {
        let built = driver.build(&parsed.skin)?;
        for spec in built.layers() {
            let name = spec.topology.name.clone();
            layers.push(LayerPlan {
                pull_file: skin::config::pull_file_in(dir, &parsed.skin, &name),
                taxels: spec.topology.sensors.len(),
                name,
            });
        }
    }
    if layers.is_empty() {
        bail!("{}: no layers to soak", config.display());
    }
    let mut services = Vec::new();
    for service in parsed.services.iter().filter(|s| s.rate_hz.is_some()) {
        services.push(service.name.clone());
        if service.kind == ServiceKind::Contact {
            services.push(skinware_services::taxel_channel(&service.name));
        }
    }
    Ok(Prepared { path: std::fs::canonicalize(&path)?, skin: parsed.skin, layers, services })
}

/// Arguments of the hidden `bench-soak-reader` role.
#[derive(clap::Args)]
pub struct ReaderArgs {
    #[arg(long)]
    skin: String,
    #[arg(long, value_delimiter = ',')]
    layers: Vec<String>,
    #[arg(long)]
    mode: String,
    #[arg(long)]
    report: PathBuf,
}

/// Runs one verifying reader process of the soak.
pub fn reader(args: &ReaderArgs) -> Result<()> {
    soak::reader::run(&soak::reader::ReaderArgs {
        skin: args.skin.clone(),
        layers: args.layers.clone(),
        mode: soak::reader::Mode::parse(&args.mode)?,
        report: args.report.clone(),
    })
}

/// Arguments of the hidden `bench-soak-foreign` role.
#[derive(clap::Args)]
pub struct ForeignArgs {
    #[arg(long, default_value_t = 10)]
    channels: usize,
}

/// Runs the soak's foreign writers.
pub fn foreign(args: &ForeignArgs) -> Result<()> {
    soak::helpers::foreign_writers(args.channels.clamp(1, 100))
}

/// Arguments of the hidden `bench-soak-hog` role.
#[derive(clap::Args)]
pub struct HogArgs {
    #[arg(long)]
    threads: usize,
    #[arg(long, value_parser = super::bench::parse_helper_seconds)]
    seconds: f64,
}

/// Runs the soak's CPU hog.
pub fn hog(args: &HogArgs) -> Result<()> {
    soak::helpers::hog(args.threads.clamp(1, 1024), args.seconds)
}

/// Arguments of the hidden `bench-soak-browser` role.
#[derive(clap::Args)]
pub struct BrowserArgs {
    #[arg(long)]
    address: String,
    #[arg(long)]
    report: PathBuf,
}

/// What the browser-like client reports.
#[derive(Debug, Default, serde::Serialize)]
struct BrowserReport {
    /// Updates received.
    updates: u64,
    /// Geometries received (one per connection).
    geometries: u64,
    /// Connections made (the first and every reconnection).
    connections: u64,
    /// Errors that ended a connection.
    errors: u64,
    /// The longest time without an update once connected, ms.
    longest_gap_ms: f64,
    /// When that gap ended (CLOCK_MONOTONIC ns), to find what caused it.
    longest_gap_ended_ns: u64,
    /// Every wait for an update longer than [`STALL_MS`]: when it ended
    /// (CLOCK_MONOTONIC ns) and how long it was (ms), for the soak to match
    /// with its faults (the first 10,000).
    stalls: Vec<(u64, f64)>,
    /// The last error, if any.
    last_error: Option<String>,
}

/// The shortest wait for an update that the browser lists as a stall: ten
/// times the viewer's period at 30-50 Hz layers.
const STALL_MS: f64 = 300.0;

/// The viewer's browser for the soak: takes the geometry, acknowledges
/// the updates at 60 Hz as a page does, reconnects if the connection ends,
/// and writes what it received to `--report` twice a second, until its
/// standard input closes.
pub fn browser(args: &BrowserArgs) -> Result<()> {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let stopper = stop.clone();
    std::thread::spawn(move || {
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
        stopper.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let mut report = BrowserReport::default();
    let mut last_written = Instant::now();
    let write = |report: &BrowserReport| -> Result<()> {
        let temp = args.report.with_extension("tmp");
        std::fs::write(&temp, serde_json::to_vec(report)?)?;
        std::fs::rename(&temp, &args.report)?;
        Ok(())
    };
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        report.connections += 1;
        if let Err(e) = browse(
            &args.address,
            &stop,
            &mut report,
            &mut || {
                if last_written.elapsed() > Duration::from_millis(500) {
                    last_written = Instant::now();
                    true
                } else {
                    false
                }
            },
            &write,
        ) {
            report.errors += 1;
            report.last_error = Some(format!("{e:#}"));
            std::thread::sleep(Duration::from_millis(200));
        }
        write(&report)?;
    }
    write(&report)
}

/// One connection of [`browser`].
fn browse(
    address: &str,
    stop: &std::sync::atomic::AtomicBool,
    report: &mut BrowserReport,
    due: &mut dyn FnMut() -> bool,
    write: &dyn Fn(&BrowserReport) -> Result<()>,
) -> Result<()> {
    use tungstenite::Message;
    let stream = TcpStream::connect(address).with_context(|| format!("cannot connect to the viewer at {address}"))?;
    stream.set_read_timeout(Some(Duration::from_millis(16)))?;
    let (mut socket, _) = tungstenite::client(format!("ws://{address}/ws"), stream)
        .map_err(|e| anyhow::anyhow!("WebSocket handshake with the viewer failed: {e}"))?;
    let mut unacked = 0u32;
    let mut last_update: Option<Instant> = None;
    let mut next_ack = Instant::now();
    while !stop.load(std::sync::atomic::Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Binary(data)) if data.first() == Some(&1) => {
                report.geometries += 1;
                socket.send(Message::text(r#"{"ack":2}"#))?;
            }
            Ok(Message::Binary(data)) if data.first() == Some(&2) => {
                report.updates += 1;
                unacked += 1;
                if let Some(last) = last_update {
                    let gap_ms = last.elapsed().as_secs_f64() * 1e3;
                    let now_ns = skinware::os::monotonic_ns();
                    if gap_ms > report.longest_gap_ms {
                        report.longest_gap_ms = gap_ms;
                        report.longest_gap_ended_ns = now_ns;
                    }
                    if gap_ms > STALL_MS && report.stalls.len() < 10_000 {
                        report.stalls.push((now_ns, gap_ms));
                    }
                }
                last_update = Some(Instant::now());
            }
            Ok(Message::Close(_)) => bail!("the viewer closed the connection"),
            Ok(Message::Text(text)) => bail!("the viewer refused the browser: {text}"),
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => return Err(e.into()),
        }
        if Instant::now() >= next_ack {
            next_ack = Instant::now() + Duration::from_secs_f64(1.0 / 60.0);
            if unacked > 0 {
                socket.send(Message::text(format!(r#"{{"ack":{unacked}}}"#)))?;
                unacked = 0;
            }
        }
        if due() {
            write(report)?;
        }
    }
    let _ = socket.close(None);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("skin-soak-test-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn the_papers_skin_becomes_a_patterned_skin_with_its_services() {
        let out = scratch("paper");
        let config = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/paper-virtual-skin.toml");
        let prepared = prepare(&config, Path::new("/dev/shm/soak-test"), &out).unwrap();
        assert_eq!(prepared.layers.len(), 5);
        assert_eq!(prepared.layers.iter().map(|l| l.taxels).sum::<usize>(), 30_848);
        assert_eq!(prepared.layers[2].pull_file, Path::new("/dev/shm/soak-test/skinware-ctl.default.virtual-2.pulled"));
        assert_eq!(prepared.services, ["contact", "contact-taxels", "motion"]);
        let written = Config::load(&prepared.path).unwrap();
        assert!(written.drivers.iter().all(|d| d.verify_pattern));
        let _ = std::fs::remove_dir_all(out);
    }

    #[test]
    fn services_are_added_and_other_drivers_refused() {
        let out = scratch("small");
        let config = out.join("small.toml");
        std::fs::write(
            &config,
            "skin = \"s\"\n[[driver]]\nname = \"v\"\nkind = \"virtual\"\nsensors = 240\nlayers = 2\n",
        )
        .unwrap();
        let prepared = prepare(&config, &out, &out).unwrap();
        assert_eq!(prepared.skin, "s");
        assert_eq!(prepared.services, ["contact", "contact-taxels", "motion"]);
        std::fs::write(
            &config,
            "[[driver]]\nname = \"c\"\nkind = \"can\"\ninterface = \"candump:///x\"\nprotocol = \"icub-mtb\"\n",
        )
        .unwrap();
        let error = format!("{:#}", prepare(&config, &out, &out).err().unwrap());
        assert!(error.contains("virtual") || error.contains("board"), "{error}");
        let _ = std::fs::remove_dir_all(out);
    }
}
