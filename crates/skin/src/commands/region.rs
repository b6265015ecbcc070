//! `skin region record NAME`: define a region by touching it. The modules
//! touched while it runs are written into the config as a `[[region]]`.

use std::collections::BTreeSet;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use skinware::Reader;

use skin::config::Config;

/// `skin region` subcommands.
#[derive(clap::Subcommand)]
pub enum Which {
    /// Record the modules touched until Ctrl-C (or --seconds) and add them to
    /// CONFIG as region NAME. Keep hands off during the first second: it
    /// measures each sensor's baseline and noise.
    Record(RecordArgs),
}

/// Arguments of `skin region record`.
#[derive(clap::Args)]
pub struct RecordArgs {
    /// The new region's name.
    name: String,
    /// The config the skin runs from; the region is appended to it.
    #[arg(long)]
    config: PathBuf,
    /// Stop after this many seconds instead of on Ctrl-C.
    #[arg(long)]
    seconds: Option<f64>,
    /// A sensor counts as touched this far above its baseline, in response
    /// units; 0 derives it from the measured noise (10 sigma, at least 100).
    #[arg(long, default_value_t = 0.0)]
    threshold: f64,
    /// Seconds of baseline measurement.
    #[arg(long, default_value_t = 1.0)]
    baseline_seconds: f64,
}

/// Runs a `skin region` subcommand.
pub fn run(which: &Which) -> Result<()> {
    match which {
        Which::Record(args) => record(args),
    }
}

struct LayerWatch {
    name: String,
    reader: Reader,
    topology: skinware::LayerTopology,
    /// Per sensor: (count, mean, M2) while measuring, then the threshold level.
    stats: Vec<(f64, f64, f64)>,
    level: Vec<f64>,
}

fn record(args: &RecordArgs) -> Result<()> {
    let config = Config::load(&args.config)?;
    check_new_region_name(&config, args)?;
    let mut layers = watch_layers(&config, args)?;
    let stop = super::run::shutdown_on_signals()?;
    eprintln!("measuring the baseline for {:.1} s: do not touch the skin", args.baseline_seconds);
    measure_baseline(&mut layers, args.baseline_seconds, &stop);
    for layer in &mut layers {
        layer.set_levels(args.threshold);
    }
    for layer in &layers {
        if layer.stats.iter().all(|&(count, _, _)| count == 0.0) {
            eprintln!("layer {} delivered no frame during the baseline; it is left out", layer.name);
        }
    }
    match args.seconds {
        Some(s) => eprintln!("recording region {:?} for {s} s: touch it now", args.name),
        None => eprintln!("recording region {:?}: touch it now, Ctrl-C when done", args.name),
    }
    let touched = record_touches(&mut layers, args.seconds, &stop);
    if touched.is_empty() {
        bail!("no module was touched; region {:?} not written", args.name);
    }
    append_to_config(&args.config, &region_block(&args.name, &layers, &touched))?;
    println!("region {:?}: {} modules written to {}", args.name, touched.len(), args.config.display());
    Ok(())
}

/// Refuses a name the config already has, or one with characters other than
/// A-Z a-z 0-9 _ -.
fn check_new_region_name(config: &Config, args: &RecordArgs) -> Result<()> {
    if config.regions.iter().any(|r| r.name == args.name) {
        bail!("{}: region {:?} already exists; remove it or pick another name", args.config.display(), args.name);
    }
    if args.name.is_empty() || !args.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
        bail!("region name {:?}: use A-Z a-z 0-9 _ -", args.name);
    }
    Ok(())
}

/// A reader on every layer of every driver of `config`; the skin must be running.
fn watch_layers(config: &Config, args: &RecordArgs) -> Result<Vec<LayerWatch>> {
    let mut layers = Vec::new();
    for driver in &config.drivers {
        for spec in driver.build(&config.skin)?.layers() {
            let name = spec.topology.name.clone();
            let reader = Reader::open(&config.skin, &name)
                .with_context(|| format!("layer {name}: is `skin run {}` running?", args.config.display()))?;
            let n = spec.topology.sensors.len();
            layers.push(LayerWatch {
                name,
                reader,
                topology: spec.topology,
                stats: vec![(0.0, 0.0, 0.0); n],
                level: vec![f64::INFINITY; n],
            });
        }
    }
    Ok(layers)
}

/// Accumulates every sensor's mean and variance for `seconds` (or until `stop`).
fn measure_baseline(layers: &mut [LayerWatch], seconds: f64, stop: &AtomicBool) {
    let started = Instant::now();
    while started.elapsed().as_secs_f64() < seconds && !stop.load(Ordering::Relaxed) {
        for layer in layers.iter_mut() {
            if let Ok(frame) = layer.reader.latest() {
                for (s, &r) in layer.stats.iter_mut().zip(frame.responses()) {
                    // Welford's running mean and variance.
                    s.0 += 1.0;
                    let delta = f64::from(r) - s.1;
                    s.1 += delta / s.0;
                    s.2 += delta * (f64::from(r) - s.1);
                }
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

impl LayerWatch {
    /// Sets each measured sensor's touch level: its baseline mean plus
    /// `threshold`, or plus 10 sigma (at least 100) when `threshold` is 0.
    fn set_levels(&mut self, threshold: f64) {
        for (level, &(count, mean, m2)) in self.level.iter_mut().zip(&self.stats) {
            if count == 0.0 {
                // No frame during the baseline: this layer cannot be judged.
                continue;
            }
            let sigma = if count > 1.0 { (m2 / (count - 1.0)).sqrt() } else { 0.0 };
            let threshold = if threshold > 0.0 { threshold } else { (10.0 * sigma).max(100.0) };
            *level = mean + threshold;
        }
    }
}

/// The modules, as (layer index, module id), whose sensors rose above their
/// level before `seconds` passed (or `stop` was set); each is announced once.
fn record_touches(layers: &mut [LayerWatch], seconds: Option<f64>, stop: &AtomicBool) -> BTreeSet<(usize, u32)> {
    let mut touched: BTreeSet<(usize, u32)> = BTreeSet::new();
    let deadline = seconds.map(|s| Instant::now() + Duration::from_secs_f64(s.clamp(0.0, 86_400.0)));
    while !stop.load(Ordering::Relaxed) && deadline.is_none_or(|d| Instant::now() < d) {
        for (l, layer) in layers.iter_mut().enumerate() {
            let Ok(frame) = layer.reader.latest() else { continue };
            if frame.status().is_fault() {
                continue;
            }
            for (k, (&r, &level)) in frame.responses().iter().zip(&layer.level).enumerate() {
                if f64::from(r) > level {
                    let module = layer.topology.modules[layer.topology.sensors[k].module].id;
                    if touched.insert((l, module)) {
                        eprintln!("  touched {} module {module}", layer.name);
                    }
                }
            }
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    touched
}

/// The `[[region]]` table, with one `[[region.in_layer]]` per touched layer.
fn region_block(name: &str, layers: &[LayerWatch], touched: &BTreeSet<(usize, u32)>) -> String {
    let mut block = format!(
        "\n# Recorded by `skin region record` on {} modules.\n[[region]]\nname = \"{}\"\n",
        touched.len(),
        name
    );
    for (l, layer) in layers.iter().enumerate() {
        let modules: Vec<String> = touched.iter().filter(|(tl, _)| *tl == l).map(|(_, m)| m.to_string()).collect();
        if !modules.is_empty() {
            block.push_str(&format!(
                "[[region.in_layer]]\nlayer = \"{}\"\nmodules = [{}]\n",
                layer.name,
                modules.join(", ")
            ));
        }
    }
    block
}

/// Appends `block` to the config at `path`, and puts the file back as it was
/// if the config no longer loads.
fn append_to_config(path: &Path, block: &str) -> Result<()> {
    let original = skinware::shm::read_named_text(path, 16 << 20)?;
    let mut file = std::fs::OpenOptions::new().append(true).open(path)?;
    file.write_all(block.as_bytes())?;
    drop(file);
    if let Err(e) = Config::load(path) {
        std::fs::write(path, original)?;
        bail!(
            "the recorded region made the config invalid, so it was not kept: {}",
            skin::report::causes_once(e.as_ref())
        );
    }
    Ok(())
}
