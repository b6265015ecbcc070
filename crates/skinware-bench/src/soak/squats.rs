//! The squats: files, FIFOs and symlinks at the names of a channel of a
//! skin that does not run (and a stale socket with a FIFO lock beside a
//! driver kill), and their removal, which must leave nothing behind.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use rustix::process::Signal;

use super::Soak;
use super::injection::{FaultKind, Injected};
use crate::procs;

/// The skin whose channel names the squats take: no skin runs under it.
const GHOST_SKIN: &str = "soak-ghost";

/// Removes a path the soak put in the segment directory. A FIFO is opened
/// first (read-write, non-blocking), which lets anyone blocked opening it
/// go on (they then read its end).
pub(super) fn remove_squat(path: &Path) {
    use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
    let Ok(meta) = std::fs::symlink_metadata(path) else { return };
    let opened = meta
        .file_type()
        .is_fifo()
        .then(|| std::fs::OpenOptions::new().read(true).write(true).custom_flags(libc::O_NONBLOCK).open(path).ok());
    let _ = std::fs::remove_file(path);
    drop(opened);
}

/// The socket and name-lock paths of `skin`/`channel` in `dir`.
pub(super) fn channel_paths(dir: &Path, skin: &str, channel: &str) -> [PathBuf; 2] {
    [dir.join(format!("skinware.{skin}.{channel}")), dir.join(format!(".skinware-lock.{skin}.{channel}"))]
}

impl Soak<'_> {
    pub(super) fn fifo_squat_driver_kill(&mut self, index: usize) -> Result<Injected> {
        let channel = format!("layer{index}");
        let [socket, lock] = channel_paths(&self.options.dir, GHOST_SKIN, &channel);
        self.squats.push(socket.clone());
        // A socket nobody listens on: what a writer killed without cleaning up leaves.
        drop(
            std::os::unix::net::UnixListener::bind(&socket)
                .with_context(|| format!("cannot bind {}", socket.display()))?,
        );
        self.squats.push(lock.clone());
        let status = std::process::Command::new("mkfifo").arg(&lock).status().context("cannot run mkfifo")?;
        if !status.success() {
            bail!("mkfifo {} failed ({status})", lock.display());
        }
        self.idle(Duration::from_millis(500));
        let (name, driver) = self.driver()?;
        let injected = self.begin(
            FaultKind::FifoSquatDriverKill,
            index,
            format!("a stale socket and a FIFO lock at {GHOST_SKIN}/{channel}, then {name} (pid {driver}) killed"),
        );
        procs::signal(driver, Signal::KILL);
        self.observer.mark(injected.ended_ns);
        let killed = Instant::now();
        while killed.elapsed() < Duration::from_secs(5) && self.observer.recovered().is_none() {
            if !self.idle(Duration::from_millis(5)) {
                break;
            }
        }
        for path in [&socket, &lock] {
            remove_squat(path);
        }
        self.squats.retain(|p| p != &socket && p != &lock);
        Ok(injected)
    }

    pub(super) fn squat(&mut self, kind: FaultKind, index: usize) -> Result<Injected> {
        let channel = format!("layer{index}");
        let paths = channel_paths(&self.options.dir, GHOST_SKIN, &channel);
        let hold = self.chaos.seconds(1.0, 3.0);
        let what = match kind {
            FaultKind::SquatFifo => "FIFOs",
            FaultKind::SquatSymlink => "symlinks to nowhere",
            _ => "regular files",
        };
        let mut injected = self.begin(kind, index, format!("{what} at {GHOST_SKIN}/{channel}'s socket and lock"));
        let targets: Vec<PathBuf> = (0..2).map(|i| self.work.join(format!("symlink-target-{index}-{i}"))).collect();
        for (path, target) in paths.iter().zip(&targets) {
            self.squats.push(path.clone());
            match kind {
                FaultKind::SquatFifo => {
                    let status =
                        std::process::Command::new("mkfifo").arg(path).status().context("cannot run mkfifo")?;
                    if !status.success() {
                        bail!("mkfifo {} failed ({status})", path.display());
                    }
                }
                FaultKind::SquatSymlink => std::os::unix::fs::symlink(target, path)
                    .with_context(|| format!("cannot create the symlink {}", path.display()))?,
                _ => std::fs::write(path, b"squatted by skin bench soak\n")
                    .with_context(|| format!("cannot create {}", path.display()))?,
            }
        }
        self.idle(hold);
        for path in &paths {
            remove_squat(path);
        }
        self.squats.retain(|p| !paths.contains(p));
        self.end(&mut injected);
        let created: Vec<String> = targets.iter().filter(|t| t.exists()).map(|t| t.display().to_string()).collect();
        if !created.is_empty() {
            injected.record.note = format!("something created the symlinks' targets: {}", created.join(", "));
            for target in targets {
                let _ = std::fs::remove_file(target);
            }
        }
        Ok(injected)
    }
}
