//! `skin bench`: the benchmarks (they print tables and write JSON and
//! plots). They are `skinware-bench`'s; this file is their command line and
//! hands each to its bench.

mod soak_config;

use std::path::PathBuf;

use anyhow::{Context, Result};
use skinware_bench::kilohertz::{self, KilohertzOptions, Part, Wake};
use skinware_bench::run_options::{RunOptions, parse_bench_seconds};
use skinware_bench::soak::{self, SoakBenchOptions};
use skinware_bench::table1::{self, Table1Options, Transport};
use skinware_bench::{
    bridge, c, can, contact, ethercat, follow, netns, paper, peers, python, record, recorder, scale, wake,
};

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
    /// `skin record --services` of the paper's skin at 1 kHz (about 100 MB/s of messages), with each compression: frames written and lost, MB/s, CPU and memory over time, against a plain write of the same bytes to the same disk.
    Recorder(RecorderArgs),
    /// How every cost grows with the skin: 10k, 30,848, 100k and 300k taxels at 100, 500, 1,000 and 2,000 Hz, with 0, 1 and 15 readers: publish against memcpy, missed periods against the control, reader copy, CPU, latency; the frontier, a JSON and a plot.
    Scale(Common),
    /// The contact service's cost per frame on the paper's skin with scripted contacts: the detector alone, and the service beside the skin's writers.
    Contact(Common),
    /// The Python bindings beside the Rust reader on a 30,848-sensor layer of `skin run`: latest(), read_into(), wait_newer() latency ($SKINWARE_PYTHON).
    Python(Common),
    /// The C API and the C++ wrapper beside the Rust reader on a 30,848-sensor layer at 1 kHz: C latest() into a buffer against Rust latest(), the C++ periodic reader's wake-up jitter against Rust's, the installed files' sizes (builds against the installed library: pkg-config skinware).
    C(Common),
    /// A 1 kHz writer of the whole skin's frame with 0 or 15 readers asleep on the futex, woken by the writer or by its ringer: period start to visible, start jitter, missed periods, reader latency, CPU.
    Wake(Common),
    /// The paper's skin at 1 kHz alone, then with 15 applications, both services at 1 kHz, the viewer with 3 browsers and the recorder; then the viewer with 1 and 10 browsers: missed periods, publish times, CPU per component, latency from acquisition.
    Kilohertz(KilohertzArgs),
    /// Readers in every mode beside a 1 kHz writer that is SIGKILLed and restarted: the successor's first publication to each reader holding a frame of it, with the successor watcher and with the 100 ms re-check of before.
    Follow(FollowArgs),
    /// The paper's skin across a veth link between two network namespaces: `skin bridge` (feature `zenoh`) beside the local exchange, at 100/10/1 Mbit/s, and a cut link (needs root).
    Bridge(Common),
    /// The skin's ROS 2 topics to stock rclpy subscribers (Fast DDS): skin bridge's DDS side (feature `dds`) at its default rates, with clouds at 30 Hz, and with the shipped 4 MiB Fast DDS profile; rclpy to rclpy over UDP as the baseline; the rmw_zenoh path (feature `zenoh`). Needs SKINWARE_ROS2_PYTHONS.
    Ros2(Common),
    /// Faults for N minutes on a skin of virtual drivers under `skin run`, with verifying readers in every mode, both services, the viewer and a browser, and a recorder: torn, backwards and lost frames, stuck readers, leaks, and how long every layer takes to run again after each kind of fault.
    Soak(SoakArgs),
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

impl Common {
    /// The bench's run options: these, and this executable to run again.
    fn run_options(&self) -> Result<RunOptions> {
        Ok(RunOptions { quick: self.quick, out: self.out.clone(), seconds: self.seconds, exe: this_executable()? })
    }
}

/// The `skin` executable, which the benches run again for their helpers.
fn this_executable() -> Result<PathBuf> {
    std::env::current_exe().context("cannot find the skin executable")
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

/// Options of `skin bench recorder`.
#[derive(clap::Args)]
pub struct RecorderArgs {
    #[command(flatten)]
    common: Common,
    /// Taxels of the skin over its 5 layers (default: the paper's 30,848);
    /// the JSON is then `recorder-TAXELS.json`.
    #[arg(long)]
    taxels: Option<usize>,
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
    only: Option<Part>,
    /// Who wakes the layers' sleeping readers (`reader_wake` under
    /// `[driver.rt]`); the library's default if absent.
    #[arg(long)]
    reader_wake: Option<Wake>,
    /// Bytes of the floor server's message, 1 to 16 MiB, to see what an
    /// update's size costs a browser (default: the viewer's update, 61,872
    /// bytes; the viewer part only).
    #[arg(long, value_parser = kilohertz::floor::parse_update_bytes)]
    floor_bytes: Option<usize>,
    /// The floor server reads every layer with the viewer's own readers and
    /// sends their board, instead of a stand-in message: the viewer without
    /// what its sessions decide, whose 10/1 ratio is that of a viewer whose
    /// sessions cost only the message (the viewer part only; not with
    /// --floor-bytes).
    #[arg(long)]
    floor_reads_skin: bool,
    /// Taxels of the skin over its 5 layers (default: the paper's 30,848),
    /// for the control and loaded runs (`--only runs`).
    #[arg(long)]
    taxels: Option<usize>,
    /// The recorder's compression in the loaded run (default: `skin
    /// record`'s, zstd); at 100,000 taxels and 1 kHz, zstd cannot keep up on
    /// 2 cores.
    #[arg(long)]
    record_compression: Option<super::record::CompressionArg>,
    /// In the loaded run, open the viewer's page in a real headless
    /// Chromium (through chromedriver) in place of one of the 3 emulated
    /// browsers, and report how many new updates it draws a second (fps),
    /// its updates/s and bytes per update, and Chromium's own CPU, which
    /// runs on the same cores as the skin. Not with `--only viewer`. Needs
    /// chromium and chromedriver (Debian: apt-get install chromium
    /// chromium-driver).
    #[arg(long)]
    chromium: bool,
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

/// Options of `skin bench soak`.
#[derive(clap::Args)]
pub struct SoakArgs {
    /// The skin to soak: a config of virtual drivers (e.g.
    /// examples/paper-virtual-skin.toml). Its drivers publish their
    /// verification pattern during the soak; the contact and motion
    /// services are added if it has no service.
    config: PathBuf,
    /// Minutes of faults (the start and the end take some seconds more; at
    /// least one round of every kind of fault, about 80 s, however short).
    #[arg(long, value_parser = soak::parse_minutes)]
    minutes: Option<f64>,
    /// Two minutes, as CI runs it (unless --minutes says otherwise).
    #[arg(long)]
    quick: bool,
    /// The faults' seed, to run the same faults again (printed at the start).
    #[arg(long)]
    seed: Option<u64>,
    /// Directory for soak.json and the logs (soak-work/).
    #[arg(long, default_value = "target/bench")]
    out: PathBuf,
}

/// Runs `skin bench ...`: hands the options to the bench.
pub fn run(which: &Which) -> Result<()> {
    match which {
        Which::Paper(PaperArgs { common, rounds }) => {
            paper::run(&paper::PaperOptions { run: common.run_options()?, rounds: *rounds }).map(drop)
        }
        Which::Table1(args) => run_table1(args),
        Which::Ethercat(common) => {
            netns::enter_own_namespace()?;
            ethercat::run(&common.run_options()?).map(drop)
        }
        Which::Can(common) => can::run(&common.run_options()?).map(drop),
        Which::Peers(common) => peers::run(&common.run_options()?).map(drop),
        Which::Record(common) => record::run(&common.run_options()?).map(drop),
        Which::Recorder(args) => recorder::run(&args.common.run_options()?, args.taxels).map(drop),
        Which::Scale(common) => scale::run(&common.run_options()?).map(drop),
        Which::Contact(common) => contact::run(&common.run_options()?).map(drop),
        Which::Python(common) => {
            let python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
            python::run(&python::PythonBenchOptions { run: common.run_options()?, python }).map(drop)
        }
        Which::C(common) => c::run(&common.run_options()?).map(drop),
        Which::Wake(common) => wake::run(&common.run_options()?).map(drop),
        Which::Kilohertz(args) => kilohertz::bench(&args.options()?),
        Which::Follow(FollowArgs { common, rounds }) => {
            let rounds = rounds.map(|r| r as usize);
            follow::run(&follow::FollowOptions { run: common.run_options()?, rounds }).map(drop)
        }
        Which::Bridge(common) => bridge::bench(&common.run_options()?),
        Which::Ros2(common) => {
            let ros_python = skinware_bench::ros2::default_ros_python().context(
                "skin bench ros2 needs SKINWARE_ROS2_PYTHONS: a Python with rclpy and the standard messages \
                 (pip, no ROS installation; docs/ros2.md)",
            )?;
            let zenoh_python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
            skinware_bench::ros2::bench(&skinware_bench::ros2::Ros2BenchOptions {
                run: common.run_options()?,
                ros_python: ros_python.display().to_string(),
                zenoh_python,
            })
            .map(drop)
        }
        Which::Soak(args) => soak::bench(&args.options()?, &soak_config::SkinConfigs),
    }
}

/// `skin bench table1`, in a network namespace of its own for `--transport ethercat`.
fn run_table1(Table1Args { common, transport }: &Table1Args) -> Result<()> {
    let transport = match transport.as_str() {
        "slcan" => Transport::Slcan,
        "ethercat" => {
            netns::enter_own_namespace()?;
            Transport::Ethercat
        }
        _ => Transport::Memory,
    };
    table1::run(&Table1Options { run: common.run_options()?, transport }).map(drop)
}

impl KilohertzArgs {
    fn options(&self) -> Result<KilohertzOptions> {
        Ok(KilohertzOptions {
            run: self.common.run_options()?,
            viewer_exe: self.viewer_exe.clone(),
            only: self.only,
            wake: self.reader_wake,
            floor_bytes: self.floor_bytes,
            floor_reads_skin: self.floor_reads_skin,
            taxels: self.taxels,
            record_compression: self.record_compression.map(super::record::CompressionArg::library),
            chromium: self.chromium,
        })
    }
}

impl SoakArgs {
    fn options(&self) -> Result<SoakBenchOptions> {
        // The soak counts minutes, not seconds per configuration.
        let run = RunOptions { quick: self.quick, out: self.out.clone(), seconds: None, exe: this_executable()? };
        Ok(SoakBenchOptions { run, config: self.config.clone(), minutes: self.minutes, seed: self.seed })
    }
}
