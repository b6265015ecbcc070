#!/usr/bin/env python3
"""A live heatmap of a running skin on its 2-D map, with matplotlib
(`pip install matplotlib`, beside the `skinware` package).

    python examples/python/heatmap.py --skin default
    python examples/python/heatmap.py --skin default --frames 20 --save skin.png   # headless

Every layer is read periodically (the newest frame at --hz, never a backlog)
and drawn at its sensors' places on the skin's flattened map, one colour per
response above the layer's first frame (a simple baseline).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import skinware


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skin", default="default")
    parser.add_argument("--hz", type=float, default=20.0, help="redraws per second")
    parser.add_argument("--frames", type=int, default=None, help="stop after this many redraws")
    parser.add_argument("--save", default=None, help="write the last image to this PNG (no window)")
    args = parser.parse_args()

    import matplotlib

    if args.save:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    geometry = skinware.Geometry.open(args.skin)
    readers = {name: skinware.Reader(args.skin, name) for name in geometry.layers}
    ranges = {name: geometry.layer_range(name) for name in geometry.layers}
    values = np.zeros(len(geometry), np.float32)
    baseline: dict[str, np.ndarray] = {}
    ticks = iter(readers[geometry.layers[0]].periodic(args.hz))

    figure, axes = plt.subplots(figsize=(9, 6))
    dots = axes.scatter(geometry.map[:, 0], geometry.map[:, 1], c=values, s=4, cmap="inferno", vmin=0, vmax=2000)
    axes.set_aspect("equal")
    axes.set_title(f"skin {args.skin}: {len(geometry)} taxels on the 2-D map")
    figure.colorbar(dots, label="response above baseline")

    def update() -> None:
        next(ticks)  # paces the loop on the first layer's periodic reads
        for name, reader in readers.items():
            start, end = ranges[name]
            try:
                frame = reader.latest()
            except skinware.NoFrameYet:
                continue
            responses = frame.responses.astype(np.float32)
            base = baseline.setdefault(name, responses)
            values[start:end] = 0 if frame.faulted else np.clip(responses - base, 0, None)
        dots.set_array(values)

    drawn = 0
    try:
        while args.frames is None or drawn < args.frames:
            update()
            drawn += 1
            if args.save:
                continue
            plt.pause(0.001)
            if not plt.fignum_exists(figure.number):
                break
    except KeyboardInterrupt:
        pass
    if args.save:
        figure.savefig(args.save, dpi=80)
        print(f"wrote {args.save} after {drawn} frames, max response {values.max():.0f}")
    for reader in readers.values():
        reader.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
