//! `skin bench table1`: the paper's Table I with our figures beside it.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{LayerTopology, Stop, TopologyBuilder};

use crate::app::AppSamples;
use crate::measure::{self, Percentiles, WriterSample};
use crate::run_options::RunOptions;

/// Options of `skin bench table1`.
#[derive(Clone, Debug)]
pub struct Table1Options {
    /// Quick: 2 s of measurement instead of 60 s; `table1.json` goes to
    /// `out`; `exe` is run again for the application process.
    pub run: RunOptions,
    /// How one writer gets its data.
    pub transport: Transport,
}

/// How the writers of Table I get their data: both from memory, or one of
/// them through its real driver.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Transport {
    /// Generated in memory, as in the paper's own measurement of the exchange.
    #[default]
    Memory,
    /// The real driver path: emulated MTB boards (one board, 15 triangles) on
    /// an SLCAN pseudo-terminal, the SLCAN codec and the `icub-mtb` decoder.
    /// Each write is the driver's acquisition (a copy of the newest decoded
    /// image) and the publish; the decoding runs in the driver's bus thread.
    Slcan,
    /// The EtherCAT writer on the real driver path: ethercrab's MainDevice on
    /// a raw socket at one end of a veth pair, the ESC model of one 708-taxel
    /// segment at the other, in a network namespace of the bench's own (the
    /// caller enters it: [`crate::netns`]). Each write is the driver's
    /// acquisition (it waits for a bus cycle newer than the last frame's, if
    /// none is there yet, then copies that cycle's taxels) and the publish.
    /// The bus cycles run in the driver's bus thread at the layer's 50 Hz,
    /// each scheduled to end just before the writer's period deadline.
    Ethercat,
}

impl Transport {
    /// Its name in `table1.json`.
    pub fn name(self) -> &'static str {
        match self {
            Transport::Memory => "memory",
            Transport::Slcan => "slcan",
            Transport::Ethercat => "ethercat",
        }
    }
}

/// One row of Table I.
#[derive(Debug, Serialize)]
pub struct Table1Row {
    /// `writer_EC`, `writer_CAN`, `reader_EC` or `reader_CAN`.
    pub name: &'static str,
    /// Our average, ns.
    pub avg_ns: f64,
    /// Our worst case, ns.
    pub worst_ns: u64,
    /// Our standard deviation, ns.
    pub std_ns: f64,
    /// Samples behind it.
    pub samples: usize,
    /// The paper's (average, worst case, std), ns (Core 2 Duo, RTAI).
    pub paper: [f64; 3],
    /// For a writer, where its data came from: `memory`, `slcan` or `ethercat`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub transport: Option<&'static str>,
    /// For the EtherCAT writer on its driver: the part of each write from
    /// the moment its bus cycle's data was there (the bus thread's receipt
    /// of the answer, or `begin` if later) to the end of `publish`, ns: the
    /// row without the wait for the bus cycle.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub after_bus_data_ns: Option<Percentiles>,
}

const PAPER: [(&str, [f64; 3]); 4] = [
    ("writer_EC", [23915.0, 87315.0, 4381.0]),
    ("writer_CAN", [20108.0, 44077.0, 2951.0]),
    ("reader_EC", [10996.0, 86635.0, 3533.0]),
    ("reader_CAN", [6703.0, 47102.0, 1733.0]),
];

/// The paper's saddle: 15 modules on CAN; 12 + 3 x 16 modules on EtherCAT,
/// 12 taxels each (one EtherCAT module broken: 59 x 12 = 708).
fn saddle() -> Result<Vec<LayerTopology>> {
    let mut can = TopologyBuilder::new("can", "pressure", 50.0);
    can.patch(1);
    for module in 0..15u32 {
        can.module(module + 1, module * 12 + 1..module * 12 + 13);
    }
    let mut ethercat = TopologyBuilder::new("ethercat", "pressure", 50.0);
    let mut module_id = 100;
    for (patch, modules) in [(2u32, 11u32), (3, 16), (4, 16), (5, 16)] {
        ethercat.patch(patch);
        for _ in 0..modules {
            let first = module_id * 12;
            ethercat.module(module_id, first..first + 12);
            module_id += 1;
        }
    }
    let topologies = vec![ethercat.build()?, can.build()?];
    debug_assert_eq!((topologies[0].sensors.len(), topologies[1].sensors.len()), (708, 180));
    Ok(topologies)
}

/// The writers, on the transport asked for, and what must be stopped after them.
struct Writers {
    threads: Vec<std::thread::JoinHandle<Vec<WriterSample>>>,
    emulator: Option<slcan::Running>,
    ethercat_bus: Option<crate::netns::EmulatedBus>,
    /// The EtherCAT writer's time from its bus data to the end of publish.
    after_bus_data: Arc<Mutex<Vec<WriterSample>>>,
}

impl Writers {
    fn start(transport: Transport, skin: &str, topologies: &[LayerTopology], stop: &Stop) -> Result<Writers> {
        let mut writers =
            Writers { threads: Vec::new(), emulator: None, ethercat_bus: None, after_bus_data: Arc::default() };
        writers.threads = match transport {
            Transport::Memory => measure::run_writers(skin, topologies, stop, None)?,
            Transport::Ethercat => {
                if !crate::netns::inside() {
                    bail!(
                        "the ethercat transport runs in a network namespace of its own: start it as \
                         `skin bench table1 --transport ethercat`, which enters one"
                    );
                }
                crate::netns::make_veth_pair()?;
                writers.ethercat_bus = Some(crate::netns::EmulatedBus::start(ecat::segment()?, Some(75))?);
                let mut threads = vec![ecat::run_ec_writer(skin, stop, writers.after_bus_data.clone())?];
                threads.extend(measure::run_writers(skin, &topologies[1..], stop, None)?);
                threads
            }
            Transport::Slcan => {
                let mut threads = measure::run_writers(skin, &topologies[..1], stop, None)?;
                let (device, thread) = slcan::start_emulator()?;
                writers.emulator = Some(thread);
                threads.push(slcan::run_can_writer(skin, &device, stop)?);
                threads
            }
        };
        Ok(writers)
    }

    /// Joins the writers (stopped by their stop signal) and stops the emulators.
    fn join(self) -> Result<Vec<Vec<WriterSample>>> {
        let mut samples = Vec::new();
        for writer in self.threads {
            samples.push(writer.join().map_err(|_| anyhow::anyhow!("writer thread panicked"))?);
        }
        if let Some((stop_emulator, thread)) = self.emulator {
            stop_emulator.store(true, std::sync::atomic::Ordering::Relaxed);
            let _ = thread.join();
        }
        if let Some(bus) = self.ethercat_bus {
            let served = bus.stop()?;
            println!("emulated EtherCAT segment: {} frames taken, {} answered", served.frames, served.answered);
        }
        Ok(samples)
    }
}

/// Runs the test, prints the table beside the paper's and writes `table1.json`.
pub fn run(options: &Table1Options) -> Result<Vec<Table1Row>> {
    let seconds = options.run.seconds_or(2.0, 60.0);
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!("--seconds must be a positive number of seconds");
    }
    std::fs::create_dir_all(&options.run.out)
        .with_context(|| format!("cannot create {}", options.run.out.display()))?;
    let skin = format!("table1-{}", std::process::id());
    let topologies = saddle()?;
    let stop = Stop::new();
    let writers = Writers::start(options.transport, &skin, &topologies, &stop)?;
    let after_bus_data = writers.after_bus_data.clone();
    let out = options.run.out.join("table1-app.json");
    let names: Vec<String> = topologies.iter().map(|t| t.name.clone()).collect();
    let mut app = measure::spawn_app(&options.run.exe, &skin, &names, "asap", seconds, 1, &out)?;
    let status = app.wait()?;
    std::thread::sleep(Duration::from_millis(50));
    stop.stop();
    let writer_samples = writers.join()?;
    if !status.success() {
        bail!("the application process failed ({status})");
    }
    let app_samples: AppSamples = serde_json::from_slice(&std::fs::read(&out)?)?;
    let _ = std::fs::remove_file(&out);
    let window = [app_samples.window_ns];
    let mut all = [
        measure::steady_state(&writer_samples[0], &window)?,
        measure::steady_state(&writer_samples[1], &window)?,
        app_samples.read_ns.first().cloned().unwrap_or_default(),
        app_samples.read_ns.get(1).cloned().unwrap_or_default(),
    ];
    let mut rows = rows_of(options.transport, &mut all);
    if options.transport == Transport::Ethercat {
        let samples = skinware::lock(&after_bus_data);
        rows[0].after_bus_data_ns = Some(Percentiles::of(&mut measure::steady_state(&samples, &window)?));
    }
    print_table(options.transport, seconds, &rows);
    let json = options.run.out.join("table1.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&rows)?)?;
    println!("\nwrote {}", json.display());
    Ok(rows)
}

/// The table's rows from the samples of each, in the paper's order.
fn rows_of(transport: Transport, all: &mut [Vec<u64>; 4]) -> Vec<Table1Row> {
    PAPER
        .iter()
        .zip(all.iter_mut())
        .map(|(&(name, paper), samples)| {
            let p = Percentiles::of(samples);
            let driven = |t: Transport| if transport == t { t.name() } else { Transport::Memory.name() };
            let transport = match name {
                "writer_CAN" => Some(driven(Transport::Slcan)),
                "writer_EC" => Some(driven(Transport::Ethercat)),
                _ => None,
            };
            Table1Row {
                name,
                avg_ns: p.avg,
                worst_ns: p.max,
                std_ns: p.std,
                samples: p.samples,
                paper,
                transport,
                after_bus_data_ns: None,
            }
        })
        .collect()
}

fn print_table(transport: Transport, seconds: f64, rows: &[Table1Row]) {
    println!(
        "skin bench table1: EtherCAT layer 708 sensors, CAN layer 180 sensors ({} transport), writers at 50 Hz, aperiodic readers",
        transport.name()
    );
    if let Some(p) = &rows[0].after_bus_data_ns {
        println!(
            "writer_EC's acquisition waits for a bus cycle newer than its last frame if none is there yet; \
             from that cycle's data (or begin) to the end of publish: avg {:.0} ns, p99 {} ns, worst {} ns, std {:.0} ns",
            p.avg, p.p99, p.max, p.std
        );
    }
    println!("{seconds} s of measurement; ours on this machine, the paper's on a Core 2 Duo E8200 with RTAI\n");
    println!(
        "{:<12} {:>12} {:>12} {:>10} | {:>12} {:>12} {:>10}",
        "", "avg (ns)", "worst (ns)", "std", "paper avg", "paper worst", "paper std"
    );
    for row in rows {
        println!(
            "{:<12} {:>12.0} {:>12} {:>10.0} | {:>12.0} {:>12.0} {:>10.0}",
            row.name, row.avg_ns, row.worst_ns, row.std_ns, row.paper[0], row.paper[1], row.paper[2]
        );
    }
}

/// The EtherCAT writer on the real driver path: ESC model → veth → ethercrab.
mod ecat {
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    use anyhow::{Context, Result};
    use skinware::driver::Driver;
    use skinware::{RtOptions, Stop, Ticker, Writer, WriterOptions};
    use skinware_emulate::ethercat::{Segment, TactileConfig, TactileSubDevice};

    use crate::measure::WriterSample;

    /// The paper's EtherCAT sensors: 59 modules of 12.
    const TAXELS: usize = 708;

    /// One emulated segment of 708 taxels feeling a slowly moving press.
    pub(super) fn segment() -> Result<Segment> {
        let press = |sample: u64, taxels: &mut [u16]| {
            let t = sample as f64 / 50.0;
            for (i, taxel) in taxels.iter_mut().enumerate() {
                let phase = (t * 2.0 + i as f64 * 0.1).sin().max(0.0);
                *taxel = skinware_drivers::virtual_skin::BASELINE + (phase * 20_000.0) as u16;
            }
        };
        let subdevice = TactileSubDevice::new(TactileConfig::new(TAXELS, 1), press)
            .context("cannot build the emulated EtherCAT segment")?;
        Ok(Segment::new(vec![subdevice]))
    }

    /// The EtherCAT layer's writer: at 50 Hz, the driver's acquisition and
    /// the publish. Returns the whole spans; `after_bus_data` gets the
    /// spans from the cycle's data (or `begin`, if later) to the publish.
    pub(super) fn run_ec_writer(
        skin: &str,
        stop: &Stop,
        after_bus_data: Arc<Mutex<Vec<WriterSample>>>,
    ) -> Result<std::thread::JoinHandle<Vec<WriterSample>>> {
        // The bus thread paces the acquisition: at the writer's priority.
        let rt = RtOptions { fifo_priority: Some(80), ..RtOptions::default() };
        let mut driver = crate::netns::driver("ethercat", 2, TAXELS, 50.0, rt)?;
        let status = driver.status_handle();
        let topology = driver.layers().remove(0).topology;
        let mut sources = driver.start().map_err(|e| anyhow::anyhow!("the EtherCAT driver did not start: {e}"))?;
        let mut source = sources.remove(0);
        let period = Duration::from_millis(20);
        let options = WriterOptions { period: Some(period), ..WriterOptions::default() };
        let mut writer = Writer::create(skin, "ethercat", topology.frame_bytes(), &topology.encode(), &options)
            .context("creating layer ethercat")?;
        writer.set_stop(stop);
        // Bring-up to OP.
        if !crate::netns::wait_until(Duration::from_secs(10), || {
            status.bus_fault().is_none() && status.segments().iter().all(|s| s.state == "OP")
        }) {
            driver.stop();
            anyhow::bail!(
                "the EtherCAT driver did not bring the emulated segment to OP within 10 s: bus {:?}, segments {:?}",
                status.bus_fault(),
                status.segments()
            );
        }
        // The writer runs as the driver handler runs it (`run_periodic`,
        // which tells the driver each period's deadline, so that its bus
        // cycles end just before the acquisition). `run_periodic` times each
        // frame from `begin` to the end of `publish` itself; a sampler
        // thread reads that (write_ns_last) from the channel's statistics
        // after each frame, outside the span.
        let reader = skinware::Reader::open(skin, "ethercat").context("opening layer ethercat to sample its writer")?;
        let acquisitions = Arc::new(Mutex::new(Vec::<(u64, u64)>::with_capacity(4096)));
        let first_frame = reader.writer_stats().frames + 1;
        let writing = {
            let acquisitions = acquisitions.clone();
            std::thread::spawn(move || {
                for refused in (RtOptions { fifo_priority: Some(80), ..RtOptions::default() }).apply() {
                    eprintln!("warning: writer_EC: {refused}");
                }
                let _ = writer.run_periodic(Ticker::new(period), |frame| {
                    let started = skinware::os::monotonic_ns();
                    let result = source.acquire(frame);
                    if result.is_ok() {
                        let data = frame.acquired_ns().unwrap_or(started);
                        skinware::lock(&acquisitions).push((started, data));
                    }
                    result
                });
                driver.stop();
            })
        };
        let stop = stop.clone();
        Ok(std::thread::spawn(move || {
            // Frame number → its begin-to-publish time, as the writer measured it.
            let mut write_ns = std::collections::HashMap::with_capacity(4096);
            while !stop.is_stopped() {
                let a = reader.writer_stats();
                let b = reader.writer_stats();
                if a.frames == b.frames && a.write_ns_last == b.write_ns_last && a.frames >= first_frame {
                    write_ns.insert(a.frames, a.write_ns_last);
                }
                std::thread::sleep(Duration::from_millis(2));
            }
            let _ = writing.join();
            let acquisitions = std::mem::take(&mut *skinware::lock(&acquisitions));
            let mut samples = Vec::with_capacity(acquisitions.len());
            let mut after = Vec::with_capacity(acquisitions.len());
            for (k, &(started, data)) in acquisitions.iter().enumerate() {
                let Some(&took) = write_ns.get(&(first_frame + k as u64)) else { continue };
                samples.push(WriterSample { started_ns: started, took_ns: took });
                let published = started + took;
                after.push(WriterSample { started_ns: started, took_ns: published.saturating_sub(data.max(started)) });
            }
            *skinware::lock(&after_bus_data) = after;
            samples
        }))
    }
}

/// The CAN writer on the real driver path: emulated boards → SLCAN → decoder.
mod slcan {
    use std::sync::Arc;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::time::Duration;

    use anyhow::{Context, Result};
    use skinware::driver::Driver;
    use skinware::{RtOptions, Stop, Ticker, Writer, WriterOptions};
    use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
    use skinware_drivers::can::icub_mtb::{Board, BoardSettings};
    use skinware_emulate::{MtbBoards, MtbFaults, SlcanDevice, run_mtb};

    use crate::measure::WriterSample;

    /// Emulated boards that feel a slowly moving press.
    fn touch(t: f64, responses: &mut [u16]) {
        for (i, response) in responses.iter_mut().enumerate() {
            let phase = (t * 2.0 + i as f64 * 0.1).sin().max(0.0);
            *response = skinware_drivers::virtual_skin::BASELINE + (phase * 20_000.0) as u16;
        }
    }

    /// A running emulator: its stop flag and its thread.
    pub(super) type Running = (Arc<AtomicBool>, std::thread::JoinHandle<()>);

    /// One MTB board of 15 triangles (the paper's 180 sensors) on an SLCAN
    /// pseudo-terminal; returns its URL and the running emulator.
    pub(super) fn start_emulator() -> Result<(String, Running)> {
        let mut device = SlcanDevice::new().context("cannot open a pseudo-terminal for the emulated boards")?;
        let url = device.url();
        let stop = Arc::new(AtomicBool::new(false));
        let stopped = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut boards = MtbBoards::new(1, 15, Duration::from_millis(20), MtbFaults::default());
            let _ = run_mtb(&mut boards, &mut device, &touch, None, &|| stopped.load(Ordering::Relaxed));
        });
        Ok((url, (stop, thread)))
    }

    /// The CAN layer's writer: at 50 Hz, the driver's acquisition and the publish.
    pub(super) fn run_can_writer(
        skin: &str,
        url: &str,
        stop: &Stop,
    ) -> Result<std::thread::JoinHandle<Vec<WriterSample>>> {
        let mut driver = CanDriver::new(CanDriverConfig {
            name: "table1-can".into(),
            layer: "can".into(),
            interface: url.into(),
            protocol: Protocol::IcubMtb {
                boards: vec![Board { address: 1, triangles: (0..15).collect() }],
                settings: BoardSettings { period_ms: 20, ..BoardSettings::default() },
            },
            rate_hz: 50.0,
            rt: RtOptions::default(),
        })
        .map_err(anyhow::Error::msg)?;
        let topology = driver.layers().remove(0).topology;
        let mut sources = driver.start().map_err(|e| anyhow::anyhow!("the CAN driver did not start: {e}"))?;
        let mut source = sources.remove(0);
        let period = Duration::from_millis(20);
        let options = WriterOptions { period: Some(period), ..WriterOptions::default() };
        let mut writer = Writer::create(skin, "can", topology.frame_bytes(), &topology.encode(), &options)
            .context("creating layer can")?;
        writer.set_stop(stop);
        // The boards need a moment to be configured and stream.
        std::thread::sleep(Duration::from_millis(200));
        Ok(std::thread::spawn(move || {
            let _ = RtOptions { fifo_priority: Some(80), ..RtOptions::default() }.apply();
            let mut samples = Vec::with_capacity(4096);
            let mut ticker = Ticker::new(period);
            let stop = writer.stop_signal().clone();
            while ticker.wait(&stop).is_some() {
                let started = skinware::os::monotonic_ns();
                let mut frame = writer.begin();
                if source.acquire(&mut frame).is_ok() {
                    frame.publish();
                } else {
                    frame.discard();
                }
                samples.push(WriterSample { started_ns: started, took_ns: skinware::os::monotonic_ns() - started });
            }
            driver.stop();
            samples
        }))
    }
}
