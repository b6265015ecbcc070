//! One configuration of `skin bench peers`: a real-time writer thread
//! publishing frames through one system, and the reader processes receiving
//! them.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use skinware::{RtOptions, Stop, Ticker, Writer, WriterOptions};

use super::setup::{FRAME_BYTES, PeerReaderSamples, RATE_HZ, SENSORS};
use crate::measure::Percentiles;
use crate::run_options::RunOptions;
use crate::rwlock_peer::RwLockChannel;

pub(super) fn run_one(
    options: &RunOptions,
    system: &str,
    readers: usize,
    seconds: f64,
) -> Result<(Percentiles, Percentiles, Percentiles, usize)> {
    run_mode(options, system, readers, seconds, "wait")
}

/// Runs one configuration; readers `wait` for each frame or read `busy`
/// back to back. Returns (publish, latency, copy, frames or reads received).
pub(super) fn run_mode(
    options: &RunOptions,
    system: &str,
    readers: usize,
    seconds: f64,
    mode: &str,
) -> Result<(Percentiles, Percentiles, Percentiles, usize)> {
    let name = format!("peers{}{system}{readers}{mode}", std::process::id());
    let dir = skinware::shm::segment_dir();
    let stop = Stop::new();
    let period = Duration::from_secs_f64(1.0 / RATE_HZ);
    let frame: Vec<u16> = (0..SENSORS).map(|i| (i % 4096) as u16).collect();
    let work = options.out.join("peers-work");
    std::fs::create_dir_all(&work)?;

    // The writer thread creates the channel (iceoryx2's ports cannot move
    // between threads), says it is ready, waits for the readers to attach,
    // then publishes in real time until stopped. Running it in its own thread
    // also keeps SCHED_FIFO away from this thread, whose children inherit it.
    let bytes: Vec<u8> = frame.iter().flat_map(|value| value.to_ne_bytes()).collect();
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<()>>();
    let (go_tx, go_rx) = std::sync::mpsc::channel::<()>();
    let mut children = Vec::new();
    let publish = std::thread::scope(|scope| -> Result<Vec<u64>> {
        let (ready_tx, go_rx) = (ready_tx, go_rx);
        let (stop, frame, bytes, name) = (&stop, &frame, &bytes, &name);
        let writer = scope.spawn(move || -> Result<Vec<u64>> {
            let mut side = match Side::create(system, name, &dir, period) {
                Ok(side) => {
                    let _ = ready_tx.send(Ok(()));
                    side
                }
                Err(error) => {
                    let _ = ready_tx.send(Err(error));
                    return Ok(Vec::new());
                }
            };
            if go_rx.recv().is_err() {
                return Ok(Vec::new());
            }
            publish_frames(&mut side, period, seconds, stop, frame, bytes)
        });
        ready_rx.recv().map_err(|_| anyhow::anyhow!("the writer thread ended early"))??;
        children = spawn_readers(&options.exe, &work, system, name, mode, readers, seconds)?;
        // Give every reader time to attach and start waiting.
        std::thread::sleep(Duration::from_millis(300));
        let _ = go_tx.send(());
        std::thread::sleep(Duration::from_secs_f64(seconds));
        stop.stop();
        writer.join().map_err(|_| anyhow::anyhow!("the writer thread panicked"))?
    })?;
    let mut publish = publish;
    let (mut latency, mut copy, frames) = collect_readers(children, system, mode)?;
    Ok((Percentiles::of(&mut publish), Percentiles::of(&mut latency), Percentiles::of(&mut copy), frames))
}

/// The writer's end of the system under test.
enum Side {
    Skinware(Box<Writer>),
    RwLock(RwLockChannel),
    #[cfg(feature = "iceoryx2")]
    Iceoryx2(Box<crate::iceoryx2_peer::IceoryxWriter>),
}

impl Side {
    /// Creates the writer's end of channel `name` of `system` (rwlock's
    /// segment in `dir`).
    fn create(system: &str, name: &str, dir: &Path, period: Duration) -> Result<Side> {
        Ok(match system {
            "skinware" | "skinware-spin" => {
                let options = WriterOptions { period: Some(period), ..WriterOptions::default() };
                Side::Skinware(Box::new(Writer::create(name, "frame", FRAME_BYTES, b"peers", &options)?))
            }
            #[cfg(feature = "iceoryx2")]
            "iceoryx2" => Side::Iceoryx2(Box::new(crate::iceoryx2_peer::IceoryxWriter::create(name, SENSORS)?)),
            _ => Side::RwLock(RwLockChannel::create(&dir.join(format!("skinware-bench-rwlock.{name}")), FRAME_BYTES)?),
        })
    }
}

/// Publishes `frame` (as `bytes` for rwlock) once a period, in real time,
/// until stopped. Returns each publication's cost, ns.
fn publish_frames(
    side: &mut Side,
    period: Duration,
    seconds: f64,
    stop: &Stop,
    frame: &[u16],
    bytes: &[u8],
) -> Result<Vec<u64>> {
    let _ = RtOptions { fifo_priority: Some(80), ..RtOptions::default() }.apply();
    let mut publish = Vec::with_capacity((RATE_HZ * seconds) as usize + 16);
    let mut ticker = Ticker::new(period);
    while ticker.wait(stop).is_some() {
        let started = skinware::os::monotonic_ns();
        match side {
            Side::Skinware(writer) => {
                let mut guard = writer.begin();
                guard.write_responses(0, frame)?;
                guard.publish();
            }
            Side::RwLock(channel) => {
                channel.publish(bytes)?;
            }
            #[cfg(feature = "iceoryx2")]
            Side::Iceoryx2(writer) => writer.publish(frame)?,
        }
        publish.push(skinware::os::monotonic_ns() - started);
    }
    Ok(publish)
}

/// Starts the reader processes of one configuration; each writes its samples
/// to a file in `work`.
pub(crate) fn spawn_readers(
    exe: &Path,
    work: &Path,
    system: &str,
    name: &str,
    mode: &str,
    readers: usize,
    seconds: f64,
) -> Result<Vec<(Child, PathBuf)>> {
    let mut children = Vec::new();
    for reader in 0..readers {
        let out = work.join(format!("{name}-{reader}.json"));
        let child = Command::new(exe)
            .args(["bench-peer-reader", "--system", system, "--name", name, "--mode", mode])
            .args(["--seconds", &(seconds + 30.0).to_string()])
            .arg("--out")
            .arg(&out)
            .stdin(std::process::Stdio::piped())
            .spawn()
            .context("cannot start a peer reader process")?;
        children.push((child, out));
    }
    Ok(children)
}

/// Stops the reader processes and pools their samples. Returns (latency,
/// copy, frames or reads received).
pub(crate) fn collect_readers(
    mut children: Vec<(Child, PathBuf)>,
    system: &str,
    mode: &str,
) -> Result<(Vec<u64>, Vec<u64>, usize)> {
    let mut latency = Vec::new();
    let mut copy = Vec::new();
    let mut busy_reads = 0;
    // Readers stop when their stdin closes: all of them overlap the whole
    // publishing window, however the scheduler ran them.
    for (child, _) in children.iter_mut() {
        drop(child.stdin.take());
    }
    for (mut child, out) in children {
        let status = child.wait()?;
        if !status.success() {
            bail!("a {system} reader process failed ({status})");
        }
        let samples: PeerReaderSamples = serde_json::from_slice(&std::fs::read(&out)?)?;
        latency.extend(samples.latency_ns);
        copy.extend(samples.copy_ns);
        busy_reads += samples.reads;
        let _ = std::fs::remove_file(&out);
    }
    let frames = if mode == "busy" { busy_reads } else { latency.len() };
    Ok((latency, copy, frames))
}
