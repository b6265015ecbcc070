//! What the test modules share.

use std::process::{Child, ExitStatus};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use skinware::{Reader, WriterState};

/// Held by each test that runs a whole skin. Those tests assert on timing
/// (no missed period, the page keeps up), and as separate test binaries they
/// never ran at the same time; in one binary the test threads would run them
/// side by side, so each takes this first.
pub fn one_skin_at_a_time() -> MutexGuard<'static, ()> {
    static LOCK: Mutex<()> = Mutex::new(());
    // A test that failed while holding it poisoned it; the others still run.
    skinware::lock(&LOCK)
}

/// Waits until `reader`'s writer is in `state` (following a re-created
/// channel meanwhile, unless waiting for it to be gone) and returns how long
/// that took; fails the test after `within`.
pub fn wait_for(reader: &mut Reader, state: WriterState, within: Duration) -> Duration {
    let started = Instant::now();
    loop {
        if state != WriterState::Gone {
            reader.follow_recreated();
        }
        if reader.writer_state() == state {
            return started.elapsed();
        }
        assert!(started.elapsed() < within, "{} never became {state} (is {})", reader.label(), reader.writer_state());
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Sends `child` SIGINT, as Ctrl-C does, and waits up to `within` for it to
/// exit; one still running then is killed, and the test fails naming
/// `what`. The one way the tests stop a process as a user would.
pub fn interrupt_and_wait(child: &mut Child, what: &str, within: Duration) -> ExitStatus {
    if let Some(pid) = rustix::process::Pid::from_raw(child.id() as i32) {
        let _ = rustix::process::kill_process(pid, rustix::process::Signal::INT);
    }
    exit_within(child, &format!("{what}, sent SIGINT,"), within)
}

/// Waits up to `within` for `child` to exit; one still running then is
/// killed, and the test fails naming `what`.
pub fn exit_within(child: &mut Child, what: &str, within: Duration) -> ExitStatus {
    let started = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            return status;
        }
        if started.elapsed() > within {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{what} did not exit within {within:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A file for a child's output (`NAME.log`, beside `dir` in `DIR-logs/`: a
/// test may check that `dir` is left empty), so that a passing test prints
/// nothing of its children's logs; [`show_logs_if_failing`] prints them when
/// the test fails, and removes them.
pub fn log_file(dir: &std::path::Path, name: &str) -> std::process::Stdio {
    let logs = logs_dir(dir);
    let _ = std::fs::create_dir_all(&logs);
    std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(logs.join(format!("{name}.log")))
        .map_or_else(|_| std::process::Stdio::inherit(), std::process::Stdio::from)
}

fn logs_dir(dir: &std::path::Path) -> std::path::PathBuf {
    let mut name = dir.as_os_str().to_owned();
    name.push("-logs");
    name.into()
}

/// While a test panics (called from a `Drop`), prints every log that
/// [`log_file`] kept for `dir`; then removes them.
pub fn show_logs_if_failing(dir: &std::path::Path) {
    let logs = logs_dir(dir);
    if std::thread::panicking() {
        for entry in std::fs::read_dir(&logs).into_iter().flatten().flatten() {
            let path = entry.path();
            eprintln!("--- {} ---\n{}", path.display(), std::fs::read_to_string(&path).unwrap_or_default());
        }
    }
    let _ = std::fs::remove_dir_all(&logs);
}

/// A background child (a skin, a bridge, a peer) stopped with SIGINT when
/// dropped, then killed if it has not exited within 10 s; never a panic in
/// drop, where a failing test is already unwinding.
#[cfg(any(feature = "zenoh", feature = "dds"))]
pub struct Running(pub Child);

#[cfg(any(feature = "zenoh", feature = "dds"))]
impl Drop for Running {
    fn drop(&mut self) {
        if let Some(pid) = rustix::process::Pid::from_raw(self.0.id() as i32) {
            let _ = rustix::process::kill_process(pid, rustix::process::Signal::INT);
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        while Instant::now() < deadline {
            if let Ok(Some(_)) = self.0.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
