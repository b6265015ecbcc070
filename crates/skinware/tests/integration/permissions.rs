//! Readers with read permission alone: a child process running as `nobody`
//! attaches to channels created with each access level, reads in all three
//! modes, and checks that what it holds is read-only. Needs root (to start a
//! child as another user); skipped, saying so, without.

use std::io::Write as _;
use std::os::unix::process::CommandExt;
use std::process::Command;
use std::time::Duration;

use skinware::{Access, Reader, ReaderOptions, Stop, Ticker, Writer, WriterOptions};

use crate::util::SegmentDir;

const ROLE: &str = "SKINWARE_TEST_PERMISSION_CHILD";
const NOBODY: u32 = 65534;
const NOGROUP: u32 = 65534;

#[test]
fn permission_child_process() {
    let Some(dir) = std::env::var_os(ROLE) else { return };
    let options = ReaderOptions { dir: Some(dir.into()), ..ReaderOptions::default() };
    let mut lines =
        vec![format!("uid={} gid={}", rustix::process::getuid().as_raw(), rustix::process::getgid().as_raw())];
    match Reader::open_with("skin", "layer", &options) {
        Err(e) => lines.push(format!("attach: {e}")),
        Ok(mut reader) => {
            lines.push("attach: ok".into());
            lines.push(format!("latest: {:?}", reader.latest().map(|f| f.seq() > 0)));
            lines.push(format!("wait_newer: {:?}", reader.wait_newer(Duration::from_secs(2)).map(|f| f.seq() > 0)));
            lines.push(format!("request: {:?}", reader.request(Duration::from_secs(2)).map(|f| f.seq() > 0)));
            lines.push(format!("frames descriptors: {}", frames_descriptors()));
        }
    }
    println!("{}", lines.join("\n"));
    std::io::stdout().flush().unwrap();
}

/// For every open descriptor of a channel's frames: its access mode, and
/// whether reopening it read-write through /proc succeeds.
fn frames_descriptors() -> String {
    let mut found = Vec::new();
    for entry in std::fs::read_dir("/proc/self/fd").unwrap().flatten() {
        let Ok(target) = std::fs::read_link(entry.path()) else { continue };
        if !target.to_string_lossy().contains(":frames") {
            continue;
        }
        let info = std::fs::read_to_string(format!("/proc/self/fdinfo/{}", entry.file_name().to_string_lossy()))
            .unwrap_or_default();
        let flags = info
            .lines()
            .find_map(|l| l.strip_prefix("flags:").and_then(|f| u32::from_str_radix(f.trim(), 8).ok()))
            .unwrap_or(u32::MAX);
        let mode = if flags & 0o3 == 0 { "read-only" } else { "WRITABLE" };
        let reopened = std::fs::OpenOptions::new().read(true).write(true).open(entry.path());
        found.push(format!("{mode}, reopen read-write: {:?}", reopened.map(|_| ()).map_err(|e| e.kind())));
    }
    found.join("; ")
}

/// Runs a periodic writer with `access` while a child as `nobody` (in group
/// `gid`) reads; returns the child's report.
fn read_as_nobody(access: Access, gid: u32) -> String {
    let dir = SegmentDir::new("permissions");
    // The test binary, where `nobody` may run it.
    let binary = dir.path.join("test-binary");
    std::fs::copy(std::env::current_exe().unwrap(), &binary).unwrap();
    let stop = Stop::new();
    let options = WriterOptions { access, period: Some(Duration::from_millis(5)), ..dir.writer() };
    let mut writer = Writer::create("skin", "layer", 64, b"topology", &options).unwrap();
    writer.set_stop(&stop);
    let publisher = std::thread::spawn(move || {
        writer.run_periodic(Ticker::new(Duration::from_millis(5)), |frame| frame.write_responses(0, &[7; 32]))
    });
    let mut attempts = 0;
    let output = loop {
        let run = Command::new(&binary)
            .args(["--exact", "permissions::permission_child_process", "--nocapture"])
            .env(ROLE, &dir.path)
            .uid(NOBODY)
            .gid(gid)
            .output();
        match run {
            // Another test's child, forked while the copy was open for
            // writing, may still hold it so for a moment.
            Err(e) if e.kind() == std::io::ErrorKind::ExecutableFileBusy && attempts < 50 => {
                attempts += 1;
                std::thread::sleep(Duration::from_millis(20));
            }
            run => break run.unwrap(),
        }
    };
    stop.stop();
    publisher.join().unwrap().unwrap();
    let report = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(output.status.success(), "the child failed: {report}\n{}", String::from_utf8_lossy(&output.stderr));
    report
}

fn skipped() -> bool {
    if rustix::process::getuid().is_root() {
        return false;
    }
    println!("SKIPPED: starting a child as nobody needs root");
    true
}

fn assert_reads_read_only(report: &str) {
    assert!(report.contains("attach: ok"), "{report}");
    for mode in ["latest", "wait_newer", "request"] {
        assert!(report.contains(&format!("{mode}: Ok(true)")), "{mode}: {report}");
    }
    assert!(report.contains("frames descriptors: read-only, reopen read-write: Err(PermissionDenied)"), "{report}");
    assert!(!report.contains("WRITABLE"), "{report}");
}

#[test]
#[cfg_attr(skip_not_root, ignore = "needs root: starts a reader as the user nobody")]
fn owner_only_channels_refuse_other_users() {
    if skipped() {
        return;
    }
    let report = read_as_nobody(Access::Owner, 0);
    assert!(report.contains("attach: no permission to read channel skin/layer"), "{report}");
    assert!(report.contains("access = \"group\""), "the error must say how to grant access: {report}");
}

#[test]
#[cfg_attr(skip_not_root, ignore = "needs root: starts a reader as the user nobody")]
fn group_channels_refuse_users_outside_the_group() {
    if skipped() {
        return;
    }
    let report = read_as_nobody(Access::Group, NOGROUP);
    assert!(report.contains("attach: no permission"), "{report}");
}

#[test]
#[cfg_attr(skip_not_root, ignore = "needs root: starts a reader as the user nobody")]
fn group_channels_are_read_only_for_the_group() {
    if skipped() {
        return;
    }
    assert_reads_read_only(&read_as_nobody(Access::Group, 0));
}

#[test]
#[cfg_attr(skip_not_root, ignore = "needs root: starts a reader as the user nobody")]
fn everyone_channels_are_read_only_for_everyone() {
    if skipped() {
        return;
    }
    assert_reads_read_only(&read_as_nobody(Access::Everyone, NOGROUP));
}
