#!/usr/bin/env python3
"""Benchmark: how the motion-graph build grows with the knowledge base, toward a million frames.

The knowledge base is every clip under DATA (default ../shared/data: Bandai-Namco
dataset-1, dataset-2, dataset-2-extra, then CMU) with mirror and reverse augmentation,
as the million-frame build runs it. Each size is a deterministic subset of the source
files (a fixed shuffle, taken until the augmented frame count reaches the size; the
first Bandai file always comes first, so every size pools onto the same skeleton), built
by `graphsvc build FILES --augment mirror,reverse --jobs N --quiet -o G` in its own
process, then read back by `graphsvc info --json`. Peak RSS is that of the whole build
process tree (every descendant's resident set summed, polled from /proc every 0.1 s).

Prints one JSON line a size: kb_frames (augmented), nodes, edges, file bytes and bytes
per KB frame, the build's stages in seconds (its `times:` line), wall and CPU seconds,
peak RSS, the connectivity report's largest share, and the growth exponent of every
figure against the previous size (log ratio over log of the frames' ratio).

With --live DIR each graph is also served and streamed as `tools/bench_live_scale.py`
does it (DIR: held-out `.rec` recordings in the default wrists-ankles layout; --markers
DIR: marker recordings for the SSG), its JSON under "live": the server's load, each
strategy's figures a frame. Leave the recordings' clips out of every build with
--exclude GLOB (a file-name pattern, e.g. '*_004.bvh').

Usage: tools/bench_scale.py [DATA] [--sizes 76000,300000,600000,1030000] [--jobs 2]
    [--max-rss-gb 7] [--keep DIR] [--exclude GLOB] [--live DIR [--markers DIR] [--seconds 60]]

A build whose tree passes --max-rss-gb is killed and reported as such (the machine is
shared). Sizes above the whole set are skipped.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("bandai/dataset-1/data", "bandai/dataset-2/data", "bandai/dataset-2-extra/data", "cmu")
AUGMENT_COPIES = 4  # mirror, reverse of the originals and of the mirrors
RATE_HZ = 30.0


def clip_frames(path: Path) -> int:
    """Frames of a BVH or AMC file at the graph rate, from the header (BVH) or by
    counting frame numbers (AMC, 120 Hz), without parsing the motion."""
    if path.suffix.lower() == ".bvh":
        frames, dt = 0, 1.0 / RATE_HZ
        with open(path, errors="replace") as f:
            for line in f:
                if line.startswith("Frames:"):
                    frames = int(line.split()[1])
                elif line.startswith("Frame Time:"):
                    dt = float(line.split()[2])
                    break
        rate = 1.0 / dt
    else:
        with open(path, errors="replace") as f:
            frames = sum(1 for line in f if line.strip().isdigit())
        rate = 120.0
    return int(math.floor((frames - 1) * RATE_HZ / rate + 1e-9)) + 1 if frames else 0


def source_files(data: Path) -> list[Path]:
    from graphsvc.motion.library import find_motion_files

    out: list[Path] = []
    for part in PARTS:
        if (data / part).exists():
            out += find_motion_files([str(data / part)])
    return out


def choose(files: list[Path], frames: list[int], target: int) -> list[Path]:
    """The first file, then a fixed shuffle of the rest, until the augmented frames reach target."""
    import numpy as np

    order = [0] + [int(i) + 1 for i in np.random.default_rng(0).permutation(len(files) - 1)]
    keep, total = [], 0
    for i in order:
        if total >= target:
            break
        keep.append(i)
        total += frames[i] * AUGMENT_COPIES
    return [files[i] for i in sorted(keep)]


def tree_rss(pid: int) -> int:
    """Resident bytes of pid and all its descendants (from /proc)."""
    total, stack = 0, [pid]
    while stack:
        p = stack.pop()
        try:
            with open(f"/proc/{p}/statm") as f:
                total += int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
            for task in os.listdir(f"/proc/{p}/task"):
                with open(f"/proc/{p}/task/{task}/children") as f:
                    stack += [int(c) for c in f.read().split()]
        except (FileNotFoundError, ProcessLookupError, ValueError):
            continue
    return total


def run_watched(cmd: list[str], max_rss: float) -> tuple[subprocess.CompletedProcess | None, int, float, float]:
    """(result or None if killed past max_rss, peak tree RSS bytes, wall s, CPU s of the children)."""
    before = os.times()
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, text=True, start_new_session=True)
        peak, killed = 0, False
        while proc.poll() is None:
            peak = max(peak, tree_rss(proc.pid))
            if peak > max_rss:
                os.killpg(proc.pid, 9)
                killed = True
                proc.wait()
                break
            time.sleep(0.1)
        wall = time.perf_counter() - t0
        after = os.times()
        cpu = (after.children_user - before.children_user) + (after.children_system - before.children_system)
        out.seek(0)
        err.seek(0)
        result = subprocess.CompletedProcess(cmd, proc.returncode, out.read(), err.read())
    return (None if killed else result), peak, wall, cpu


def parse_times(stdout: str) -> dict:
    line = next((x for x in stdout.splitlines() if x.startswith("times: ")), "")
    return {k: float(v) for k, v in re.findall(r"(\w+) ([0-9.]+) s", line.split(" (total")[0])}


def exponent(a: float, b: float, fa: float, fb: float) -> float | None:
    if a <= 0 or b <= 0 or fa <= 0 or fb <= 0 or fa == fb:
        return None
    return round(math.log(b / a) / math.log(fb / fa), 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="?", default=str(ROOT.parent / "shared" / "data"))
    parser.add_argument("--sizes", default="76000,300000,600000,1030000", help="augmented KB frames a build")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--max-rss-gb", type=float, default=7.0, help="kill a build whose tree passes this")
    parser.add_argument("--keep", help="keep the graph files in this folder")
    parser.add_argument("--exclude", action="append", default=[], metavar="GLOB", help="leave out matching files")
    parser.add_argument("--live", metavar="DIR", help="held-out .rec recordings: each graph's live figures too")
    parser.add_argument("--markers", metavar="DIR", help="with --live: marker recordings for the SSG")
    parser.add_argument("--seconds", type=float, default=60.0, help="with --live: seconds a live stream")
    args = parser.parse_args()
    data = Path(args.data)
    files = [f for f in source_files(data) if not any(fnmatch.fnmatch(f.name, g) for g in args.exclude)]
    if not files:
        sys.exit(f"bench_scale: no motion files under {data}")
    frames = [clip_frames(f) for f in files]
    whole = sum(frames) * AUGMENT_COPIES
    exe = str(Path(sys.executable).with_name("graphsvc"))
    previous = None
    for size in (int(s) for s in args.sizes.split(",") if s):
        if size > whole * 1.02:
            print(json.dumps({"size": size, "skipped": f"above the whole set ({whole} augmented frames)"}), flush=True)
            continue
        chosen = choose(files, frames, size)
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(args.keep) if args.keep else Path(tmp)
            folder.mkdir(parents=True, exist_ok=True)
            graph = folder / f"scale-{size}.graph"
            cmd = [exe, "build", *map(str, chosen), "--augment", "mirror,reverse", "--jobs", str(args.jobs)]
            result, peak, wall, cpu = run_watched([*cmd, "--quiet", "-o", str(graph)], args.max_rss_gb * 2**30)
            row: dict = {"size": size, "source_files": len(chosen), "peak_rss_mb": round(peak / 2**20)}
            if result is None or result.returncode != 0:
                row["error"] = "killed past --max-rss-gb" if result is None else result.stderr.strip()[-400:]
                print(json.dumps(row), flush=True)
                continue
            info = json.loads(
                subprocess.run([exe, "info", str(graph), "--json"], capture_output=True, text=True).stdout
            )
            size_bytes = graph.stat().st_size
            if args.live:
                live = [sys.executable, str(ROOT / "tools" / "bench_live_scale.py"), str(graph)]
                live += ["--recordings", args.live, "--seconds", str(args.seconds)]
                live += ["--markers", args.markers] if args.markers else []
                done = subprocess.run(live, capture_output=True, text=True)
                row["live"] = json.loads(done.stdout) if done.returncode == 0 else {"error": done.stderr[-400:]}
        kb = info["kb_frames"]
        row.update(
            {
                "kb_frames": kb,
                "kb_frames_original": info.get("kb_frames_original"),
                "clips": info["clips"],
                "nodes": info["nodes"],
                "edges": info["edges"],
                "nodes_by_kind": info["nodes_by_kind"],
                "file_bytes": size_bytes,
                "bytes_per_kb_frame": round(size_bytes / kb),
                "wall_s": round(wall, 1),
                "cpu_s": round(cpu, 1),
                "stages_s": parse_times(result.stdout),
                "largest_share": info.get("connectivity", {}).get("largest_share"),
                "jobs": args.jobs,
            }
        )
        if previous is not None:
            f0, f1 = previous["kb_frames"], kb
            row["exponent_vs_previous"] = {
                k: exponent(previous[k], row[k], f0, f1)
                for k in ("nodes", "edges", "file_bytes", "wall_s", "cpu_s", "peak_rss_mb")
            } | {f"stage_{k}": exponent(previous["stages_s"].get(k, 0), v, f0, f1) for k, v in row["stages_s"].items()}
        print(json.dumps(row), flush=True)
        previous = row


if __name__ == "__main__":
    main()
