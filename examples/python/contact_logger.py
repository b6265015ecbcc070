#!/usr/bin/env python3
"""Logs the contacts of a running skin as CSV: one row per contact and frame.

    python examples/python/contact_logger.py --skin default --seconds 10 > contacts.csv

Columns: time_s (since the first frame), seq, region, taxels, total, peak,
x, y, z (centroid, metres), map_x, map_y, area_m2.
"""

from __future__ import annotations

import argparse
import csv
import sys
import time

import skinware


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skin", default="default")
    parser.add_argument("--service", default="contact")
    parser.add_argument("--seconds", type=float, default=None, help="stop after this long (default: until Ctrl-C)")
    args = parser.parse_args()

    out = csv.writer(sys.stdout)
    out.writerow(["time_s", "seq", "region", "taxels", "total", "peak", "x", "y", "z", "map_x", "map_y", "area_m2"])
    started = time.monotonic()
    first_ns = None
    with skinware.ContactReader(args.skin, args.service) as contacts:
        try:
            for frame in contacts.frames():
                first_ns = first_ns or frame.acquired_ns
                t = (frame.acquired_ns - first_ns) / 1e9
                for region, record in zip(contacts.labels, frame.records):
                    for contact in record["contacts"][: record["count"]]:
                        x, y, z = contact["centroid"]
                        mx, my = contact["map"]
                        out.writerow(
                            [f"{t:.3f}", frame.seq, region, int(contact["taxels"]), f"{contact['total']:.1f}",
                             f"{contact['peak']:.1f}", f"{x:.4f}", f"{y:.4f}", f"{z:.4f}", f"{mx:.4f}", f"{my:.4f}",
                             f"{contact['area_m2']:.6f}"]
                        )
                sys.stdout.flush()
                if args.seconds is not None and time.monotonic() - started >= args.seconds:
                    break
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
