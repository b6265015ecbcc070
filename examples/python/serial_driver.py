#!/usr/bin/env python3
"""A skinware driver written in Python: a tactile sensor on a serial port.

The device (say, a microcontroller scanning a taxel array) sends one text
line per frame:

    F <counter> <v0> <v1> ... <vN-1>\\n

with decimal responses 0..65535. This driver publishes each line as a frame
of layer LAYER, which every skinware reader, service, recorder and the
viewer then sees like any other layer:

    python examples/python/serial_driver.py --port /dev/ttyACM0 --taxels 48

* A line that is not a frame (wrong count, a value out of range) is counted
  and reported, never published.
* No line for --timeout seconds, or a port that fails: the layer turns
  "faulted" (readers see it, and frames flagged Status.FAULT); it returns to
  "running" with the next good line. A port that disappears is reopened with
  backoff, so unplugging and replugging the device needs no restart.
* The device's counter tells frames it lost on the wire; they are reported.

Needs pyserial (pip install pyserial).
"""

from __future__ import annotations

import argparse
import signal
import sys
import time

import numpy as np
import serial

import skinware


def parse_line(line: bytes, taxels: int) -> tuple[int, np.ndarray] | str:
    """A frame `(counter, responses)`, or why the line is not one."""
    fields = line.split()
    if not fields or fields[0] != b"F":
        return "not a frame line (it does not start with F)"
    if len(fields) != taxels + 2:
        return f"{len(fields) - 2} values, expected {taxels}"
    try:
        numbers = [int(f) for f in fields[1:]]
    except ValueError:
        return "a value that is not a decimal integer"
    values = np.array(numbers[1:], dtype=np.int64)
    if values.min() < 0 or values.max() > 65535:
        return "a value outside 0..65535"
    return numbers[0], values.astype(np.uint16)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", required=True, help="serial device, e.g. /dev/ttyACM0")
    parser.add_argument("--baud", type=int, default=115200)
    parser.add_argument("--skin", default="default")
    parser.add_argument("--layer", default="serial")
    parser.add_argument("--taxels", type=int, required=True, help="responses per line")
    parser.add_argument("--module-size", type=int, default=12, help="taxels per module (for the topology)")
    parser.add_argument("--rate", type=float, default=100.0, help="the device's nominal frame rate, Hz")
    parser.add_argument("--timeout", type=float, default=0.5, help="seconds without a frame before the layer is faulted")
    args = parser.parse_args()

    size = max(1, min(args.module_size, args.taxels))
    modules = [(0, m, list(range(m * size, min(args.taxels, (m + 1) * size)))) for m in range((args.taxels + size - 1) // size)]
    topology = skinware.Topology(args.layer, modules, sensor_type="pressure", rate_hz=args.rate)

    with skinware.Writer(args.skin, args.layer, topology) as writer:
        stopping = False

        def stop(*_):
            nonlocal stopping
            stopping = True

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)
        print(f"publishing {args.port} as {writer.label} ({args.taxels} taxels)", flush=True)
        last = np.zeros(args.taxels, np.uint16)
        last_good = time.monotonic()
        backoff = 0.05
        bad_lines = lost = 0
        counter = None
        port = None
        while not stopping:
            if port is None:
                try:
                    port = serial.Serial(args.port, args.baud, timeout=0.05)
                    backoff = 0.05
                except (serial.SerialException, OSError) as error:
                    fault(writer, last, f"cannot open {args.port}: {error}")
                    time.sleep(backoff)
                    backoff = min(2.0, backoff * 2)
                    continue
            try:
                line = port.readline()
            except (serial.SerialException, OSError) as error:
                fault(writer, last, f"{args.port} failed: {error}; reopening")
                port.close()
                port = None
                continue
            now = time.monotonic()
            if not line:
                if now - last_good > args.timeout and writer.state != "faulted":
                    fault(writer, last, f"no frame for {args.timeout} s")
                continue
            frame = parse_line(line, args.taxels)
            if isinstance(frame, str):
                bad_lines += 1
                print(f"skipped a bad line ({frame}); {bad_lines} so far", file=sys.stderr, flush=True)
                continue
            seen, last = frame
            if counter is not None and seen != (counter + 1) % (1 << 32):
                lost += (seen - counter - 1) % (1 << 32)
                print(f"the device's counter jumped from {counter} to {seen}: {lost} frames lost so far", file=sys.stderr, flush=True)
            counter = seen
            if writer.state != "running":
                writer.state = "running"
                print("frames are back: running", file=sys.stderr, flush=True)
            writer.publish(last, acquired_ns=skinware.monotonic_ns())
            last_good = now
        if port is not None:
            port.close()
    return 0


def fault(writer: skinware.Writer, last: np.ndarray, why: str) -> None:
    """Marks the layer faulted, with a frame that says so."""
    if writer.state != "faulted":
        print(f"faulted: {why}", file=sys.stderr, flush=True)
        # The frame first: a reader that sees the state sees the frame too.
        writer.publish(last, status=skinware.Status.FAULT)
        writer.state = "faulted"


if __name__ == "__main__":
    sys.exit(main())
