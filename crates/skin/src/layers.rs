//! What `ls` and `top` show of a layer, gathered from its channel.

use std::time::Duration;

use anyhow::Result;
use serde::Serialize;
use skinware::{ChannelKind, Reader, ReaderOptions, WriterStats};

/// One layer as the CLI reports it.
#[derive(Debug, Serialize)]
pub struct LayerReport {
    pub skin: String,
    pub name: String,
    pub state: &'static str,
    pub sensor_type: String,
    pub sensors: usize,
    pub modules: usize,
    pub patches: usize,
    /// Measured over the sampling window (see [`rate_between`]).
    pub rate_hz: f64,
    pub nominal_rate_hz: f64,
    pub frames: u64,
    pub overruns: u64,
    /// Deadlines skipped because a period's work ran past the next one.
    pub missed_periods: u64,
    /// Mean lateness of the writer's wake-ups after their deadlines: how
    /// well the machine keeps the writer's time.
    pub lateness_ns_mean: u64,
    /// Worst lateness of a wake-up.
    pub lateness_ns_max: u64,
    pub faults: u64,
    pub restarts: u64,
    pub writer_pid: u32,
    pub write_ns_mean: u64,
    pub write_ns_max: u64,
    /// Publish time minus acquisition time of the newest frame.
    pub latency_ns: u64,
    #[serde(skip)]
    pub tree: Vec<(u32, Vec<(u32, usize)>)>,
    /// The device that feeds it, where its driver reports devices (an
    /// EtherCAT SubDevice: identity, state, fault).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<skin::driver_status::DeviceStatus>,
}

/// A channel with a reader on it and its writer's rate, measured.
pub struct Sampled {
    pub info: skinware::ChannelInfo,
    pub reader: Reader,
    /// Frames per second published during the sampling window (0 if gone
    /// or silent), to 0.01 Hz; see [`rate_between`].
    pub rate_hz: f64,
}

/// The sequence number and publication time of a channel's newest frame.
type Stamp = (u64, u64);

/// The newest frame's [`Stamp`], if there is one.
fn newest(reader: &mut Reader) -> Option<Stamp> {
    reader.latest().ok().map(|frame| (frame.seq(), frame.published_ns()))
}

/// Frames per second between two of a writer's frames, from their sequence
/// numbers and the writer's own publication times: as exact as the
/// writer's clock over however many frames the window held. A count of
/// frames divided by the window (what this replaced) is a multiple of
/// 1/window: 3.33 Hz steps for `skin ls`'s 0.3 s. `None` without two
/// distinct frames in order.
pub fn rate_between(first: Option<Stamp>, last: Option<Stamp>) -> Option<f64> {
    let ((first_seq, first_ns), (last_seq, last_ns)) = (first?, last?);
    if last_seq <= first_seq || last_ns <= first_ns {
        return None;
    }
    Some((last_seq - first_seq) as f64 * 1e9 / (last_ns - first_ns) as f64)
}

/// Opens every channel of one of `kinds` of `skin` (or of all skins) and
/// measures their writers' rates over `window` (see [`rate_between`]).
pub fn sample_channels(skin: Option<&str>, kinds: &[ChannelKind], window: Duration) -> Result<Vec<Sampled>> {
    let channels = skinware::list_channels_where(&skinware::shm::segment_dir(), skin, |_| true)?;
    let mut readers = Vec::new();
    for info in channels {
        if skin.is_some_and(|s| s != info.skin) || !info.kind.is_some_and(|kind| kinds.contains(&kind)) {
            continue;
        }
        let options = ReaderOptions { allow_gone: true, ..ReaderOptions::default() };
        if let Ok(mut reader) = Reader::open_with(&info.skin, &info.channel, &options) {
            let before = (reader.writer_stats().frames, newest(&mut reader));
            readers.push((info, reader, before));
        }
    }
    let started = std::time::Instant::now();
    std::thread::sleep(window);
    let elapsed = started.elapsed().as_secs_f64();
    Ok(readers
        .into_iter()
        .map(|(info, mut reader, (frames_before, first))| {
            let gone = reader.writer_state() == skinware::WriterState::Gone;
            let last = newest(&mut reader);
            // Without two frames to time (a writer that has just begun, or
            // was replaced meanwhile), the count over the window.
            let counted = || reader.writer_stats().frames.saturating_sub(frames_before) as f64 / elapsed;
            let rate = if gone { 0.0 } else { rate_between(first, last).unwrap_or_else(counted) };
            Sampled { info, reader, rate_hz: (rate * 100.0).round() / 100.0 }
        })
        .collect())
}

/// Opens every layer channel of `skin` (or of all skins) and measures their
/// rates over `window`.
pub fn gather(skin: Option<&str>, window: Duration) -> Result<Vec<LayerReport>> {
    Ok(reports(sample_channels(skin, &[ChannelKind::Layer], window)?))
}

/// What the CLI reports of the sampled layers.
pub fn reports(sampled: Vec<Sampled>) -> Vec<LayerReport> {
    let mut reports = Vec::new();
    for Sampled { info, mut reader, rate_hz } in sampled {
        let stats: WriterStats = reader.writer_stats();
        let topology = reader.topology().ok();
        let latency_ns = reader.latest().map(|f| f.published_ns().saturating_sub(f.acquired_ns())).unwrap_or(0);
        let state = reader.writer_state();
        let tree = topology
            .as_ref()
            .map(|t| {
                t.patches
                    .iter()
                    .map(|p| (p.id, t.modules[p.modules.clone()].iter().map(|m| (m.id, m.sensors.len())).collect()))
                    .collect()
            })
            .unwrap_or_default();
        reports.push(LayerReport {
            skin: info.skin,
            name: info.channel,
            state: state.as_str(),
            sensor_type: topology.as_ref().map(|t| t.sensor_type.clone()).unwrap_or_default(),
            sensors: topology.as_ref().map_or(0, |t| t.sensors.len()),
            modules: topology.as_ref().map_or(0, |t| t.modules.len()),
            patches: topology.as_ref().map_or(0, |t| t.patches.len()),
            rate_hz,
            nominal_rate_hz: topology.as_ref().map_or(0.0, |t| t.rate_hz),
            frames: stats.frames,
            overruns: stats.overruns,
            missed_periods: stats.missed_periods,
            lateness_ns_mean: stats.lateness_ns_mean,
            lateness_ns_max: stats.lateness_ns_max,
            faults: stats.faults,
            restarts: reader.writer_generation().saturating_sub(1),
            writer_pid: reader.writer_pid(),
            write_ns_mean: stats.write_ns_mean,
            write_ns_max: stats.write_ns_max,
            latency_ns,
            tree,
            device: None,
        });
    }
    reports
}

/// The status of every live driver that reports its devices, of `skin` or of
/// every skin; files of drivers that are gone are left out (`skin clean`
/// removes them), unreadable ones are warned about.
pub fn driver_statuses(skin: Option<&str>) -> Result<Vec<skin::driver_status::DriverStatus>> {
    let dir = skinware::shm::segment_dir();
    let now = skin::driver_status::now_ns();
    let mut statuses = Vec::new();
    for found in skin::driver_status::find(&dir, skin)? {
        match found.status {
            Ok(status) if status.is_live(now) => statuses.push(status),
            Ok(_) => {}
            Err(why) => eprintln!("warning: {}: {why}", found.path.display()),
        }
    }
    Ok(statuses)
}

/// Attaches to each layer the device its driver reports for it.
pub fn attach_devices(layers: &mut [LayerReport], drivers: &[skin::driver_status::DriverStatus]) {
    for layer in layers {
        layer.device = drivers
            .iter()
            .filter(|d| d.skin == layer.skin)
            .flat_map(|d| &d.devices)
            .find(|device| device.layer == layer.name)
            .cloned();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rate_is_timed_by_the_writers_clock() {
        // 11 frames of a 41.3 Hz writer: 266.3 ms between the first and the last.
        let period_ns = 1e9 / 41.3;
        let first = (100, 5_000_000_000);
        let last = (111, 5_000_000_000 + (11.0 * period_ns) as u64);
        let rate = rate_between(Some(first), Some(last)).unwrap();
        assert!((rate - 41.3).abs() < 1e-6, "{rate}");
    }

    #[test]
    fn without_two_ordered_frames_there_is_no_rate() {
        assert_eq!(rate_between(None, Some((2, 20))), None);
        assert_eq!(rate_between(Some((2, 20)), None), None);
        assert_eq!(rate_between(Some((2, 20)), Some((2, 20))), None, "no new frame");
        assert_eq!(rate_between(Some((9, 20)), Some((3, 40))), None, "a successor's frames start again");
        assert_eq!(rate_between(Some((2, 40)), Some((3, 40))), None, "no time between them");
    }
}
