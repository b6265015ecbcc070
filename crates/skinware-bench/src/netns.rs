//! The EtherCAT benches' bus: a veth pair in a network namespace of the
//! bench's own, ethercrab's raw socket on one end and the ESC model
//! ([`serve_interface`]) on the other.
//!
//! A process cannot move itself into a new network namespace once it has
//! threads, so the bench replaces itself (`exec`, same process id: Ctrl-C and
//! `kill` reach it directly) with `unshare -n` (as root, which keeps
//! `CAP_SYS_NICE` for SCHED_FIFO) or `unshare -rn` (elsewhere, where user
//! namespaces are allowed) running the same command again, marked by
//! [`INSIDE`]. The namespace, and the veth pair in it, disappear with the
//! last process in it: nothing is left behind, however the bench ends.

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use skinware::RtOptions;
use skinware_drivers::ethercat::{EthercatDriver, EthercatDriverConfig, FrameLink, SegmentConfig};
use skinware_emulate::ethercat::tactile::{EMULATED_PRODUCT_CODE, EMULATED_VENDOR_ID};
use skinware_emulate::ethercat::{InterfaceError, InterfaceStats, Segment, serve_interface};

/// Set in the copy of the bench that runs inside its own network namespace.
pub const INSIDE: &str = "SKINWARE_BENCH_NETNS";
/// The MainDevice's end of the veth pair.
pub const DRIVER_END: &str = "ecat-drv";
/// The emulated segment's end of the veth pair.
pub const SEGMENT_END: &str = "ecat-emu";

/// Whether this process is the copy inside the bench's own namespace.
pub fn inside() -> bool {
    std::env::var_os(INSIDE).is_some()
}

/// Replaces this process with `unshare` running the same command line in a
/// new network namespace; returns only on failure, saying why and what to
/// do. Call it only when [`inside`] is false.
pub fn reexec_in_own_namespace() -> Result<std::convert::Infallible> {
    use std::os::unix::process::CommandExt;
    let root = skinware_is_root();
    let flags = if root { "-n" } else { "-rn" };
    let probe = Command::new("unshare").args([flags, "true"]).output().map_err(|e| {
        anyhow::anyhow!(
            "cannot run `unshare` ({e}): the EtherCAT bench runs its bus on a veth pair in a network namespace \
             of its own; install util-linux"
        )
    })?;
    if !probe.status.success() {
        bail!(
            "`unshare {flags}` fails here ({}): the EtherCAT bench needs a network namespace of its own for its \
             veth pair; run it as root, or allow unprivileged user namespaces \
             (sysctl kernel.unprivileged_userns_clone=1 / user.max_user_namespaces)",
            String::from_utf8_lossy(&probe.stderr).trim()
        );
    }
    let exe = std::env::current_exe().context("cannot find this executable to run it again")?;
    let error = Command::new("unshare").arg(flags).arg(exe).args(std::env::args_os().skip(1)).env(INSIDE, "1").exec();
    Err(anyhow::anyhow!("cannot run the bench again under `unshare {flags}`: {error}"))
}

/// Runs this command again in a network namespace of its own (for the
/// EtherCAT bus's veth pair), unless this is already that copy. Inside,
/// Ctrl-C or SIGTERM removes this process's channels before it exits (the
/// namespace and its veth pair go with the last process in it).
pub fn enter_own_namespace() -> Result<()> {
    if !inside() {
        match reexec_in_own_namespace()? {}
    }
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM])
        .context("cannot install signal handlers")?;
    std::thread::spawn(move || {
        if let Some(signal) = signals.forever().next() {
            remove_channels_of_this_process();
            eprintln!("skin bench: interrupted; channels removed");
            std::process::exit(128 + signal);
        }
    });
    Ok(())
}

/// Whether the effective user is root (from `/proc/self/status`; no libc).
fn skinware_is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|status| {
            status.lines().find(|l| l.starts_with("Uid:")).and_then(|l| l.split_whitespace().nth(2).map(|u| u == "0"))
        })
        .unwrap_or(false)
}

/// Runs `ip args`; the error carries its stderr.
pub fn ip(args: &[&str]) -> Result<()> {
    let out = Command::new("ip").args(args).output().with_context(|| {
        format!("cannot run `ip {}` (iproute2): the EtherCAT bench makes a veth pair with it", args.join(" "))
    })?;
    if !out.status.success() {
        bail!("`ip {}` failed: {}", args.join(" "), String::from_utf8_lossy(&out.stderr).trim());
    }
    Ok(())
}

/// Makes the veth pair and brings both ends up (inside the namespace).
pub fn make_veth_pair() -> Result<()> {
    ip(&["link", "add", DRIVER_END, "type", "veth", "peer", "name", SEGMENT_END])
        .and_then(|()| ip(&["link", "set", DRIVER_END, "up"]))
        .and_then(|()| ip(&["link", "set", SEGMENT_END, "up"]))
        .context("cannot make the bench's veth pair (needs the veth kernel module and iproute2's `ip`)")
}

/// The emulated segment answering on [`SEGMENT_END`], in a thread of its own.
pub struct EmulatedBus {
    /// The segment: its fault switches can be thrown while it runs.
    pub segment: Arc<Mutex<Segment>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<InterfaceStats, InterfaceError>>>,
}

impl EmulatedBus {
    /// Starts serving `segment` on [`SEGMENT_END`], its thread at SCHED_FIFO
    /// `fifo_priority` if given (a refusal is warned about, once).
    pub fn start(segment: Segment, fifo_priority: Option<u8>) -> Result<EmulatedBus> {
        let segment = Arc::new(Mutex::new(segment));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (segment, stop) = (segment.clone(), stop.clone());
            std::thread::Builder::new().name("ecat-emulator".into()).spawn(move || {
                for refused in (RtOptions { fifo_priority, ..RtOptions::default() }).apply() {
                    eprintln!("warning: emulated segment: {refused}");
                }
                serve_interface(&segment, SEGMENT_END, &|| stop.load(Ordering::Relaxed), None)
            })?
        };
        Ok(EmulatedBus { segment, stop, thread: Some(thread) })
    }

    /// Locks the segment (to throw a fault switch).
    pub fn lock(&self) -> std::sync::MutexGuard<'_, Segment> {
        skinware::lock(&self.segment)
    }

    /// Whether the emulator's thread ended (it failed).
    pub fn ended(&self) -> bool {
        self.thread.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Stops the emulator; its statistics, or why it failed.
    pub fn stop(mut self) -> Result<InterfaceStats> {
        self.stop.store(true, Ordering::Relaxed);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(result)) => result.context("the emulated EtherCAT segment failed"),
            Some(Err(_)) => bail!("the emulated EtherCAT segment's thread panicked"),
            None => bail!("the emulated EtherCAT segment was stopped twice"),
        }
    }
}

impl Drop for EmulatedBus {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// The driver for one segment of `taxels` (modules of 12) publishing
/// `layer`, on [`DRIVER_END`].
pub fn driver(layer: &str, patch: u32, taxels: usize, rate_hz: f64, rt: RtOptions) -> Result<EthercatDriver> {
    let config = EthercatDriverConfig {
        name: format!("bench-{layer}"),
        segments: vec![SegmentConfig {
            layer: layer.into(),
            vendor_id: EMULATED_VENDOR_ID,
            product_code: EMULATED_PRODUCT_CODE,
            taxels,
            modules: vec![12; taxels / 12],
            patch,
            baseline: false,
        }],
        rate_hz,
        frame_timeout: None,
        rt,
    };
    EthercatDriver::new(config, FrameLink::Interface(DRIVER_END.into())).map_err(anyhow::Error::msg)
}

/// Waits up to `within` for `ready`, polling every millisecond.
pub fn wait_until(within: Duration, mut ready: impl FnMut() -> bool) -> bool {
    let started = std::time::Instant::now();
    while !ready() {
        if started.elapsed() > within {
            return false;
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    true
}

/// Waits up to `within` for `ready`, polling every 100 µs (to time what it
/// waits for); returns whether it came.
pub fn wait_until_fine(within: Duration, mut ready: impl FnMut() -> bool) -> bool {
    let started = std::time::Instant::now();
    while !ready() {
        if started.elapsed() > within {
            return false;
        }
        std::thread::sleep(Duration::from_micros(100));
    }
    true
}

/// Removes what this process's EtherCAT benches put in the shared-memory
/// directory (for an interrupted run): `skinware-bench-ecat-<pid>` and the
/// channels of skin `table1-<pid>`.
pub fn remove_channels_of_this_process() {
    let pid = std::process::id();
    let dir = skinware::shm::segment_dir();
    let _ = std::fs::remove_dir_all(dir.join(format!("skinware-bench-ecat-{pid}")));
    let table1 = format!("table1-{pid}.");
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            if name.contains(&table1) {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
}
