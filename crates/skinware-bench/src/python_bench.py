"""The Python half of `skin bench python` (run by it with $SKINWARE_PYTHON):
times the bindings' reads of a layer the bench writes, and prints JSON."""

import json
import platform
import sys
import time

import numpy as np

import skinware

skin, layer, reads = sys.argv[1], sys.argv[2], int(sys.argv[3])
reader = skinware.Reader(skin, layer)
reader.wait_newer(5.0)
clock = time.perf_counter_ns

latest = []
for _ in range(reads):
    started = clock()
    reader.latest()
    latest.append(clock() - started)

out = np.empty(len(reader), np.uint16)
read_into = []
for _ in range(reads):
    started = clock()
    reader.read_into(out)
    read_into.append(clock() - started)

# As soon as available, from the frame's publication to the frame in Python,
# in blocks that alternate with the bench's Rust reader: it writes a block
# size on stdin, this side reads that many frames and answers, and so on
# until an empty line. Never both at once, so neither waits for the other's
# CPU, and both see the same machine.
print("ready", flush=True)
newer = []
skipped = 0
for line in sys.stdin:
    block = int(line.strip() or 0)
    if block == 0:
        break
    reader.wait_newer(5.0)
    for _ in range(block):
        frame = reader.wait_newer(5.0)
        newer.append(skinware.monotonic_ns() - frame.published_ns)
        skipped += frame.skipped
    print("done", flush=True)

print(
    json.dumps(
        {
            "latest_ns": latest,
            "read_into_ns": read_into,
            "newer_latency_ns": newer,
            "newer_skipped": skipped,
            "python": platform.python_version(),
            "numpy": np.__version__,
            "skinware": skinware.__version__,
        }
    )
)
