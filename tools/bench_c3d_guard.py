#!/usr/bin/env python3
"""What reading a C3D file safely costs: ezc3d in this process, the structure check
(graphsvc.sensors.c3d_guard.check_c3d) and ezc3d in a child process (read_isolated),
per file, best of --repeat. Prints JSON.

    tools/bench_c3d_guard.py ../shared/data/c3d/*.c3d [--repeat 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def best_ms(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return round(1000 * min(times), 2)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("files", nargs="+")
    p.add_argument("--repeat", type=int, default=5)
    args = p.parse_args()
    import ezc3d

    from graphsvc.sensors.c3d_guard import check_c3d, read_isolated

    rows = []
    for name in args.files:
        data = Path(name).read_bytes()
        rows.append(
            {
                "file": Path(name).name,
                "bytes": len(data),
                "ezc3d_in_process_ms": best_ms(lambda: ezc3d.c3d(name), args.repeat),
                "check_ms": best_ms(lambda: check_c3d(name, data), args.repeat),
                "child_process_ms": best_ms(lambda: read_isolated(name, len(data)), args.repeat),
            }
        )
    print(json.dumps({"files": rows}, indent=1))


if __name__ == "__main__":
    main()
