//! `skin services`: the services of a skin, with their state, rate, inputs
//! and per-frame cost.

use std::io::Write;
use std::time::Duration;

use anyhow::Result;
use serde::Serialize;
use skinware::{ChannelKind, FrameStatus};
use skinware_services::framework::ServiceInfo;

use crate::layers::Sampled;

/// Arguments of `skin services`.
#[derive(clap::Args)]
pub struct Args {
    /// Only this skin.
    #[arg(long)]
    skin: Option<String>,
    /// Print JSON for scripts.
    #[arg(long)]
    json: bool,
}

/// One service as `skin services` (and `skin ls`) reports it.
#[derive(Debug, Serialize)]
pub struct ServiceReport {
    skin: String,
    name: String,
    state: &'static str,
    schema: String,
    schema_version: u32,
    records: usize,
    record_bytes: usize,
    inputs: Vec<String>,
    /// The newest frame says an input is faulted, gone or stale.
    inputs_faulted: bool,
    rate_hz: f64,
    /// `None` for a sporadic service.
    nominal_rate_hz: Option<f64>,
    frames: u64,
    faults: u64,
    /// Mean per-frame cost (computing and publishing), ns.
    cost_ns_mean: u64,
    cost_ns_max: u64,
    writer_pid: u32,
}

/// Runs `skin services`.
pub fn run(args: &Args) -> Result<()> {
    let sampled =
        crate::layers::sample_channels(args.skin.as_deref(), &[ChannelKind::Service], Duration::from_millis(500))?;
    let reports = reports(sampled);
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &serde_json::json!({ "services": reports }))?;
        writeln!(out)?;
        return Ok(());
    }
    if reports.is_empty() {
        let Some(skin) = args.skin.as_deref() else {
            writeln!(out, "no services (add [[service]] tables to the config of `skin run`; see examples/README.md)")?;
            return Ok(());
        };
        if skinware::list_skin_channels(&skinware::shm::segment_dir(), skin)?.is_empty() {
            return Err(crate::skins::missing_skin(skin));
        }
        writeln!(out, "skin {skin} has no services (add [[service]] tables to its config; see examples/README.md)")?;
    }
    for report in &reports {
        writeln!(out, "{}", describe(report))?;
    }
    Ok(())
}

/// What the CLI reports of the sampled services.
pub fn reports(sampled: Vec<Sampled>) -> Vec<ServiceReport> {
    let mut reports = Vec::new();
    for Sampled { info, mut reader, rate_hz } in sampled {
        let stats = reader.writer_stats();
        let description = ServiceInfo::parse(&reader.description());
        let (schema, schema_version) = reader.schema();
        let state = reader.writer_state();
        let inputs_faulted = reader.latest().map(|f| f.status().contains(FrameStatus::INPUT_FAULTED)).unwrap_or(false);
        let record_bytes = description.as_ref().map_or(0, |d| d.record_bytes);
        reports.push(ServiceReport {
            skin: info.skin,
            name: info.channel,
            state: state.as_str(),
            schema,
            schema_version,
            records: reader.payload_bytes().checked_div(record_bytes).unwrap_or(0),
            record_bytes,
            inputs: description.as_ref().map(|d| d.inputs.clone()).unwrap_or_default(),
            inputs_faulted,
            rate_hz,
            nominal_rate_hz: description.as_ref().and_then(|d| d.rate_hz),
            frames: stats.frames,
            faults: stats.faults,
            cost_ns_mean: stats.write_ns_mean,
            cost_ns_max: stats.write_ns_max,
            writer_pid: reader.writer_pid(),
        });
    }
    reports
}

/// One line on a service: `default/contact  [running]  skinware.contacts
/// v1, 7 records of 432 B; 50.0 Hz measured (50.0 Hz nominal); cost mean
/// 329 µs, max 1873 µs; inputs: virtual-0, ...`.
pub fn describe(r: &ServiceReport) -> String {
    let nominal = r.nominal_rate_hz.map_or("sporadic".to_owned(), |hz| format!("{hz:.1} Hz nominal"));
    format!(
        "{}/{}  [{}{}]  {} v{}, {} records of {} B; {:.1} Hz measured ({nominal}); cost mean {:.0} µs, max {:.0} µs; inputs: {}",
        r.skin,
        r.name,
        r.state,
        if r.inputs_faulted { ", inputs faulted" } else { "" },
        r.schema,
        r.schema_version,
        r.records,
        r.record_bytes,
        r.rate_hz,
        r.cost_ns_mean as f64 / 1e3,
        r.cost_ns_max as f64 / 1e3,
        if r.inputs.len() > 6 { format!("{} layers", r.inputs.len()) } else { r.inputs.join(", ") }
    )
}
