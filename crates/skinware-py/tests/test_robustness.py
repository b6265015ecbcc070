"""What a Python reader can and cannot do to others: killed mid-read it harms
nobody; readers shared by threads release the GIL while they wait; Ctrl-C
interrupts a wait; reads do not leak."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

import numpy as np
import pytest

import skinware
from conftest import PythonProcess, drive_in_thread, start_driver, wait_for

#: A reader process: `skin layer mode`; reads as fast as it can, forever.
BUSY_READER = """
import sys, numpy as np, skinware
skin, layer, mode = sys.argv[1:4]
reader = skinware.Reader(skin, layer)
reader.wait_newer(5.0)
print("reading", flush=True)
out = np.empty(len(reader), np.uint16)
while True:
    if mode == "latest":
        frame = reader.latest()
    elif mode == "newer":
        frame = reader.wait_newer(5.0)
    elif mode == "into":
        frame = reader.read_into(out)
    else:
        for frame in reader.periodic(1000):
            pass
"""


def test_sigkilled_python_readers_harm_nobody(skin):
    driver = start_driver(skin, "pressure", sensors=30848 // 4, hz=250)
    try:
        observer = skinware.Reader(skin, "pressure")
        observer.wait_newer(2.0)
        for round in range(4):
            victims = [PythonProcess(BUSY_READER, skin, "pressure", mode) for mode in ("latest", "newer", "into", "periodic")]
            for victim in victims:
                assert victim.process.stdout.readline().strip() == "reading", victim.process.stderr.read()
            time.sleep(0.05 * round)
            for victim in victims:
                victim.kill()
                assert victim.process.returncode == -signal.SIGKILL
            # The writer goes on at its rate, and every frame is whole.
            published = observer.published_seq
            seqs = []
            deadline = time.monotonic() + 0.5
            while time.monotonic() < deadline:
                frame = observer.wait_newer(1.0)
                assert (frame.responses == frame.seq % 65536).all(), "a torn frame"
                seqs.append(frame.seq)
            # 125 frames at 250 Hz; a loaded CI machine may delay some, not stop them.
            assert observer.published_seq - published > 10, "the writer stopped after readers were killed"
            assert seqs == sorted(set(seqs))
        assert observer.state == "running"
        # A newcomer attaches and reads as if nothing happened.
        assert skinware.Reader(skin, "pressure").wait_newer(1.0).seq > 0
        observer.close()
    finally:
        code, _, err = driver.stop()
        assert code == 0, f"the driver failed: {err}"


def test_a_wait_releases_the_gil(skin):
    topology = skinware.Topology.uniform("silent", 1, 1, 4)
    with skinware.Writer(skin, "silent", topology):
        reader = skinware.Reader(skin, "silent")
        outcome = []

        def wait():
            try:
                reader.wait_newer(1.0)
            except skinware.Timeout:
                outcome.append("timeout")

        thread = threading.Thread(target=wait)
        thread.start()
        # While the other thread waits, this one runs Python code.
        counted = 0
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            counted += 1
        thread.join()
        assert outcome == ["timeout"]
        assert counted > 10_000, f"only {counted} iterations ran while another thread waited"
        reader.close()


def test_readers_shared_by_threads(skin):
    topology = skinware.Topology.uniform("shared", 4, 8, 12, rate_hz=500)
    writer = skinware.Writer(skin, "shared", topology)
    finish = drive_in_thread(writer)
    shared = skinware.Reader(skin, "shared")
    results: dict[str, list[int]] = {}
    errors: list[BaseException] = []

    def read(name: str, reader: skinware.Reader, mode: str):
        seqs = []
        out = np.empty(len(reader), np.uint16)
        try:
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                # Generous timeouts: 17 threads share 2 cores and one GIL.
                if mode == "newer":
                    frame = reader.wait_newer(10.0)
                elif mode == "latest":
                    frame = reader.latest()
                elif mode == "into":
                    frame = reader.read_into(out, mode="newer", timeout=10.0)
                else:
                    frame = next(reader.periodic(200))
                assert (frame.responses == frame.seq % 65536).all(), "a torn frame"
                seqs.append(frame.seq)
        except BaseException as error:  # reported below
            errors.append(error)
        results[name] = seqs

    wait_for(lambda: shared.published_seq > 0, what="the first frame")
    threads = []
    for i, mode in enumerate(("newer", "latest", "into", "periodic") * 2):
        own = skinware.Reader(skin, "shared")
        threads.append(threading.Thread(target=read, args=(f"own-{mode}-{i}", own, mode)))
        threads.append(threading.Thread(target=read, args=(f"shared-{mode}-{i}", shared, mode)))
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)
    finish()
    assert not errors, errors
    assert len(results) == 16
    for name, seqs in results.items():
        assert seqs, f"{name} read nothing"
        if name.startswith("own"):
            # A reader of its own sees its frames in order.
            assert seqs == sorted(seqs), name


def test_closing_a_reader_wakes_a_thread_blocked_in_it(skin):
    topology = skinware.Topology.uniform("still", 1, 1, 4)
    with skinware.Writer(skin, "still", topology):
        reader = skinware.Reader(skin, "still")
        raised = []

        def wait_forever():
            try:
                reader.wait_newer(timeout=None)
            except skinware.ReaderClosed as error:
                raised.append(error)

        thread = threading.Thread(target=wait_forever)
        thread.start()
        time.sleep(0.2)
        started = time.monotonic()
        reader.close()
        thread.join(5)
        assert not thread.is_alive() and len(raised) == 1
        assert time.monotonic() - started < 2.0


def test_ctrl_c_interrupts_a_wait_without_timeout(skin):
    topology = skinware.Topology.uniform("idle", 1, 1, 4)
    with skinware.Writer(skin, "idle", topology):
        code = """
import sys, skinware
reader = skinware.Reader(sys.argv[1], "idle")
print("waiting", flush=True)
reader.wait_newer(timeout=None)
"""
        with PythonProcess(code, skin) as waiter:
            assert waiter.process.stdout.readline().strip() == "waiting"
            time.sleep(0.2)
            started = time.monotonic()
            waiter.process.send_signal(signal.SIGINT)
            # A bound for a wait that never ends, not a timing: a loaded
            # machine may take seconds to run the interrupted process.
            waiter.process.wait(timeout=30)
            print(f"interrupted in {time.monotonic() - started:.3f} s")
            assert "KeyboardInterrupt" in waiter.process.stderr.read()


def rss_bytes() -> int:
    with open(f"/proc/{os.getpid()}/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_reads_do_not_leak(skin):
    topology = skinware.Topology.uniform("leak", 1, 10, 100)
    with skinware.Writer(skin, "leak", topology) as writer:
        writer.publish(np.arange(1000, dtype=np.uint16))
        reader = skinware.Reader(skin, "leak")
        out = np.empty(1000, np.uint16)
        for _ in range(2000):
            reader.latest()
        before = rss_bytes()
        refs = sys.getrefcount(out)
        for _ in range(30_000):
            frame = reader.latest()
            reader.read_into(out)
        # 30,000 frames of 2,000 bytes leaked would be 60 MB.
        grown = rss_bytes() - before
        assert grown < 8 << 20, f"RSS grew by {grown} bytes over 30,000 reads"
        assert sys.getrefcount(out) == refs
        assert frame.responses[999] == 999
        reader.close()
