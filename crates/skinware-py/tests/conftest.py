"""Fixtures of the Python tests: a private channel directory, unique skin
names, Python drivers in their own processes, and a `skin run` of the
virtual skin with both services.

Run them with `pytest crates/skinware-py/tests` after
`pip install ./crates/skinware-py`; `cargo test --workspace` runs them too
(`crates/skin/tests/integration/python.rs`) when `$SKINWARE_PYTHON` has the
package.
"""

from __future__ import annotations

import itertools
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

# Every channel of this run lives in a directory of its own, so that nothing
# here meets the channels of another test run or a skin running on the machine.
SHM_DIR = tempfile.mkdtemp(prefix="skinware-pytest-", dir="/dev/shm" if os.path.isdir("/dev/shm") else None)
os.environ["SKINWARE_SHM_DIR"] = SHM_DIR

import skinware  # noqa: E402  (after the directory is set)

REPO = Path(__file__).resolve().parents[3]
_names = itertools.count()


def pytest_sessionfinish(session, exitstatus):
    shutil.rmtree(SHM_DIR, ignore_errors=True)


@pytest.fixture
def skin() -> str:
    """A skin name no other test uses."""
    return f"py{os.getpid()}n{next(_names)}"


def wait_for(predicate, timeout: float = 10.0, what: str = "condition", interval: float = 0.01):
    """Polls `predicate` until it returns something true; fails after `timeout`."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(interval)


class PythonProcess:
    """A Python program in its own process (a driver, a reader), with the
    test's channel directory."""

    def __init__(self, code: str, *args: str):
        self.process = subprocess.Popen(
            [sys.executable, "-c", textwrap.dedent(code), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=10)

    def stop(self, timeout: float = 10.0) -> tuple[int, str, str]:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        out, err = self.process.communicate(timeout=timeout)
        return self.process.returncode, out, err

    def __enter__(self) -> "PythonProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.kill()


#: A Python driver: `skin layer sensors hz`; every response of frame k is
#: k % 65536 (so a torn frame would show), until SIGTERM.
DRIVER = """
import signal, sys
import numpy as np
import skinware
skin, layer, sensors, hz = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
topology = skinware.Topology.uniform(layer, 1, max(1, sensors // 12), 12 if sensors >= 12 else sensors)
with skinware.Writer(skin, layer, topology, rate_hz=hz) as writer:
    signal.signal(signal.SIGTERM, lambda *_: writer.close())
    print("ready", flush=True)
    frame = np.empty(len(writer), np.uint16)
    for k, _ in enumerate(writer.ticks(), start=1):
        frame.fill(k % 65536)
        writer.publish(frame)
"""


def drive_in_thread(writer: "skinware.Writer"):
    """Publishes frame k, holding k % 65536 in every response, at each of the
    writer's periods, from a thread of this process. Returns the function
    that stops the thread and closes the writer."""
    import threading

    import numpy as np

    stop = threading.Event()

    def drive():
        frame = np.empty(len(writer), np.uint16)
        try:
            for k, _ in enumerate(writer.ticks(), start=1):
                if stop.is_set():
                    return
                frame.fill(k % 65536)
                writer.publish(frame)
        except skinware.WriterClosed:
            pass

    thread = threading.Thread(target=drive, daemon=True)
    thread.start()

    def finish():
        stop.set()
        writer.close()
        thread.join(5)

    return finish


def start_driver(skin: str, layer: str = "pressure", sensors: int = 120, hz: float = 200.0) -> PythonProcess:
    driver = PythonProcess(DRIVER, skin, layer, str(sensors), str(hz))
    line = driver.process.stdout.readline()
    if line.strip() != "ready":
        driver.kill()
        raise AssertionError(f"the driver did not start: {line!r} {driver.process.stderr.read()}")
    return driver


def skin_binary() -> Path | None:
    """The `skin` command: $SKIN_BIN, else a build in target/."""
    if os.environ.get("SKIN_BIN"):
        return Path(os.environ["SKIN_BIN"])
    for profile in ("release", "debug"):
        candidate = REPO / "target" / profile / "skin"
        if candidate.exists():
            return candidate
    found = shutil.which("skin")
    return Path(found) if found else None


VIRTUAL_SKIN = """
skin = "{skin}"

[[driver]]
name = "body"
kind = "virtual"
sensors = 3000
layers = 2
rate_hz = 50
random_contacts = false

[[driver.contact]]
part = "torso"
at_s = 0.5
angle_deg = 90
height = 0.3
slide_s = 600

[[driver.contact]]
part = "left_forearm"
at_s = 0.5
angle_deg = 0
height = 0.05
velocity = [0.03, 0.0]
slide_s = 600

[[region]]
name = "torso"
links = ["torso"]

[[region]]
name = "left_forearm"
links = ["left_forearm"]

[[service]]
name = "contact"
kind = "contact"
rate_hz = 50

[[service]]
name = "motion"
kind = "motion"
input = "contact"
rate_hz = 50
"""


@pytest.fixture(scope="module")
def virtual_skin(tmp_path_factory):
    """`skin run` of a 3,000-sensor virtual skin (2 layers at 50 Hz, two
    regions, a scripted contact on each) with the contact and motion services."""
    binary = skin_binary()
    if binary is None:
        message = "no `skin` binary: build it (cargo build -p skin) or set SKIN_BIN"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    name = f"pyvirt{os.getpid()}n{next(_names)}"
    directory = tmp_path_factory.mktemp("virtual-skin")
    config = directory / "skin.toml"
    config.write_text(VIRTUAL_SKIN.format(skin=name))
    log = open(directory / "skin-run.log", "w+")
    process = subprocess.Popen([str(binary), "run", str(config)], stdout=log, stderr=subprocess.STDOUT)
    try:
        def ready():
            states = {c.name: c.state for c in skinware.channels(name)}
            wanted = ("body-0", "body-1", "contact", "contact-taxels", "motion")
            return all(states.get(c) == "running" for c in wanted)

        try:
            wait_for(ready, timeout=60, what=f"skin {name} to run its layers and services")
        except AssertionError:
            log.seek(0)
            raise AssertionError(f"skin run did not come up; its log:\n{log.read()}")
        yield name
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
        log.close()
