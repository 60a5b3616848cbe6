#!/usr/bin/env python3
"""Benchmark: a motion written as glTF (.glb and .gltf) against BVH — bytes and seconds
a write (the document made and written atomically), and `read_gltf`'s seconds reading
the .glb back.

Prints one JSON object. Usage: tools/bench_gltf.py [MOTION] [--minutes M] [--repeat N]
(default: a procedural performance; with MOTION, the file looped to M minutes, default 1).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphsvc.motion.gltf_read import read_gltf  # noqa: E402
from graphsvc.motion.library import load_motion  # noqa: E402
from graphsvc.motion.output import write_motion  # noqa: E402
from graphsvc.motion.procedural import generate_performance  # noqa: E402


def looped(motion, frames: int):
    """`motion`'s frames repeated to `frames` (the root's path restarts: only sizes matter)."""
    idx = np.arange(frames) % motion.num_frames
    return motion.copy(rotations=motion.rotations[idx], translations=motion.translations[idx])


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("motion", nargs="?", help="a motion file (default: a procedural performance)")
    p.add_argument("--minutes", type=float, default=1.0)
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    source = load_motion(args.motion) if args.motion else generate_performance(seed=0)[0]
    motion = looped(source, int(round(args.minutes * 60 * source.rate_hz)))
    out = {
        "motion": args.motion or "procedural performance",
        "frames": motion.num_frames,
        "rate_hz": motion.rate_hz,
        "joints": motion.skeleton.num_joints,
        "machine": platform.machine(),
    }
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".bvh", ".glb", ".gltf"):
            path = Path(tmp) / f"m{suffix}"
            write_motion(path, motion)  # (warm-up: imports)
            out[suffix[1:]] = {
                "bytes": path.stat().st_size,
                "write_s": round(best_of(lambda: write_motion(path, motion), args.repeat), 4),
            }
        out["glb"]["read_s"] = round(best_of(lambda: read_gltf(Path(tmp) / "m.glb"), args.repeat), 4)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
