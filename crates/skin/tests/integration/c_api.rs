//! The C API and its C++ wrapper against `skin run`'s virtual skin: C and
//! C++ test programs (crates/skinware-c/tests/) read what a Rust reader reads,
//! frame by frame (by sequence number); every read mode, the topology, the
//! geometry and the services' records work from C; bad arguments give the
//! codes and messages the header promises; C writers (periodic and sporadic)
//! are read back by Rust; a C reader SIGKILLed in the middle of its reads
//! hurts no one; and the programs run clean under AddressSanitizer and
//! Valgrind (0 errors, 0 leaks). The programs link the cdylib cargo built
//! beside this test (libskinware_c.so); the installed library (cargo-c,
//! pkg-config, CMake) is tested by `.ci/run`, which builds the examples out
//! of tree against it.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use skinware::{Reader, ReaderOptions, WriterState};

use crate::util::{one_skin_at_a_time, show_logs_if_failing};

const CONFIG: &str = r#"
skin = "capi"

[[driver]]
name = "body"
kind = "virtual"
sensors = 4000
layers = 2
rate_hz = 200

[[region]]
name = "torso"
links = ["torso"]

[[region]]
name = "left_forearm"
links = ["left_forearm"]

[[service]]
name = "contact"
kind = "contact"
rate_hz = 100

[[service]]
name = "motion"
kind = "motion"
input = "contact"
rate_hz = 100
"#;

/// The programs, built once: plain, and with AddressSanitizer.
struct Programs {
    api: PathBuf,
    wrapper: PathBuf,
    api_asan: PathBuf,
    wrapper_asan: PathBuf,
}

/// The directory holding the cdylib cargo built for this test run: in
/// `deps/` (skinware-c built as skin's dev-dependency) or beside it (built as
/// a workspace member); the newer, if both are there (a build of one kind
/// does not refresh the other's copy).
fn library_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test's path");
    let deps = exe.parent().expect("target/<profile>/deps").to_owned();
    let modified = |dir: &Path| std::fs::metadata(dir.join("libskinware_c.so")).and_then(|m| m.modified()).ok();
    [deps.clone(), deps.parent().unwrap().to_owned()]
        .into_iter()
        .filter_map(|dir| modified(&dir).map(|when| (when, dir)))
        .max_by_key(|(when, _)| *when)
        .map(|(_, dir)| dir)
        .unwrap_or_else(|| {
            panic!(
                "libskinware_c.so is neither in {} nor beside it: build skinware-c (a dev-dependency of skin)",
                deps.display()
            )
        })
}

fn compile(compiler: &str, source: &Path, out: &Path, extra: &[&str]) -> PathBuf {
    let include = Path::new(env!("CARGO_MANIFEST_DIR")).join("../skinware-c/include");
    let lib = library_dir();
    let standard = if compiler == "c++" { "-std=c++17" } else { "-std=c11" };
    let output = Command::new(compiler)
        .args([standard, "-O1", "-g", "-Wall", "-Wextra", "-Werror"])
        .args(extra)
        .arg("-I")
        .arg(&include)
        .arg(source)
        .arg("-o")
        .arg(out)
        .arg("-L")
        .arg(&lib)
        .arg(format!("-Wl,-rpath,{}", lib.display()))
        .args(["-lskinware_c", "-lpthread"])
        .output()
        .unwrap_or_else(|e| panic!("{compiler} could not run ({e}); install gcc and g++ (build-essential)"));
    assert!(output.status.success(), "{compiler} {}:\n{}", source.display(), String::from_utf8_lossy(&output.stderr));
    out.to_owned()
}

impl Programs {
    fn build(dir: &Path) -> Programs {
        let sources = Path::new(env!("CARGO_MANIFEST_DIR")).join("../skinware-c/tests");
        let (c, cpp) = (sources.join("c/api_check.c"), sources.join("cpp/wrapper_check.cpp"));
        let asan = ["-fsanitize=address", "-fno-omit-frame-pointer"];
        Programs {
            api: compile("cc", &c, &dir.join("api_check"), &[]),
            wrapper: compile("c++", &cpp, &dir.join("wrapper_check"), &[]),
            api_asan: compile("cc", &c, &dir.join("api_check_asan"), &asan),
            wrapper_asan: compile("c++", &cpp, &dir.join("wrapper_check_asan"), &asan),
        }
    }
}

struct Skin {
    dir: PathBuf,
    supervisor: Child,
}

impl Drop for Skin {
    fn drop(&mut self) {
        let _ = self.supervisor.kill();
        let _ = self.supervisor.wait();
        show_logs_if_failing(&self.dir);
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl Skin {
    fn command(&self, program: &Path) -> Command {
        let mut command = Command::new(program);
        command.env("SKINWARE_SHM_DIR", &self.dir).env("SKINWARE_CACHE_DIR", self.dir.join("cache"));
        // cargo's LD_LIBRARY_PATH (target/<profile> first) would win over the
        // programs' rpath and could load another build's copy of the library.
        command.env_remove("LD_LIBRARY_PATH");
        command
    }

    fn run(&self, program: &Path, args: &[&str]) -> Output {
        let output = self.command(program).args(args).output().expect("run a test program");
        assert!(
            output.status.success(),
            "{} {args:?} failed ({}):\n{}\n{}",
            program.display(),
            output.status,
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        );
        output
    }

    fn reader(&self, channel: &str) -> Reader {
        let options = ReaderOptions { dir: Some(self.dir.clone()), ..ReaderOptions::default() };
        Reader::open_with("capi", channel, &options).unwrap()
    }
}

fn start_skin() -> Skin {
    let dir = PathBuf::from("/dev/shm").join(format!("skin-capi-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("config.toml"), CONFIG).unwrap();
    let supervisor = Command::new(env!("CARGO_BIN_EXE_skin"))
        .arg("run")
        .arg(dir.join("config.toml"))
        .env("SKINWARE_SHM_DIR", &dir)
        .env("SKINWARE_CACHE_DIR", dir.join("cache"))
        .env("RUST_LOG", "warn")
        .stdout(crate::util::log_file(&dir, "skin-run"))
        .stderr(crate::util::log_file(&dir, "skin-run"))
        .spawn()
        .expect("start skin run");
    let skin = Skin { dir, supervisor };
    let options = ReaderOptions { dir: Some(skin.dir.clone()), ..ReaderOptions::default() };
    let started = Instant::now();
    loop {
        let ready = ["body-0", "body-1", "contact", "motion"]
            .iter()
            .all(|channel| Reader::open_with("capi", channel, &options).is_ok_and(|r| r.published_seq() > 5));
        if ready {
            return skin;
        }
        assert!(started.elapsed() < Duration::from_secs(60), "the virtual skin and its services did not start");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// FNV-1a over the responses' little-endian bytes, as the C programs compute it.
fn checksum(values: &[u16]) -> u64 {
    values
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
}

/// The value `api_check write` publishes for sensor `i` of frame `seq`.
fn pattern(seq: u64, i: usize) -> u16 {
    ((seq * 31 + i as u64 * 7) & 0xFFFF) as u16
}

/// Runs `program args` (which prints "seq SEQ CHECKSUM" lines) while a Rust
/// reader reads the same layer; every sequence both saw has the same bytes.
fn same_frames_as_rust(skin: &Skin, program: &Path, args: &[&str], layer: &str) -> usize {
    let mut child = skin.command(program).args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let mut rust = skin.reader(layer);
    let mut seen = BTreeMap::new();
    while child.try_wait().unwrap().is_none() {
        if let Ok(frame) = rust.wait_newer(Duration::from_millis(100)) {
            seen.insert(frame.seq(), checksum(frame.responses()));
        }
    }
    let output = child.wait_with_output().unwrap();
    assert!(output.status.success(), "{args:?}: {}", String::from_utf8_lossy(&output.stderr));
    let mut compared = 0;
    for line in String::from_utf8_lossy(&output.stdout).lines() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let (seq, sum): (u64, u64) = (fields[1].parse().unwrap(), fields[2].parse().unwrap());
        if let Some(&expected) = seen.get(&seq) {
            assert_eq!(sum, expected, "frame {seq} of {layer}: C/C++ and Rust read different bytes");
            compared += 1;
        }
    }
    compared
}

#[test]
fn c_and_cpp_read_the_virtual_skin_as_rust_does() {
    let _alone = one_skin_at_a_time();
    let skin = start_skin();
    let programs = Programs::build(&skin.dir);

    let c = same_frames_as_rust(&skin, &programs.api, &["frames", "capi", "body-0", "200"], "body-0");
    assert!(c >= 150, "only {c} of 200 C frames were also read by Rust");
    let cpp = same_frames_as_rust(&skin, &programs.wrapper, &["periodic", "capi", "body-1", "100", "100"], "body-1");
    assert!(cpp >= 75, "only {cpp} of 100 C++ frames were also read by Rust");
    println!("C and C++ frames equal Rust's by sequence: {c} of 200 C frames, {cpp} of 100 C++ frames compared");

    let modes = skin.run(&programs.api, &["modes", "capi", "body-0"]);
    let text = String::from_utf8_lossy(&modes.stdout);
    for part in ["modes ok", "topology ok", "geometry ok", "services ok", "listing ok"] {
        assert!(text.contains(part), "{part} missing from:\n{text}");
    }
    println!("{text}");
    assert!(
        String::from_utf8_lossy(&skin.run(&programs.api, &["errors", "capi", "body-0"]).stdout).contains("errors ok")
    );
    let wrapped = skin.run(&programs.wrapper, &["exceptions", "capi", "body-0"]);
    assert!(String::from_utf8_lossy(&wrapped.stdout).contains("wrapper ok"));

    c_writers_are_read_by_rust(&skin, &programs.api);
    a_killed_c_reader_hurts_no_one(&skin, &programs.api);
    sanitizers_find_nothing(&skin, &programs);
}

/// A periodic C writer's every frame, and a sporadic C writer's answers.
fn c_writers_are_read_by_rust(skin: &Skin, api: &Path) {
    let mut writer =
        skin.command(api).args(["write", "capi", "c_layer", "300", "200"]).stdout(Stdio::piped()).spawn().unwrap();
    let mut lines = BufReader::new(writer.stdout.take().unwrap()).lines();
    assert_eq!(lines.next().unwrap().unwrap(), "writing");
    let mut reader = skin.reader("c_layer");
    let mut last = 0;
    while last < 300 {
        let frame = reader.wait_newer(Duration::from_secs(2)).expect("the C writer's frames");
        let seq = frame.seq();
        assert!(
            frame.responses().iter().enumerate().all(|(i, &v)| v == pattern(seq, i)),
            "frame {seq} is not pattern({seq})"
        );
        last = seq;
    }
    assert!(writer.wait().unwrap().success());
    assert_eq!(reader.writer_state(), WriterState::Gone, "a closed C writer is gone");

    let mut server =
        skin.command(api).args(["serve", "capi", "c_sporadic", "5"]).stdout(Stdio::piped()).spawn().unwrap();
    let mut lines = BufReader::new(server.stdout.take().unwrap()).lines();
    assert_eq!(lines.next().unwrap().unwrap(), "serving");
    let mut reader = skin.reader("c_sporadic");
    for answer in 1..=5u64 {
        let frame = reader.request(Duration::from_secs(2)).expect("the sporadic C writer answers");
        assert_eq!(
            frame.responses(),
            &[pattern(answer, 0), pattern(answer, 1), pattern(answer, 2), pattern(answer, 3)]
        );
    }
    assert!(server.wait().unwrap().success());
    println!("C writers: 300 periodic frames and 5 requests read back by Rust");
}

/// SIGKILL a C reader in the middle of its reads (it copies frames back to
/// back): the writer keeps its rate and other readers keep reading.
fn a_killed_c_reader_hurts_no_one(skin: &Skin, api: &Path) {
    let mut watcher = skin.reader("body-0");
    for round in 0..5 {
        let mut spinner = skin.command(api).args(["spin", "capi", "body-0"]).stdout(Stdio::piped()).spawn().unwrap();
        let mut lines = BufReader::new(spinner.stdout.take().unwrap()).lines();
        assert_eq!(lines.next().unwrap().unwrap(), "spinning");
        std::thread::sleep(Duration::from_millis(100 + 37 * round));
        let before = watcher.writer_stats();
        spinner.kill().unwrap();
        spinner.wait().unwrap();
        std::thread::sleep(Duration::from_millis(250));
        let after = watcher.writer_stats();
        let frames = after.frames - before.frames;
        assert!(frames >= 35, "the writer published {frames} frames in 250 ms after the kill (200 Hz)");
        assert!(watcher.wait_newer(Duration::from_secs(1)).is_ok(), "another reader still reads");
        assert_eq!(watcher.writer_state(), WriterState::Running);
    }
    let fresh = skin.reader("body-0").latest().map(|f| f.seq()).unwrap();
    assert!(fresh > 0);
    println!("5 C readers SIGKILLed mid-read: the writer kept publishing, the other reader kept reading");
}

/// AddressSanitizer (with LeakSanitizer) and Valgrind: no error, no leak.
fn sanitizers_find_nothing(skin: &Skin, programs: &Programs) {
    for (program, args) in [
        (&programs.api_asan, vec!["modes", "capi", "body-0"]),
        (&programs.api_asan, vec!["errors", "capi", "body-0"]),
        (&programs.wrapper_asan, vec!["exceptions", "capi", "body-1"]),
    ] {
        let output =
            skin.command(program).args(&args).env("ASAN_OPTIONS", "detect_leaks=1:halt_on_error=1").output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success() && !stderr.contains("Sanitizer"), "ASan {args:?}:\n{stderr}");
        println!("ASan {} {args:?}: 0 errors, 0 leaks", program.file_name().unwrap().to_string_lossy());
    }
    if Command::new("valgrind").arg("--version").output().is_err() {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "valgrind is missing under CI=true (.ci/run installs it)"
        );
        println!("SKIPPED: Valgrind is not installed (apt-get install valgrind)");
        return;
    }
    for (program, args) in [
        (&programs.api, vec!["modes", "capi", "body-0"]),
        (&programs.api, vec!["errors", "capi", "body-0"]),
        (&programs.wrapper, vec!["exceptions", "capi", "body-1"]),
    ] {
        let output = skin
            .command(Path::new("valgrind"))
            .args(["--leak-check=full", "--errors-for-leak-kinds=definite,indirect", "--error-exitcode=99"])
            .arg(program)
            .args(&args)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        let summary: Vec<&str> = stderr
            .lines()
            .filter(|l| {
                l.contains("ERROR SUMMARY")
                    || l.contains("definitely lost")
                    || l.contains("indirectly lost")
                    || l.contains("All heap blocks")
            })
            .collect();
        assert!(output.status.success() && stderr.contains("ERROR SUMMARY: 0 errors"), "Valgrind {args:?}:\n{stderr}");
        println!("Valgrind {} {args:?}: {}", program.file_name().unwrap().to_string_lossy(), summary.join(" | "));
    }
}
