//! `skin bench`: the benchmarks (they print tables and write JSON and plots).

use std::path::PathBuf;

use anyhow::{Context, Result};

/// Which benchmark.
#[derive(clap::Subcommand)]
pub enum Which {
    /// The paper's performance test (Fig. 6): 1..5 layers x 1..15 apps.
    Paper(PaperArgs),
    /// The paper's Table I: a 180-sensor CAN layer and a 708-sensor EtherCAT layer.
    Table1(Table1Args),
    /// The EtherCAT driver on a veth pair against the ESC model (in a network namespace of its own): cycle rate and jitter at 1 kHz, latency from the SubDevice to a reader, fault detection and recovery.
    Ethercat(Common),
    /// A CAN skin on the real driver path: emulated MTB boards over SLCAN, frames/s and latency to a reader.
    Can(Common),
    /// The whole-skin frame to 1, 4 and 15 waiting readers: skinware, iceoryx2 (feature), a lock-based baseline, memcpy, cyclictest.
    Peers(Common),
    /// The recorder (zstd, lz4, none) and the replay on the paper's skin: throughput, CPU, file size, timing error.
    Record(Common),
    /// The contact service's cost per frame on the paper's skin with scripted contacts: the detector alone, and the service beside the skin's writers.
    Contact(Common),
    /// The Python bindings beside the Rust reader on a 30,848-sensor layer of `skin run`: latest(), read_into(), wait_newer() latency ($SKINWARE_PYTHON).
    Python(Common),
    /// A 1 kHz writer of the whole skin's frame with 0 or 15 readers asleep on the futex, woken by the writer or by its ringer: period start to visible, start jitter, missed periods, reader latency, CPU.
    Wake(Common),
    /// The paper's skin at 1 kHz alone, then with 15 applications, both services at 1 kHz, the viewer with 3 browsers and the recorder; then the viewer with 1 and 10 browsers: missed periods, publish times, CPU per component, latency from acquisition.
    Kilohertz(KilohertzArgs),
    /// Readers in every mode beside a 1 kHz writer that is SIGKILLed and restarted: the successor's first publication to each reader holding a frame of it, with the successor watcher and with the 100 ms re-check of before.
    Follow(FollowArgs),
    /// The paper's skin across a veth link between two network namespaces: `skin bridge` (feature `zenoh`) beside the local exchange, at 100/10/1 Mbit/s, and a cut link (needs root).
    Bridge(Common),
    /// Faults for N minutes on a skin of virtual drivers under `skin run`, with verifying readers in every mode, both services, the viewer and a browser, and a recorder: torn, backwards and lost frames, stuck readers, leaks, and how long every layer takes to run again after each kind of fault.
    Soak(super::soak::SoakArgs),
}

/// Options every benchmark takes.
#[derive(clap::Args)]
pub struct Common {
    /// A short, CI-sized run.
    #[arg(long)]
    pub quick: bool,
    /// Directory for the JSON and plots.
    #[arg(long, default_value = "target/bench")]
    pub out: PathBuf,
    /// Seconds per configuration (and round; overrides the default of --quick or the full run).
    #[arg(long, value_parser = parse_bench_seconds)]
    pub seconds: Option<f64>,
}

/// The longest `--seconds` a bench accepts: a day per configuration.
const MAX_BENCH_SECONDS: f64 = 86_400.0;

/// The longest `--seconds` of the benches' own helper processes, which their
/// bench starts with its `--seconds` plus a margin (at most a minute now).
const MAX_HELPER_SECONDS: f64 = 2.0 * MAX_BENCH_SECONDS;

/// `--seconds`: a positive, finite number of seconds up to a day, refused
/// here rather than as a panic deep in a bench (`1e20` seconds is no
/// `Duration` at all).
fn parse_bench_seconds(text: &str) -> Result<f64, String> {
    parse_seconds_up_to(text, MAX_BENCH_SECONDS, "a day")
}

/// `--seconds` of a bench's helper process (hidden roles).
pub(crate) fn parse_helper_seconds(text: &str) -> Result<f64, String> {
    parse_seconds_up_to(text, MAX_HELPER_SECONDS, "two days")
}

fn parse_seconds_up_to(text: &str, most: f64, said: &str) -> Result<f64, String> {
    let seconds: f64 = text.trim().parse().map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if seconds.is_finite() && seconds > 0.0 && seconds <= most {
        Ok(seconds)
    } else {
        Err(format!("{text} seconds: give more than 0 and at most {most} ({said})"))
    }
}

/// Options of `skin bench paper`.
#[derive(clap::Args)]
pub struct PaperArgs {
    #[command(flatten)]
    common: Common,
    /// Times to run the whole grid, interleaved, pooling each configuration's
    /// samples (default 1 with --quick, 3 for the full run).
    #[arg(long)]
    rounds: Option<u32>,
}

/// Options of `skin bench kilohertz`.
#[derive(clap::Args)]
pub struct KilohertzArgs {
    #[command(flatten)]
    common: Common,
    /// Measure the viewer of another `skin` build (for a before/after).
    #[arg(long, hide = true)]
    viewer_exe: Option<PathBuf>,
    /// Run only this part (`viewer`: the viewer alone with 1, 10 and 9 + 1
    /// slow browsers, written to `kilohertz-viewer.json`).
    #[arg(long)]
    only: Option<super::kilohertz::Part>,
    /// Who wakes the layers' sleeping readers (`reader_wake` under
    /// `[driver.rt]`); the library's default if absent.
    #[arg(long)]
    reader_wake: Option<super::kilohertz::Wake>,
    /// Bytes of the floor server's message, 1 to 16 MiB, to see what an
    /// update's size costs a browser (default: the viewer's update, 61,832
    /// bytes; the viewer part only).
    #[arg(long, value_parser = super::kilohertz::floor::parse_update_bytes)]
    floor_bytes: Option<usize>,
    /// The floor server reads every layer with the viewer's own readers and
    /// sends their board, instead of a stand-in message: the viewer without
    /// what its sessions decide, whose 10/1 ratio is that of a viewer whose
    /// sessions cost only the message (the viewer part only; not with
    /// --floor-bytes).
    #[arg(long)]
    floor_reads_skin: bool,
}

/// Options of `skin bench table1`.
#[derive(clap::Args)]
pub struct Table1Args {
    #[command(flatten)]
    common: Common,
    /// Where one writer's data comes from: `memory` (both), `slcan` (the CAN
    /// writer: emulated MTB boards on a pseudo-terminal, through the SLCAN
    /// codec and the icub-mtb decoder) or `ethercat` (the EtherCAT writer:
    /// ethercrab on a veth pair against the ESC model, in a network
    /// namespace of the bench's own).
    #[arg(long, default_value = "memory", value_parser = ["memory", "slcan", "ethercat"])]
    transport: String,
}

/// Options of `skin bench follow`.
#[derive(clap::Args)]
pub struct FollowArgs {
    #[command(flatten)]
    common: Common,
    /// Writer restarts to measure (default 100; 15 with --quick).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=100_000))]
    rounds: Option<u32>,
}

/// Arguments of the hidden `bench-follow-writer` role.
#[derive(clap::Args)]
pub struct FollowWriterArgs {
    #[arg(long)]
    dir: PathBuf,
}

/// Runs the writer process of `skin bench follow`.
pub fn follow_writer(args: &FollowWriterArgs) -> Result<()> {
    skinware_bench::follow::run_writer(&skinware_bench::follow::FollowWriterArgs { dir: args.dir.clone() })
}

/// Arguments of the hidden `bench-app` role.
#[derive(clap::Args)]
pub struct AppArgs {
    #[arg(long)]
    skin: String,
    #[arg(long, value_delimiter = ',')]
    layers: Vec<String>,
    #[arg(long, default_value = "periodic")]
    mode: String,
    #[arg(long, value_parser = parse_helper_seconds)]
    seconds: f64,
    #[arg(long)]
    seed: u64,
    #[arg(long)]
    out: PathBuf,
}

/// Runs `skin bench ...`.
pub fn run(which: &Which) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the skin executable")?;
    match which {
        Which::Paper(PaperArgs { common, rounds }) => {
            let options = skinware_bench::paper::PaperOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                rounds: *rounds,
                exe,
            };
            skinware_bench::paper::run(&options).map(|_| ())
        }
        Which::Table1(Table1Args { common, transport }) => {
            let transport = match transport.as_str() {
                "slcan" => skinware_bench::table1::Transport::Slcan,
                "ethercat" => {
                    enter_own_network_namespace()?;
                    skinware_bench::table1::Transport::Ethercat
                }
                _ => skinware_bench::table1::Transport::Memory,
            };
            let options = skinware_bench::table1::Table1Options {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                exe,
                transport,
            };
            skinware_bench::table1::run(&options).map(|_| ())
        }
        Which::Ethercat(common) => {
            enter_own_network_namespace()?;
            let options = skinware_bench::ethercat::EthercatOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                exe,
            };
            skinware_bench::ethercat::run(&options).map(|_| ())
        }
        Which::Can(common) => {
            let options = skinware_bench::can::CanOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
            };
            skinware_bench::can::run(&options).map(|_| ())
        }
        Which::Peers(common) => {
            let options = skinware_bench::peers::PeersOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                exe,
            };
            skinware_bench::peers::run(&options).map(|_| ())
        }
        Which::Wake(common) => {
            let options = skinware_bench::wake::WakeOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                exe,
            };
            skinware_bench::wake::run(&options).map(|_| ())
        }
        Which::Record(common) => {
            let options = skinware_bench::record::RecordBenchOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                exe,
            };
            skinware_bench::record::run(&options).map(|_| ())
        }
        Which::Kilohertz(KilohertzArgs { common, viewer_exe, only, reader_wake, floor_bytes, floor_reads_skin }) => {
            let options = super::kilohertz::Options {
                viewer_exe: viewer_exe.as_deref(),
                only: *only,
                wake: *reader_wake,
                floor_bytes: *floor_bytes,
                floor_reads_skin: *floor_reads_skin,
            };
            super::kilohertz::bench(common, &options)
        }
        Which::Bridge(common) => super::bridge_bench::bench(common),
        Which::Follow(FollowArgs { common, rounds }) => {
            let options = skinware_bench::follow::FollowOptions {
                quick: common.quick,
                out: common.out.clone(),
                rounds: rounds.map(|r| r as usize),
                exe,
            };
            skinware_bench::follow::run(&options).map(|_| ())
        }
        Which::Soak(args) => super::soak::bench(args),
        Which::Contact(common) => {
            let options = skinware_bench::contact::ContactBenchOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
            };
            skinware_bench::contact::run(&options).map(|_| ())
        }
        Which::Python(common) => {
            let options = skinware_bench::python::PythonBenchOptions {
                quick: common.quick,
                out: common.out.clone(),
                seconds: common.seconds,
                python: std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into()),
                exe,
            };
            skinware_bench::python::run(&options).map(|_| ())
        }
    }
}

/// Runs this command again in a network namespace of its own (for the
/// EtherCAT bus's veth pair), unless this is already that copy.
/// Inside, Ctrl-C or SIGTERM removes this process's channels before it
/// exits (the namespace and its veth pair go with the last process in it).
fn enter_own_network_namespace() -> Result<()> {
    if !skinware_bench::netns::inside() {
        match skinware_bench::netns::reexec_in_own_namespace()? {}
    }
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])
        .context("cannot install signal handlers")?;
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            skinware_bench::netns::remove_channels_of_this_process();
            eprintln!("skin bench: interrupted; channels removed");
            std::process::exit(128 + signal);
        }
    });
    Ok(())
}

/// Arguments of the hidden `bench-ecat-reader` role.
#[derive(clap::Args)]
pub struct EcatReaderArgs {
    #[arg(long)]
    dir: PathBuf,
    #[arg(long, value_parser = parse_helper_seconds)]
    seconds: f64,
    #[arg(long)]
    out: PathBuf,
}

/// Runs the reader process of `skin bench ethercat`.
pub fn ecat_reader(args: &EcatReaderArgs) -> Result<()> {
    skinware_bench::ethercat::run_latency_reader(&skinware_bench::ethercat::LatencyReaderArgs {
        dir: args.dir.clone(),
        seconds: args.seconds,
        out: args.out.clone(),
    })
}

/// Arguments of the hidden `bench-peer-reader` role.
#[derive(clap::Args)]
pub struct PeerReaderArgs {
    #[arg(long)]
    system: String,
    #[arg(long)]
    name: String,
    #[arg(long, value_parser = parse_helper_seconds)]
    seconds: f64,
    #[arg(long, default_value = "wait")]
    mode: String,
    #[arg(long)]
    out: PathBuf,
}

/// Runs one reader process of `skin bench peers`.
pub fn peer_reader(args: &PeerReaderArgs) -> Result<()> {
    skinware_bench::peers::run_reader(&skinware_bench::peers::PeerReaderArgs {
        system: args.system.clone(),
        name: args.name.clone(),
        seconds: args.seconds,
        mode: args.mode.clone(),
        out: args.out.clone(),
    })
}

/// Runs one application process of a benchmark.
pub fn app(args: &AppArgs) -> Result<()> {
    skinware_bench::app::run(&skinware_bench::app::AppArgs {
        skin: args.skin.clone(),
        layers: args.layers.clone(),
        mode: args.mode.clone(),
        seconds: args.seconds,
        seed: args.seed,
        out: args.out.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bench_seconds_are_a_positive_number_up_to_a_day() {
        assert_eq!(parse_bench_seconds("2.5"), Ok(2.5));
        assert_eq!(parse_bench_seconds("86400"), Ok(86_400.0));
        for bad in ["0", "-1", "1e20", "inf", "NaN", "ten"] {
            let error = parse_bench_seconds(bad).unwrap_err();
            assert!(error.contains(bad) || error.contains("not a number"), "{bad}: {error}");
        }
        // A bench's helper gets the bench's seconds plus a margin.
        assert_eq!(parse_helper_seconds("86430"), Ok(86_430.0));
        assert!(parse_helper_seconds("1e20").is_err());
    }
}
