//! `skin emulate`: software skin boards that speak the real protocol on the
//! device side, for users without the hardware and for tests.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use skinware_emulate::{MtbEmulation, MtbFaults, Transport};

/// Which boards.
#[derive(clap::Subcommand)]
pub enum Which {
    /// iCub MTB skin boards: B boards of T triangles (12 taxels each).
    IcubMtb(MtbArgs),
    /// EtherCAT tactile segments (one SubDevice each) answering raw frames on
    /// a network interface (needs CAP_NET_RAW, or a network namespace of
    /// one's own: `unshare -rn`).
    Ethercat(EthercatArgs),
}

/// Options of `skin emulate ethercat`.
#[derive(clap::Args)]
pub struct EthercatArgs {
    /// The network interface to answer on (one end of a veth pair, say).
    #[arg(long)]
    interface: String,
    /// Segments (SubDevices) in the line.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..=16))]
    segments: u16,
    /// Taxels per segment.
    #[arg(long, default_value_t = 708, value_parser = clap::value_parser!(u16).range(1..=2048))]
    taxels: u16,
    /// Fault: lose every Nth process-data frame (the bring-up's are never lost).
    #[arg(long)]
    drop_every: Option<std::num::NonZeroU64>,
    /// Fault: answer every Nth process-data frame late (by --late-by-ms).
    #[arg(long, requires = "late_by_ms")]
    late_every: Option<std::num::NonZeroU64>,
    /// How late, in milliseconds, those answers are (more than the driver's frame timeout makes them late answers).
    #[arg(long, requires = "late_every")]
    late_by_ms: Option<u64>,
    /// The segment the per-segment faults hit (from 0).
    #[arg(long, default_value_t = 0)]
    fault_segment: usize,
    /// Fault: that segment leaves the process data's working counter alone.
    #[arg(long)]
    wrong_wkc: bool,
    /// Fault: that segment drops out of OP this many seconds after entering it.
    #[arg(long)]
    leave_op_after: Option<f64>,
    /// Fault: every segment stops answering (a pulled cable) this many seconds after the start.
    #[arg(long)]
    link_down_after: Option<f64>,
    /// Seed of the virtual body's moving contacts.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// SCHED_FIFO priority of the emulator's thread.
    #[arg(long, default_value = "70")]
    fifo_priority: Option<u8>,
    /// Write a pcapng capture of every frame taken and answer sent (Wireshark reads it).
    #[arg(long)]
    capture: Option<PathBuf>,
}

/// Options of `skin emulate icub-mtb`.
#[derive(clap::Args)]
pub struct MtbArgs {
    /// Boards on the bus (addresses 1..=B, at most 15).
    #[arg(long, default_value_t = 4)]
    boards: u8,
    /// Triangles per board (at most 16).
    #[arg(long, default_value_t = 16)]
    triangles: u8,
    /// Frames per second per triangle until the host configures a period.
    #[arg(long, default_value_t = 50.0)]
    rate: f64,
    /// Be an SLCAN adapter on a pseudo-terminal (the default).
    #[arg(long, conflicts_with = "cannelloni")]
    slcan: bool,
    /// With SLCAN: also make this path a symbolic link to the pseudo-terminal.
    #[arg(long, conflicts_with = "cannelloni")]
    link: Option<PathBuf>,
    /// Speak cannelloni from this address (e.g. 127.0.0.1:20000) ...
    #[arg(long, requires = "peer")]
    cannelloni: Option<String>,
    /// ... to the host at this address.
    #[arg(long)]
    peer: Option<String>,
    /// Also write every frame sent to this file, in `candump -l` format.
    #[arg(long)]
    candump: Option<PathBuf>,
    /// Fault: never send a triangle's tail frame.
    #[arg(long)]
    drop_tails: bool,
    /// Fault: report this error code (1 I2C no-ack, 2 not connected) in every tail.
    #[arg(long, value_parser = clap::value_parser!(u8).range(0..16))]
    error_nibble: Option<u8>,
    /// Fault: fall silent this many seconds after streaming starts.
    #[arg(long)]
    silence_after: Option<f64>,
    /// Seed of the virtual body's moving contacts.
    #[arg(long, default_value_t = 7)]
    seed: u64,
    /// SCHED_FIFO priority of the boards' thread (real boards are punctual).
    #[arg(long, default_value = "70")]
    fifo_priority: Option<u8>,
}

/// Runs `skin emulate`: prints the URL a host opens on the first line of
/// stdout, then streams until SIGINT or SIGTERM.
pub fn run(which: &Which) -> Result<()> {
    let args = match which {
        Which::IcubMtb(args) => args,
        Which::Ethercat(args) => return run_ethercat(args),
    };
    if args.boards == 0 || args.boards > 15 || args.triangles == 0 || args.triangles > 16 {
        bail!("--boards must be 1 to 15 and --triangles 1 to 16 (an MTB bus addresses 15 boards of 16 triangles)");
    }
    if let Some(seconds) = args.silence_after
        && !(seconds.is_finite() && seconds >= 0.0)
    {
        bail!("--silence-after must be a number of seconds, 0 or more");
    }
    let transport = match (&args.cannelloni, &args.peer) {
        (Some(local), Some(peer)) => Transport::Cannelloni { local: local.clone(), peer: peer.clone() },
        _ => Transport::Slcan { link: args.link.clone() },
    };
    let emulation = MtbEmulation {
        boards: args.boards,
        triangles: args.triangles,
        rate_hz: args.rate,
        transport,
        candump: args.candump.clone(),
        faults: MtbFaults {
            drop_tails: args.drop_tails,
            error_nibble: args.error_nibble,
            silence_after: args.silence_after.map(Duration::from_secs_f64),
        },
        seed: args.seed,
        fifo_priority: args.fifo_priority,
    };
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("cannot install signal handlers")?;
    }
    let sent = emulation
        .run(
            |url| {
                println!("{url}");
                use std::io::Write;
                let _ = std::io::stdout().flush();
                tracing::info!(%url, boards = args.boards, triangles = args.triangles, "emulated MTB boards ready; they stream once a host starts them");
            },
            &|| stop.load(Ordering::Relaxed),
        )
        .context("the emulated boards failed")?;
    tracing::info!(frames = sent, "emulated boards stopped");
    Ok(())
}

/// Runs `skin emulate ethercat`: prints the interface on the first line of
/// stdout once it answers, then answers until SIGINT or SIGTERM.
fn run_ethercat(args: &EthercatArgs) -> Result<()> {
    let seconds = |name: &str, value: Option<f64>| -> Result<Option<Duration>> {
        match value {
            None => Ok(None),
            Some(s) => match Duration::try_from_secs_f64(s) {
                Ok(duration) => Ok(Some(duration)),
                Err(_) => bail!("--{name} {s}: give a number of seconds, 0 or more"),
            },
        }
    };
    let emulation = skinware_emulate::ethercat::EthercatEmulation {
        segments: usize::from(args.segments),
        taxels: usize::from(args.taxels),
        interface: args.interface.clone(),
        seed: args.seed,
        faults: skinware_emulate::ethercat::EmulationFaults {
            drop_every_nth_frame: args.drop_every,
            late_every_nth_frame: args.late_every,
            late_by: Duration::from_millis(args.late_by_ms.unwrap_or(0)),
            segment: args.fault_segment,
            wrong_working_counter: args.wrong_wkc,
            leave_op_after: seconds("leave-op-after", args.leave_op_after)?,
            link_down_after: seconds("link-down-after", args.link_down_after)?,
        },
        fifo_priority: args.fifo_priority,
        capture: args.capture.clone(),
    };
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("cannot install signal handlers")?;
    }
    let stats = emulation
        .run(
            |interface| {
                println!("{interface}");
                use std::io::Write;
                let _ = std::io::stdout().flush();
                tracing::info!(%interface, segments = args.segments, taxels = args.taxels, "emulated EtherCAT segments answering");
            },
            &|| stop.load(Ordering::Relaxed),
        )
        .context("the emulated EtherCAT segments failed")?;
    tracing::info!(frames = stats.frames, answered = stats.answered, "emulated EtherCAT segments stopped");
    Ok(())
}

/// Runs the `[[emulator]]` table `name` of a configuration (what `skin run`
/// starts for it), until SIGINT, SIGTERM or the supervisor's death.
pub fn run_configured(config_path: &std::path::Path, name: &str) -> Result<()> {
    super::run::watch_supervisor()?;
    let config = skin::config::Config::load(config_path)?;
    let emulation = config.emulator(name)?.emulation();
    let stop = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(signal, stop.clone()).context("cannot install signal handlers")?;
    }
    match emulation {
        skin::config::Emulation::Mtb(emulation) => {
            emulation
                .run(|url| tracing::info!(emulator = name, %url, "emulated boards ready"), &|| {
                    stop.load(Ordering::Relaxed)
                })
                .with_context(|| format!("emulator {name} failed"))?;
        }
        skin::config::Emulation::Ethercat(emulation) => {
            emulation
                .run(
                    |interface| tracing::info!(emulator = name, %interface, "emulated EtherCAT segments answering"),
                    &|| stop.load(Ordering::Relaxed),
                )
                .with_context(|| format!("emulator {name} failed"))?;
        }
    }
    Ok(())
}
