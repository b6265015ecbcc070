"""The example Python driver (examples/python/serial_driver.py) against a
device emulated on a pseudo-terminal: frames end to end, bad lines, the
device going silent (faulted) and coming back (running)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
import tty

import numpy as np
import pytest

import skinware
from conftest import REPO, wait_for

pytest.importorskip("serial", reason="the serial driver example needs pyserial")

DRIVER = REPO / "examples" / "python" / "serial_driver.py"
TAXELS = 24


class Device:
    """The device side of a PTY: writes frame lines while `sending` is set."""

    def __init__(self):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.sending = threading.Event()
        self.counter = 0
        self.stopped = False
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def values(self, k: int) -> list[int]:
        return [(k * 7 + i * 100) % 65536 for i in range(TAXELS)]

    def send(self, line: bytes) -> None:
        os.write(self.master, line)

    def run(self) -> None:
        while not self.stopped:
            if self.sending.is_set():
                self.counter += 1
                values = " ".join(str(v) for v in self.values(self.counter))
                self.send(f"F {self.counter} {values}\n".encode())
            time.sleep(0.01)

    def close(self) -> None:
        self.stopped = True
        self.thread.join(2)
        os.close(self.master)
        os.close(self.slave)


def test_the_serial_driver_publishes_faults_and_recovers(skin):
    device = Device()
    driver = subprocess.Popen(
        [sys.executable, str(DRIVER), "--port", device.port, "--skin", skin, "--layer", "serial",
         "--taxels", str(TAXELS), "--rate", "100", "--timeout", "0.3"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert "publishing" in driver.stdout.readline()
        device.sending.set()
        reader = skinware.Reader(skin, "serial")
        assert len(reader.topology) == TAXELS and len(reader.topology.modules) == 2
        assert reader.topology.rate_hz == 100

        def a_device_frame():
            frame = reader.wait_newer(2.0)
            values = frame.responses.tolist()
            return frame if any(values == device.values(k) for k in range(device.counter - 5, device.counter + 1)) else None

        frame = wait_for(a_device_frame, what="the device's values in a frame")
        assert frame.status == skinware.Status.OK and reader.state == "running"

        # A broken line is skipped; frames go on.
        device.send(b"F 1 2 3\n")
        seq = reader.wait_newer(2.0).seq
        assert reader.wait_newer(2.0).seq > seq

        # The device goes silent: the layer turns faulted, with a FAULT frame.
        device.sending.clear()
        wait_for(lambda: reader.state == "faulted", timeout=5, what="the layer to turn faulted")
        wait_for(lambda: reader.latest().faulted, timeout=5, what="a FAULT frame")
        # It comes back: running again, good frames.
        device.sending.set()
        wait_for(lambda: reader.state == "running", timeout=5, what="the layer to run again")
        assert not reader.wait_newer(2.0).faulted
        reader.close()
    finally:
        device.sending.clear()
        driver.send_signal(signal.SIGTERM)
        out, err = driver.communicate(timeout=10)
        device.close()
    assert driver.returncode == 0, err
    assert "skipped a bad line (2 values, expected 24)" in err
    assert "faulted: no frame for 0.3 s" in err
    assert "frames are back" in err
    with pytest.raises(skinware.ChannelMissing):
        skinware.Reader(skin, "serial")
