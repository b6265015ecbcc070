//! Processes a benchmark starts and watches: a child killed when dropped,
//! `skin view` on a free port, the children of `skin run` by role, and what
//! `/proc` says of a process (resident memory, open file descriptors).

#![forbid(unsafe_code)]

use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};

/// A child process killed (and reaped) when dropped.
pub struct Guarded(pub Child);

impl Drop for Guarded {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `skin view` (of `exe`) on a free loopback port, with its channels
/// in `dir` and `extra` arguments (e.g. `--skin NAME`), and waits until it
/// answers; returns it and where it listens. Its standard error goes to
/// `log` if given, else to ours.
pub fn start_viewer(exe: &Path, dir: &Path, extra: &[&str], log: Option<&Path>) -> Result<(Guarded, String)> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let address = format!("127.0.0.1:{port}");
    let mut command = Command::new(exe);
    command
        .args(["view", "--listen", &address])
        .args(extra)
        .env("SKINWARE_SHM_DIR", dir)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null());
    if let Some(log) = log {
        command
            .env("NO_COLOR", "1")
            .stderr(std::fs::File::create(log).with_context(|| format!("cannot create {}", log.display()))?);
    }
    let child = Guarded(command.spawn().context("cannot start `skin view`")?);
    let deadline = Instant::now() + Duration::from_secs(20);
    while TcpStream::connect(&address).is_err() {
        if Instant::now() > deadline {
            bail!("`skin view` did not listen on {address} within 20 s");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok((child, address))
}

/// The driver and service processes `skin run` (process `parent`) started,
/// named by their command lines (`skin driver CONFIG --name virtual`:
/// "driver virtual").
pub fn supervised_pids(parent: u32) -> Vec<(String, u32)> {
    let mut found = Vec::new();
    let Ok(entries) = std::fs::read_dir("/proc") else { return found };
    for entry in entries.flatten() {
        let Some(pid) = entry.file_name().to_str().and_then(|name| name.parse::<u32>().ok()) else { continue };
        if parent_of(pid) != Some(parent) {
            continue;
        }
        let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
        let words: Vec<String> = cmdline.split(|&b| b == 0).map(|w| String::from_utf8_lossy(w).into_owned()).collect();
        let role = words.get(1).cloned().unwrap_or_default();
        let name = words.iter().skip_while(|w| *w != "--name").nth(1).cloned().unwrap_or_else(|| pid.to_string());
        found.push((format!("{role} {name}"), pid));
    }
    found
}

/// The fields of `/proc/PID/stat` after the command name (which may hold
/// spaces, in parentheses): field 0 is the state, 1 the parent.
fn stat_fields(pid: u32) -> Option<Vec<String>> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let (_, rest) = stat.rsplit_once(')')?;
    Some(rest.split_whitespace().map(str::to_owned).collect())
}

/// The parent of process `pid`, if it exists.
pub fn parent_of(pid: u32) -> Option<u32> {
    stat_fields(pid)?.get(1)?.parse().ok()
}

/// The state letter of process `pid` (`R`, `S`, `T` stopped, `Z` zombie...),
/// if it exists.
pub fn state_of(pid: u32) -> Option<char> {
    stat_fields(pid)?.first()?.chars().next()
}

/// What `/proc` says of one process's resources at one moment.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Resources {
    /// Resident set size, KiB (`VmRSS`).
    pub rss_kib: u64,
    /// Open file descriptors (entries of `/proc/PID/fd`).
    pub fds: u64,
}

/// The resident memory and open descriptors of process `pid`; `None` if it
/// is gone (or a zombie, which has neither).
pub fn resources_of(pid: u32) -> Option<Resources> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let rss_kib = status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|value| value.split_whitespace().next()?.parse().ok())?;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count() as u64;
    Some(Resources { rss_kib, fds })
}

/// Sends `signal` to process `pid` (nothing if there is no such process).
pub fn signal(pid: u32, signal: rustix::process::Signal) {
    if let Some(pid) = rustix::process::Pid::from_raw(pid as i32) {
        let _ = rustix::process::kill_process(pid, signal);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_has_memory_descriptors_and_a_parent() {
        let me = std::process::id();
        let resources = resources_of(me).expect("this process is in /proc");
        assert!(resources.rss_kib > 0 && resources.fds >= 3, "{resources:?}");
        assert_eq!(parent_of(me), Some(std::os::unix::process::parent_id()));
        assert!(matches!(state_of(me), Some('R' | 'S')));
        assert_eq!(resources_of(u32::MAX / 2), None);
    }
}
