//! `skin echo LAYER`: print a layer's frames, in any reader mode.

use std::io::Write;
use std::time::Duration;

use anyhow::{Context, Result};
use skinware::{ChannelKind, Error, Reader, ReaderOptions, Ticker};
use skinware_services::{MotionRecord, RegionContacts, TaxelState, contact_flags, motion_flags};

/// How `echo` reads.
#[derive(Clone, Copy, clap::ValueEnum)]
enum Mode {
    /// At a fixed rate (--rate), absolute time.
    Periodic,
    /// Every frame, as soon as it is published.
    Asap,
    /// Ask for a frame (a sporadic writer acquires one) every period.
    Request,
}

/// Arguments of `skin echo`.
#[derive(clap::Args)]
pub struct Args {
    /// The layer (channel) name.
    #[arg(required_unless_present = "service", conflicts_with = "service")]
    layer: Option<String>,
    /// Print a service's output instead (contact, motion or taxel states, decoded).
    #[arg(long)]
    service: Option<String>,
    /// The skin.
    #[arg(long, default_value = "default")]
    skin: String,
    /// Reader mode.
    #[arg(long, value_enum, default_value = "asap")]
    mode: Mode,
    /// Rate of the periodic and request modes, Hz.
    #[arg(long, default_value_t = 10.0)]
    rate: f64,
    /// Stop after this many frames.
    #[arg(long)]
    count: Option<u64>,
    /// Print every response, not just a summary.
    #[arg(long)]
    full: bool,
    /// Seconds to wait for a frame before reporting the writer's state.
    #[arg(long, default_value_t = 2.0)]
    timeout: f64,
    #[command(flatten)]
    remote: super::bridge::RemoteArgs,
}

/// Runs `skin echo`.
pub fn run(args: &Args) -> Result<()> {
    let (what, channel) = match (&args.layer, &args.service) {
        (_, Some(service)) => ("service", service.as_str()),
        (Some(layer), None) => ("layer", layer.as_str()),
        (None, None) => anyhow::bail!("name a layer, or a service with --service"),
    };
    if args.remote.remote.is_some() {
        let mode = match args.mode {
            Mode::Periodic => super::bridge::EchoMode::Periodic,
            Mode::Asap => super::bridge::EchoMode::Asap,
            Mode::Request => super::bridge::EchoMode::Request,
        };
        let echo = super::bridge::RemoteEcho {
            skin: args.skin.clone(),
            channel: channel.to_owned(),
            mode,
            rate: args.rate,
            count: args.count,
            full: args.full,
            timeout: args.timeout,
        };
        return super::bridge::echo(&args.remote, &echo);
    }
    let mut reader = open(args, what, channel)?;
    let decoder = if args.service.is_some() { Some(ServiceDecoder::new(&reader)?) } else { None };
    let timeout = Duration::from_secs_f64(args.timeout.clamp(0.001, 86_400.0));
    let mut ticker = Ticker::from_hz(args.rate.clamp(0.001, 100_000.0));
    let mut out = std::io::stdout().lock();
    let mut printed = 0;
    while args.count.is_none_or(|count| printed < count) {
        let result = match args.mode {
            Mode::Periodic => reader.next_periodic(&mut ticker),
            Mode::Asap => reader.wait_newer(timeout),
            Mode::Request => {
                let _ = ticker.wait(reader.stop_signal());
                reader.request(timeout)
            }
        };
        match result {
            Ok(frame) if decoder.is_some() => {
                let decoder = decoder.as_ref().expect("checked");
                writeln!(
                    out,
                    "seq {} acquired {} ns status {:#x}",
                    frame.seq(),
                    frame.acquired_ns(),
                    frame.status().0
                )?;
                decoder.print(frame.bytes(), args.full, &mut out)?;
                printed += 1;
            }
            Ok(frame) => {
                let responses = frame.responses();
                let (min, max) = responses.iter().fold((u16::MAX, 0), |(lo, hi), &r| (lo.min(r), hi.max(r)));
                let mean = responses.iter().map(|&r| f64::from(r)).sum::<f64>() / responses.len().max(1) as f64;
                write!(
                    out,
                    "seq {} acquired {} ns status {:#x} skipped {} sensors {} min {min} mean {mean:.1} max {max}",
                    frame.seq(),
                    frame.acquired_ns(),
                    frame.status().0,
                    frame.skipped(),
                    responses.len()
                )?;
                if args.full {
                    write!(out, " responses {responses:?}")?;
                }
                writeln!(out)?;
                printed += 1;
            }
            Err(Error::Timeout { .. } | Error::NoFrameYet { .. } | Error::WriterGone { .. }) => {
                writeln!(out, "no new frame; writer is {}", reader.writer_state())?;
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

/// A reader of the `what` (layer or service) `channel`; one that is not
/// there is said with the skins and channels that are, not its path.
fn open(args: &Args, what: &str, channel: &str) -> Result<Reader> {
    let options = ReaderOptions { allow_gone: true, ..ReaderOptions::default() };
    let context = || format!("cannot attach to {what} {}/{channel}", args.skin);
    match Reader::open_with(&args.skin, channel, &options) {
        Ok(reader) => Ok(reader),
        Err(Error::Missing { .. }) => {
            let kind = if args.service.is_some() { ChannelKind::Service } else { ChannelKind::Layer };
            Err(crate::skins::missing_channel(&args.skin, channel, kind)).with_context(context)
        }
        Err(e) => Err(e).with_context(context),
    }
}

/// Decodes the records of the services this crate knows.
struct ServiceDecoder {
    schema: String,
    labels: Vec<String>,
}

impl ServiceDecoder {
    fn new(reader: &Reader) -> Result<ServiceDecoder> {
        use skinware_services::framework::ServicePayload;
        if reader.kind() != skinware::ChannelKind::Service {
            anyhow::bail!("{} is a layer, not a service; drop --service to echo it", reader.label());
        }
        let (schema, version) = reader.schema();
        let info = skinware_services::framework::ServiceInfo::parse(&reader.description());
        let expected = match schema.as_str() {
            s if s == RegionContacts::SCHEMA => Some((RegionContacts::VERSION, std::mem::size_of::<RegionContacts>())),
            s if s == MotionRecord::SCHEMA => Some((MotionRecord::VERSION, std::mem::size_of::<MotionRecord>())),
            s if s == TaxelState::SCHEMA => Some((TaxelState::VERSION, std::mem::size_of::<TaxelState>())),
            _ => None,
        };
        if let Some((expected_version, record_bytes)) = expected
            && (version != expected_version || info.as_ref().is_none_or(|i| i.record_bytes != record_bytes))
        {
            anyhow::bail!(
                "{} publishes {schema} version {version}; this skin command reads version {expected_version}: rebuild it against the same skinware",
                reader.label()
            );
        }
        Ok(ServiceDecoder { schema, labels: info.map(|i| i.labels).unwrap_or_default() })
    }

    fn label(&self, k: usize) -> String {
        self.labels.get(k).cloned().unwrap_or_else(|| format!("#{k}"))
    }

    fn print(&self, bytes: &[u8], full: bool, out: &mut impl Write) -> Result<()> {
        use skinware_services::framework::ServicePayload;
        if self.schema == RegionContacts::SCHEMA {
            self.print_contacts(bytes, out)?;
        } else if self.schema == MotionRecord::SCHEMA {
            self.print_motion(bytes, out)?;
        } else if self.schema == TaxelState::SCHEMA {
            print_taxel_states(bytes, full, out)?;
        } else {
            writeln!(out, "  {} bytes of schema {:?} (not decoded by this command)", bytes.len(), self.schema)?;
        }
        Ok(())
    }

    /// One line per region, then one per contact in it.
    fn print_contacts(&self, bytes: &[u8], out: &mut impl Write) -> Result<()> {
        let records: Vec<RegionContacts> = bytemuck::pod_collect_to_vec(bytes);
        for (k, r) in records.iter().enumerate() {
            let faulted = if r.flags & contact_flags::INPUT_FAULTED != 0 { " INPUT FAULTED" } else { "" };
            writeln!(out, "  {}: {} contacts, {} dead, {} stuck{faulted}", self.label(k), r.count, r.dead, r.stuck)?;
            for c in r.contacts() {
                writeln!(
                    out,
                    "    {} taxels, area {:.1} cm², total {:.0}, peak {:.0} at sensor {}; centroid [{:.1}, {:.1}, {:.1}] mm, map [{:.1}, {:.1}] mm, normal [{:.2}, {:.2}, {:.2}]",
                    c.taxels,
                    c.area_m2 * 1e4,
                    c.total,
                    c.peak,
                    c.peak_sensor,
                    mm(c.centroid[0]),
                    mm(c.centroid[1]),
                    mm(c.centroid[2]),
                    mm(c.map[0]),
                    mm(c.map[1]),
                    c.normal[0],
                    c.normal[1],
                    c.normal[2]
                )?;
            }
        }
        Ok(())
    }

    /// One line per region: its state and, in contact, how it moves.
    fn print_motion(&self, bytes: &[u8], out: &mut impl Write) -> Result<()> {
        let records: Vec<MotionRecord> = bytemuck::pod_collect_to_vec(bytes);
        for (k, r) in records.iter().enumerate() {
            let state = if r.flags & motion_flags::SLIDING != 0 {
                "sliding"
            } else if r.flags & motion_flags::CONTACT != 0 {
                "contact"
            } else {
                "no contact"
            };
            let faulted = if r.flags & motion_flags::INPUT_FAULTED != 0 { " INPUT FAULTED" } else { "" };
            write!(out, "  {}: {state}{faulted}", self.label(k))?;
            if r.flags & motion_flags::CONTACT != 0 {
                write!(
                    out,
                    " for {:.2} s; {:.1} mm/s in 3-D, {:.1} mm/s at {:.0}° on the map; from [{:.1}, {:.1}, {:.1}] to [{:.1}, {:.1}, {:.1}] mm",
                    r.duration_s,
                    mm(r.speed_3d),
                    mm(r.speed_map),
                    r.direction_map_rad.to_degrees(),
                    mm(r.start_3d[0]),
                    mm(r.start_3d[1]),
                    mm(r.start_3d[2]),
                    mm(r.now_3d[0]),
                    mm(r.now_3d[1]),
                    mm(r.now_3d[2])
                )?;
            }
            writeln!(out)?;
        }
        Ok(())
    }
}

/// Metres to millimetres.
fn mm(v: f32) -> f32 {
    v * 1e3
}

/// How many taxels are in each state, and with `full` every taxel's state.
fn print_taxel_states(bytes: &[u8], full: bool, out: &mut impl Write) -> Result<()> {
    let mut counts = [0usize; 5];
    for &b in bytes {
        counts[usize::from(b).min(4)] += 1;
    }
    writeln!(
        out,
        "  {} taxels: {} idle, {} touched, {} dead, {} stuck, {} without input",
        bytes.len(),
        counts[0],
        counts[1],
        counts[2],
        counts[3],
        counts[4]
    )?;
    if full {
        writeln!(out, "  states {bytes:?}")?;
    }
    Ok(())
}
