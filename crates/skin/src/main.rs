//! `skin`: run a skin (drivers under a supervisor) and look at it.

#![forbid(unsafe_code)]

mod commands;
mod geometry;
mod layers;
mod skins;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

/// Skinware: real-time acquisition of tactile data from large robot skins.
#[derive(Parser)]
#[command(name = "skin", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Start the drivers of CONFIG, each in its own supervised process.
    Run {
        /// The TOML configuration (see examples/).
        config: PathBuf,
    },
    /// List the layers of a skin: patches, modules, sensors, state and rate.
    Ls(commands::ls::Args),
    /// Live per-layer rate, latency, overruns, faults and restarts.
    Top(commands::top::Args),
    /// Print a layer's frames, in any reader mode.
    Echo(commands::echo::Args),
    /// Remove the channels of dead writers.
    Clean(commands::clean::Args),
    /// Pull (or plug back) a virtual layer's cable, as a fault injection.
    Pull(commands::pull::Args),
    /// List the services: state, rate, schema, inputs, per-frame cost.
    Services(commands::services::Args),
    /// The skin's geometry: neighbour graph and 2-D map statistics, build times.
    Geometry(commands::geometry::Args),
    /// Serve a live web view of a running skin (heatmap, layer states, reader modes).
    View(commands::view::Args),
    /// Start the paper's virtual skin and the web viewer, and print the URL.
    Demo(commands::demo::Args),
    /// Record a running skin's layers and services into an MCAP file (Foxglove, ROS 2 tools, Python `mcap` read it).
    Record(commands::record::Args),
    /// Replay a recording into live channels, at its recorded times.
    Replay(commands::replay::Args),
    /// What a recording holds: channels, duration, frames, gaps; whether it was finished.
    Info(commands::info::Args),
    /// The skin on zenoh: for skinware readers on other machines and ROS 2 (rmw_zenoh) nodes (feature `zenoh`).
    Bridge(commands::bridge::Args),
    /// Regions: record one by touching the skin.
    Region {
        #[command(subcommand)]
        which: commands::region::Which,
    },
    /// Software skin boards that speak a real protocol (for trying skinware without the hardware).
    Emulate {
        #[command(subcommand)]
        which: commands::emulate::Which,
    },
    /// Benchmarks: the paper's experiment, its Table I, and peers side by side.
    #[cfg(feature = "bench")]
    Bench {
        #[command(subcommand)]
        which: commands::bench::Which,
    },
    /// Benchmarks (not in this build: build `skin` with `--features bench`).
    #[cfg(not(feature = "bench"))]
    Bench {
        /// The benchmark and its options.
        #[arg(trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<String>,
    },
    /// The benches' helper processes (hidden): what `skin bench` starts by running `skin` again.
    #[cfg(feature = "bench")]
    #[command(flatten)]
    BenchRole(skinware_bench::roles::Role),
    /// Run one service of CONFIG in this process (what `skin run` starts).
    #[command(hide = true)]
    Service {
        /// The TOML configuration.
        config: PathBuf,
        /// The service's name in it.
        #[arg(long)]
        name: String,
    },
    /// Run one emulator of CONFIG in this process (what `skin run` starts).
    #[command(hide = true)]
    Emulator {
        /// The TOML configuration.
        config: PathBuf,
        /// The emulator's name in it.
        #[arg(long)]
        name: String,
    },
    /// Run one driver of CONFIG in this process (what `skin run` starts).
    #[command(hide = true)]
    Driver {
        /// The TOML configuration.
        config: PathBuf,
        /// The driver's name in it.
        #[arg(long)]
        name: String,
    },
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    // The soak's own readers follow every restarted driver: at `info` its
    // console would hold a line per layer per restart among the faults' lines.
    #[cfg(feature = "bench")]
    let soak = matches!(cli.command, Command::Bench { which: commands::bench::Which::Soak(_) });
    #[cfg(not(feature = "bench"))]
    let soak = false;
    // zenoh's own warnings (a scouting delay elapsed at every remote command)
    // are about its discovery, not the skin: its errors still show. RustDDS
    // logs every discovery step at info, and ros2-client warns that no
    // ROS_DISTRO is set (skinware needs none).
    let default_filter = if soak { "warn" } else { "info,zenoh=error,rustdds=warn,ros2_client=error" };
    {
        use tracing_subscriber::layer::SubscriberExt as _;
        use tracing_subscriber::util::SubscriberInitExt as _;
        tracing_subscriber::fmt()
            .with_writer(std::io::stderr)
            // Colours for a person at a terminal; none in a log file or a pipe.
            .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
            .finish()
            .with(log_filter(default_filter))
            .init();
    }
    // A reader of our stdout that goes away (`skin ls | head`) is not an
    // error of these commands; for the others a broken pipe is a real failure
    // (an SLCAN adapter unplugged gives one too).
    let prints_to_stdout = matches!(
        cli.command,
        Command::Ls(_)
            | Command::Top(_)
            | Command::Echo(_)
            | Command::Services(_)
            | Command::Geometry(_)
            | Command::Info(_)
    );
    let result = match cli.command {
        Command::Run { config } => commands::run::run(&config),
        Command::Ls(args) => commands::ls::run(&args),
        Command::Top(args) => commands::top::run(&args),
        Command::Echo(args) => commands::echo::run(&args),
        Command::Clean(args) => commands::clean::run(&args),
        Command::Pull(args) => commands::pull::run(&args),
        Command::Driver { config, name } => commands::driver::run(&config, &name),
        #[cfg(feature = "bench")]
        Command::Bench { which } => commands::bench::run(&which),
        #[cfg(not(feature = "bench"))]
        Command::Bench { args } => Err(anyhow::anyhow!(
            "this `skin` was built without its benchmarks, so `skin bench {}` cannot run; build it with them: \
             `cargo build --release -p skin --features bench` (then ./target/release/skin bench ...), or \
             `cargo install --path crates/skin --features bench`",
            args.join(" ")
        )),
        Command::Emulate { which } => commands::emulate::run(&which),
        Command::Emulator { config, name } => commands::emulate::run_configured(&config, &name),
        Command::Services(args) => commands::services::run(&args),
        Command::Service { config, name } => commands::service::run(&config, &name),
        Command::Geometry(args) => commands::geometry::run(&args),
        Command::View(args) => commands::view::run(&args),
        Command::Demo(args) => commands::demo::run(&args),
        Command::Record(args) => commands::record::run(&args),
        Command::Replay(args) => commands::replay::run(&args),
        Command::Info(args) => commands::info::run(&args),
        Command::Region { which } => commands::region::run(&which),
        Command::Bridge(args) => commands::bridge::run(&args),
        #[cfg(feature = "bench")]
        Command::BenchRole(role) => role.run(),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if prints_to_stdout && is_broken_pipe(&e) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("skin: error: {}", skin::report::causes_once(e.as_ref()));
            std::process::ExitCode::FAILURE
        }
    }
}

/// What to log: `RUST_LOG` (levels and targets, `warn,skinware=debug`) or
/// `default`. A filter that does not parse is said, not ignored in silence.
fn log_filter(default: &str) -> tracing_subscriber::filter::Targets {
    let fallback = || default.parse().unwrap_or_default();
    match std::env::var("RUST_LOG") {
        Ok(text) if !text.trim().is_empty() => text.parse().unwrap_or_else(|error| {
            eprintln!(
                "skin: RUST_LOG={text:?} is not a filter skin understands ({error}): give levels and targets, \
                 like `info` or `warn,skinware=debug`; logging `{default}` instead"
            );
            fallback()
        }),
        _ => fallback(),
    }
}

fn is_broken_pipe(error: &anyhow::Error) -> bool {
    error
        .chain()
        .any(|cause| cause.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe))
}
