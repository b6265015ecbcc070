//! One doc's commands, run in the doc's order as a person would type them,
//! each in bash in a scratch directory (a copy of `examples/`, an empty
//! `docs/`) with this build's `skin` first on PATH and a private segment
//! directory (`SKINWARE_SHM_DIR`). Where the machine allows it, each runs in
//! a network namespace of its own, so that the docs' fixed ports (8080, 7447)
//! meet nobody else's.
//!
//! - A one-shot command must exit 0 within [`ONE_SHOT_WITHIN`].
//! - A long-running one (`skin run`, `demo`, `view`, `emulate`, `bridge`,
//!   `top`, `echo`, `record`, `replay`, `region record`) must still be alive
//!   after [`ALIVE`] (or, for `run` and `demo`, once its skin is up), then
//!   gets SIGINT, as Ctrl-C sends it to its process group, and must exit 0
//!   (or die of that SIGINT, as a tool with nothing to clean up does), leave
//!   no process of its group running and, if it started a skin, no file in
//!   the segment directory.
//! - `skin run` and commands ending in `&` stay in the background for the
//!   doc's next commands (the doc's "in another terminal"), until a command
//!   that starts a skin of its own (`run`, `demo`, `replay`) or the doc's end.
//! - A command that reads a skin when the session has none runs against one
//!   the test starts: `skin run examples/paper-virtual-skin.toml`.

use std::fs::File;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use rustix::process::{Pid, Signal, kill_process_group};
use skinware::WriterState;
use skinware_geometry::SkinGeometry;

use super::markdown::{DocCommand, SkinCall, skin_calls};

/// How long a long-running command runs before it must still be alive.
const ALIVE: Duration = Duration::from_secs(3);
/// How long a whole skin must stay alive once it is up.
const ALIVE_AFTER_UP: Duration = Duration::from_secs(1);
/// How long a skin may take to come up: the first to start computes the
/// paper's geometry in a debug build (tens of seconds on a busy machine).
const UP_WITHIN: Duration = Duration::from_secs(120);
/// How long a one-shot command may take (the documented quick benchmarks).
const ONE_SHOT_WITHIN: Duration = Duration::from_secs(180);
/// How long a command may take to stop after SIGINT.
const STOP_WITHIN: Duration = Duration::from_secs(20);

/// What became of one command.
pub enum Verdict {
    /// It ran as the doc says; how it went.
    Ran(String),
    /// A marker says why it cannot run here.
    Skipped(String),
    /// What went wrong.
    Failed(String),
}

/// One command's verdict, with where the doc has it.
pub struct Outcome {
    /// The doc's line (0 for the skin the test started itself).
    pub line: usize,
    /// The command's first line as written.
    pub written: String,
    /// What became of it.
    pub verdict: Verdict,
}

/// A command's process group (its leader is the spawned bash): killed with
/// the group if still running when dropped, so a failed check leaks nothing.
struct Process {
    child: Child,
    log: PathBuf,
    /// It started a skin (its stop must leave the segment directory empty).
    starts_skin: bool,
    /// Its entry in the outcomes, whose verdict its stop completes.
    outcome: Option<usize>,
    /// How the summary names it if it has no outcome of its own.
    label: String,
}

impl Process {
    fn group(&self) -> Pid {
        Pid::from_raw(self.child.id() as i32).expect("a child's pid is positive")
    }

    /// Waits up to `duration`, returning early if it exits.
    fn hold(&mut self, duration: Duration) -> Option<ExitStatus> {
        let started = Instant::now();
        while started.elapsed() < duration {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        self.child.try_wait().ok().flatten()
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = kill_process_group(self.group(), Signal::KILL);
        let _ = self.child.wait();
    }
}

/// The commands of one doc, with the processes they left running.
pub struct Session {
    repo: PathBuf,
    scratch: PathBuf,
    shm: PathBuf,
    netns: bool,
    background: Vec<Process>,
    logs: usize,
    outcomes: Vec<Outcome>,
}

impl Session {
    /// A fresh scratch and segment directory for the doc `name`, the
    /// `index`th; `netns`: run each command in a network namespace of its own.
    pub fn new(name: &str, index: usize, repo: &Path, netns: bool) -> Session {
        let slug: String = name.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '-' }).collect();
        let scratch = std::env::temp_dir().join(format!("skin-docs-{}-{slug}", std::process::id()));
        // Short: a channel's socket path, bound first under a longer
        // temporary name, must fit a Unix socket address (107 bytes).
        let shm = PathBuf::from("/dev/shm").join(format!("skin-docs-{}-{index}", std::process::id()));
        let _ = std::fs::remove_dir_all(&scratch);
        let _ = std::fs::remove_dir_all(&shm);
        std::fs::create_dir_all(scratch.join("bin")).unwrap();
        std::fs::create_dir_all(scratch.join("docs")).unwrap();
        std::fs::create_dir_all(&shm).unwrap();
        std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_skin"), scratch.join("bin/skin")).unwrap();
        copy_dir(&repo.join("examples"), &scratch.join("examples"));
        Session { repo: repo.to_owned(), scratch, shm, netns, background: Vec::new(), logs: 0, outcomes: Vec::new() }
    }

    /// Runs `command` (or records why not), after what it depends on.
    pub fn run(&mut self, command: &DocCommand) {
        let unknown: Vec<&str> =
            command.features.iter().map(String::as_str).filter(|f| built_with(f).is_none()).collect();
        let lacking: Vec<&str> =
            command.features.iter().map(String::as_str).filter(|f| built_with(f) == Some(false)).collect();
        let verdict = if !unknown.is_empty() {
            Verdict::Failed(format!("needs the cargo features {unknown:?}, which skin does not have"))
        } else if !lacking.is_empty() {
            // Its `skin` command line cannot even be parsed without them.
            let why = format!("needs skin built with --features {} (this test was not)", lacking.join(","));
            Verdict::Skipped(command.skip.as_ref().map_or(why.clone(), |reason| format!("{reason}; {why}")))
        } else {
            match &command.skip {
                Some(reason) => skipped(command, reason),
                None => match self.execute(command) {
                    Ok(detail) => Verdict::Ran(detail),
                    Err(failure) => Verdict::Failed(failure),
                },
            }
        };
        self.outcomes.push(Outcome { line: command.line, written: command.written.clone(), verdict });
    }

    /// Stops what is still running and gives every command's outcome.
    pub fn finish(mut self) -> Vec<Outcome> {
        self.stop_background(false);
        let failed = self.outcomes.iter().any(|o| matches!(o.verdict, Verdict::Failed(_)));
        if !failed {
            let _ = std::fs::remove_dir_all(&self.scratch);
        } else {
            println!("docs: the failed commands' logs are in {}", self.scratch.display());
        }
        std::mem::take(&mut self.outcomes)
    }

    fn execute(&mut self, command: &DocCommand) -> Result<String, String> {
        let first_word = command.shell.split_whitespace().next().unwrap_or("");
        if matches!(first_word, "cd" | "export" | "source" | ".") {
            return Err(format!(
                "`{first_word}` changes the shell the doc's next commands run in, which each command here does \
                 not share: write the command another way, or mark the block"
            ));
        }
        let calls = skin_calls(&command.shell);
        if calls.iter().any(SkinCall::starts_skin) {
            self.stop_background(true);
        }
        let mut notes = Vec::new();
        if calls.iter().any(SkinCall::needs_skin) && !self.background.iter().any(|p| p.starts_skin) {
            notes.push(self.start_test_skin()?);
        }
        let detail = if command.background || calls.iter().any(|c| c.verb() == "run") {
            self.start_background(command, &calls)?
        } else if calls.iter().any(SkinCall::long_running) {
            self.run_for_a_while(command, &calls)?
        } else {
            self.run_once(command)?
        };
        notes.insert(0, detail);
        Ok(notes.join("; "))
    }

    /// Starts `shell` in bash, in its own process group (as a terminal
    /// starts a job), its output in a log of the scratch directory.
    fn spawn(&mut self, shell: &str, label: &str) -> Result<Process, String> {
        self.logs += 1;
        let log = self.scratch.join(format!("command-{:02}.log", self.logs));
        let out = File::create(&log).map_err(|e| format!("{}: {e}", log.display()))?;
        let err = out.try_clone().map_err(|e| format!("{}: {e}", log.display()))?;
        // The command comes in the environment, so that no quoting of ours
        // changes it; the namespace's loopback must be brought up first.
        let script = "ip link set lo up || exit 97; c=$DOC_COMMAND; unset DOC_COMMAND; exec bash -c \"$c\"";
        let mut bash = if self.netns {
            let mut unshare = Command::new("unshare");
            unshare.args(["-rn", "bash", "-c", script]);
            unshare
        } else {
            let mut bash = Command::new("bash");
            bash.args(["-c", "c=$DOC_COMMAND; unset DOC_COMMAND; exec bash -c \"$c\""]);
            bash
        };
        let path = format!("{}:{}", self.scratch.join("bin").display(), std::env::var("PATH").unwrap_or_default());
        bash.env("DOC_COMMAND", shell)
            .env("PATH", path)
            .env("SKINWARE_SHM_DIR", &self.shm)
            .env("NO_COLOR", "1")
            .current_dir(&self.scratch)
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .process_group(0);
        let child = bash.spawn().map_err(|e| format!("cannot start bash: {e}"))?;
        Ok(Process { child, log, starts_skin: false, outcome: None, label: label.to_owned() })
    }

    fn run_once(&mut self, command: &DocCommand) -> Result<String, String> {
        let mut process = self.spawn(&command.shell, &command.written)?;
        let started = Instant::now();
        let status = loop {
            if let Some(status) = process.child.try_wait().map_err(|e| e.to_string())? {
                break status;
            }
            if started.elapsed() > ONE_SHOT_WITHIN {
                return Err(format!(
                    "still running after {} s (a command that runs until Ctrl-C must be one the test knows as \
                     long-running){}",
                    ONE_SHOT_WITHIN.as_secs(),
                    tail(&process.log)
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let took = started.elapsed();
        if !status.success() {
            return Err(format!("{}{}", describe(status), tail(&process.log)));
        }
        let left = wait_until_group_gone(process.group(), Duration::from_secs(5));
        if !left.is_empty() {
            return Err(format!("exit 0, but left running: {}", left.join(", ")));
        }
        Ok(format!("exit 0 in {:.1} s, {} lines of output", took.as_secs_f64(), line_count(&process.log)))
    }

    fn run_for_a_while(&mut self, command: &DocCommand, calls: &[SkinCall]) -> Result<String, String> {
        let mut process = self.spawn(&command.shell, &command.written)?;
        process.starts_skin = calls.iter().any(SkinCall::starts_skin);
        let (mut detail, held) = if calls.iter().any(SkinCall::waits_until_up) {
            let up = self.wait_until_up(&mut process)?;
            (format!("up in {:.1} s, ", up.as_secs_f64()), process.hold(ALIVE_AFTER_UP))
        } else {
            (String::new(), process.hold(ALIVE))
        };
        if let Some(status) = held {
            let may_end = calls.iter().all(|c| !c.long_running() || c.may_end_by_itself());
            if !(status.success() && may_end) {
                return Err(format!("{} while it should still run{}", describe(status), tail(&process.log)));
            }
            detail.push_str(&format!("ended by itself with exit 0 within {} s", ALIVE.as_secs()));
        } else {
            detail.push_str(&format!("alive after {} s; {}", held_for(calls).as_secs(), self.interrupt(&mut process)?));
        }
        if process.starts_skin && !self.background.iter().any(|p| p.starts_skin) {
            self.check_no_file_left()?;
        }
        Ok(detail)
    }

    fn start_background(&mut self, command: &DocCommand, calls: &[SkinCall]) -> Result<String, String> {
        let mut process = self.spawn(&command.shell, &command.written)?;
        process.starts_skin = calls.iter().any(SkinCall::starts_skin);
        let mut detail = String::from("in the background for the next commands");
        let held = if calls.iter().any(SkinCall::waits_until_up) {
            let up = self.wait_until_up(&mut process)?;
            detail.push_str(&format!(", up in {:.1} s", up.as_secs_f64()));
            process.hold(ALIVE_AFTER_UP)
        } else {
            process.hold(ALIVE)
        };
        if let Some(status) = held {
            return Err(format!("{} while it should still run{}", describe(status), tail(&process.log)));
        }
        // `run` pushes this command's outcome next: its stop completes it.
        process.outcome = Some(self.outcomes.len());
        self.background.push(process);
        Ok(detail)
    }

    /// Starts the paper's virtual skin for a command that reads a skin
    /// when the doc has none running.
    fn start_test_skin(&mut self) -> Result<String, String> {
        let config = self.repo.join("examples/paper-virtual-skin.toml");
        let label = "(the test's skin: skin run examples/paper-virtual-skin.toml)";
        let mut process = self.spawn(&format!("skin run '{}'", config.display()), label)?;
        process.starts_skin = true;
        let up = self.wait_until_up(&mut process).map_err(|e| format!("the test's skin: {e}"))?;
        if let Some(status) = process.hold(ALIVE_AFTER_UP) {
            return Err(format!("the test's skin: {}{}", describe(status), tail(&process.log)));
        }
        self.background.push(process);
        Ok(format!(
            "against a skin the test started (`skin run examples/paper-virtual-skin.toml`, up in {:.1} s)",
            up.as_secs_f64()
        ))
    }

    /// Stops the background processes (only the skins, if `only_skins`),
    /// newest first; each stop completes its command's verdict.
    fn stop_background(&mut self, only_skins: bool) {
        while let Some(at) = self.background.iter().rposition(|p| p.starts_skin || !only_skins) {
            let mut process = self.background.remove(at);
            let mut result = self.interrupt(&mut process);
            if result.is_ok() && process.starts_skin && !self.background.iter().any(|p| p.starts_skin) {
                result = self.check_no_file_left().and(result);
            }
            match (process.outcome, result) {
                (Some(index), result) => {
                    let outcome = &mut self.outcomes[index];
                    outcome.verdict = match (&outcome.verdict, result) {
                        (Verdict::Ran(detail), Ok(stop)) => Verdict::Ran(format!("{detail}; then {stop}")),
                        (Verdict::Ran(_), Err(failure)) => Verdict::Failed(format!("when stopped: {failure}")),
                        (_, _) => continue,
                    };
                }
                (None, Ok(_)) => {}
                (None, Err(failure)) => self.outcomes.push(Outcome {
                    line: 0,
                    written: process.label.clone(),
                    verdict: Verdict::Failed(format!("when stopped: {failure}")),
                }),
            }
        }
    }

    /// Ctrl-C: SIGINT to the process group; it must exit 0 or of that
    /// signal, and take the rest of its group with it.
    fn interrupt(&self, process: &mut Process) -> Result<String, String> {
        let _ = kill_process_group(process.group(), Signal::INT);
        let started = Instant::now();
        let status = loop {
            if let Some(status) = process.child.try_wait().map_err(|e| e.to_string())? {
                break status;
            }
            if started.elapsed() > STOP_WITHIN {
                return Err(format!("still running {} s after SIGINT{}", STOP_WITHIN.as_secs(), tail(&process.log)));
            }
            std::thread::sleep(Duration::from_millis(20));
        };
        let took = started.elapsed();
        if !(status.success() || status.signal() == Some(Signal::INT.as_raw())) {
            return Err(format!("SIGINT, then {}{}", describe(status), tail(&process.log)));
        }
        let left = wait_until_group_gone(process.group(), Duration::from_secs(10));
        if !left.is_empty() {
            return Err(format!("SIGINT, then {}, but left running: {}", describe(status), left.join(", ")));
        }
        Ok(format!("SIGINT: {} in {:.1} s", describe(status), took.as_secs_f64()))
    }

    /// Waits until every skin with channels in the segment directory is up:
    /// each layer of its published geometry running, and no channel new or
    /// gone for a second.
    fn wait_until_up(&self, process: &mut Process) -> Result<Duration, String> {
        let started = Instant::now();
        let mut known: Vec<(String, String)> = Vec::new();
        let mut stable_since = Instant::now();
        loop {
            if let Some(status) = process.child.try_wait().map_err(|e| e.to_string())? {
                return Err(format!("{} before its skin was up{}", describe(status), tail(&process.log)));
            }
            let mut running: Vec<(String, String)> = skinware::list_channels(&self.shm)
                .unwrap_or_default()
                .into_iter()
                .filter(|c| c.state != WriterState::Gone)
                .map(|c| (c.skin, c.channel))
                .collect();
            running.sort();
            if running != known {
                known = running;
                stable_since = Instant::now();
            }
            let layers_up = !known.is_empty()
                && known.iter().all(|(skin, _)| match SkinGeometry::open_in(&self.shm, skin) {
                    Ok(geometry) => {
                        geometry.layers.iter().all(|l| known.iter().any(|(s, c)| s == skin && *c == l.name))
                    }
                    Err(_) => true,
                });
            if layers_up && stable_since.elapsed() >= Duration::from_secs(1) {
                return Ok(started.elapsed());
            }
            if started.elapsed() > UP_WITHIN {
                return Err(format!("its skin was not up within {} s{}", UP_WITHIN.as_secs(), tail(&process.log)));
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// After a skin's Ctrl-C: nothing of it in the segment directory (the
    /// README: "Ctrl-C stops everything and leaves no channel behind").
    fn check_no_file_left(&self) -> Result<(), String> {
        let left: Vec<String> = std::fs::read_dir(&self.shm)
            .map_err(|e| format!("{}: {e}", self.shm.display()))?
            .filter_map(Result::ok)
            .map(|entry| entry.file_name().to_string_lossy().into_owned())
            .collect();
        if left.is_empty() {
            return Ok(());
        }
        // Cleared, so that the doc's next commands start from nothing.
        for name in &left {
            let _ = std::fs::remove_file(self.shm.join(name));
        }
        Err(format!("left in the segment directory after Ctrl-C: {}", left.join(", ")))
    }
}

impl Drop for Session {
    fn drop(&mut self) {
        // Killed (each Process's drop) before their directory goes.
        self.background.clear();
        let _ = std::fs::remove_dir_all(&self.shm);
    }
}

/// A skipped command's `skin` invocations must still parse (`--help` after
/// them): a stale flag or verb fails even where the command cannot run.
fn skipped(command: &DocCommand, reason: &str) -> Verdict {
    for call in skin_calls(&command.shell).iter().filter(|c| !c.args.is_empty()) {
        let output = Command::new(env!("CARGO_BIN_EXE_skin")).args(&call.args).arg("--help").output();
        match output {
            Ok(output) if output.status.success() => {}
            Ok(output) => {
                return Verdict::Failed(format!(
                    "skipped ({reason}), but `skin {}` does not parse: {}",
                    call.args.join(" "),
                    String::from_utf8_lossy(&output.stderr).trim()
                ));
            }
            Err(e) => return Verdict::Failed(format!("cannot run skin --help: {e}")),
        }
    }
    Verdict::Skipped(reason.to_owned())
}

/// Whether this build of `skin` (the test's) has the cargo feature `name`;
/// `None` for a feature `skin` does not have.
fn built_with(name: &str) -> Option<bool> {
    match name {
        "cli" => Some(true),
        "bench" => Some(cfg!(feature = "bench")),
        "zenoh" => Some(cfg!(feature = "zenoh")),
        "dds" => Some(cfg!(feature = "dds")),
        "iceoryx2" => Some(cfg!(feature = "iceoryx2")),
        _ => None,
    }
}

/// How long [`Session::run_for_a_while`] let it run before SIGINT.
fn held_for(calls: &[SkinCall]) -> Duration {
    if calls.iter().any(SkinCall::waits_until_up) { ALIVE_AFTER_UP } else { ALIVE }
}

fn describe(status: ExitStatus) -> String {
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exit {code}"),
        (None, Some(signal)) if signal == Signal::INT.as_raw() => "ended by SIGINT".to_owned(),
        (None, Some(signal)) => format!("killed by signal {signal}"),
        (None, None) => status.to_string(),
    }
}

/// The processes of `group` that are still alive (not zombies) after up to
/// `within`, as `pid name`.
fn wait_until_group_gone(group: Pid, within: Duration) -> Vec<String> {
    let started = Instant::now();
    loop {
        let members = group_members(group);
        if members.is_empty() || started.elapsed() > within {
            return members;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn group_members(group: Pid) -> Vec<String> {
    let Ok(entries) = std::fs::read_dir("/proc") else { return Vec::new() };
    let mut members = Vec::new();
    for entry in entries.filter_map(Result::ok) {
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else { continue };
        // pid (comm) state ppid pgrp ...; comm may hold spaces and parentheses.
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else { continue };
        let fields: Vec<&str> = stat[close + 1..].split_whitespace().collect();
        if fields.len() > 2 && fields[0] != "Z" && fields[2] == group.as_raw_nonzero().to_string() {
            members.push(format!("{} {}", stat[..open].trim(), &stat[open + 1..close]));
        }
    }
    members
}

/// The last lines of a command's log, indented, to show with a failure.
fn tail(log: &Path) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    let shown = &lines[lines.len().saturating_sub(25)..];
    if shown.is_empty() {
        return " (no output)".to_owned();
    }
    format!("; its output ends:\n      | {}", shown.join("\n      | "))
}

fn line_count(log: &Path) -> usize {
    std::fs::read_to_string(log).map(|t| t.lines().count()).unwrap_or(0)
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap().filter_map(Result::ok) {
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}

#[test]
fn a_skipped_command_must_still_parse() {
    let skipped_command = |shell: &str| DocCommand {
        line: 1,
        written: shell.to_owned(),
        shell: shell.to_owned(),
        background: false,
        skip: Some("a second host".to_owned()),
        features: Vec::new(),
    };
    let parses = "sudo skin record run.mcap --services --seconds 60 --compression lz4";
    let verdict = skipped(&skipped_command(parses), "a second host");
    assert!(matches!(verdict, Verdict::Skipped(_)), "a command line that parses is skipped");
    for stale in ["skin record run.mcap --compresion lz4", "skin recrod run.mcap", "SKINWARE_SHM_DIR=d skin lss"] {
        let verdict = skipped(&skipped_command(stale), "a second host");
        assert!(matches!(&verdict, Verdict::Failed(why) if why.contains("does not parse")), "{stale} passed");
    }
}
