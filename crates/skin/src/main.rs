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
    Bench {
        #[command(subcommand)]
        which: commands::bench::Which,
    },
    /// The benches' helper processes (hidden): what `skin bench` starts by running `skin` again.
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
    let soak = matches!(cli.command, Command::Bench { which: commands::bench::Which::Soak(_) });
    let default_filter = if soak { "warn" } else { "info,zenoh=warn" };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| default_filter.into()),
        )
        .with_writer(std::io::stderr)
        .init();
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
        Command::Bench { which } => commands::bench::run(&which),
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
        Command::BenchRole(role) => role.run(),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) if prints_to_stdout && is_broken_pipe(&e) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("skin: error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn is_broken_pipe(error: &anyhow::Error) -> bool {
    error
        .chain()
        .any(|cause| cause.downcast_ref::<std::io::Error>().is_some_and(|e| e.kind() == std::io::ErrorKind::BrokenPipe))
}
