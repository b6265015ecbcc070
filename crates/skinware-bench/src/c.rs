//! `skin bench c`: the C API and its C++ wrapper beside the Rust reader, in
//! one run, on the same writer.
//!
//! `skin run` writes one virtual layer of the paper's whole-skin size (30,848
//! sensors) at 1 kHz in its own process. This bench builds two programs
//! against the *installed* library (`pkg-config skinware`, as a user's build
//! would), then times, in alternating blocks so both see the same stretch of
//! the machine's life:
//!
//! * `latest()`: Rust's `Reader::latest()` (one copy into the reader's
//!   buffer) against C's `skinware_reader_latest()` into the caller's buffer
//!   (one copy too, plus the boundary: the handle lookup, a lock, the checks);
//! * a periodic reader at 1 kHz: Rust's `Ticker` + `latest()` against the C++
//!   wrapper's `reader.periodic()` range, by each tick's wake-up lateness.
//!
//! Every reader runs on the same CPU (the last), one at a time, and each
//! block starts with untimed reads (a new process faults its pages in).
//! It also reports the sizes of the installed header, shared and static libraries.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use skinware::{Reader, ReaderOptions, Stop, Ticker, WriterState};

use crate::measure::{Percentiles, RunningSkin};
use crate::run_options::RunOptions;

const C_SOURCE: &str = include_str!("c_bench.c");
const CPP_SOURCE: &str = include_str!("c_bench_periodic.cpp");
const SENSORS: u32 = 30_848;
const RATE_HZ: f64 = 1000.0;
const SKIN: &str = "cbench";
const LAYER: &str = "bench-0";
const CONFIG: &str = r#"
skin = "cbench"

[[driver]]
name = "bench"
kind = "virtual"
sensors = 30848
layers = 1
rate_hz = 1000
"#;

/// What `skin bench c` measured.
#[derive(Clone, Debug, Serialize)]
pub struct CReport {
    /// Sensors per frame.
    pub sensors: u32,
    /// The writer's rate, Hz (and the periodic readers').
    pub rate_hz: f64,
    /// Rust `Reader::latest()`, ns.
    pub rust_latest: Percentiles,
    /// C `skinware_reader_latest()` into the caller's buffer, ns.
    pub c_latest: Percentiles,
    /// C's median over Rust's.
    pub latest_ratio_p50: f64,
    /// C's mean over Rust's.
    pub latest_ratio_mean: f64,
    /// Rust periodic reader (`Ticker` + `latest()`): wake-up lateness, ns.
    pub rust_periodic_lateness: Percentiles,
    /// C++ `reader.periodic()`: wake-up lateness, ns.
    pub cpp_periodic_lateness: Percentiles,
    /// The CPU every reader of the bench ran on (`None`: pinning failed).
    pub pinned_cpu: Option<usize>,
    /// The installed files' sizes, bytes.
    pub sizes: Sizes,
    /// The compilers, as `cc --version` and `c++ --version` name them.
    pub compilers: String,
}

/// The installed C API's files.
#[derive(Clone, Debug, Serialize)]
pub struct Sizes {
    /// `skinware.h`.
    pub header: u64,
    /// `skinware.hpp`.
    pub cpp_header: u64,
    /// `libskinware.so` (the file its links lead to).
    pub shared_library: u64,
    /// `libskinware.a`.
    pub static_library: u64,
    /// Where they are.
    pub libdir: String,
}

/// Runs the benchmark, prints its table and writes `c.json`.
pub fn run(options: &RunOptions) -> Result<CReport> {
    let installed = Installed::find()?;
    let reads = if options.quick { 4_000 } else { 40_000 };
    let seconds = options.seconds_or(2.0, 20.0);
    if !(seconds.is_finite() && seconds >= 1.0) {
        bail!("--seconds must be at least 1 (the periodic readers run in 1 s blocks)");
    }
    let dir = skinware::shm::segment_dir().join(format!("skinware-bench-c-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir)?;
    let result = installed.build(&dir).and_then(|programs| {
        let _skin = start_skin(options, &dir)?;
        measure(&dir, &programs, reads, seconds.round() as usize, &installed)
    });
    let _ = std::fs::remove_dir_all(&dir);
    let report = result?;
    print(&report);
    std::fs::create_dir_all(&options.out).with_context(|| format!("cannot create {}", options.out.display()))?;
    let path = options.out.join("c.json");
    std::fs::write(&path, serde_json::to_vec_pretty(&report)?)?;
    println!("  written: {}", path.display());
    Ok(report)
}

/// The installed library, as pkg-config finds it.
struct Installed {
    cflags: Vec<String>,
    libs: Vec<String>,
    libdir: PathBuf,
    includedir: PathBuf,
}

/// The bench's two programs, built.
struct Programs {
    latest: PathBuf,
    periodic: PathBuf,
}

fn pkg_config(args: &[&str]) -> Result<String> {
    let output = Command::new("pkg-config").args(args).arg("skinware").output().context(
        "cannot run pkg-config: install it (apt-get install pkg-config); skin bench c builds against the installed C API",
    )?;
    if !output.status.success() {
        bail!(
            "pkg-config does not find skinware ({}): install the C API with \
             `cargo cinstall -p skinware-c --release --prefix PREFIX` and set PKG_CONFIG_PATH to its pkgconfig \
             directory (docs/c.md)",
            String::from_utf8_lossy(&output.stderr).trim()
        );
    }
    Ok(String::from_utf8_lossy(&output.stdout).trim().to_owned())
}

impl Installed {
    fn find() -> Result<Installed> {
        let split = |s: String| s.split_whitespace().map(str::to_owned).collect();
        Ok(Installed {
            cflags: split(pkg_config(&["--cflags"])?),
            libs: split(pkg_config(&["--libs"])?),
            libdir: PathBuf::from(pkg_config(&["--variable=libdir"])?),
            includedir: PathBuf::from(pkg_config(&["--variable=includedir"])?).join("skinware"),
        })
    }

    fn compile(&self, compiler: &str, standard: &str, source: &Path, out: &Path) -> Result<PathBuf> {
        let output = Command::new(compiler)
            .args([standard, "-O2"])
            .args(&self.cflags)
            .arg(source)
            .arg("-o")
            .arg(out)
            .args(&self.libs)
            .arg(format!("-Wl,-rpath,{}", self.libdir.display()))
            .output()
            .with_context(|| format!("cannot run {compiler}: install gcc and g++ (apt-get install build-essential)"))?;
        if !output.status.success() {
            bail!("{compiler} {} failed:\n{}", source.display(), String::from_utf8_lossy(&output.stderr));
        }
        Ok(out.to_owned())
    }

    fn build(&self, dir: &Path) -> Result<Programs> {
        let (c, cpp) = (dir.join("c_bench.c"), dir.join("c_bench_periodic.cpp"));
        std::fs::write(&c, C_SOURCE)?;
        std::fs::write(&cpp, CPP_SOURCE)?;
        let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
        let cxx = std::env::var("CXX").unwrap_or_else(|_| "c++".into());
        Ok(Programs {
            latest: self.compile(&cc, "-std=c11", &c, &dir.join("c_bench"))?,
            periodic: self.compile(&cxx, "-std=c++17", &cpp, &dir.join("c_bench_periodic"))?,
        })
    }

    fn sizes(&self) -> Sizes {
        let size = |path: PathBuf| std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
        Sizes {
            header: size(self.includedir.join("skinware.h")),
            cpp_header: size(self.includedir.join("skinware.hpp")),
            shared_library: size(self.libdir.join("libskinware.so")),
            static_library: size(self.libdir.join("libskinware.a")),
            libdir: self.libdir.display().to_string(),
        }
    }
}

fn start_skin(options: &RunOptions, dir: &Path) -> Result<RunningSkin> {
    RunningSkin::start_until(&options.exe, CONFIG, dir, "the one-layer skin", |channels| {
        channels.iter().any(|c| c.channel == LAYER && c.state == WriterState::Running && c.stats.frames > 5)
    })
}

/// Runs `program args` and parses its one-number-per-line output.
fn samples_of(dir: &Path, program: &Path, args: &[String]) -> Result<Vec<u64>> {
    let output = Command::new(program).args(args).env("SKINWARE_SHM_DIR", dir).output()?;
    if !output.status.success() {
        bail!("{} failed: {}", program.display(), String::from_utf8_lossy(&output.stderr));
    }
    String::from_utf8_lossy(&output.stdout)
        .lines()
        .map(|line| line.trim().parse::<u64>().with_context(|| format!("{}: not a number: {line}", program.display())))
        .collect()
}

/// Untimed reads at the start of every block, on both sides: a new
/// process's first reads fault in its buffer and the channel's pages.
const WARMUP: usize = 100;
/// Blocks per side, alternating.
const BLOCKS: usize = 8;

fn measure(dir: &Path, programs: &Programs, reads: usize, seconds: usize, installed: &Installed) -> Result<CReport> {
    let mut reader =
        Reader::open_with(SKIN, LAYER, &ReaderOptions { dir: Some(dir.to_owned()), ..Default::default() })?;
    reader.wait_newer(Duration::from_secs(5))?;
    // Both sides on the same CPU (the C and C++ programs inherit this
    // thread's affinity), so that neither copies across caches the other does not.
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let pinned = skinware::os::pin_to_cpus(&[cpus - 1]).is_ok();
    let result = measure_pinned(dir, programs, &mut reader, reads, seconds);
    let _ = skinware::os::pin_to_cpus(&(0..cpus).collect::<Vec<_>>());
    let (rust, c, rust_periodic, cpp_periodic) = result?;
    Ok(CReport {
        sensors: SENSORS,
        rate_hz: RATE_HZ,
        latest_ratio_p50: c.p50 as f64 / rust.p50.max(1) as f64,
        latest_ratio_mean: c.avg / rust.avg.max(1.0),
        rust_latest: rust,
        c_latest: c,
        rust_periodic_lateness: rust_periodic,
        cpp_periodic_lateness: cpp_periodic,
        pinned_cpu: pinned.then_some(cpus - 1),
        sizes: installed.sizes(),
        compilers: compilers(),
    })
}

type Measured = (Percentiles, Percentiles, Percentiles, Percentiles);

fn measure_pinned(
    dir: &Path,
    programs: &Programs,
    reader: &mut Reader,
    reads: usize,
    seconds: usize,
) -> Result<Measured> {
    let (mut rust_latest, mut c_latest) = (Vec::with_capacity(reads), Vec::with_capacity(reads));
    let block = reads / BLOCKS;
    let args = |extra: &[String]| [vec![SKIN.to_owned(), LAYER.to_owned()], extra.to_vec()].concat();
    for _ in 0..BLOCKS {
        for read in 0..WARMUP + block {
            let started = skinware::os::monotonic_ns();
            let frame = reader.latest()?;
            let took = skinware::os::monotonic_ns() - started;
            std::hint::black_box(frame.seq());
            if read >= WARMUP {
                rust_latest.push(took);
            }
        }
        let samples = samples_of(dir, &programs.latest, &args(&[(WARMUP + block).to_string()]))?;
        c_latest.extend(samples.into_iter().skip(WARMUP));
    }
    let stop = Stop::new();
    let (mut rust_periodic, mut cpp_periodic) = (Vec::new(), Vec::new());
    for _ in 0..seconds {
        let mut ticker = Ticker::from_hz(RATE_HZ);
        for _ in 0..RATE_HZ as usize {
            let tick = ticker.wait(&stop).context("the ticker stopped")?;
            rust_periodic.push(tick.lateness_ns);
            std::hint::black_box(reader.latest()?.seq());
        }
        cpp_periodic.extend(samples_of(dir, &programs.periodic, &args(&[RATE_HZ.to_string(), "1".to_owned()]))?);
    }
    Ok((
        Percentiles::of(&mut rust_latest),
        Percentiles::of(&mut c_latest),
        Percentiles::of(&mut rust_periodic),
        Percentiles::of(&mut cpp_periodic),
    ))
}

fn compilers() -> String {
    ["cc", "c++"]
        .iter()
        .map(|compiler| {
            Command::new(compiler)
                .arg("--version")
                .output()
                .ok()
                .and_then(|o| String::from_utf8_lossy(&o.stdout).lines().next().map(str::to_owned))
                .unwrap_or_else(|| format!("{compiler}: unknown"))
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn print(report: &CReport) {
    let us = |ns: u64| ns as f64 / 1000.0;
    println!(
        "\nThe C API and the C++ wrapper beside the Rust reader: one {}-sensor layer at {} Hz ({})",
        report.sensors, report.rate_hz, report.compilers
    );
    println!("  {:<52} {:>9} {:>9} {:>9} {:>9} {:>8}", "read", "p50 µs", "p99 µs", "max µs", "mean µs", "samples");
    let rows = [
        ("Rust latest() (copy into the reader's buffer)", &report.rust_latest),
        ("C skinware_reader_latest() into the caller's buffer", &report.c_latest),
        ("Rust periodic reader at 1 kHz: wake-up lateness", &report.rust_periodic_lateness),
        ("C++ reader.periodic() at 1 kHz: wake-up lateness", &report.cpp_periodic_lateness),
    ];
    for (name, p) in rows {
        println!(
            "  {:<52} {:>9.1} {:>9.1} {:>9.1} {:>9.1} {:>8}",
            name,
            us(p.p50),
            us(p.p99),
            us(p.max),
            p.avg / 1000.0,
            p.samples
        );
    }
    println!(
        "  C latest() over Rust latest(): {:.3}x at the median, {:.3}x in the mean (goal: at most 1.1x)",
        report.latest_ratio_p50, report.latest_ratio_mean
    );
    let s = &report.sizes;
    println!(
        "  installed in {}: skinware.h {} B, skinware.hpp {} B, libskinware.so {} KiB, libskinware.a {} KiB",
        s.libdir,
        s.header,
        s.cpp_header,
        s.shared_library / 1024,
        s.static_library / 1024
    );
}
