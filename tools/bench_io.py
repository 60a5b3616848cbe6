#!/usr/bin/env python3
"""Benchmark: load + forward kinematics + sensor simulation over a motion folder.

Prints one JSON object. Usage: tools/bench_io.py [DATA_DIR] [--layout kelly6]
(default ../shared/data/bandai). A warm-up pass over one file comes first so numba
compilation and imports are not counted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphsvc.motion import signals  # noqa: E402
from graphsvc.motion.joints import joint_map  # noqa: E402
from graphsvc.motion.kinematics import motion_fk  # noqa: E402
from graphsvc.motion.library import find_motion_files, load_motion  # noqa: E402
from graphsvc.sensors.accelerometer import simulate_accelerations  # noqa: E402
from graphsvc.sensors.layout import load_layout, place  # noqa: E402


def process(path, layout):
    t0 = time.perf_counter()
    motion = load_motion(path)
    t1 = time.perf_counter()
    world_rot, world_pos = motion_fk(motion)
    t2 = time.perf_counter()
    placement = place(layout, motion.skeleton)
    simulate_accelerations(world_rot, world_pos, placement, motion.rate_hz)
    table = joint_map(motion.skeleton)
    signals.foot_contacts(world_pos, table, motion.rate_hz)
    signals.heading(world_pos, table)
    t3 = time.perf_counter()
    return motion.num_frames, (t1 - t0, t2 - t1, t3 - t2)


def main() -> None:
    default = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai"
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", default=str(default))
    parser.add_argument("--layout", default="kelly6")
    parser.add_argument("--jobs", type=int, default=1, help="files processed in parallel (threads)")
    args = parser.parse_args()
    if not Path(args.data).exists():
        sys.exit(f"bench_io: data folder {args.data} not found")
    layout = load_layout(args.layout)
    files = find_motion_files([args.data])
    process(files[0], layout)  # warm-up
    frames = 0
    stage = [0.0, 0.0, 0.0]
    start = time.perf_counter()
    # The numba kernels release the GIL, so threads overlap parsing, FK and sensors.
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        for n, times in pool.map(lambda f: process(f, layout), files):
            frames += n
            stage = [a + b for a, b in zip(stage, times)]
    seconds = time.perf_counter() - start
    print(
        json.dumps(
            {
                "benchmark": "io",
                "data": str(args.data),
                "files": len(files),
                "frames": frames,
                "layout": args.layout,
                "jobs": args.jobs,
                "seconds": round(seconds, 3),
                "frames_per_s": round(frames / seconds),
                # Per-stage times are summed over threads (CPU-side), not wall time.
                "load_s": round(stage[0], 3),
                "fk_s": round(stage[1], 3),
                "sensors_contacts_s": round(stage[2], 3),
                "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                "machine": f"{platform.machine()} {os.cpu_count()} cores, Python {platform.python_version()}",
            }
        )
    )


if __name__ == "__main__":
    main()
