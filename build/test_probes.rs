// What this machine lacks for some tests, found when the tests are built:
// each build script of a crate with such tests `include!`s this file and
// calls `probe` for what its tests need. A test that cannot run here is then
// built `#[ignore = "why"]`, so a passing `cargo test` lists it as ignored,
// with its reason, and counts it in its summary (instead of a test that
// passes having done nothing). `cargo test -- --ignored` still runs them, to
// see the failure.
//
// Under `CI=true`, what CI installs is never ignored: a missing oracle there
// fails its test. Only what no CI machine has (a CAN interface) is.

#[allow(dead_code)]
mod test_probes {
    use std::path::Path;
    use std::process::Command;

    /// Declares the cfg `name` and sets it if `available` is false (never,
    /// under `CI=true`, if `ci_installs_it`).
    pub fn probe(name: &str, available: bool, ci_installs_it: bool) {
        println!("cargo::rustc-check-cfg=cfg({name})");
        let in_ci = std::env::var("CI").is_ok_and(|v| v == "true");
        if !(available || (in_ci && ci_installs_it)) {
            println!("cargo::rustc-cfg={name}");
        }
    }

    /// Whether this build runs as root (the tests run as whoever builds them).
    pub fn is_root() -> bool {
        let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
        status
            .lines()
            .find_map(|line| line.strip_prefix("Uid:"))
            .and_then(|ids| ids.split_whitespace().nth(1))
            .is_some_and(|effective| effective == "0")
    }

    /// The Python the tests use: `$SKINWARE_PYTHON`, else `python3`.
    pub fn python() -> String {
        println!("cargo::rerun-if-env-changed=SKINWARE_PYTHON");
        std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into())
    }

    /// Whether the tests' Python imports every module of `modules`. A
    /// package installed later makes the build script run again (its
    /// site-packages changes).
    pub fn python_has(modules: &[&str]) -> bool {
        let python = python();
        let site = Command::new(&python)
            .args(["-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"])
            .output()
            .ok()
            .filter(|out| out.status.success())
            .map(|out| String::from_utf8_lossy(&out.stdout).trim().to_owned());
        if let Some(site) = site.filter(|site| Path::new(site).is_dir()) {
            println!("cargo::rerun-if-changed={site}");
        }
        imports(&python, modules)
    }

    /// Whether `python` runs and imports every module of `modules`.
    pub fn imports(python: &str, modules: &[&str]) -> bool {
        Command::new(python)
            .args(["-c", &format!("import {}", modules.join(", "))])
            .output()
            .is_ok_and(|out| out.status.success())
    }

    /// Whether every Python of `SKINWARE_ROS2_PYTHONS` (colon-separated, one
    /// per ROS distro) imports every module of `modules` (rclpy and the
    /// message packages a test uses).
    pub fn ros2_pythons_import(modules: &[&str]) -> bool {
        println!("cargo::rerun-if-env-changed=SKINWARE_ROS2_PYTHONS");
        let list = std::env::var("SKINWARE_ROS2_PYTHONS").unwrap_or_default();
        let pythons: Vec<&str> = list.split(':').filter(|p| !p.is_empty()).collect();
        !pythons.is_empty() && pythons.iter().all(|python| imports(python, modules))
    }

    /// Whether one of `names` is a program on PATH.
    pub fn program(names: &[&str]) -> bool {
        println!("cargo::rerun-if-env-changed=PATH");
        let path = std::env::var_os("PATH").unwrap_or_default();
        std::env::split_paths(&path).any(|dir| names.iter().any(|name| dir.join(name).is_file()))
    }
}
