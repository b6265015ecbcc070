//! `skin bench paper`: the paper's performance test (Section IV.B, Fig. 6).

use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use skinware::Stop;
use skinware_drivers::{Rate, VirtualSkin, VirtualSkinConfig};

use crate::app::AppSamples;
use crate::measure::{self, Percentiles};
use crate::run_options::RunOptions;

pub use crate::paper_record::PaperRecord;

/// Options of `skin bench paper`.
#[derive(Clone, Debug)]
pub struct PaperOptions {
    /// Quick: layers {1, 3, 5} x apps {1, 5, 15}, 1 s each (else 4 s per
    /// configuration and round); `paper.json` and `paper.png` go to `out`;
    /// `exe` is run again for the application processes.
    pub run: RunOptions,
    /// Times the whole grid of configurations is run (default 1 quick, 3
    /// full). Rounds are interleaved and each configuration's samples pooled
    /// over them, so that a slow drift of a shared machine's load does not
    /// fall on one configuration.
    pub rounds: Option<u32>,
}

/// Runs the experiment, prints a table, writes `paper.json` and `paper.png`.
pub fn run(options: &PaperOptions) -> Result<Vec<PaperRecord>> {
    let layer_counts: Vec<usize> = if options.run.quick { vec![1, 3, 5] } else { (1..=5).collect() };
    let app_counts: Vec<usize> = if options.run.quick { vec![1, 5, 15] } else { (1..=15).collect() };
    let seconds = options.run.seconds_or(1.0, 4.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    let rounds = options.rounds.unwrap_or(if options.run.quick { 1 } else { 3 });
    if rounds == 0 {
        bail!("--rounds must be at least 1");
    }
    std::fs::create_dir_all(&options.run.out)
        .with_context(|| format!("cannot create {}", options.run.out.display()))?;
    let work = options.run.out.join("paper-work");
    std::fs::create_dir_all(&work)?;
    let total = (layer_counts.len() * app_counts.len()) as u64 * u64::from(rounds);
    let progress = indicatif::ProgressBar::new(total).with_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {pos}/{len} configurations, {elapsed} elapsed, ~{eta} left  {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let configurations: Vec<(usize, usize)> =
        layer_counts.iter().flat_map(|&layers| app_counts.iter().map(move |&apps| (layers, apps))).collect();
    let mut pooled: Vec<Samples> = configurations.iter().map(|_| Samples::default()).collect();
    for round in 1..=rounds {
        for (&(layers, apps), pool) in configurations.iter().zip(&mut pooled) {
            progress.set_message(format!("round {round}/{rounds}: {layers} layer(s), {apps} app(s)"));
            let samples = run_one(options, &work, layers, apps, seconds)?;
            pool.writer_ns.extend(samples.writer_ns);
            pool.reader_ns.extend(samples.reader_ns);
            pool.writer_rates_hz = samples.writer_rates_hz;
            progress.inc(1);
        }
    }
    progress.finish_and_clear();
    let records: Vec<PaperRecord> = configurations
        .iter()
        .zip(pooled)
        .map(|(&(layers, apps), mut pool)| PaperRecord {
            layers,
            apps,
            writer_ns: Percentiles::of(&mut pool.writer_ns),
            reader_ns: Percentiles::of(&mut pool.reader_ns),
            writer_rates_hz: pool.writer_rates_hz,
        })
        .collect();
    let _ = std::fs::remove_dir_all(&work);

    println!(
        "skin bench paper: 30,848 sensors, writers at random 30-50 Hz, apps reading every layer at random 10-100 Hz"
    );
    println!("{rounds} round(s) of {seconds} s per configuration; times in microseconds\n");
    println!(
        "{:>6} {:>4} | {:>8} {:>8} {:>8} {:>8} | {:>8} {:>8} {:>8} {:>8}",
        "layers", "apps", "wr p50", "wr p99", "wr p99.9", "wr max", "rd p50", "rd p99", "rd p99.9", "rd max"
    );
    let us = |ns: u64| ns as f64 / 1e3;
    for r in &records {
        println!(
            "{:>6} {:>4} | {:>8.1} {:>8.1} {:>8.1} {:>8.1} | {:>8.1} {:>8.1} {:>8.1} {:>8.1}",
            r.layers,
            r.apps,
            us(r.writer_ns.p50),
            us(r.writer_ns.p99),
            us(r.writer_ns.p999),
            us(r.writer_ns.max),
            us(r.reader_ns.p50),
            us(r.reader_ns.p99),
            us(r.reader_ns.p999),
            us(r.reader_ns.max)
        );
    }
    let json = options.run.out.join("paper.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&records)?)?;
    let png = options.run.out.join("paper.png");
    crate::plot::fig6(&records, &png)?;
    println!("\nwrote {} and {}", json.display(), png.display());
    Ok(records)
}

/// One run of one configuration.
#[derive(Default)]
struct Samples {
    writer_ns: Vec<u64>,
    reader_ns: Vec<u64>,
    writer_rates_hz: Vec<f64>,
}

fn run_one(options: &PaperOptions, work: &Path, layers: usize, apps: usize, seconds: f64) -> Result<Samples> {
    let skin = format!("bench{}L{layers}A{apps}", std::process::id());
    let config = VirtualSkinConfig {
        layers,
        rate: Rate::Random { random: [30.0, 50.0] },
        seed: 2013 + layers as u64,
        ..VirtualSkinConfig::default()
    };
    let skin_model = VirtualSkin::new(config).map_err(|e| anyhow::anyhow!(e))?;
    let topologies: Vec<_> = skinware::Driver::layers(&skin_model).into_iter().map(|spec| spec.topology).collect();
    let names: Vec<String> = topologies.iter().map(|t| t.name.clone()).collect();
    let stop = Stop::new();
    let writers = measure::run_writers(&skin, &topologies, &stop, None)?;
    let mut children = Vec::new();
    for app in 0..apps {
        let out = work.join(format!("{skin}-app{app}.json"));
        let child = measure::spawn_app(&options.run.exe, &skin, &names, "periodic", seconds, app as u64 + 1, &out)?;
        children.push((child, out));
    }
    let mut reader_samples = Vec::new();
    let mut windows = Vec::new();
    let mut failure = None;
    for (mut child, out) in children {
        let status = child.wait()?;
        if !status.success() {
            failure.get_or_insert_with(|| format!("an application process failed ({status})"));
            continue;
        }
        let samples: AppSamples = serde_json::from_slice(&std::fs::read(&out)?)?;
        reader_samples.extend(samples.read_ns.into_iter().flatten());
        windows.push(samples.window_ns);
    }
    // Let the writers run a little past the last reader, then stop them.
    std::thread::sleep(Duration::from_millis(50));
    stop.stop();
    let mut writer_samples = Vec::new();
    for writer in writers {
        writer_samples.extend(writer.join().map_err(|_| anyhow::anyhow!("writer thread panicked"))?);
    }
    if let Some(failure) = failure {
        bail!("{failure} in configuration {layers} layers x {apps} apps");
    }
    let writer_samples = measure::steady_state(&writer_samples, &windows)
        .with_context(|| format!("configuration {layers} layers x {apps} apps"))?;
    Ok(Samples {
        writer_ns: writer_samples,
        reader_ns: reader_samples,
        writer_rates_hz: topologies.iter().map(|t| t.rate_hz).collect(),
    })
}
