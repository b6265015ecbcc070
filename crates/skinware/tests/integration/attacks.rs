//! A process that may read a channel attacks it every way its descriptors
//! allow: it truncates the memory (to zero, by one slot), shrinks and regrows
//! it, unlinks the channel's socket and name lock, and scribbles over every
//! byte it can write. Each attack runs in its own process beside a writer
//! process and one reader process per mode; the writer must keep publishing,
//! and every process must exit cleanly (errors allowed, signals never).

use std::io::Write as _;
use std::os::unix::process::ExitStatusExt;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use skinware::{Reader, Ticker, Writer, WriterOptions};

use crate::util::{SegmentDir, receive_fds};

/// Set in child processes: `writer`, `reader:<mode>` or `attacker:<attack>`.
const ROLE: &str = "SKINWARE_TEST_ATTACK_ROLE";
/// Set in child processes: the segment directory.
const DIR: &str = "SKINWARE_TEST_ATTACK_DIR";

/// How long the writer and readers run; the attack happens in the middle.
const RUN: Duration = Duration::from_millis(3000);
const PAYLOAD_BYTES: usize = 8192;
/// Starts each line a child reports.
const MARK: &str = "ATTACK-REPORT ";

#[test]
fn attack_child_process() {
    let (Some(role), Some(dir)) = (std::env::var_os(ROLE), std::env::var_os(DIR)) else {
        return;
    };
    let role = role.to_string_lossy().into_owned();
    let dir = std::path::PathBuf::from(dir);
    let outcome = match role.split_once(':') {
        None => run_writer(&dir),
        Some(("reader", mode)) => run_reader(&dir, mode),
        Some(("attacker", attack)) => run_attack(&dir, attack),
        Some(_) => panic!("unknown role {role}"),
    };
    // Marked, to tell them from the test harness's own lines.
    for line in outcome.lines() {
        println!("{MARK}{line}");
    }
    std::io::stdout().flush().unwrap();
}

fn run_writer(dir: &std::path::Path) -> String {
    let options =
        WriterOptions { dir: Some(dir.to_owned()), period: Some(Duration::from_millis(5)), ..WriterOptions::default() };
    let mut writer = Writer::create("skin", "layer", PAYLOAD_BYTES, b"topology", &options).unwrap();
    let mut ticker = Ticker::new(Duration::from_millis(5));
    let started = Instant::now();
    let stop = skinware::Stop::new();
    let mut value = 0u16;
    while started.elapsed() < RUN && ticker.wait(&stop).is_some() {
        value = value.wrapping_add(1);
        let mut frame = writer.begin();
        frame.write_responses(0, &[value; PAYLOAD_BYTES / 2]).unwrap();
        frame.publish();
    }
    format!("published={}", writer.last_seq())
}

fn run_reader(dir: &std::path::Path, mode: &str) -> String {
    let options = skinware::ReaderOptions { dir: Some(dir.to_owned()), ..Default::default() };
    let started = Instant::now();
    let mut reader = loop {
        match Reader::open_with("skin", "layer", &options) {
            Ok(reader) => break reader,
            Err(e) if started.elapsed() > Duration::from_secs(10) => return format!("never attached: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
    };
    let (mut frames, mut errors, mut torn) = (0u64, 0u64, 0u64);
    let mut ticker = Ticker::new(Duration::from_millis(10));
    let stop = skinware::Stop::new();
    while started.elapsed() < RUN {
        let result = match mode {
            "periodic" => {
                ticker.wait(&stop);
                reader.latest().map(|f| f.responses().to_vec())
            }
            "asap" => reader.wait_newer(Duration::from_millis(200)).map(|f| f.responses().to_vec()),
            _ => reader.request(Duration::from_millis(200)).map(|f| f.responses().to_vec()),
        };
        match result {
            Ok(responses) => {
                frames += 1;
                // Every frame is whole: one value throughout.
                if responses.iter().any(|&r| r != responses[0]) {
                    torn += 1;
                }
            }
            Err(_) => errors += 1,
        }
    }
    format!("frames={frames} errors={errors} torn={torn}")
}

/// Each attempt, and what the kernel said.
fn run_attack(dir: &std::path::Path, attack: &str) -> String {
    let socket = dir.join("skinware.skin.layer");
    let (data, bell) = receive_fds(&socket);
    let size = std::fs::File::from(data.try_clone().unwrap()).metadata().unwrap().len();
    let reopen = |fd: &std::os::fd::OwnedFd| {
        let path = format!("/proc/self/fd/{}", std::os::fd::AsRawFd::as_raw_fd(fd));
        rustix::fs::open(path.as_str(), rustix::fs::OFlags::RDWR, rustix::fs::Mode::empty())
    };
    let data_rw = reopen(&data);
    // As the writer's own user (these tests run as the writer's user), the
    // file's permissions allow it; the seals are what stop everything after.
    let mut attempts: Vec<String> = vec![format!(
        "reopen the frames read-write: {:?} (allowed to the writer's user)",
        data_rw.as_ref().map(|_| ())
    )];
    let mut truncate = |what: &str, fd: &std::os::fd::OwnedFd, to: u64| {
        attempts.push(format!("{what} to {to}: {:?}", rustix::fs::ftruncate(fd, to)));
    };
    let slot = PAYLOAD_BYTES as u64 + 64;
    let targets: Vec<(&str, &std::os::fd::OwnedFd)> = [
        ("frames (as received)", Some(&data)),
        ("frames (reopened)", data_rw.as_ref().ok()),
        ("doorbell", Some(&bell)),
    ]
    .into_iter()
    .filter_map(|(what, fd)| fd.map(|fd| (what, fd)))
    .collect();
    match attack {
        "truncate-to-zero" => targets.iter().for_each(|(what, fd)| truncate(what, fd, 0)),
        "truncate-one-slot" => targets.iter().for_each(|(what, fd)| truncate(what, fd, size - slot)),
        "shrink-and-regrow" => targets.iter().for_each(|(what, fd)| {
            truncate(what, fd, size / 2);
            truncate(what, fd, size * 2);
        }),
        "unlink" => {
            for path in [socket.clone(), dir.join(".skinware-lock.skin.layer")] {
                attempts.push(format!("unlink {}: {:?} (allowed)", path.display(), std::fs::remove_file(&path)));
            }
        }
        "scribble" => {
            // Writing through a descriptor meets the same seals a writable
            // mapping would (F_SEAL_FUTURE_WRITE refuses both).
            for (what, fd) in &targets {
                let allowed = if *what == "doorbell" { " (allowed)" } else { "" };
                attempts.push(format!("{what}: write: {:?}{allowed}", rustix::io::pwrite(fd, &[0xff; 64], 0)));
            }
            // What readers may write, the doorbell, gets random bytes for a second.
            let bell_file = std::fs::File::from(bell.try_clone().unwrap());
            let mut state = 0x9e37_79b9_7f4a_7c15u64;
            let started = Instant::now();
            let mut writes = 0u64;
            while started.elapsed() < Duration::from_secs(1) {
                let mut page = [0u8; 4096];
                for chunk in page.chunks_exact_mut(8) {
                    state ^= state << 13;
                    state ^= state >> 7;
                    state ^= state << 17;
                    chunk.copy_from_slice(&state.to_ne_bytes());
                }
                std::os::unix::fs::FileExt::write_all_at(&bell_file, &page, 0).unwrap();
                writes += 1;
            }
            attempts.push(format!("doorbell page overwritten with random bytes {writes} times (allowed)"));
        }
        other => panic!("unknown attack {other}"),
    }
    attempts.join("\n")
}

#[allow(clippy::zombie_processes)] // every child is waited for by `finish`
fn spawn(dir: &SegmentDir, role: &str) -> Child {
    Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "attacks::attack_child_process", "--nocapture", "--test-threads=1"])
        .env(ROLE, role)
        .env(DIR, &dir.path)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Waits for a child and returns its last output line; a child killed by a
/// signal (SIGBUS above all) or failing fails the test.
fn finish(child: Child, role: &str) -> String {
    let output = child.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout).into_owned();
    assert!(
        output.status.signal().is_none(),
        "{role} was killed by signal {:?}\nstdout: {stdout}\nstderr: {}",
        output.status.signal(),
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(output.status.success(), "{role} failed: {stdout}\n{}", String::from_utf8_lossy(&output.stderr));
    stdout.lines().filter_map(|l| l.split_once(MARK).map(|(_, ours)| ours)).collect::<Vec<_>>().join("\n")
}

fn frames_published(dir: &SegmentDir) -> u64 {
    match Reader::open_with("skin", "layer", &dir.reader()) {
        Ok(reader) => reader.published_seq(),
        Err(_) => 0,
    }
}

fn attack(name: &str) {
    let dir = SegmentDir::new(name);
    let writer = spawn(&dir, "writer");
    let started = Instant::now();
    while frames_published(&dir) == 0 {
        assert!(started.elapsed() < Duration::from_secs(10), "the writer never came up");
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut watcher = Reader::open_with("skin", "layer", &dir.reader()).unwrap();
    let readers: Vec<(String, Child)> = ["periodic", "asap", "request"]
        .iter()
        .map(|mode| (format!("reader:{mode}"), spawn(&dir, &format!("reader:{mode}"))))
        .collect();
    std::thread::sleep(Duration::from_millis(500));
    let attacker = spawn(&dir, &format!("attacker:{name}"));
    let attempts = finish(attacker, name);
    println!("{name}:\n{attempts}");
    for line in attempts.lines().filter(|l| !l.contains("(allowed")) {
        assert!(line.contains("Err("), "{name}: an attempt succeeded: {line}");
    }
    // The writer goes on: new frames, seen by a reader attached before the attack.
    // (Waited for, not timed: a loaded machine may run the writer late.)
    let before = watcher.published_seq();
    let started = Instant::now();
    while watcher.published_seq() <= before + 20 {
        assert!(started.elapsed() < Duration::from_secs(20), "{name}: the writer stopped publishing after the attack");
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(watcher.latest().is_ok());
    if name == "unlink" {
        // New readers can attach again once the writer has put its socket back.
        let started = Instant::now();
        while Reader::open_with("skin", "layer", &dir.reader()).is_err() {
            assert!(started.elapsed() < Duration::from_secs(2), "the writer did not put its socket back");
            std::thread::sleep(Duration::from_millis(10));
        }
        let err = Writer::create("skin", "layer", 8, b"", &dir.writer()).unwrap_err();
        assert!(matches!(err, skinware::Error::Busy { .. }), "the writer lost its name: {err}");
    }
    for (role, child) in readers {
        let summary = finish(child, &role);
        println!("  {role}: {summary}");
        let frames: u64 = summary
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix("frames="))
            .and_then(|n| n.parse().ok())
            .unwrap_or(0);
        assert!(frames > 50, "{name}: {role} got only {frames} frames: {summary}");
        assert!(summary.contains("torn=0"), "{name}: {role} got a torn frame: {summary}");
    }
    println!("  writer: {}", finish(writer, "writer"));
}

#[test]
fn truncate_to_zero() {
    attack("truncate-to-zero");
}

#[test]
fn truncate_by_one_slot() {
    attack("truncate-one-slot");
}

#[test]
fn shrink_and_regrow() {
    attack("shrink-and-regrow");
}

#[test]
fn unlink_the_socket_and_the_name_lock() {
    attack("unlink");
}

#[test]
fn scribble_over_every_writable_byte() {
    attack("scribble");
}
