//! `skin demo`: the paper's virtual skin under the supervisor, and the web
//! viewer on it, in one command. The configuration is `examples/demo.toml`,
//! built into the binary.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use skinware::WriterState;
use skinware_geometry::SkinGeometry;
use skinware_viewer::{self as view, Site};

use skin::config::Config;

/// The demo's skin: drivers (and, later, services) in one place.
const DEMO_CONFIG: &str = include_str!("../../../../examples/demo.toml");

/// How long the skin may take to come up (the first run computes its geometry).
const STARTUP_LIMIT: Duration = Duration::from_secs(120);

/// Arguments of `skin demo`.
#[derive(clap::Args)]
pub struct Args {
    /// Address of the viewer; loopback unless you mean to share the view.
    #[arg(long, default_value = "127.0.0.1:8080")]
    listen: String,
    /// Print only the URL, without the suggestions of what to try.
    #[arg(long)]
    no_browser_hint: bool,
    /// Show this recording (`skin record`), looping, instead of the virtual skin.
    #[arg(long, value_name = "FILE.mcap")]
    replay: Option<PathBuf>,
}

/// The demo's configuration: the paper's virtual skin, or a recording
/// replayed in a loop with the demo's services running live on it.
fn demo_config(replay: Option<&Path>) -> Result<String> {
    let Some(file) = replay else {
        return Ok(DEMO_CONFIG.to_owned());
    };
    let file = std::fs::canonicalize(file).with_context(|| format!("cannot find the recording {}", file.display()))?;
    let header = skinware_record::file::RecordStream::open(&file)
        .and_then(|mut stream| skinware_record::file::read_header(&mut stream))
        .with_context(|| format!("cannot replay {}", file.display()))?
        .0;
    // The demo's services, not its regions (they name the virtual body's links).
    let services = DEMO_CONFIG.find("[[service]]").map_or("", |at| &DEMO_CONFIG[at..]);
    Ok(format!(
        "skin = {:?}\n\n[[driver]]\nname = \"replay\"\nkind = \"replay\"\nfile = {:?}\nloop = true\n\n{services}",
        header.skin,
        file.display().to_string()
    ))
}

/// Removes the demo's configuration file when the demo ends, however it ends.
struct TemporaryFile(PathBuf);

impl Drop for TemporaryFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Runs `skin demo` until SIGINT or SIGTERM.
pub fn run(args: &Args) -> Result<()> {
    // The port first: a port in use should stop the demo before anything starts.
    let listener = view::bind(&args.listen)?;
    let url = format!("http://{}/", listener.local_addr()?);
    // The drivers are processes that read the configuration from a file.
    let config_file = TemporaryFile(std::env::temp_dir().join(format!("skin-demo-{}.toml", std::process::id())));
    std::fs::write(&config_file.0, demo_config(args.replay.as_deref())?)
        .with_context(|| format!("cannot write the demo configuration to {}", config_file.0.display()))?;
    let config = Config::load(&config_file.0)?;
    refuse_if_running(&config.skin)?;

    let shutdown = super::run::shutdown_on_signals()?;
    let supervisor = {
        let (path, shutdown) = (config_file.0.clone(), shutdown.clone());
        std::thread::Builder::new()
            .name("supervisor".into())
            .spawn(move || super::run::supervise(&path, &shutdown))
            .context("cannot start the supervisor thread")?
    };
    let served = wait_until_running(&config, &shutdown, &supervisor).and_then(|()| {
        if shutdown.load(Ordering::Relaxed) {
            return Ok(());
        }
        println!("skin demo: {url}");
        if !args.no_browser_hint {
            println!(
                "  open it in a browser: {} sensors of skin {} live, per-layer state, rate and latency.\n  \
                 try, in another terminal: skin pull {} (then --restore), skin top, skin ls.\n  Ctrl-C stops everything.",
                SkinGeometry::open(&config.skin).map(|g| g.sensor_count()).unwrap_or(0),
                config.skin,
                last_layer_name(&config.skin).unwrap_or_else(|| "LAYER".into()),
            );
        }
        view::serve(listener, &Site::new(&config.skin, None, shutdown.clone()))
    });
    shutdown.store(true, Ordering::Relaxed);
    let supervised = supervisor.join().unwrap_or_else(|_| Err(anyhow::anyhow!("the supervisor thread panicked")));
    // A failed supervisor explains a failed start better than the viewer can.
    supervised.and(served)
}

/// A second demo (or a `skin run` of the same skin) would fight over the channels.
fn refuse_if_running(skin: &str) -> Result<()> {
    let dir = skinware::shm::segment_dir();
    let channels =
        skinware::list_skin_channels(&dir, skin).with_context(|| format!("cannot list {}", dir.display()))?;
    if let Some(live) = channels.iter().find(|c| c.skin == skin && c.state != WriterState::Gone) {
        bail!(
            "skin {skin} is already running here (channel {}, writer pid {}); stop that `skin run` or `skin demo` \
             first (Ctrl-C), or watch it with `skin view --skin {skin}`",
            live.channel,
            live.writer_pid
        );
    }
    Ok(())
}

fn last_layer_name(skin: &str) -> Option<String> {
    SkinGeometry::open(skin).ok()?.layers.last().map(|l| l.name.clone())
}

/// Waits until the geometry is published and every layer of it is running.
fn wait_until_running(config: &Config, shutdown: &AtomicBool, supervisor: &JoinHandle<Result<()>>) -> Result<()> {
    let started = Instant::now();
    let dir = skinware::shm::segment_dir();
    let mut missing = vec!["the geometry".to_owned()];
    while !shutdown.load(Ordering::Relaxed) {
        if supervisor.is_finished() {
            // Its error, if any, is reported when it is joined.
            bail!("the skin stopped while starting");
        }
        missing = not_running(&dir, &config.skin);
        if missing.is_empty() {
            return Ok(());
        }
        if started.elapsed() > STARTUP_LIMIT {
            bail!(
                "skin {} did not come up within {} s: not running: {}; see the messages above",
                config.skin,
                STARTUP_LIMIT.as_secs(),
                missing.join(", ")
            );
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    tracing::debug!(?missing, "demo interrupted while starting");
    Ok(())
}

/// What of the skin is not up yet: its geometry, or layers that are not running.
fn not_running(dir: &Path, skin: &str) -> Vec<String> {
    let Ok(geometry) = SkinGeometry::open_in(dir, skin) else {
        return vec!["the geometry".to_owned()];
    };
    let channels = skinware::list_skin_channels(dir, skin).unwrap_or_default();
    geometry
        .layers
        .iter()
        .filter(|layer| {
            !channels.iter().any(|c| c.skin == skin && c.channel == layer.name && c.state == WriterState::Running)
        })
        .map(|layer| format!("layer {}", layer.name))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_demo_config_is_the_papers_skin() {
        let path = std::env::temp_dir().join(format!("skin-demo-test-{}.toml", std::process::id()));
        std::fs::write(&path, DEMO_CONFIG).unwrap();
        let config = Config::load(&path);
        let _ = std::fs::remove_file(&path);
        let config = config.unwrap();
        let (layers, _, _) = crate::geometry::inputs(&config).unwrap();
        assert_eq!(layers.len(), 5);
        assert_eq!(layers.iter().map(|l| l.sensors.len()).sum::<usize>(), 30_848);
    }
}
