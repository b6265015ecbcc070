//! `skin bench ethercat`: the EtherCAT driver on its real path, measured.
//! ethercrab's MainDevice on a raw socket at one end of a veth pair, the ESC
//! model of one 708-taxel segment at the other, in a network namespace of
//! the bench's own ([`crate::netns`]); the layer published by the driver
//! handler, as `skin run` does, at 1 kHz.
//!
//! * Cycles: the emulated SubDevice notes the CLOCK_MONOTONIC time at which
//!   it fills each cycle's inputs; from those, the achieved rate, the period
//!   and its jitter (|period − 1 ms|), and the cycles missed.
//! * Latency: the SubDevice writes that time into its first 4 taxels; a
//!   reader in another process (this executable, `bench-ecat-reader`)
//!   waits for each new frame (`wait_newer`, a futex wake), and its copy in
//!   hand, takes now − that time. The span
//!   holds the frame's trip back over the veth pair, ethercrab, the driver's
//!   bus thread, the writer thread's acquisition and publish, and the
//!   reader's wake and copy.
//! * Faults: each of the emulator's fault switches, thrown while the layer
//!   runs: the time from throwing it to the layer's writer state turning
//!   `Faulted` (as a reader sees it), and from its end to a stretch of
//!   `Running` of at least [`STABLE`].

use std::num::NonZeroU64;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::driver::DriverHandler;
use skinware::{HandlerOptions, Reader, ReaderOptions, RtOptions, WriterState};
use skinware_drivers::ethercat::EthercatStatus;
use skinware_emulate::ethercat::{AlState, LeaveOp, Segment, TactileConfig, TactileSubDevice};

use crate::measure::Percentiles;
use crate::netns::{self, EmulatedBus};
use crate::run_options::{RunOptions, parse_helper_seconds};

/// Taxels of the segment: the paper's EtherCAT sensors.
const TAXELS: usize = 708;
/// The bus and the layer, Hz.
const RATE_HZ: f64 = 1000.0;
/// SCHED_FIFO priority of the driver's threads (bus, frame I/O, writer).
const DRIVER_PRIORITY: u8 = 80;
/// … of the emulated SubDevice's thread and of the reader.
const PEER_PRIORITY: u8 = 70;
/// … of the thread that throws the faults and watches the layer's state.
const WATCHER_PRIORITY: u8 = 90;
/// Idle CPUs asked to wake within this many µs (0: they poll).
const CPU_WAKE_LATENCY_US: u32 = 0;
/// Before a fault that takes the bus down (full run), the layer has run at
/// least this long: longer than the driver's 8 s after which its reconnect
/// backoff starts again from 100 ms.
const BUS_SETTLE: Duration = Duration::from_millis(8500);
/// A recovery counts once the layer has been running this long.
pub const STABLE: Duration = Duration::from_millis(50);

/// Arguments of the reader process (`bench-ecat-reader`).
#[derive(Clone, Debug, clap::Args)]
pub struct LatencyReaderArgs {
    /// The channels' directory.
    #[arg(long)]
    pub dir: PathBuf,
    /// How long to read.
    #[arg(long, value_parser = parse_helper_seconds)]
    pub seconds: f64,
    /// Where to write its samples (JSON).
    #[arg(long)]
    pub out: PathBuf,
}

/// What the reader process measured, ns per frame.
#[derive(Debug, Default, Serialize, serde::Deserialize)]
struct ReaderSamples {
    latency: Vec<u64>,
    to_driver: Vec<u64>,
    driver_to_reader: Vec<u64>,
    skipped: u64,
}

/// The reader process: waits for each new frame of the bench's layer,
/// copies it and takes now − the SubDevice's time in its first 4 taxels.
pub fn run_latency_reader(args: &LatencyReaderArgs) -> Result<()> {
    for refused in (RtOptions { fifo_priority: Some(PEER_PRIORITY), ..RtOptions::default() }).apply() {
        eprintln!("warning: reader: {refused}");
    }
    let mut reader =
        Reader::open_with("bench-ecat", "skin", &ReaderOptions { dir: Some(args.dir.clone()), ..Default::default() })
            .context("the reader process cannot open the layer")?;
    let capacity = (args.seconds * RATE_HZ * 1.2) as usize;
    let mut samples = ReaderSamples {
        latency: Vec::with_capacity(capacity),
        to_driver: Vec::with_capacity(capacity),
        driver_to_reader: Vec::with_capacity(capacity),
        skipped: 0,
    };
    let deadline = Instant::now() + Duration::from_secs_f64(args.seconds);
    while Instant::now() < deadline {
        let frame = match reader.wait_newer(Duration::from_millis(100)) {
            Ok(frame) => frame,
            // The bench that runs the writer died (a signal, a crash): stop
            // now rather than at the end of `--seconds`.
            Err(skinware::Error::WriterGone { .. }) => bail!("the bench's EtherCAT layer is gone"),
            Err(_) => continue,
        };
        let copied = skinware::os::monotonic_ns();
        samples.skipped += frame.skipped();
        let stamped = stamp_of(frame.responses());
        let received = frame.acquired_ns();
        if stamped != 0 && stamped <= received && received <= copied {
            samples.latency.push(copied - stamped);
            samples.to_driver.push(received - stamped);
            samples.driver_to_reader.push(copied - received);
        }
    }
    std::fs::write(&args.out, serde_json::to_vec(&samples)?).with_context(|| format!("writing {}", args.out.display()))
}

/// The bus cycles, as the SubDevice saw them.
#[derive(Debug, Serialize)]
pub struct CycleReport {
    /// Cycles seen.
    pub cycles: usize,
    /// Cycles per second achieved.
    pub achieved_hz: f64,
    /// From one cycle's inputs to the next's, ns.
    pub period_ns: Percentiles,
    /// |period − 1 ms|, ns.
    pub jitter_ns: Percentiles,
    /// Slots of the 1 ms schedule, from the first cycle to the last, with
    /// no cycle in them (the driver skips a cycle it is too late for).
    pub missed_cycles: u64,
    /// Periods longer than 1.5 ms (a late cycle; the next one keeps to the
    /// schedule, so a late cycle need not be a missed one).
    pub late_periods: usize,
    /// Frames the layer's writer published per second.
    pub layer_frames_per_s: f64,
}

/// The SubDevice's inputs to a reader's copy.
#[derive(Debug, Serialize)]
pub struct LatencyReport {
    /// Who reads: another process, waiting on the futex.
    pub reader: &'static str,
    /// The SubDevice's filling of a cycle's inputs to the reader holding
    /// the frame's copy, ns.
    pub latency_ns: Percentiles,
    /// Its first part: the SubDevice's filling of the inputs to the driver's
    /// bus thread having the answer (the frame's `acquired_ns`): the veth
    /// pair, the raw sockets and ethercrab, ns.
    pub to_driver_ns: Percentiles,
    /// Its second part: from there to the reader's copy: the wait for the
    /// layer writer's next tick (the writer and the bus both run at 1 kHz,
    /// not in step: 0 to 1 period, nearly fixed within a run), its
    /// acquisition and publish, and the reader's wake and copy, ns.
    pub driver_to_reader_ns: Percentiles,
    /// Frames the reader missed.
    pub skipped: u64,
}

/// One fault's detection and recovery.
#[derive(Debug, Serialize)]
pub struct FaultReport {
    /// The fault.
    pub fault: &'static str,
    /// How it was thrown and ended.
    pub how: &'static str,
    /// Whether recovery counts from the detection (a fault the SubDevice
    /// ends itself once the driver repairs it) rather than from its end.
    pub recovery_from_detection: bool,
    /// Each repetition: throwing it to the layer faulted, ms.
    pub detect_ms: Vec<f64>,
    /// Each repetition: its end to a stretch of running, ms.
    pub recover_ms: Vec<f64>,
    /// Each repetition: how long the layer had been running before the
    /// fault was thrown, ms.
    pub up_before_ms: Vec<f64>,
    /// Repetitions in which the layer never turned faulted (within 5 s).
    pub undetected: u32,
    /// Repetitions in which it never ran again (within 20 s).
    pub unrecovered: u32,
}

/// What `skin bench ethercat` measured.
#[derive(Debug, Serialize)]
pub struct EthercatReport {
    /// Taxels of the segment.
    pub taxels: usize,
    /// The bus and layer rate asked for, Hz.
    pub rate_hz: f64,
    /// Seconds of cycles measured.
    pub seconds: f64,
    /// The driver's threads' SCHED_FIFO priority asked for.
    pub fifo_priority: u8,
    /// What the system refused of the real-time settings.
    pub rt_refused: Vec<String>,
    /// The CPU wake latency asked for, µs.
    pub requested_cpu_wake_latency_us: Option<u32>,
    /// The CPU wake latency this process held, µs.
    pub cpu_wake_latency_us: Option<u32>,
    /// How long a frame may take before it counts as lost, ms.
    pub frame_timeout_ms: f64,
    /// The cycles.
    pub cycles: CycleReport,
    /// The latency to a reader.
    pub latency: LatencyReport,
    /// Each fault.
    pub faults: Vec<FaultReport>,
}

/// Times at which the SubDevice filled its inputs, while recording.
#[derive(Default)]
struct Stamps {
    recording: AtomicBool,
    at_ns: Mutex<Vec<u64>>,
}

/// The segment: taxels 0..4 carry the CLOCK_MONOTONIC time (ns, u16 words,
/// low first) at which it filled them; the rest follow the sample number.
fn stamped_segment(stamps: Arc<Stamps>) -> Result<Segment> {
    let source = move |sample: u64, taxels: &mut [u16]| {
        for (k, taxel) in taxels.iter_mut().enumerate().skip(4) {
            *taxel = (sample as u16).wrapping_add(k as u16);
        }
        let now = skinware::os::monotonic_ns();
        for (k, taxel) in taxels.iter_mut().take(4).enumerate() {
            *taxel = (now >> (16 * k)) as u16;
        }
        if stamps.recording.load(Ordering::Relaxed) {
            skinware::lock(&stamps.at_ns).push(now);
        }
    };
    let subdevice = TactileSubDevice::new(TactileConfig::new(TAXELS, 1), source)
        .context("cannot build the emulated EtherCAT segment")?;
    Ok(Segment::new(vec![subdevice]))
}

/// The time a frame's first 4 taxels carry.
fn stamp_of(responses: &[u16]) -> u64 {
    responses.iter().take(4).enumerate().fold(0, |at, (k, &word)| at | u64::from(word) << (16 * k))
}

/// What the applied real-time settings refused, found once on a thread of
/// its own (the wake latency is held for the process's life from here on;
/// the driver's threads apply the rest).
fn refused_rt(rt: &RtOptions) -> Result<Vec<String>> {
    let rt = rt.clone();
    let refused =
        std::thread::spawn(move || rt.apply()).join().map_err(|_| anyhow::anyhow!("probe thread panicked"))?;
    for refused in &refused {
        eprintln!("warning: {refused}");
    }
    Ok(refused)
}

/// Runs the measurement (inside the bench's own network namespace), prints
/// it and writes `ethercat.json`.
pub fn run(options: &RunOptions) -> Result<EthercatReport> {
    let seconds = options.seconds_or(2.0, 30.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    if !netns::inside() {
        bail!("skin bench ethercat runs in a network namespace of its own: start it as `skin bench ethercat`");
    }
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    netns::make_veth_pair()?;
    let rt = RtOptions {
        fifo_priority: Some(DRIVER_PRIORITY),
        cpu_wake_latency_us: Some(CPU_WAKE_LATENCY_US),
        ..RtOptions::default()
    };
    let rt_refused = refused_rt(&rt)?;
    let stamps = Arc::new(Stamps::default());
    let bus = EmulatedBus::start(stamped_segment(stamps.clone())?, Some(PEER_PRIORITY))?;

    let channels = ChannelDir::create(format!("skinware-bench-ecat-{}", std::process::id()))?;
    let dir = channels.0.clone();
    let driver = netns::driver("skin", 1, TAXELS, RATE_HZ, rt)?;
    let status = driver.status_handle();
    let handler = DriverHandler::start(
        "bench-ecat",
        Box::new(driver),
        &HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() },
    )?;
    let bench = Bench { options, seconds, dir: &dir, bus: &bus, status: &status, stamps: &stamps };
    let result = bench.measure(rt_refused);
    handler.stop();
    let served = bus.stop();
    drop(channels);
    // The emulator's own failure is the cause of whatever the bench saw.
    let (report, served) = match (result, served) {
        (Ok(report), Ok(served)) => (report, served),
        (Err(seen), Err(emulator)) => return Err(emulator.context(format!("{seen:#}"))),
        (Err(seen), Ok(_)) => return Err(seen),
        (Ok(_), Err(emulator)) => return Err(emulator),
    };
    print(&report, served.frames, served.answered);
    let json = options.out.join("ethercat.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&report)?)?;
    println!("wrote {}", json.display());
    Ok(report)
}

/// The running bench: the emulated segment, the driver's status and the
/// channel directory.
struct Bench<'a> {
    options: &'a RunOptions,
    seconds: f64,
    dir: &'a PathBuf,
    bus: &'a EmulatedBus,
    status: &'a EthercatStatus,
    stamps: &'a Stamps,
}

impl Bench<'_> {
    /// Waits for the layer to run, then measures cycles, latency and faults.
    fn measure(&self, rt_refused: Vec<String>) -> Result<EthercatReport> {
        let mut watcher = Reader::open_with(
            "bench-ecat",
            "skin",
            &ReaderOptions { dir: Some(self.dir.clone()), ..Default::default() },
        )?;
        if !netns::wait_until(Duration::from_secs(10), || watcher.writer_state() == WriterState::Running) {
            if self.bus.ended() {
                bail!("the emulated EtherCAT segment stopped before the layer ran");
            }
            bail!(
                "the EtherCAT layer was not running 10 s after start: bus {:?}, segments {:?}",
                self.status.bus_fault(),
                self.status.segments()
            );
        }
        std::thread::sleep(Duration::from_millis(500));
        let (cycles, latency) = self.cycles_and_latency(&watcher)?;
        let repetitions = if self.options.quick { 1 } else { 5 };
        let mut faults = Vec::new();
        // Above the driver, so that the polls of the layer's state (every
        // 100 µs) are on time: they take microseconds each.
        let watcher_fifo = skinware::os::set_fifo_priority(WATCHER_PRIORITY).is_ok();
        for fault in &FAULTS {
            faults.push(measure_fault(fault, repetitions, !self.options.quick, self.bus, self.status, &mut watcher)?);
        }
        if watcher_fifo {
            let _ = skinware::os::set_normal_scheduling();
        }
        Ok(EthercatReport {
            taxels: TAXELS,
            rate_hz: RATE_HZ,
            seconds: self.seconds,
            fifo_priority: DRIVER_PRIORITY,
            rt_refused,
            requested_cpu_wake_latency_us: Some(CPU_WAKE_LATENCY_US),
            cpu_wake_latency_us: skinware::rt::held_cpu_wake_latency_us(),
            frame_timeout_ms: (2.0 / RATE_HZ * 1e3).max(10.0),
            cycles,
            latency,
            faults,
        })
    }

    /// Cycles and latency, together: the segment stamps each cycle, and a
    /// reader in another process reads every frame.
    fn cycles_and_latency(&self, watcher: &Reader) -> Result<(CycleReport, LatencyReport)> {
        let (options, seconds, stamps) = (self.options, self.seconds, self.stamps);
        let frames_before = watcher.writer_stats().frames;
        skinware::lock(&stamps.at_ns).reserve((seconds * RATE_HZ * 1.2) as usize);
        stamps.recording.store(true, Ordering::Relaxed);
        let started = Instant::now();
        let samples_file = options.out.join("ethercat-reader.json");
        let status_of_reader = std::process::Command::new(&options.exe)
            .arg("bench-ecat-reader")
            .arg("--dir")
            .arg(self.dir)
            .args(["--seconds", &seconds.to_string()])
            .arg("--out")
            .arg(&samples_file)
            .status()
            .with_context(|| format!("cannot start the reader process {}", options.exe.display()))?;
        if !status_of_reader.success() {
            bail!("the reader process failed ({status_of_reader})");
        }
        let samples: ReaderSamples = serde_json::from_slice(&std::fs::read(&samples_file)?)?;
        let _ = std::fs::remove_file(&samples_file);
        let ReaderSamples { mut latency, mut to_driver, mut driver_to_reader, skipped } = samples;
        stamps.recording.store(false, Ordering::Relaxed);
        let elapsed = started.elapsed().as_secs_f64();
        let layer_frames_per_s = (watcher.writer_stats().frames - frames_before) as f64 / elapsed;
        let at = std::mem::take(&mut *skinware::lock(&stamps.at_ns));
        let latency = LatencyReport {
            reader: "another process (SCHED_FIFO 70), wait_newer (futex wake)",
            latency_ns: Percentiles::of(&mut latency),
            to_driver_ns: Percentiles::of(&mut to_driver),
            driver_to_reader_ns: Percentiles::of(&mut driver_to_reader),
            skipped,
        };
        Ok((cycle_report(&at, layer_frames_per_s), latency))
    }
}

/// (`$SKINWARE_SHM_DIR` or `/dev/shm`), removed however the bench ends.
struct ChannelDir(PathBuf);

impl ChannelDir {
    fn create(name: String) -> Result<ChannelDir> {
        let dir = skinware::shm::segment_dir().join(name);
        std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
        Ok(ChannelDir(dir))
    }
}

impl Drop for ChannelDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The cycles from the SubDevice's times of filling its inputs.
fn cycle_report(at: &[u64], layer_frames_per_s: f64) -> CycleReport {
    let period_ns = (1e9 / RATE_HZ) as u64;
    let mut periods: Vec<u64> = at.windows(2).map(|w| w[1].saturating_sub(w[0])).collect();
    let mut jitter: Vec<u64> = periods.iter().map(|&p| p.abs_diff(period_ns)).collect();
    let late_periods = periods.iter().filter(|&&p| p > period_ns * 3 / 2).count();
    let span = match (at.first(), at.last()) {
        (Some(first), Some(last)) if last > first => (last - first) as f64 / 1e9,
        _ => 0.0,
    };
    let slots = (span * 1e9 / period_ns as f64).round() as u64 + 1;
    let missed = slots.saturating_sub(at.len() as u64);
    CycleReport {
        cycles: at.len(),
        achieved_hz: if span > 0.0 { (at.len() - 1) as f64 / span } else { 0.0 },
        period_ns: Percentiles::of(&mut periods),
        jitter_ns: Percentiles::of(&mut jitter),
        missed_cycles: missed,
        late_periods,
        layer_frames_per_s,
    }
}

/// A fault switch of the emulator (or of the link).
struct Fault {
    name: &'static str,
    how: &'static str,
    throw: fn(&EmulatedBus) -> Result<()>,
    end: fn(&EmulatedBus) -> Result<()>,
    /// The fault ends once detected: the SubDevice left OP on its own, and
    /// it is the driver that brings it back.
    ends_at_detection: bool,
    /// Held until the bus as a whole counts as down (then
    /// [`BUS_FAULT_TAIL`] more), rather than 200 ms from throwing it.
    until_bus_down: bool,
}

/// How long a bus fault is held after the bus counts as down: well before
/// the driver's first reconnect (100 ms after it saw the bus down), so that
/// the reconnect finds the fault over. Ending it at the same moment as the
/// reconnect made the recovery depend on which came first.
const BUS_FAULT_TAIL: Duration = Duration::from_millis(30);

const FAULTS: [Fault; 6] = [
    Fault {
        name: "every 2nd frame lost",
        how: "the segment's drop_every_nth_frame = 2 for 200 ms",
        throw: |bus| {
            bus.lock().faults_mut().drop_every_nth_frame = NonZeroU64::new(2);
            Ok(())
        },
        end: |bus| {
            bus.lock().faults_mut().drop_every_nth_frame = None;
            Ok(())
        },
        ends_at_detection: false,
        until_bus_down: false,
    },
    Fault {
        name: "every 2nd answer 20 ms late",
        how: "the segment's late_every_nth_frame = 2, late_by = 20 ms (past the 10 ms frame timeout) for 200 ms",
        throw: |bus| {
            let mut segment = bus.lock();
            segment.faults_mut().late_by = Duration::from_millis(20);
            segment.faults_mut().late_every_nth_frame = NonZeroU64::new(2);
            Ok(())
        },
        end: |bus| {
            bus.lock().faults_mut().late_every_nth_frame = None;
            Ok(())
        },
        ends_at_detection: false,
        until_bus_down: false,
    },
    Fault {
        name: "wrong working counter",
        how: "the SubDevice's wrong_working_counter for 200 ms",
        throw: |bus| set_subdevice(bus, |f| f.wrong_working_counter = true),
        end: |bus| set_subdevice(bus, |f| f.wrong_working_counter = false),
        ends_at_detection: false,
        until_bus_down: false,
    },
    Fault {
        name: "SubDevice leaves OP",
        how: "leave_op = after 0 cycles (to SAFE-OP with its error flag), cleared as soon as it left OP (it would \
              leave again on every entry into OP); the driver acknowledges the error and asks for OP",
        throw: |bus| {
            set_subdevice(bus, |f| f.leave_op = Some(LeaveOp::AfterCycles(0)))?;
            // Polled every 20 µs at SCHED_FIFO 90 (this thread's priority
            // here): the driver acknowledges within a frame or two, and a
            // switch still set then would take the SubDevice out of OP again
            // (and the driver's next acknowledgement is 100 ms later).
            let started = Instant::now();
            let mut left = false;
            while !left && started.elapsed() < Duration::from_secs(1) {
                let mut segment = bus.lock();
                left = segment.subdevices().first().is_some_and(|s| s.state() != AlState::Op);
                if left && let Some(subdevice) = segment.subdevice_mut(0) {
                    subdevice.faults_mut().leave_op = None;
                }
                drop(segment);
                // Slept on briefly, not spun: a spin at this priority would
                // keep the emulator from the segment's lock.
                std::thread::sleep(Duration::from_micros(20));
            }
            set_subdevice(bus, |f| f.leave_op = None)?;
            if !left {
                bail!("the emulated SubDevice did not leave OP within 1 s of its leave_op switch");
            }
            Ok(())
        },
        end: |_| Ok(()),
        ends_at_detection: true,
        until_bus_down: false,
    },
    Fault {
        name: "segment silent",
        how: "the segment's link_down switch (no answers, carrier up) until the bus counts as down, +30 ms",
        throw: |bus| {
            bus.lock().faults_mut().link_down = true;
            Ok(())
        },
        end: |bus| {
            bus.lock().faults_mut().link_down = false;
            Ok(())
        },
        ends_at_detection: false,
        until_bus_down: true,
    },
    Fault {
        name: "cable pull",
        how: "`ip link set ecat-emu down` until the bus counts as down, +30 ms, then `up`",
        throw: |_| netns::ip(&["link", "set", netns::SEGMENT_END, "down"]),
        end: |_| netns::ip(&["link", "set", netns::SEGMENT_END, "up"]),
        ends_at_detection: false,
        until_bus_down: true,
    },
];

fn set_subdevice(bus: &EmulatedBus, set: impl FnOnce(&mut skinware_emulate::ethercat::SubDeviceFaults)) -> Result<()> {
    let mut segment = bus.lock();
    set(segment.subdevice_mut(0).context("the emulated segment has no SubDevice")?.faults_mut());
    Ok(())
}

/// Waits for a stretch of `Running` of [`STABLE`]; returns when it began.
fn stably_running(watcher: &Reader, within: Duration) -> Option<Instant> {
    let started = Instant::now();
    let mut since: Option<Instant> = None;
    while started.elapsed() < within {
        if watcher.writer_state() == WriterState::Running {
            let from = *since.get_or_insert_with(Instant::now);
            if from.elapsed() >= STABLE {
                return Some(from);
            }
        } else {
            since = None;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    None
}

fn measure_fault(
    fault: &Fault,
    repetitions: u32,
    settle_bus: bool,
    bus: &EmulatedBus,
    status: &skinware_drivers::ethercat::EthercatStatus,
    watcher: &mut Reader,
) -> Result<FaultReport> {
    let mut report = FaultReport {
        fault: fault.name,
        how: fault.how,
        recovery_from_detection: fault.ends_at_detection,
        detect_ms: Vec::new(),
        recover_ms: Vec::new(),
        up_before_ms: Vec::new(),
        undetected: 0,
        unrecovered: 0,
    };
    for _ in 0..repetitions {
        let Some(running) = stably_running(watcher, Duration::from_secs(20)) else {
            bail!("before {}: the layer is not running (bus {:?})", fault.name, status.bus_fault());
        };
        // The driver's reconnect backoff (100 ms, doubling to 2 s) starts
        // again only after a session of 8 s: a bus fault thrown sooner would
        // measure the backoff the previous one left.
        let settle = if fault.until_bus_down && settle_bus { BUS_SETTLE } else { Duration::from_millis(200) };
        std::thread::sleep(settle.saturating_sub(running.elapsed()).max(Duration::from_millis(200)));
        report.up_before_ms.push(running.elapsed().as_secs_f64() * 1e3);
        if bus.ended() {
            bail!("the emulated segment stopped");
        }
        // From before the switch: for the cable pull that includes starting
        // `ip` (in the normal scheduler: the bench's real-time priority is
        // not inherited across fork), an upper bound on the detection.
        let thrown = Instant::now();
        (fault.throw)(bus)?;
        let detected =
            netns::wait_until_fine(Duration::from_secs(5), || watcher.writer_state() == WriterState::Faulted);
        match detected {
            true => report.detect_ms.push(thrown.elapsed().as_secs_f64() * 1e3),
            false => report.undetected += 1,
        }
        let ended_at = if fault.ends_at_detection {
            let at = Instant::now();
            (fault.end)(bus)?;
            at
        } else {
            if fault.until_bus_down {
                netns::wait_until(Duration::from_secs(5), || status.bus_fault().is_some());
                std::thread::sleep(BUS_FAULT_TAIL);
            } else {
                std::thread::sleep(Duration::from_millis(200).saturating_sub(thrown.elapsed()));
            }
            (fault.end)(bus)?;
            Instant::now()
        };
        // A fault the driver never saw has nothing to recover from: its
        // "recovery" would be the time to the next stable stretch.
        match stably_running(watcher, Duration::from_secs(20)) {
            Some(running) if detected => {
                report.recover_ms.push(running.saturating_duration_since(ended_at).as_secs_f64() * 1e3)
            }
            Some(_) => {}
            None => report.unrecovered += 1,
        }
    }
    Ok(report)
}

fn print(report: &EthercatReport, frames: u64, answered: u64) {
    println!(
        "skin bench ethercat: one segment of {} taxels at {} Hz, ethercrab on a veth pair against the ESC model, {} s",
        report.taxels, report.rate_hz, report.seconds
    );
    println!(
        "  driver threads SCHED_FIFO {} ({}), CPU wake latency held: {:?} us; frame timeout {} ms",
        report.fifo_priority,
        if report.rt_refused.is_empty() { "granted".to_string() } else { report.rt_refused.join("; ") },
        report.cpu_wake_latency_us,
        report.frame_timeout_ms
    );
    let c = &report.cycles;
    println!(
        "  cycles (the SubDevice's filling of its inputs): {} cycles, {:.1} Hz, {} missed, {} periods over 1.5 ms; \
         layer {:.1} frames/s",
        c.cycles, c.achieved_hz, c.missed_cycles, c.late_periods, c.layer_frames_per_s
    );
    println!("  {:<36} {:>10} {:>10} {:>10}", "", "p50 (us)", "p99 (us)", "max (us)");
    let us = |p: &Percentiles, label: &str| {
        println!(
            "  {:<36} {:>10.1} {:>10.1} {:>10.1}",
            label,
            p.p50 as f64 / 1e3,
            p.p99 as f64 / 1e3,
            p.max as f64 / 1e3
        )
    };
    us(&c.period_ns, "period");
    us(&c.jitter_ns, "jitter |period - 1 ms|");
    us(&report.latency.latency_ns, "SubDevice's inputs -> reader's copy");
    us(&report.latency.to_driver_ns, "  of which SubDevice -> bus thread");
    us(&report.latency.driver_to_reader_ns, "  and bus thread -> reader's copy");
    println!("  reader: {}; skipped {} frames", report.latency.reader, report.latency.skipped);
    println!("\n  {:<28} {:>6} {:>22} {:>22}", "fault", "reps", "detect ms (med / max)", "recover ms (med / max)");
    for f in &report.faults {
        let summary = |v: &[f64]| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            match (v.get(v.len() / 2), v.last()) {
                (Some(m), Some(x)) => format!("{m:.1} / {x:.1}"),
                _ => "-".into(),
            }
        };
        println!(
            "  {:<28} {:>6} {:>22} {:>22}{}",
            f.fault,
            f.detect_ms.len() as u32 + f.undetected,
            summary(&f.detect_ms),
            summary(&f.recover_ms),
            if f.recovery_from_detection { "  (recovery from detection)" } else { "" }
        );
    }
    println!("  emulated segment: {frames} frames taken, {answered} answered");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_stamp_in_four_taxels_reads_back() {
        let at = 0x0123_4567_89AB_CDEFu64;
        let taxels: Vec<u16> = (0..4).map(|k| (at >> (16 * k)) as u16).chain([7, 7]).collect();
        assert_eq!(stamp_of(&taxels), at);
    }

    #[test]
    fn cycles_count_the_empty_slots_of_the_schedule() {
        // 1 ms cycles with one late by 0.6 ms (kept to the schedule after
        // it) and two missing.
        let at: Vec<u64> = [0u64, 1, 2, 3, 5, 6, 8, 9].iter().map(|ms| ms * 1_000_000).collect();
        let mut late = at.clone();
        late[2] += 600_000;
        let report = cycle_report(&late, 1000.0);
        assert_eq!((report.cycles, report.missed_cycles, report.late_periods), (8, 2, 3));
        assert_eq!(report.period_ns.max, 2_000_000);
        assert!((report.achieved_hz - 7.0 / 0.009).abs() < 1e-6);
    }
}
