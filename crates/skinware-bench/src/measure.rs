//! Sample statistics and the writer side of the experiments.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::Duration;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use skinware::{LayerTopology, RtOptions, Stop, Ticker, Writer, WriterOptions};

/// Percentiles of a set of durations, ns.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq)]
pub struct Percentiles {
    /// Median.
    pub p50: u64,
    /// 99th percentile.
    pub p99: u64,
    /// 99.9th percentile.
    pub p999: u64,
    /// Worst case.
    pub max: u64,
    /// Mean.
    pub avg: f64,
    /// Standard deviation.
    pub std: f64,
    /// Number of samples.
    pub samples: usize,
}

impl Percentiles {
    /// Computes the statistics of `samples` (sorted in place).
    pub fn of(samples: &mut [u64]) -> Percentiles {
        if samples.is_empty() {
            return Percentiles::default();
        }
        samples.sort_unstable();
        let at = |q: f64| samples[((q * samples.len() as f64).ceil() as usize).clamp(1, samples.len()) - 1];
        let n = samples.len() as f64;
        let avg = samples.iter().map(|&s| s as f64).sum::<f64>() / n;
        let var = samples.iter().map(|&s| (s as f64 - avg).powi(2)).sum::<f64>() / n;
        Percentiles {
            p50: at(0.5),
            p99: at(0.99),
            p999: at(0.999),
            max: samples[samples.len() - 1],
            avg,
            std: var.sqrt(),
            samples: samples.len(),
        }
    }
}

/// The frames a writer published between two readings of its statistics,
/// and their mean write time, ns: from the statistics' running mean (over
/// every frame so far) and frame count at both ends.
pub fn write_ns_between(before: &skinware::WriterStats, after: &skinware::WriterStats) -> (u64, u64) {
    let frames = after.frames.saturating_sub(before.frames);
    let total = |s: &skinware::WriterStats| u128::from(s.write_ns_mean) * u128::from(s.frames);
    let mean = total(after).saturating_sub(total(before)) / u128::from(frames.max(1));
    (frames, u64::try_from(mean).unwrap_or(u64::MAX))
}

/// One timed frame of a writer.
#[derive(Clone, Copy, Debug)]
pub struct WriterSample {
    /// When `begin` was called (CLOCK_MONOTONIC, comparable across processes), ns.
    pub started_ns: u64,
    /// From `begin` to the end of `publish`, ns.
    pub took_ns: u64,
}

/// The writers' times of the frames begun while every application process
/// was up and reading: the start-up and exit of the processes themselves
/// (exec, page faults, TLB shootdowns) are not what the experiment measures.
///
/// Fails, naming the fix, if the applications never all ran at once.
pub fn steady_state(samples: &[WriterSample], windows: &[[u64; 2]]) -> Result<Vec<u64>> {
    let from = windows.iter().map(|w| w[0]).max().unwrap_or(0);
    let to = windows.iter().map(|w| w[1]).min().unwrap_or(u64::MAX);
    if from >= to {
        anyhow::bail!(
            "the {} application processes never all ran at the same time (they took too long to start); \
             give each configuration more time with --seconds",
            windows.len()
        );
    }
    Ok(samples.iter().filter(|s| (from..to).contains(&s.started_ns)).map(|s| s.took_ns).collect())
}

/// Runs one writer thread per layer until `stop`, each at its layer's rate,
/// filling every frame from a driver-side buffer (as a driver copies from its
/// bus) and timing `begin` to `publish`. Returns each layer's samples.
pub fn run_writers(
    skin: &str,
    layers: &[LayerTopology],
    stop: &Stop,
    dir: Option<PathBuf>,
) -> Result<Vec<std::thread::JoinHandle<Vec<WriterSample>>>> {
    let mut threads = Vec::new();
    for topology in layers {
        let period = Duration::from_secs_f64(1.0 / topology.rate_hz);
        let options = WriterOptions { period: Some(period), dir: dir.clone(), ..WriterOptions::default() };
        let mut writer = Writer::create(skin, &topology.name, topology.frame_bytes(), &topology.encode(), &options)
            .with_context(|| format!("creating layer {}", topology.name))?;
        writer.set_stop(stop);
        let sensors = topology.sensors.len();
        threads.push(std::thread::spawn(move || {
            let _ = RtOptions { fifo_priority: Some(80), ..RtOptions::default() }.apply();
            let mut bus: Vec<u16> = (0..sensors).map(|i| (i % 4096) as u16).collect();
            let mut samples = Vec::with_capacity(4096);
            let mut ticker = Ticker::new(period);
            let stop = writer.stop_signal().clone();
            while ticker.wait(&stop).is_some() {
                bus.iter_mut().for_each(|r| *r = r.wrapping_add(1));
                let started = skinware::os::monotonic_ns();
                let mut frame = writer.begin();
                if frame.write_responses(0, &bus).is_ok() {
                    frame.publish();
                }
                samples.push(WriterSample { started_ns: started, took_ns: skinware::os::monotonic_ns() - started });
            }
            samples
        }));
    }
    Ok(threads)
}

/// Starts one application process: `exe bench-app ...`.
pub fn spawn_app(
    exe: &Path,
    skin: &str,
    layers: &[String],
    mode: &str,
    seconds: f64,
    seed: u64,
    out: &Path,
) -> Result<Child> {
    Command::new(exe)
        .arg("bench-app")
        .args(["--skin", skin, "--layers", &layers.join(","), "--mode", mode])
        .args(["--seconds", &seconds.to_string(), "--seed", &seed.to_string()])
        .arg("--out")
        .arg(out)
        .spawn()
        .with_context(|| format!("cannot start application process {}", exe.display()))
}

/// A `skin run` a benchmark started, with its channels in `dir`: stopped
/// with SIGINT (as Ctrl-C would) when dropped, killed if it has not exited
/// 10 s later.
pub struct RunningSkin(Child);

impl RunningSkin {
    /// Starts `exe run config` with its channels in `dir`.
    pub fn start(exe: &Path, config: &Path, dir: &Path) -> Result<RunningSkin> {
        let child = Command::new(exe)
            .arg("run")
            .arg(config)
            .env("SKINWARE_SHM_DIR", dir)
            .env("RUST_LOG", "warn")
            .stdout(std::process::Stdio::null())
            .spawn()
            .context("cannot start `skin run`")?;
        Ok(RunningSkin(child))
    }

    /// Writes `config_text` to `dir/skin.toml`, starts `exe run` on it with
    /// its channels in `dir`, and waits (up to 120 s) until `ready` says the
    /// channels listed are what the bench needs; `what` names the skin in
    /// the error if they never are.
    pub fn start_until(
        exe: &Path,
        config_text: &str,
        dir: &Path,
        what: &str,
        ready: impl Fn(&[skinware::ChannelInfo]) -> bool,
    ) -> Result<RunningSkin> {
        let config = dir.join("skin.toml");
        std::fs::write(&config, config_text)?;
        let skin = RunningSkin::start(exe, &config, dir)?;
        let started = std::time::Instant::now();
        loop {
            if ready(&skinware::list_channels(dir).unwrap_or_default()) {
                return Ok(skin);
            }
            if started.elapsed() > Duration::from_secs(120) {
                anyhow::bail!("{what} did not come up within 120 s");
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Starts `exe run config` with its channels in `dir`, in a process
    /// group of its own (Ctrl-C reaches only its starter, which stops it),
    /// its standard error appended to `log`.
    pub fn start_logged(exe: &Path, config: &Path, dir: &Path, log: &Path) -> Result<RunningSkin> {
        use std::os::unix::process::CommandExt;
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
            .with_context(|| format!("cannot open {}", log.display()))?;
        let child = Command::new(exe)
            .arg("run")
            .arg(config)
            .env("SKINWARE_SHM_DIR", dir)
            .env("RUST_LOG", "info")
            .env("NO_COLOR", "1")
            .stdout(std::process::Stdio::null())
            .stderr(file)
            .process_group(0)
            .spawn()
            .context("cannot start `skin run`")?;
        Ok(RunningSkin(child))
    }

    /// The process id of `skin run`.
    pub fn pid(&self) -> u32 {
        self.0.id()
    }

    /// Its exit status, if it has exited.
    pub fn try_wait(&mut self) -> Option<std::process::ExitStatus> {
        self.0.try_wait().ok().flatten()
    }

    /// Stops it with SIGINT (as Ctrl-C would) and waits up to `patience`
    /// for it to stop its children and remove its channels; fails if it had
    /// to be killed or exited with a failure.
    pub fn stop(mut self, patience: Duration) -> Result<()> {
        let _ = Command::new("kill").args(["-INT", &self.0.id().to_string()]).status();
        let deadline = std::time::Instant::now() + patience;
        loop {
            if let Ok(Some(status)) = self.0.try_wait() {
                return if status.success() { Ok(()) } else { Err(anyhow::anyhow!("`skin run` exited with {status}")) };
            }
            if std::time::Instant::now() > deadline {
                let _ = self.0.kill();
                anyhow::bail!("`skin run` did not stop within {} s of SIGINT; killed", patience.as_secs());
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for RunningSkin {
    fn drop(&mut self) {
        if let Ok(Some(_)) = self.0.try_wait() {
            return;
        }
        let _ = Command::new("kill").args(["-INT", &self.0.id().to_string()]).status();
        let deadline = std::time::Instant::now() + Duration::from_secs(10);
        while std::time::Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steady_state_keeps_only_frames_begun_while_every_app_ran() {
        let samples: Vec<WriterSample> = (0..10).map(|i| WriterSample { started_ns: i * 100, took_ns: i }).collect();
        let kept = steady_state(&samples, &[[150, 800], [250, 950]]).unwrap();
        assert_eq!(kept, vec![3, 4, 5, 6, 7]);
        let error = steady_state(&samples, &[[100, 300], [400, 900]]).unwrap_err().to_string();
        assert!(error.contains("--seconds"), "{error}");
    }

    #[test]
    fn percentiles_of_known_samples() {
        let mut samples: Vec<u64> = (1..=1000).rev().collect();
        let p = Percentiles::of(&mut samples);
        assert_eq!((p.p50, p.p99, p.p999, p.max, p.samples), (500, 990, 999, 1000, 1000));
        assert!((p.avg - 500.5).abs() < 1e-9);
        assert!((p.std - 288.675).abs() < 0.01);
        assert_eq!(Percentiles::of(&mut []), Percentiles::default());
    }
}
