//! The Python bindings' own tests (pytest, `crates/skinware-py/tests`), run
//! from `cargo test` against this build's `skin` binary, so that the README's
//! one test command covers them.
//!
//! They need a Python with the `skinware` package installed from this tree
//! and pytest: `$SKINWARE_PYTHON` (`.ci/run` makes a venv and runs
//! `pip install ./crates/skinware-py`), else `python3`. Without them the test
//! says so and is skipped, except under `CI=true`, where it fails. After
//! changing `crates/skinware-py`, reinstall it: the tests import the
//! installed package.

use std::path::Path;
use std::process::Command;

use crate::util::one_skin_at_a_time;

#[test]
#[cfg_attr(
    skip_no_python_bindings,
    ignore = "needs skinware, pytest and numpy in $SKINWARE_PYTHON or python3: pip install ./crates/skinware-py pytest"
)]
fn the_python_bindings_pass_their_pytest_suite() {
    let python = std::env::var("SKINWARE_PYTHON").unwrap_or_else(|_| "python3".into());
    let probe = Command::new(&python).args(["-c", "import skinware, pytest, numpy"]).output();
    let missing = match &probe {
        Ok(output) if output.status.success() => None,
        Ok(output) => Some(String::from_utf8_lossy(&output.stderr).trim().to_owned()),
        Err(e) => Some(format!("{python} cannot run: {e}")),
    };
    if let Some(why) = missing {
        let message = format!(
            "the Python tests need skinware, pytest and numpy in {python} ({why}); \
             install them with `pip install ./crates/skinware-py pytest`, or set SKINWARE_PYTHON to a venv that has them"
        );
        assert!(std::env::var_os("CI").is_none(), "{message}");
        eprintln!("SKIPPED: {message}");
        return;
    }
    let _alone = one_skin_at_a_time();
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let output = Command::new(&python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", "crates/skinware-py/tests"])
        .current_dir(&repo)
        .env("SKIN_BIN", env!("CARGO_BIN_EXE_skin"))
        .output()
        .expect("pytest runs");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    eprintln!("{stdout}");
    assert!(output.status.success(), "pytest failed:\n{stdout}\n{stderr}");
    assert!(
        !stdout.contains(" skipped") || std::env::var_os("CI").is_none(),
        "a Python test was skipped under CI:\n{stdout}"
    );
}
