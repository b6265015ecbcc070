//! The hidden roles of the `skin` binary: the helper processes the benches
//! start by running `skin` again (`skin bench-app ...`), each in a process
//! of its own. A bench and the helpers it starts are both in this crate, so
//! their command line (a protocol between the two) is defined here too;
//! `skin` only flattens [`Role`] into its commands and calls [`Role::run`].

use anyhow::Result;

use crate::{app, bridge, ethercat, follow, kilohertz, peers, soak};

/// A helper process of a bench.
#[derive(Clone, Debug, clap::Subcommand)]
pub enum Role {
    /// The far side of `skin bench bridge`: reads every layer, remote or local, and prints figures as JSON.
    #[command(hide = true)]
    BridgeProbe(bridge::ProbeArgs),
    /// One reader process of `skin bench peers`.
    #[command(hide = true)]
    BenchPeerReader(peers::PeerReaderArgs),
    /// The reader process of `skin bench ethercat`.
    #[command(hide = true)]
    BenchEcatReader(ethercat::LatencyReaderArgs),
    /// One application process of a benchmark (what `skin bench` starts).
    #[command(hide = true)]
    BenchApp(app::AppArgs),
    /// The writer process of `skin bench follow`.
    #[command(hide = true)]
    BenchFollowWriter(follow::FollowWriterArgs),
    /// The floor server of `skin bench kilohertz`: one message of `--bytes` per acknowledgement.
    #[command(hide = true)]
    BenchFloor(kilohertz::floor::FloorArgs),
    /// One verifying reader process of `skin bench soak`.
    #[command(hide = true)]
    BenchSoakReader(soak::reader::ReaderArgs),
    /// The stopped foreign writers of `skin bench soak`.
    #[command(hide = true)]
    BenchSoakForeign(soak::helpers::ForeignArgs),
    /// The CPU hog of `skin bench soak`.
    #[command(hide = true)]
    BenchSoakHog(soak::helpers::HogArgs),
    /// The viewer's browser-like client of `skin bench soak`.
    #[command(hide = true)]
    BenchSoakBrowser(soak::browser::BrowserArgs),
}

impl Role {
    /// Runs this helper until it is done (or its bench closes its input).
    pub fn run(&self) -> Result<()> {
        match self {
            Role::BridgeProbe(args) => bridge::probe(args),
            Role::BenchPeerReader(args) => peers::run_reader(args),
            Role::BenchEcatReader(args) => ethercat::run_latency_reader(args),
            Role::BenchApp(args) => app::run(args),
            Role::BenchFollowWriter(args) => follow::run_writer(args),
            Role::BenchFloor(args) => kilohertz::floor::run(args),
            Role::BenchSoakReader(args) => soak::reader::run(args),
            Role::BenchSoakForeign(args) => soak::helpers::foreign_writers(args.channels.clamp(1, 100)),
            Role::BenchSoakHog(args) => soak::helpers::hog(args.threads.clamp(1, 1024), args.seconds),
            Role::BenchSoakBrowser(args) => soak::browser::run(args),
        }
    }
}
