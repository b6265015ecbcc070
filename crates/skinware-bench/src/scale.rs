//! `skin bench scale`: how every cost grows with the skin's size and rate.
//!
//! Each point of the sweep is one skin of N taxels published as one frame
//! (N × 2 bytes) at R Hz by a writer thread at SCHED_FIFO 80 in this
//! process, read by 0, 1 or 15 application processes in the paper's mix of
//! modes (1: one that waits for every frame; 15: 5 that wait for every
//! frame and 10 that read the newest at random 10–100 Hz). The writer fills
//! each frame from its driver-side buffer, as a driver copies from its bus,
//! changing one word per frame: a cheap generator, so that what is measured
//! is the exchange, not a simulation of a skin.
//!
//! Per point, in the same run: the writer's publish (begin, copy, publish,
//! wake) against a `memcpy` of the same frame by the same thread (every
//! fourth period, just before that period's publish, which is then not
//! timed); missed periods, and those missed because the writer's own work
//! overran, against the point's control without readers; the readers' copy; the CPU of the writer's
//! process (its thread and its ringer) and of the readers; the latency from
//! acquisition to each kind of reader; and how many frames the waiting
//! readers missed. Only frames begun while every reader was up count.

#![forbid(unsafe_code)]

use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{LayerTopology, RtOptions, Stop, Ticker, TopologyBuilder, Writer, WriterOptions};

use crate::app::AppSamples;
use crate::kilohertz::cpu::{cpu_ns_between, thread_cpu_ns};
use crate::measure::{self, Percentiles};
use crate::run_options::RunOptions;
pub use crate::scale_record::ScalePoint;

/// Taxels of the quick sweep: the paper's skin, a third of it, and 3.2 and
/// 9.7 times it (whole-body skins being built have 10^5).
pub const TAXELS: [usize; 4] = [10_000, 30_848, 100_000, 300_000];
/// Taxels of the full sweep: also a million (a 2 MB frame), to find where
/// the frontier lies when the smaller skins all keep up.
pub const TAXELS_FULL: [usize; 5] = [10_000, 30_848, 100_000, 300_000, 1_000_000];
/// Rates of the full sweep, Hz.
pub const RATES_HZ: [f64; 4] = [100.0, 500.0, 1000.0, 2000.0];
/// Readers of the full sweep (0 is each point's control).
pub const READERS: [usize; 3] = [0, 1, 15];
/// Of 15 readers, those that wait for every frame (the rest read periodically).
const WAITING_OF_15: usize = 5;
/// The writer's real-time priority, as the drivers'.
const WRITER_PRIORITY: u8 = 80;
/// Every this many periods, the writer also times a `memcpy` of its frame.
const MEMCPY_EVERY: u64 = 4;

/// What `skin bench scale` measured.
#[derive(Clone, Debug, Serialize)]
pub struct ScaleReport {
    /// Seconds per point.
    pub seconds: f64,
    /// Every point.
    pub points: Vec<ScalePoint>,
    /// Per rate: the largest skin whose runs with readers missed no more
    /// periods than its control (none of its smaller ones either).
    pub frontier: Vec<Frontier>,
}

/// The largest skin at one rate with no period missed because of readers.
#[derive(Clone, Debug, Serialize)]
pub struct Frontier {
    /// The rate, Hz.
    pub rate_hz: f64,
    /// Taxels; `None` if even the smallest skin of the sweep had reader-caused misses.
    pub taxels: Option<usize>,
}

/// Runs the sweep, prints it and writes `scale.json` and `scale.png`.
pub fn run(options: &RunOptions) -> Result<ScaleReport> {
    let seconds = options.seconds_or(1.5, 4.0);
    if !(seconds.is_finite() && seconds >= 0.5) {
        bail!("--seconds must be at least 0.5");
    }
    let rates: &[f64] = if options.quick { &[100.0, 1000.0] } else { &RATES_HZ };
    let readers: &[usize] = if options.quick { &[0, 15] } else { &READERS };
    let sizes: &[usize] = if options.quick { &TAXELS } else { &TAXELS_FULL };
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let work = options.out.join("scale-work");
    std::fs::create_dir_all(&work)?;
    let mut points = Vec::new();
    for &rate_hz in rates {
        for &taxels in sizes {
            let mut control: Option<(u64, u64)> = None; // (overrun misses, periods)
            for &count in readers {
                let spec = PointSpec { taxels, rate_hz, readers: count, seconds };
                let mut point = run_point(options, &work, spec)
                    .with_context(|| format!("{taxels} taxels at {rate_hz} Hz with {count} readers"))?;
                match control {
                    None if count == 0 => control = Some((point.overrun_missed, point.periods.max(1))),
                    None => point.reader_caused_missed = point.overrun_missed,
                    Some((missed, periods)) => {
                        let expected = missed as f64 * point.periods as f64 / periods as f64;
                        point.reader_caused_missed = (point.overrun_missed as f64 - expected).max(0.0).ceil() as u64;
                    }
                }
                print_point(&point);
                points.push(point);
            }
        }
    }
    let _ = std::fs::remove_dir_all(&work);
    let frontier = frontier(&points, rates, sizes);
    let report = ScaleReport { seconds, points, frontier };
    print_frontier(&report.frontier);
    let json = options.out.join("scale.json");
    std::fs::write(&json, serde_json::to_vec_pretty(&report)?)?;
    let png = options.out.join("scale.png");
    crate::plot::scale(&report.points, &png)?;
    println!("written: {} and {}", json.display(), png.display());
    Ok(report)
}

/// Per rate, the largest skin up to which no run with readers missed a
/// period its control did not.
fn frontier(points: &[ScalePoint], rates: &[f64], sizes: &[usize]) -> Vec<Frontier> {
    rates
        .iter()
        .map(|&rate_hz| {
            let mut largest = None;
            for &taxels in sizes {
                let clean = points
                    .iter()
                    .filter(|p| p.rate_hz == rate_hz && p.taxels == taxels && p.readers > 0)
                    .all(|p| p.reader_caused_missed == 0);
                if !clean {
                    break;
                }
                largest = Some(taxels);
            }
            Frontier { rate_hz, taxels: largest }
        })
        .collect()
}

/// A layer of `taxels` sensors in modules of 12, 16 modules to a patch (the
/// paper's skin's largest patches).
fn topology(name: &str, taxels: usize, rate_hz: f64) -> Result<LayerTopology> {
    let mut builder = TopologyBuilder::new(name, "pressure", rate_hz);
    let uids: Vec<u32> = (0..u32::try_from(taxels)?).collect();
    for (module, sensors) in uids.chunks(12).enumerate() {
        if module % 16 == 0 {
            builder.patch((module / 16) as u32);
        }
        builder.module(module as u32, sensors.iter().copied());
    }
    Ok(builder.build()?)
}

/// One tick of the writer's period.
struct TickRecord {
    deadline_ns: u64,
    missed: u64,
}

/// What the writer thread recorded.
#[derive(Default)]
struct WriterRecord {
    /// Per frame: when its period's work began (ns) and its publish took (ns).
    publish: Vec<measure::WriterSample>,
    /// When each timed memcpy began and what it took.
    memcpy: Vec<measure::WriterSample>,
    /// Per tick: its deadline and the periods missed just before it.
    ticks: Vec<TickRecord>,
    /// Per tick, the time its publish took (each, timed or not), ns.
    last_took_ns: Vec<u64>,
    /// Per frame: the thread's CPU time when its period's work began, ns.
    cpu_ns: Vec<u64>,
}

/// What one point's run gave, before it is summed up.
struct RawPoint {
    record: WriterRecord,
    /// Each reader process's samples, and whether it waited for every frame.
    apps: Vec<(AppSamples, bool)>,
    /// The ringer's CPU time over the readers' lifetime, ns.
    helpers_ns: u64,
}

/// What one point of the sweep runs.
#[derive(Clone, Copy, Debug)]
struct PointSpec {
    taxels: usize,
    rate_hz: f64,
    readers: usize,
    /// Seconds the readers read.
    seconds: f64,
}

/// One point: runs the writer and its readers, and sums up what they measured.
fn run_point(options: &RunOptions, work: &Path, spec: PointSpec) -> Result<ScalePoint> {
    let raw = measure_point(options, work, spec)?;
    summarize(raw, spec)
}

fn measure_point(options: &RunOptions, work: &Path, spec: PointSpec) -> Result<RawPoint> {
    let PointSpec { taxels, rate_hz, readers, seconds } = spec;
    let skin = format!("scale{}", std::process::id());
    let layer = format!("t{taxels}r{}n{readers}", rate_hz as u64);
    let topology = topology(&layer, taxels, rate_hz)?;
    let stop = Stop::new();
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let writer_options =
        WriterOptions { period: Some(period), slots: skinware::slots_for_history(Some(period)), ..Default::default() };
    let mut writer = Writer::create(&skin, &layer, topology.frame_bytes(), &topology.encode(), &writer_options)
        .with_context(|| format!("creating layer {layer}"))?;
    writer.set_stop(&stop);
    let helpers_before = thread_cpu_ns(std::process::id(), Some("skinware-ring"));
    let writer_thread = std::thread::Builder::new().name("scale-writer".into()).spawn(move || {
        let _ = RtOptions { fifo_priority: Some(WRITER_PRIORITY), ..RtOptions::default() }.apply();
        write_frames(writer, taxels, period)
    })?;
    // Let the writer settle (its first frames fault its pages in) before the readers come.
    std::thread::sleep(Duration::from_millis(200));
    let mut children = Vec::new();
    if readers == 0 {
        std::thread::sleep(Duration::from_secs_f64(seconds));
    }
    for app in 0..readers {
        let waiting = app < readers.min(WAITING_OF_15);
        let out = work.join(format!("{layer}-{app}.json"));
        let mode = if waiting { "asap" } else { "periodic" };
        let layers = [layer.clone()];
        let child = measure::spawn_app(&options.exe, &skin, &layers, mode, seconds, app as u64 + 1, &out)?;
        children.push((child, out, waiting));
    }
    let mut apps = Vec::new();
    let mut failure = None;
    for (mut child, out, waiting) in children {
        let status = child.wait()?;
        if !status.success() {
            failure.get_or_insert_with(|| format!("a reader process failed ({status})"));
            continue;
        }
        let samples: AppSamples = serde_json::from_slice(&std::fs::read(&out)?)?;
        let _ = std::fs::remove_file(&out);
        apps.push((samples, waiting));
    }
    std::thread::sleep(Duration::from_millis(20));
    let helpers_after = thread_cpu_ns(std::process::id(), Some("skinware-ring"));
    stop.stop();
    let record = writer_thread.join().map_err(|_| anyhow::anyhow!("the writer thread panicked"))?;
    if let Some(failure) = failure {
        bail!(failure);
    }
    let (helpers_ns, _) = cpu_ns_between(&helpers_before, &helpers_after);
    Ok(RawPoint { record, apps, helpers_ns })
}

/// Sums up one point's run over its window.
fn summarize(raw: RawPoint, spec: PointSpec) -> Result<ScalePoint> {
    let RawPoint { record, apps, helpers_ns } = raw;
    let PointSpec { taxels, rate_hz, readers, seconds } = spec;
    let period = Duration::from_secs_f64(1.0 / rate_hz);
    let window = window(&record, &apps, readers, seconds)?;
    let inside = |at: u64| (window[0]..window[1]).contains(&at);
    let mut publish: Vec<u64> = record.publish.iter().filter(|s| inside(s.started_ns)).map(|s| s.took_ns).collect();
    let mut memcpy: Vec<u64> = record.memcpy.iter().filter(|s| inside(s.started_ns)).map(|s| s.took_ns).collect();
    let periods = ((window[1] - window[0]) as f64 / period.as_nanos() as f64).round() as u64;
    let (missed_periods, overrun_missed, writer_thread_cpu_percent) = writer_figures(&record, period, &inside);
    // The ringer's time over the readers' lifetime: the writer's run between the two readings.
    let helpers_span_ns = match (record.publish.first(), record.publish.last()) {
        (Some(first), Some(last)) => last.started_ns.saturating_sub(first.started_ns).max(1),
        _ => 1,
    };
    let pick = |waiting: bool, of: fn(&AppSamples) -> &Vec<Vec<u64>>| -> Vec<u64> {
        apps.iter()
            .filter(|(_, w)| *w == waiting)
            .flat_map(|(a, _)| {
                let times = a.read_at_ns.iter().flatten().copied().collect::<Vec<_>>();
                of(a)
                    .iter()
                    .flatten()
                    .copied()
                    .zip(times)
                    .filter(|(_, at)| inside(*at))
                    .map(|(v, _)| v)
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let mut waiting_copy = pick(true, |a| &a.read_ns);
    let mut periodic_copy = pick(false, |a| &a.read_ns);
    let mut waiting_latency = pick(true, |a| &a.latency_ns);
    let mut periodic_latency = pick(false, |a| &a.latency_ns);
    let waiting: Vec<&AppSamples> = apps.iter().filter(|(_, w)| *w).map(|(a, _)| a).collect();
    let skipped: u64 = waiting.iter().flat_map(|a| &a.skipped).sum();
    let received: usize = waiting.iter().flat_map(|a| &a.read_ns).map(Vec::len).sum();
    let waiting_missed_share =
        if waiting.is_empty() { 0.0 } else { skipped as f64 / (skipped as f64 + received as f64) };
    let readers_cpu_ns: u64 = apps.iter().map(|(a, _)| a.cpu_ns).sum();
    let readers_seconds =
        apps.iter().map(|(a, _)| a.window_ns[1].saturating_sub(a.window_ns[0]) as f64 / 1e9).fold(0.0, f64::max);
    let publish_ns = Percentiles::of(&mut publish);
    let memcpy_ns = Percentiles::of(&mut memcpy);
    let waiting_copy_ns = Percentiles::of(&mut waiting_copy);
    let ratio = |a: u64, b: u64| if b == 0 { 0.0 } else { a as f64 / b as f64 };
    Ok(ScalePoint {
        taxels,
        frame_bytes: taxels * 2,
        rate_hz,
        readers,
        periods,
        missed_periods,
        overrun_missed,
        reader_caused_missed: 0,
        publish_over_memcpy_p50: ratio(publish_ns.p50, memcpy_ns.p50),
        publish_over_memcpy_p99: ratio(publish_ns.p99, memcpy_ns.p99),
        reader_copy_over_memcpy_p50: ratio(waiting_copy_ns.p50, memcpy_ns.p50),
        publish_ns,
        memcpy_ns,
        waiting_copy_ns,
        periodic_copy_ns: Percentiles::of(&mut periodic_copy),
        waiting_latency_ns: Percentiles::of(&mut waiting_latency),
        periodic_latency_ns: Percentiles::of(&mut periodic_latency),
        waiting_missed_share,
        writer_thread_cpu_percent,
        writer_helpers_cpu_percent: 100.0 * helpers_ns as f64 / helpers_span_ns as f64,
        readers_cpu_percent: if readers_seconds > 0.0 {
            100.0 * readers_cpu_ns as f64 / 1e9 / readers_seconds
        } else {
            0.0
        },
    })
}

/// The measured window: every reader up; for the control, the writer's
/// whole run after its settling.
fn window(record: &WriterRecord, apps: &[(AppSamples, bool)], readers: usize, seconds: f64) -> Result<[u64; 2]> {
    Ok(if apps.is_empty() {
        let first = record.publish.first().map_or(0, |s| s.started_ns) + 200_000_000;
        [first, first + (seconds * 1e9) as u64]
    } else {
        let from = apps.iter().map(|(a, _)| a.window_ns[0]).max().unwrap_or(0);
        let to = apps.iter().map(|(a, _)| a.window_ns[1]).min().unwrap_or(0);
        if from >= to {
            bail!("the {readers} reader processes never all ran at once; give each point more time with --seconds");
        }
        [from, to]
    })
}

/// The writer's missed periods in the window, those of them missed by
/// overruns, and its thread's CPU, % of one core.
fn writer_figures(record: &WriterRecord, period: Duration, inside: &dyn Fn(u64) -> bool) -> (u64, u64, f64) {
    let missed_periods = record.ticks.iter().filter(|t| inside(t.deadline_ns)).map(|t| t.missed).sum();
    // A period is missed by an overrun when the frame before it took the
    // writer longer than a period to publish: the writer's own work, which
    // readers can slow (their copies compete for the caches and the memory
    // bus). A writer at SCHED_FIFO 80 whose publish was short missed it
    // because it woke late (the timer, the hypervisor), which readers in
    // the normal scheduler do not cause.
    let overrun_missed = record
        .ticks
        .iter()
        .enumerate()
        .filter(|(_, t)| inside(t.deadline_ns) && t.missed > 0)
        .filter(|(k, _)| {
            k.checked_sub(1)
                .and_then(|k| record.last_took_ns.get(k))
                .is_some_and(|&took| took >= period.as_nanos() as u64)
        })
        .map(|(_, t)| t.missed)
        .sum();
    let cpu_in_window: Vec<(u64, u64)> = record
        .publish
        .iter()
        .zip(&record.cpu_ns)
        .filter(|(s, _)| inside(s.started_ns))
        .map(|(s, &cpu)| (s.started_ns, cpu))
        .collect();
    let writer_thread_cpu_percent = match (cpu_in_window.first(), cpu_in_window.last()) {
        (Some(first), Some(last)) if last.0 > first.0 => 100.0 * (last.1 - first.1) as f64 / (last.0 - first.0) as f64,
        _ => 0.0,
    };
    (missed_periods, overrun_missed, writer_thread_cpu_percent)
}

/// The writer's loop: one frame a period until stopped, timing its publish
/// and, every [`MEMCPY_EVERY`] periods, a `memcpy` of the same bytes.
fn write_frames(mut writer: Writer, taxels: usize, period: Duration) -> WriterRecord {
    let mut bus: Vec<u16> = (0..taxels).map(|i| (i % 4096) as u16).collect();
    let mut scratch = vec![0u16; taxels];
    let mut record = WriterRecord::default();
    let mut ticker = Ticker::new(period);
    let stop = writer.stop_signal().clone();
    let mut count = 0u64;
    while let Some(tick) = ticker.wait(&stop) {
        record.ticks.push(TickRecord { deadline_ns: tick.deadline_ns, missed: tick.missed });
        record.cpu_ns.push(thread_cpu_now_ns());
        count += 1;
        // The reference, in a period of its own, at the same point of the
        // period as a publish and from the same buffer, before the publish
        // (whose readers then copy beside it): that period's publish is not
        // timed, since the copy warmed its source.
        let reference = count.is_multiple_of(MEMCPY_EVERY);
        if reference {
            let began = skinware::os::monotonic_ns();
            scratch.copy_from_slice(std::hint::black_box(&bus));
            std::hint::black_box(&mut scratch);
            record
                .memcpy
                .push(measure::WriterSample { started_ns: began, took_ns: skinware::os::monotonic_ns() - began });
        }
        // The generator: one word changes per frame.
        if let Some(first) = bus.first_mut() {
            *first = first.wrapping_add(1);
        }
        let started = skinware::os::monotonic_ns();
        let mut frame = writer.begin();
        if frame.write_responses(0, &bus).is_ok() {
            frame.publish();
        }
        let took_ns = skinware::os::monotonic_ns() - started;
        record.last_took_ns.push(took_ns);
        if !reference {
            record.publish.push(measure::WriterSample { started_ns: started, took_ns });
        }
    }
    record
}

/// This thread's CPU time, ns.
fn thread_cpu_now_ns() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::ThreadCPUTime);
    t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64
}

fn print_point(p: &ScalePoint) {
    let us = |ns: u64| ns as f64 / 1e3;
    println!(
        "{:>7} taxels {:>5} Hz {:>2} readers | publish {:>7.1} / {:>7.1} us (memcpy {:>7.1} / {:>7.1}; {:.2}x / {:.2}x) | \
         missed {:>3} of {:>5} ({} by overruns, {} by readers) | reader copy {:>7.1} us ({:.2}x memcpy), latency waiting {:>7.1} / \
         periodic {:>7.1} us, waiting readers missed {:>5.1}% | CPU writer {:>5.1}% + ringer {:>4.1}%, readers {:>5.1}%",
        p.taxels,
        p.rate_hz,
        p.readers,
        us(p.publish_ns.p50),
        us(p.publish_ns.p99),
        us(p.memcpy_ns.p50),
        us(p.memcpy_ns.p99),
        p.publish_over_memcpy_p50,
        p.publish_over_memcpy_p99,
        p.missed_periods,
        p.periods,
        p.overrun_missed,
        p.reader_caused_missed,
        us(p.waiting_copy_ns.p50),
        p.reader_copy_over_memcpy_p50,
        us(p.waiting_latency_ns.p50),
        us(p.periodic_latency_ns.p50),
        100.0 * p.waiting_missed_share,
        p.writer_thread_cpu_percent,
        p.writer_helpers_cpu_percent,
        p.readers_cpu_percent,
    );
}

fn print_frontier(frontier: &[Frontier]) {
    let parts: Vec<String> = frontier
        .iter()
        .map(|f| match f.taxels {
            Some(taxels) => format!("{} Hz: {taxels} taxels", f.rate_hz),
            None => format!("{} Hz: none of the sweep", f.rate_hz),
        })
        .collect();
    println!("frontier (the largest skin with 0 periods missed because of readers): {}", parts.join("; "));
}
