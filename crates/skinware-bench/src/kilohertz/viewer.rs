//! The viewer alone on the 1 kHz skin with 1 and 10 browsers, and with a
//! slow one among them; beside it, in the same rounds, the [`floor`]
//! server with 1 and 10 browsers.
//!
//! [`floor`]: super::floor

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

use super::browser::{SeqClock, WindowMarks, browse};
use super::cpu::{clock_ticks_per_s, cpu_ns_between, cpu_ticks, thread_cpu_ns};
use super::floor;
use super::phase::{SkinChoice, start_skin};
use super::report::{BrowserFigures, FloorRun, ViewerRun};
use super::{DISPLAY_HZ, SLOW_BROWSER_HZ};
use crate::procs::{Guarded, start_viewer};

/// What the [`floor`] server does.
#[derive(Clone, Copy, Debug)]
pub(super) struct Floor {
    /// Bytes of its message.
    pub(super) bytes: usize,
    /// It reads the skin's layers as the viewer does (`--read-skin`).
    pub(super) reads_skin: bool,
}

/// Starts the [`floor`] server (`skin bench-floor`) on the skin in segment
/// directory `dir`; returns it and where it listens.
fn start_floor(exe: &Path, floor: Floor, dir: &Path) -> Result<(Guarded, String)> {
    use std::io::BufRead;
    let mut command = Command::new(exe);
    command.args(["bench-floor", "--bytes", &floor.bytes.to_string()]).env("SKINWARE_SHM_DIR", dir);
    if floor.reads_skin {
        command.args(["--read-skin", "default"]);
    }
    let mut child = command
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .context("cannot start the floor server (`skin bench-floor`)")?;
    let stdout = child.stdout.take().context("the floor server's stdout")?;
    let child = Guarded(child);
    let mut address = String::new();
    std::io::BufReader::new(stdout).read_line(&mut address).context("cannot read the floor server's address")?;
    let address = address.trim().to_owned();
    if address.is_empty() {
        bail!("the floor server (`skin bench-floor`) exited before it said where it listens");
    }
    Ok((child, address))
}

/// The run time of some threads now, in ns, by thread id ([`thread_cpu_ns`]).
///
/// [`thread_cpu_ns`]: super::cpu::thread_cpu_ns
type RunTimes<'a> = dyn Fn() -> BTreeMap<u32, u64> + 'a;

/// What a window with browsers measured.
struct Window {
    /// Its length, seconds.
    seconds: f64,
    /// Run time of the measured threads in the window, ns.
    ran_ns: u64,
    /// Measured threads that ended in the window.
    threads_ended: usize,
    /// Clock ticks of the measured process in the window (the viewer's only).
    ticks: u64,
    /// Run time of the threads `part` measured in the window, ns.
    part_ns: u64,
    /// What each browser received.
    per_browser: Vec<BrowserFigures>,
}

/// Browsers acknowledging at `plan`'s rates on `address`: 1 s to settle,
/// then `seconds` measured by `threads` (run time by thread id) and `ticks`;
/// `check` runs at the end of the window, right after the browsers are told
/// to stop and before they are joined.
fn with_browsers(
    address: &str,
    plan: &[f64],
    (dir, seconds): (&Path, f64),
    (threads, part): (&RunTimes<'_>, &RunTimes<'_>),
    ticks: &dyn Fn() -> u64,
    check: &mut dyn FnMut(&BTreeMap<u32, u64>) -> Result<()>,
) -> Result<Window> {
    let stop = Arc::new(AtomicBool::new(false));
    let marks = Arc::new(WindowMarks::default());
    let clock = SeqClock::start(dir, stop.clone());
    let browsers: Vec<_> = plan
        .iter()
        .map(|&hz| {
            let (stop, marks, clock, address) = (stop.clone(), marks.clone(), clock.clone(), address.to_owned());
            std::thread::spawn(move || browse(&address, hz, (&stop, &marks), &clock))
        })
        .collect();
    std::thread::sleep(Duration::from_secs(1));
    let (ticks_before, before_ns, part_before) = (ticks(), threads(), part());
    let started = Instant::now();
    let _ = marks.start.set(started);
    std::thread::sleep(Duration::from_secs_f64(seconds));
    let _ = marks.end.set(Instant::now());
    let (ticks_after, after_ns, part_after) = (ticks(), threads(), part());
    let elapsed = started.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    let checked = check(&after_ns);
    let mut per_browser = Vec::new();
    for browser in browsers {
        per_browser.push(browser.join().map_err(|_| anyhow::anyhow!("a browser thread panicked")));
    }
    checked?;
    let per_browser = per_browser.into_iter().map(|figures| figures?).collect::<Result<Vec<_>>>()?;
    let (ran_ns, threads_ended) = cpu_ns_between(&before_ns, &after_ns);
    let (part_ns, _) = cpu_ns_between(&part_before, &part_after);
    let ticks = ticks_after.saturating_sub(ticks_before);
    Ok(Window { seconds: elapsed, ran_ns, threads_ended, ticks, part_ns, per_browser })
}

/// The viewer alone on the 1 kHz skin with 1, then 10 browsers, `rounds`
/// times, each round with the [`floor`] server's 1 and 10 between; then the
/// viewer with 9 at 59.94 Hz and one slow browser at 5 Hz.
pub(super) fn viewer_scaling(
    exe: &Path,
    viewer_exe: &Path,
    dir: &Path,
    seconds: f64,
    rounds: usize,
    floor_options: Floor,
) -> Result<(Vec<ViewerRun>, Vec<FloorRun>)> {
    let (skin, _readers) = start_skin(exe, SkinChoice { dir, wake: None, taxels: None }, false)?;
    let (mut viewer, address) = start_viewer(viewer_exe, dir, &[], None)?;
    let (mut floor_server, floor_address) = start_floor(exe, floor_options, dir)?;
    let (mut runs, mut floor_runs) = (Vec::new(), Vec::new());
    for (round, on_viewer, plan) in browser_plans(rounds) {
        let server = if on_viewer { "viewer" } else { "floor server" };
        eprintln!("kilohertz: {server} with {} browsers, {seconds} s", plan.len());
        if on_viewer {
            let window = viewer_window(&mut viewer, &address, &plan, (dir, seconds))?;
            runs.push(viewer_run(round, &plan, window));
        } else {
            let window = floor_window(&mut floor_server, &floor_address, &plan, (dir, seconds))?;
            floor_runs.push(floor_run(round, &plan, window));
        }
        // The servers notice the closed sockets (the viewer stops the shared readers).
        std::thread::sleep(Duration::from_millis(500));
    }
    drop(floor_server);
    drop(viewer);
    drop(skin);
    Ok((runs, floor_runs))
}

/// The windows of [`viewer_scaling`], in order: the round, whether on the
/// viewer (else on the floor server), and the browsers' acknowledgement rates.
fn browser_plans(rounds: usize) -> Vec<(usize, bool, Vec<f64>)> {
    let one = vec![DISPLAY_HZ];
    let ten = vec![DISPLAY_HZ; 10];
    let mut plans: Vec<(usize, bool, Vec<f64>)> = (0..rounds)
        .flat_map(|round| {
            [
                (round, true, one.clone()),
                (round, false, one.clone()),
                (round, true, ten.clone()),
                (round, false, ten.clone()),
            ]
        })
        .collect();
    plans.push((rounds - 1, true, std::iter::repeat_n(DISPLAY_HZ, 9).chain([SLOW_BROWSER_HZ]).collect()));
    plans
}

/// A window of browsers at `plan`'s rates on the viewer at `address`.
fn viewer_window(viewer: &mut Guarded, address: &str, plan: &[f64], (dir, seconds): (&Path, f64)) -> Result<Window> {
    let viewer_pid = viewer.0.id();
    let pids = [("viewer".to_string(), viewer_pid)];
    let mut check = |after_ns: &BTreeMap<u32, u64>| {
        if let Ok(Some(status)) = viewer.0.try_wait() {
            bail!("the viewer exited during the run with {} browsers ({status})", plan.len());
        }
        if after_ns.is_empty() {
            bail!(
                "cannot read the viewer's threads' run time in /proc/{viewer_pid}/task/*/schedstat \
                 (a kernel without CONFIG_SCHED_INFO?)"
            );
        }
        Ok(())
    };
    with_browsers(
        address,
        plan,
        (dir, seconds),
        (&|| thread_cpu_ns(viewer_pid, None), &|| {
            thread_cpu_ns(viewer_pid, Some(skinware_viewer::server::BROWSER_THREAD_PREFIX))
        }),
        &|| cpu_ticks(&pids)[0],
        &mut check,
    )
}

/// A window of browsers at `plan`'s rates on the floor server at `address`.
fn floor_window(floor: &mut Guarded, address: &str, plan: &[f64], (dir, seconds): (&Path, f64)) -> Result<Window> {
    let floor_pid = floor.0.id();
    let mut check = |after_ns: &BTreeMap<u32, u64>| {
        if let Ok(Some(status)) = floor.0.try_wait() {
            bail!("the floor server exited during the run with {} browsers ({status})", plan.len());
        }
        if after_ns.is_empty() {
            bail!("cannot read the floor server's threads' run time in /proc/{floor_pid}/task/*/schedstat");
        }
        Ok(())
    };
    with_browsers(
        address,
        plan,
        (dir, seconds),
        (&|| thread_cpu_ns(floor_pid, None), &|| thread_cpu_ns(floor_pid, Some(floor::BROWSER_THREAD))),
        &|| 0,
        &mut check,
    )
}

/// Percent of one core of `ns` run time over `window`.
fn percent(ns: u64, window: &Window) -> f64 {
    100.0 * ns as f64 / 1e9 / window.seconds
}

/// The viewer's figures of a window.
fn viewer_run(round: usize, plan: &[f64], window: Window) -> ViewerRun {
    ViewerRun {
        round,
        browsers: plan.len(),
        with_slow_browser: plan.contains(&SLOW_BROWSER_HZ),
        seconds: window.seconds,
        viewer_cpu_percent: percent(window.ran_ns, &window),
        viewer_threads_ended: window.threads_ended,
        viewer_cpu_percent_ticks: 100.0 * window.ticks as f64 / clock_ticks_per_s() / window.seconds,
        sessions_cpu_percent: percent(window.part_ns, &window),
        per_browser: window.per_browser,
    }
}

/// The floor server's figures of a window.
fn floor_run(round: usize, plan: &[f64], window: Window) -> FloorRun {
    FloorRun {
        round,
        browsers: plan.len(),
        seconds: window.seconds,
        cpu_percent: percent(window.part_ns, &window),
        process_cpu_percent: percent(window.ran_ns, &window),
        threads_ended: window.threads_ended,
        per_browser: window.per_browser,
    }
}
