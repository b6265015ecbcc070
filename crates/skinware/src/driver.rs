//! Drivers and the driver handler: a driver describes its layers and fills
//! their frames; the handler runs one writer thread per layer, each at its own
//! rate, and contains the driver's failures to the layer they happen in.

#![forbid(unsafe_code)]

use crate::sync::{AtomicU64, Ordering};
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use crate::error::Error;
use crate::os;
use crate::rt::{RtOptions, Stop, Ticker};
use crate::stats::WriterState;
use crate::topology::LayerTopology;
use crate::writer::{FrameWriter, Writer, WriterOptions, WriterStateHandle};

/// Whatever a driver's hardware access can fail with.
pub type DriverError = Box<dyn std::error::Error + Send + Sync>;

/// One layer a driver provides.
#[derive(Clone, Debug)]
pub struct LayerSpec {
    /// Its topology; `topology.name` is the channel name and `topology.rate_hz`
    /// the acquisition rate (0 for a sporadic layer, acquired on request).
    pub topology: LayerTopology,
    /// Real-time settings of its writer thread.
    pub rt: RtOptions,
}

/// A driver: knows one network, reports its layers and fills their frames.
pub trait Driver: Send {
    /// A short name for logs.
    fn name(&self) -> &str;

    /// The layers this driver provides.
    fn layers(&self) -> Vec<LayerSpec>;

    /// Start hook: connects to the hardware and returns one source per layer,
    /// in the order of [`layers`](Self::layers). Each source is moved to that
    /// layer's writer thread.
    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError>;

    /// Stop hook, called after every writer thread has stopped.
    fn stop(&mut self) {}
}

/// The acquisition of one layer.
pub trait LayerSource: Send {
    /// Fills `frame` (one `u16` response per sensor, in topology order) in
    /// place. An error marks the layer faulted until an acquisition succeeds.
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError>;
}

/// Errors of the driver handler.
#[derive(Debug, thiserror::Error)]
pub enum HandlerError {
    /// A layer's channel could not be created.
    #[error("driver {driver}: layer {layer}: {source}")]
    Channel {
        /// Driver name.
        driver: String,
        /// Layer name.
        layer: String,
        /// The channel error.
        #[source]
        source: Box<Error>,
    },
    /// The driver's start hook failed.
    #[error("driver {driver} failed to start: {source}")]
    Start {
        /// Driver name.
        driver: String,
        /// Its error.
        #[source]
        source: DriverError,
    },
    /// A layer's rate is not a usable number.
    #[error(
        "driver {driver}: layer {layer}: rate {rate_hz} Hz is not usable; give 0 (sporadic) or a finite rate above 1e-6 Hz"
    )]
    Rate {
        /// Driver name.
        driver: String,
        /// Layer name.
        layer: String,
        /// The rate given.
        rate_hz: f64,
    },
    /// The driver returned a different number of sources than layers.
    #[error("driver {driver} describes {layers} layers but started {sources} sources; it must start one per layer")]
    SourceCount {
        /// Driver name.
        driver: String,
        /// Layers described.
        layers: usize,
        /// Sources started.
        sources: usize,
    },
}

/// How the handler runs a driver.
#[derive(Clone, Debug)]
pub struct HandlerOptions {
    /// Frame buffers per layer channel; 0: enough to keep
    /// [`READABLE_HISTORY`](crate::READABLE_HISTORY) of each layer's frames
    /// ([`slots_for_history`](crate::slots_for_history) of its period).
    pub slots: usize,
    /// An acquisition running longer than this many periods marks its layer
    /// faulted (it cannot be interrupted, but readers learn of it).
    pub timeout_periods: u32,
    /// Segment directory; `None` for the default.
    pub dir: Option<PathBuf>,
    /// Who may read the layers.
    pub access: crate::Access,
    /// Remove the channels when the handler stops (a crash leaves their names
    /// for a successor, which their readers follow).
    pub unlink_on_stop: bool,
}

impl Default for HandlerOptions {
    fn default() -> Self {
        HandlerOptions { slots: 0, timeout_periods: 10, dir: None, access: crate::Access::Owner, unlink_on_stop: true }
    }
}

/// A running driver: one writer thread per layer, plus a watchdog.
pub struct DriverHandler {
    driver: Box<dyn Driver>,
    stop: Stop,
    writers: Vec<JoinHandle<()>>,
    watchdog: Option<JoinHandle<()>>,
    layers: Vec<String>,
}

struct LayerWatch {
    state: WriterStateHandle,
    /// CLOCK_MONOTONIC ns when the current acquisition began; 0 when idle.
    busy_since: Arc<AtomicU64>,
    timeout_ns: u64,
}

impl DriverHandler {
    /// Starts the driver (connects to its hardware), then creates every
    /// layer's channel (taking over dead writers' names) under `skin` and
    /// starts acquiring.
    ///
    /// The hardware comes first: a driver whose device is missing creates
    /// no channel, so its layers never show as running, and a caller that
    /// waits for the device and tries again does not re-create them each
    /// time.
    pub fn start(
        skin: &str,
        mut driver: Box<dyn Driver>,
        options: &HandlerOptions,
    ) -> Result<DriverHandler, HandlerError> {
        let name = driver.name().to_owned();
        let specs = driver.layers();
        let sources = driver.start().map_err(|source| HandlerError::Start { driver: name.clone(), source })?;
        if sources.len() != specs.len() {
            driver.stop();
            return Err(HandlerError::SourceCount { driver: name, layers: specs.len(), sources: sources.len() });
        }
        let writers = match specs
            .iter()
            .map(|spec| create_layer_writer(skin, &name, spec, options))
            .collect::<Result<Vec<_>, _>>()
        {
            Ok(writers) => writers,
            Err(e) => {
                drop(sources);
                driver.stop();
                return Err(e);
            }
        };
        let stop = Stop::new();
        let mut threads = Vec::new();
        let mut watches = Vec::new();
        let epoch_ns = os::monotonic_ns();
        for (index, ((mut writer, source), spec)) in writers.into_iter().zip(sources).zip(&specs).enumerate() {
            writer.set_stop(&stop);
            writer.set_unlink_on_drop(options.unlink_on_stop);
            let origin_ns = epoch_ns + staggered_phase_ns(spec.topology.rate_hz, index, specs.len());
            let (thread, watch) = spawn_layer(writer, source, spec, options.timeout_periods, origin_ns)
                .map_err(|e| HandlerError::Start { driver: name.clone(), source: Box::new(e) })?;
            threads.push(thread);
            watches.push(watch);
        }
        let watchdog_stop = stop.clone();
        let watchdog = std::thread::Builder::new()
            .name("driver-watchdog".into())
            .spawn(move || watch_layers(watches, watchdog_stop))
            .ok();
        let layers = specs.into_iter().map(|s| s.topology.name).collect();
        Ok(DriverHandler { driver, stop, writers: threads, watchdog, layers })
    }

    /// Names of the layers being acquired.
    pub fn layers(&self) -> &[String] {
        &self.layers
    }

    /// The signal that stops this handler (e.g. from a SIGTERM handler).
    pub fn stop_signal(&self) -> &Stop {
        &self.stop
    }

    /// Blocks until the stop signal, then stops every layer and the driver.
    pub fn run_until_stopped(self) {
        while self.stop.sleep_until(u64::MAX) {}
        self.stop();
    }

    /// Stops every writer thread, calls the driver's stop hook and, with
    /// `unlink_on_stop`, removes the layers' channels.
    pub fn stop(mut self) {
        self.stop.stop();
        for thread in self.writers.drain(..) {
            let _ = thread.join();
        }
        if let Some(watchdog) = self.watchdog.take() {
            let _ = watchdog.join();
        }
        self.driver.stop();
    }
}

impl Drop for DriverHandler {
    /// A handler dropped without [`stop`](DriverHandler::stop) still stops its
    /// writer threads (without waiting for them: one may be stuck in the driver).
    fn drop(&mut self) {
        self.stop.stop();
    }
}

/// A layer's period from its rate: `None` for a sporadic layer (rate 0), an
/// error for a rate that is not a usable number of Hz.
fn layer_period(driver: &str, spec: &LayerSpec) -> Result<Option<Duration>, HandlerError> {
    let rate_hz = spec.topology.rate_hz;
    if rate_hz == 0.0 {
        return Ok(None);
    }
    Duration::try_from_secs_f64(1.0 / rate_hz)
        .ok()
        .filter(|_| rate_hz.is_finite() && rate_hz > 1e-6)
        .map(Some)
        .ok_or_else(|| HandlerError::Rate { driver: driver.to_owned(), layer: spec.topology.name.clone(), rate_hz })
}

/// Creates one layer's channel, publishing its topology.
fn create_layer_writer(
    skin: &str,
    driver: &str,
    spec: &LayerSpec,
    options: &HandlerOptions,
) -> Result<Writer, HandlerError> {
    let topology = &spec.topology;
    let period = layer_period(driver, spec)?;
    let writer_options = WriterOptions {
        slots: if options.slots == 0 { crate::slots_for_history(period) } else { options.slots },
        period,
        access: options.access,
        // Until every layer has started, a failure must not remove a
        // channel name that readers of a restarted layer wait on.
        unlink_on_drop: false,
        dir: options.dir.clone(),
        reader_wake: spec.rt.reader_wake,
        ..WriterOptions::default()
    };
    Writer::create(skin, &topology.name, topology.frame_bytes(), &topology.encode(), &writer_options).map_err(
        |source| HandlerError::Channel {
            driver: driver.to_owned(),
            layer: topology.name.clone(),
            source: Box::new(source),
        },
    )
}

/// Where in its period layer `index` of `layers` of one driver acquires:
/// spread evenly over the period. A driver's layers at one rate, all due at
/// the same instant at the same priority, made each other late: on 2 CPUs,
/// `perf sched` of a 5-layer skin at 1 kHz found a writer waiting behind
/// another of its driver's writers in 41 of the 317 wake-ups later than
/// 0.5 ms.
fn staggered_phase_ns(rate_hz: f64, index: usize, layers: usize) -> u64 {
    if rate_hz <= 0.0 || layers == 0 {
        return 0;
    }
    let period_ns = 1e9 / rate_hz;
    (period_ns * index as f64 / layers as f64) as u64
}

/// Starts one layer's writer thread and returns it with what the watchdog
/// needs to notice a hung acquisition. A periodic layer's deadlines lie on
/// the grid through `origin_ns`.
fn spawn_layer(
    writer: Writer,
    source: Box<dyn LayerSource>,
    spec: &LayerSpec,
    timeout_periods: u32,
    origin_ns: u64,
) -> std::io::Result<(JoinHandle<()>, LayerWatch)> {
    let busy_since = Arc::new(AtomicU64::new(0));
    let period_ns = if spec.topology.rate_hz > 0.0 { (1e9 / spec.topology.rate_hz) as u64 } else { 1_000_000_000 };
    let watch = LayerWatch {
        state: writer.state_handle(),
        busy_since: busy_since.clone(),
        timeout_ns: period_ns.saturating_mul(u64::from(timeout_periods.max(1))),
    };
    let rt = spec.rt.clone();
    let rate_hz = spec.topology.rate_hz;
    let thread = std::thread::Builder::new()
        .name(format!("writer-{}", spec.topology.name))
        .spawn(move || run_layer(writer, source, rt, (rate_hz, origin_ns), busy_since))?;
    Ok((thread, watch))
}

/// Acquires a layer until its writer stops: periodically at `schedule`'s
/// rate (Hz) on the grid through its origin (CLOCK_MONOTONIC ns), or on
/// request at rate 0.
fn run_layer(
    mut writer: Writer,
    mut source: Box<dyn LayerSource>,
    rt: RtOptions,
    schedule: (f64, u64),
    busy: Arc<AtomicU64>,
) {
    let (rate_hz, origin_ns) = schedule;
    for refusal in rt.apply() {
        tracing::warn!(layer = %writer.label(), "{refusal}");
    }
    let mut acquire = |frame: &mut FrameWriter<'_>| -> Result<(), String> {
        busy.store(os::monotonic_ns(), Ordering::Relaxed);
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| source.acquire(frame)));
        busy.store(0, Ordering::Relaxed);
        match result {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(e.to_string()),
            Err(panic) => {
                let message = panic
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "unknown panic".into());
                Err(format!("driver panicked: {message}"))
            }
        }
    };
    let result = if rate_hz > 0.0 {
        writer.run_periodic(Ticker::on_grid(Duration::from_secs_f64(1.0 / rate_hz.max(1e-9)), origin_ns), &mut acquire)
    } else {
        writer.run_sporadic(&mut acquire)
    };
    if let Err(e) = result {
        tracing::error!(layer = %writer.label(), error = %e, "writer stopped");
        writer.set_state(WriterState::Faulted);
    }
}

fn watch_layers(watches: Vec<LayerWatch>, stop: Stop) {
    let tick = watches.iter().map(|w| w.timeout_ns / 4).min().unwrap_or(100_000_000).clamp(1_000_000, 100_000_000);
    let mut next = os::monotonic_ns();
    loop {
        next += tick;
        if !stop.sleep_until(next) {
            return;
        }
        let now = os::monotonic_ns();
        for watch in &watches {
            let since = watch.busy_since.load(Ordering::Relaxed);
            if since != 0 && now.saturating_sub(since) > watch.timeout_ns && watch.state.get() != WriterState::Faulted {
                tracing::warn!(layer = %watch.state.label(), "acquisition timed out; layer faulted");
                watch.state.set(WriterState::Faulted);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drivers_layers_are_spread_over_their_period() {
        let phases: Vec<u64> = (0..5).map(|l| staggered_phase_ns(1000.0, l, 5)).collect();
        assert_eq!(phases, [0, 200_000, 400_000, 600_000, 800_000]);
        assert_eq!(staggered_phase_ns(50.0, 1, 2), 10_000_000);
        // A sporadic layer has no period to spread over.
        assert_eq!(staggered_phase_ns(0.0, 3, 5), 0);
    }
}
