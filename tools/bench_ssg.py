#!/usr/bin/env python3
"""Benchmark: the SSG strategy's subsequence DTW kernels, and its reconstruction speed on
the whole Bandai-Namco knowledge base, printed as one JSON object.

    .venv/bin/python tools/bench_ssg.py [DATA] [--graph G] [--repeats 15] [--series-frames F]
                                        [--recon-repeats 2] [--skip-dtaidistance]
                                        [--skip-blas-variant] [--evaluate | --only-evaluate]
                                        [--jobs 2] [--pretty]

(about 45 s on an idle 2-core machine, graph build included; --evaluate adds about 10
minutes.)

DATA: the motion-capture folder holding bandai/dataset-{1,2}/data (default $GRAPHSVC_DATA,
else ../shared/data beside the project); the Bandai folder itself works too. Unless
--graph G is given, a light graph of both datasets (`graphsvc build --no-msv
--no-interp --no-bridges --jobs 2`: the SSG reads only the original frames) is built
into a temporary folder, with the SSG index cached beside it.

"kernel": cells per second (query rows × series frames / seconds; best of --repeats
calls after a warm-up call, the kernels timed in turn within each repeat so that the
machine's drift hits them alike) on one query and one series:
  series — the hands-feet markers (4 × 3 = 12 dims) of every knowledge-base frame at
    30 Hz but those of the held-out clip (--series-frames caps it), centred per frame:
    x and z minus the frame's marker centroid, y (height) as it is;
  query  — N = 10 frames (the hands-feet window at 30 Hz) from the middle of the
    held-out clip's simulated marker recording (default noise, seed 0), centred alike.
Timed: `dtw.classic_dtw` (unbounded subsequence DTW, squared Euclidean cost in the
loop, one thread); dtaidistance's C subsequence alignment
(`subsequence_alignment(query, series, penalty=0, use_c=True)`: the full (N+1) × (F+1)
warping-paths matrix over the whole series with a free start and end in it, then the
matching function sqrt(last row) / N), and its C kernel alone
(`dtw_cc.warping_paths_ndim` into a preallocated matrix); `dtw.bounded_dtw` (eq. 4.2);
and the production path for one window over every knowledge-base frame, as the strategy
runs it — `dtw.local_costs` (BLAS products of the window clouds, then the rotation-
invariant cost in numba) for the window's N rows, for its new rows only (what
`reconstruct` computes per window) and for a 64-row block, `dtw.subsequence_dtw` (numba
threads), `dtw.k_best`, timed in turn as the decoder alternates them; and
subsequence_dtw again back to back (no BLAS call between) and on one numba thread,
because OpenBLAS's spinning workers slow the numba threads that follow them (compare
best and median). "agreement" checks every kernel against a numpy brute force of its
own recurrence over the whole series and compares the best end positions (the two
definitions differ in their step weights: see the notes).

"reconstruction": `pipeline.reconstruct` with strategy ssg, one child process per
marker set (hands-feet, left-foot, head-back) so each peak RSS is its own, on five
dataset-2 clips joined end to end (`evaluate.mixed.join_clips`) and simulated as
markers (default noise, seed 0, 30 Hz). One-time costs (graph load, index build in the
parent / load from its cache in the child, the knowledge base's marker clouds for the
set, numba's kernels) are timed apart from the per-input search and synthesis (best of
--recon-repeats runs after a warm-up run on another clip). Target: ≥ 1 s of input per
second on 2 cores. A diagnostic reruns hands-feet with OPENBLAS_NUM_THREADS=1 (graphsvc
instead stops OpenBLAS's threads spinning after a product, OPENBLAS_THREAD_TIMEOUT=4:
`numba_env`; --skip-blas-variant leaves it out).

"accuracy" (--evaluate): `graphsvc evaluate --strategy ssg` on Bandai-Namco dataset 2
(a light graph of all of it; the takes 001 and 004 of every content × style as tests,
each hiding every take of its content × style, and the normal and masculine styles'
takes 001 and 004, each hiding every clip of its actor — tools/accuracy.py's clips),
for the marker sets hands-feet, left-foot and head-back, each without gaps and with 30 %
of the samples in random gaps of 5–80 frames (`--gap-fraction 0.3`), default noise
(markers σ 1 mm), and hands-feet on performances of six held-out clips of six actions
joined (`--mixed 6`, takes hidden): the mean joint, root and heading errors and
labels, and the locomotion and gesture means.

Each section records "contention": the share of the machine's CPU other processes took
meanwhile (/proc/stat less this process and its children); the threaded kernels lose
most to it, so a run with a "caveat" should be repeated on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import graphsvc  # noqa: E402,F401  (first: it sets OpenBLAS's and OpenMP's waits before numpy loads)

RATE_HZ = 30.0
KERNEL_SET = "hands-feet"
HELD_OUT = "dataset-2_walk_normal_004"  # the kernel's query clip (left out of its series)
RECON_CLIPS = tuple(
    f"dataset-2_{c}_normal_004" for c in ("walk", "run", "wave-both-hands", "raise-up-left-hand", "walk-turn-left")
)
WARM_CLIP = "dataset-2_raise-up-right-hand_normal_004"
RECON_SETS = ("hands-feet", "left-foot", "head-back")
TARGET_INPUT_S_PER_S = 1.0


# ---------------------------------------------------------------- helpers


def bandai_folder(data: str) -> Path:
    p = Path(data)
    for cand in (p / "bandai", p):
        if (cand / "dataset-1" / "data").is_dir() and (cand / "dataset-2" / "data").is_dir():
            return cand
    raise SystemExit(f"no bandai/dataset-1/data and dataset-2/data under {data}")


def peak_rss_mb() -> float:
    """This process's peak resident set (VmHWM: its own, whereas ru_maxrss carries the
    parent's over fork and exec)."""
    try:
        line = next(ln for ln in Path("/proc/self/status").read_text().splitlines() if ln.startswith("VmHWM"))
        return round(int(line.split()[1]) / 1024, 1)
    except (OSError, StopIteration):
        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


class Contention:
    """How much CPU other processes took while a section ran: the machine's busy time
    (/proc/stat) less this process's and its waited-for children's, as a share of
    wall time × cores; and the hypervisor's steal."""

    def __init__(self):
        self.t0, self.busy0, self.steal0, self.own0 = time.perf_counter(), *self._read()

    @staticmethod
    def _read():
        hz = os.sysconf("SC_CLK_TCK")
        try:
            f = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
            busy, steal = (f[0] + f[1] + f[2] + f[5] + f[6]) / hz, (f[7] if len(f) > 7 else 0) / hz
        except (OSError, ValueError, IndexError):
            busy = steal = float("nan")
        a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return busy, steal, a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime

    def report(self) -> dict:
        busy, steal, own = self._read()
        wall = time.perf_counter() - self.t0
        cap = wall * (os.cpu_count() or 1)
        return {
            "wall_s": round(wall, 2),
            "own_cpu_share": round((own - self.own0) / cap, 3),
            "other_processes_cpu_share": round(max(0.0, (busy - self.busy0) - (own - self.own0)) / cap, 3),
            "steal_share": round((steal - self.steal0) / cap, 3),
            "load_average_1min_end": round(os.getloadavg()[0], 2),
        }


def best_of(fns: dict, repeats: int) -> dict[str, list[float]]:
    """Each callable once for warm-up, then `repeats` rounds calling them in turn:
    {name: [seconds, …]}."""
    for fn in fns.values():
        fn()
    out = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            out[k].append(time.perf_counter() - t0)
    return out


def rate(cells: int, times: list[float]) -> dict:
    best, med = min(times), float(np.median(times))
    return {
        "best_s": round(best, 6),
        "median_s": round(med, 6),
        "cells": int(cells),
        "cells_per_s": round(cells / best),
        "mcells_per_s": round(cells / best / 1e6, 1),
        "mcells_per_s_median": round(cells / med / 1e6, 1),
    }


def machine() -> dict:
    model = None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    flags = ""
    try:
        text = Path("/proc/cpuinfo").read_text()
        flags = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
    except OSError:
        pass
    blas = None
    try:
        cfg = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        blas = {k: cfg.get(k) for k in ("name", "version", "openblas configuration") if cfg.get(k)}
    except Exception:  # noqa: BLE001  (older numpy: not worth more)
        pass
    import numba

    mem = None
    try:
        line = next(ln for ln in Path("/proc/meminfo").read_text().splitlines() if ln.startswith("MemTotal"))
        mem = round(int(line.split()[1]) / 1024 / 1024, 1)
    except (OSError, StopIteration):
        pass
    return {
        "arch": platform.machine(),
        "cores": os.cpu_count(),
        "usable_cores": len(os.sched_getaffinity(0)),
        "cpu_model": model,
        "avx2": " avx2" in flags,
        "avx512f": " avx512f" in flags,
        "mem_gib": mem,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numpy_blas": blas,
        "numba": numba.__version__,
        "numba_threads": numba.get_num_threads(),
    }


def build_graph_file(bandai: Path, out: Path) -> float:
    t0 = time.perf_counter()
    cmd = [
        sys.executable,
        "-m",
        "graphsvc.cli",
        "build",
        str(bandai / "dataset-1" / "data"),
        str(bandai / "dataset-2" / "data"),
        "-o",
        str(out),
        "--no-msv",
        "--no-interp",
        "--no-bridges",
        "--jobs",
        "2",
        "--quiet",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"graph build failed: {r.stderr[-800:]}")
    return time.perf_counter() - t0


def clip_file(bandai: Path, name: str) -> Path:
    return bandai / name.split("_")[0] / "data" / f"{name}.bvh"


def centred(points: np.ndarray) -> np.ndarray:
    """(T, M, 3) → (T, 3M) float64: x and z minus the frame's marker centroid, y kept."""
    p = np.array(points, dtype=np.float64)
    c = p.mean(axis=1, keepdims=True)
    p[..., 0] -= c[..., 0]
    p[..., 2] -= c[..., 2]
    return np.ascontiguousarray(p.reshape(len(p), -1))


# ---------------------------------------------------------------- brute force


def _row_costs(Q: np.ndarray, S: np.ndarray) -> np.ndarray:
    return np.stack([((S - q) ** 2).sum(axis=1) for q in Q])  # (N, F)


def brute_unbounded(
    Q: np.ndarray, S: np.ndarray, diag: float, vert: float, horiz: float, vert0: float | None = None
) -> np.ndarray:
    """Last row of unbounded subsequence DTW in numpy: D[0, m] = c; D[n, m] = min(
    D[n−1, m−1] + diag·c, D[n−1, m] + vert·c, D[n, m−1] + horiz·c) (column 0: the
    vertical step only, at weight vert0, default vert). The horizontal chain within a row is a running minimum over
    cumulative sums: D[n, m] = P[m] + min_{j ≤ m} (a[j] − P[j]), P = cumsum(horiz·c)."""
    C = _row_costs(Q, S)
    D = C[0].copy()
    for n in range(1, len(Q)):
        c = C[n]
        a = np.empty_like(c)
        a[0] = D[0] + (vert if vert0 is None else vert0) * c[0]
        a[1:] = np.minimum(D[:-1] + diag * c[1:], D[1:] + vert * c[1:])
        P = np.cumsum(horiz * c)
        D = P + np.minimum.accumulate(a - P)
    return D


def brute_bounded(Q: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Last row of eq. 4.2 (one run): steps (1, 1), (1, 2) at weight 1, (2, 1) at 2."""
    C = _row_costs(Q, S)
    F = S.shape[0]
    prev2 = np.full(F, np.inf)
    prev = C[0].copy()
    for n in range(1, len(Q)):
        c = C[n]
        cur = np.full(F, np.inf)
        cur[1:] = prev[:-1] + c[1:]
        cur[2:] = np.minimum(cur[2:], prev[:-2] + c[2:])
        if n >= 2:
            cur[1:] = np.minimum(cur[1:], prev2[:-1] + 2.0 * c[1:])
        prev2, prev = prev, cur
    return prev


def rel_diff(a: np.ndarray, b: np.ndarray) -> float:
    ok = np.isfinite(a) & np.isfinite(b)
    if not ok.any():
        return 0.0
    return float(np.max(np.abs(a[ok] - b[ok]) / np.maximum(np.abs(b[ok]), 1e-12)))


# ---------------------------------------------------------------- kernel section


def kernel_section(graph, index, bandai: Path, args) -> dict:
    from graphsvc.motion.library import load_motion
    from graphsvc.sensors.markers import load_marker_set
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.simulate import simulate_marker_recording
    from graphsvc.strategies.ssg import dtw
    from graphsvc.strategies.ssg.decoder import COST_BLOCK
    from graphsvc.strategies.ssg.index import point_window, window_points
    from graphsvc.strategies.ssg.options import SsgOptions
    from graphsvc.strategies.ssg.strategy import MAX_POINTS, warm_up, windows_for

    marker_set = load_marker_set(KERNEL_SET)
    names = [c["name"] for c in graph.clips]
    held = names.index(HELD_OUT) if HELD_OUT in names else -1
    keep = index.clip != held
    t0 = time.perf_counter()
    kb_markers = index.markers(marker_set)  # (F, M, 3) world
    markers_s = time.perf_counter() - t0
    series = centred(kb_markers[keep])
    if args.series_frames:
        series = np.ascontiguousarray(series[: args.series_frames])
    F = series.shape[0]
    w, _ = windows_for(marker_set, SsgOptions(), float(graph.rate_hz))
    N = w.n
    motion = load_motion(clip_file(bandai, HELD_OUT))
    rec = simulate_marker_recording(motion, KERNEL_SET, parse_noise("default"), seed=0, rate_hz=RATE_HZ)
    pts = np.asarray(rec.marker_positions, dtype=np.float64)
    T = pts.shape[0]
    a = max(0, T // 2 - N // 2)
    query = centred(pts[a : a + N])
    d = query.shape[1]
    cells = N * F
    out: dict = {
        "series": {
            "frames": F,
            "dims": d,
            "marker_set": KERNEL_SET,
            "centring": "per frame: x and z minus the frame's marker centroid, y (height) raw; metres",
            "left_out_clip": HELD_OUT if held >= 0 else None,
            "capped": bool(args.series_frames),
        },
        "query": {
            "clip": HELD_OUT,
            "frames": [a, a + N],
            "rows": N,
            "rate_hz": RATE_HZ,
            "input": "simulated markers, default noise, seed 0, centred as the series",
        },
        "repeats": args.repeats,
    }

    last_c = np.empty(F)
    last_b = np.empty(F)
    fns = {
        "classic_dtw": lambda: dtw.classic_dtw(query, series, last_c),
        "bounded_dtw": lambda: dtw.bounded_dtw(query, series, last_b),
    }
    dtai = None
    if args.skip_dtaidistance:
        out["dtaidistance"] = {"skipped": "--skip-dtaidistance"}
    else:
        try:
            import dtaidistance
            from dtaidistance import dtw_cc
            from dtaidistance.subsequence.dtw import SubsequenceAlignment, subsequence_alignment

            holder: dict = {}

            def theirs():
                holder["sa"] = subsequence_alignment(query, series, penalty=0.0, use_c=True)
                holder["sa"].align()  # (a no-op: subsequence_alignment aligned already)

            kw = SubsequenceAlignment(query, series, penalty=0.0, use_c=True).settings.c_kwargs()

            fns["dtaidistance_subsequence_alignment"] = theirs
            dtai = (dtaidistance.__version__, holder)
        except ImportError as exc:
            out["dtaidistance"] = {"skipped": f"not installed ({exc})"}
    times = best_of(fns, args.repeats)
    if dtai is not None:
        # The C kernel alone, the matrix's allocation and fill outside the timer.
        version, holder = dtai
        c_times = []
        for i in range(args.repeats + 1):
            m = np.full((N + 1, F + 1), np.inf)
            t0 = time.perf_counter()
            dtw_cc.warping_paths_ndim(m, query, series, False, True, **kw)
            if i:  # (the first call: warm-up)
                c_times.append(time.perf_counter() - t0)
        holder["c"] = m
    out["classic_dtw"] = {
        **rate(cells, times["classic_dtw"]),
        "threads": 1,
        "what": "unbounded subsequence DTW, squared Euclidean cost in the loop, column by column",
    }
    out["bounded_dtw"] = {
        **rate(cells, times["bounded_dtw"]),
        "threads": 1,
        "what": "eq. 4.2 slope bounds [1/2, 2], squared Euclidean cost in the loop, row by row",
    }
    if dtai is not None:
        version, holder = dtai
        sa = holder["sa"]
        theirs_rate = rate(cells, times["dtaidistance_subsequence_alignment"])
        out["dtaidistance"] = {
            "version": version,
            "subsequence_alignment": {
                **theirs_rate,
                "threads": 1,
                "what": "subsequence_alignment(query, series, penalty=0, use_c=True): "
                "allocate (N+1)x(F+1) float64, C warping paths (ndim, squared "
                "Euclidean, free start/end in the series), sqrt(last row)/N",
            },
            "c_kernel_only": {
                **rate(cells, c_times),
                "threads": 1,
                "what": "dtw_cc.warping_paths_ndim into a matrix allocated and filled outside the timer",
            },
        }
        out["ratio_ours_over_theirs"] = {
            "classic_dtw_vs_subsequence_alignment": round(
                out["classic_dtw"]["cells_per_s"] / theirs_rate["cells_per_s"], 2
            ),
            "classic_dtw_vs_c_kernel_only": round(
                out["classic_dtw"]["cells_per_s"] / out["dtaidistance"]["c_kernel_only"]["cells_per_s"], 2
            ),
            "note": "cells/s ours ÷ cells/s theirs on the same query and series; > 1: ours is faster",
        }

    # The production path for one window: clouds, local costs, accumulated cost, k best.
    t0 = time.perf_counter()
    h, _ = point_window(float(graph.rate_hz))
    kb = window_points(index, kb_markers, h, MAX_POINTS)
    clouds_s = time.perf_counter() - t0
    warm_up()
    Fp = index.frames
    allowed = np.ascontiguousarray(index.allowed & keep)
    seen = np.isfinite(pts).all(axis=-1)
    ppts = np.where(seen[..., None], pts, 0.0)
    rows = np.arange(a, a + N)
    block = np.arange(max(0, min(a, T - COST_BLOCK)), max(0, min(a, T - COST_BLOCK)) + min(COST_BLOCK, T))
    state: dict = {}

    def lc():
        state["C"] = dtw.local_costs(kb, ppts, seen, rows, allowed)

    new_rows = np.arange(a + N - w.step, a + N)

    def lc_step():  # what the batch decoder computes per window: the rows new to it
        dtw.local_costs(kb, ppts, seen, new_rows, allowed)

    def lc_block():
        dtw.local_costs(kb, ppts, seen, block, allowed)

    def sdtw():
        C = state["C"]
        D = np.empty(C.shape)
        step = np.empty(C.shape, dtype=np.int8)
        dtw.subsequence_dtw(C, index.run_start, D, step)
        state["D"], state["step"] = D, step

    def kb_():
        state["found"] = dtw.k_best(state["D"], state["step"], w.k)

    lc()
    sdtw()
    ptimes = best_of(
        {
            "local_costs": lc,
            "local_costs_step": lc_step,
            "local_costs_block": lc_block,
            "subsequence_dtw": sdtw,
            "k_best": kb_,
        },
        args.repeats,
    )
    import numba

    alone = []
    for _ in range(args.repeats):  # back to back, no BLAS call in between
        t0 = time.perf_counter()
        sdtw()
        alone.append(time.perf_counter() - t0)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one = best_of({"a": sdtw}, args.repeats)["a"]
        one_lc = best_of({"a": lc}, max(3, args.repeats // 3))["a"]
    finally:
        numba.set_num_threads(threads)
    pc = N * Fp
    per_window = {k: min(v) for k, v in ptimes.items()}
    window_s = per_window["local_costs_step"] + per_window["subsequence_dtw"] + per_window["k_best"]
    batch_window_s = (
        per_window["local_costs_block"] / block.size * w.step + per_window["subsequence_dtw"] + per_window["k_best"]
    )
    med = {k: float(np.median(v)) for k, v in ptimes.items()}
    window_med = med["local_costs_step"] + med["subsequence_dtw"] + med["k_best"]
    out["production"] = {
        "kb_frames": Fp,
        "rows": N,
        "window_step": w.step,
        "k": w.k,
        "points_per_cloud": int(kb.x.shape[1]),
        "cloud_frames": int(kb.taus.size),
        "numba_threads": machine_threads(),
        "openblas_num_threads_env": os.environ.get("OPENBLAS_NUM_THREADS"),
        "timing": "local_costs (N rows, step rows, 64-row block), subsequence_dtw and k_best timed in turn, as "
        "the decoder alternates them; compare best with median, and with subsequence_dtw_alone",
        "local_costs": {
            **rate(pc, ptimes["local_costs"]),
            "what": "N rows: the window clouds' BLAS products (float32) and the numba combine",
        },
        "local_costs_step_rows": {
            **rate(w.step * Fp, ptimes["local_costs_step"]),
            "rows": w.step,
            "what": "the window's new rows only (window − overlap): the call the decoder "
            "makes per window when reconstruct pushes the input frame by frame",
        },
        "local_costs_per_row_in_block": {
            **rate(block.size * Fp, ptimes["local_costs_block"]),
            "rows": int(block.size),
            "what": "64 input rows in one product (decoder.COST_BLOCK; reconstruct's "
            "frame-by-frame pushes never reach it: the block stops at the "
            "frames pushed so far)",
        },
        "subsequence_dtw": {
            **rate(pc, ptimes["subsequence_dtw"]),
            "what": "eq. 4.2 over precomputed float32 costs, runs, steps kept (int8), parallel "
            "over frames within a row; includes allocating D and step",
        },
        "subsequence_dtw_alone": {**rate(pc, alone), "what": "the same, called back to back (no BLAS call between)"},
        "subsequence_dtw_1_thread": {**rate(pc, one), "what": "the same with numba.set_num_threads(1), back to back"},
        "local_costs_1_numba_thread": {
            **rate(pc, one_lc),
            "what": "local_costs (N rows) with the numba combine on 1 thread (BLAS threads unchanged)",
        },
        "k_best": {"best_s": round(per_window["k_best"], 6), "found": len(state["found"])},
        "window_total": {
            "best_s": round(window_s, 6),
            "median_s": round(window_med, 6),
            "mcells_per_s": round(pc / window_s / 1e6, 1),
            "mcells_per_s_median": round(pc / window_med / 1e6, 1),
            "what": "as reconstruct runs a window: local_costs (step new rows) + subsequence_dtw + k_best",
        },
        "window_total_if_blocked": {
            "best_s": round(batch_window_s, 6),
            "mcells_per_s": round(pc / batch_window_s / 1e6, 1),
            "what": "the same with the new rows' costs at the 64-row block's per-row cost",
        },
        "one_time": {"kb_markers_s": round(markers_s, 3), "kb_clouds_s": round(clouds_s, 3)},
    }

    # Agreement: each kernel against a brute force of its own recurrence, and the ends.
    t0 = time.perf_counter()
    b_ours = brute_unbounded(query, series, 2.0, 2.0, 1.0)  # as classic_dtw's docstring: eq. 4.1
    b_coded = brute_unbounded(query, series, 2.0, 2.0, 1.0, vert0=1.0)  # as its code: column 0 at weight 1
    differ = np.flatnonzero(np.abs(last_c - b_ours) > 1e-9 * np.maximum(np.abs(b_ours), 1e-12))
    b_theirs = brute_unbounded(query, series, 1.0, 1.0, 1.0)  # dtaidistance, penalty 0
    b_bounded = brute_bounded(query, series)
    agree: dict = {
        "brute_force": "numpy over the whole series, each kernel's own recurrence (row 0: any start, cost c)",
        "classic_dtw_vs_brute_as_coded_max_rel_diff": rel_diff(last_c, b_coded),
        "classic_dtw_vs_brute_docstring_max_rel_diff": rel_diff(last_c, b_ours),
        "classic_dtw_columns_differing_from_docstring": {
            "count": int(differ.size),
            "first": [int(i) for i in differ[:10]],
        },
        "bounded_dtw_vs_brute_max_rel_diff": rel_diff(last_b, b_bounded),
        "classic_dtw_best_end": int(np.argmin(last_c)),
        "classic_dtw_best_cost": float(np.min(last_c)),
        "bounded_dtw_best_end": int(np.argmin(last_b)),
        "brute_weighted_best_end": int(np.argmin(b_ours)),
        "brute_unweighted_best_end": int(np.argmin(b_theirs)),
    }
    if dtai is not None:
        sa = dtai[1]["sa"]
        paths_last = sa.paths[-1, 1:]
        agree["dtaidistance_vs_brute_unweighted_max_rel_diff"] = rel_diff(paths_last, b_theirs)
        agree["dtaidistance_c_only_same_as_alignment"] = bool(np.array_equal(dtai[1]["c"][-1, 1:], paths_last))
        agree["dtaidistance_matching_is_sqrt_over_N"] = bool(np.allclose(sa.matching, np.sqrt(paths_last) / N))
        agree["dtaidistance_best_end"] = int(np.argmin(sa.matching))
        agree["dtaidistance_best_value"] = float(np.min(sa.matching))
        agree["same_best_end"] = agree["dtaidistance_best_end"] == agree["classic_dtw_best_end"]
        gap = abs(agree["dtaidistance_best_end"] - agree["classic_dtw_best_end"])
        agree["same_best_end_within_2_frames"] = gap <= 2
    # The ten cheapest ends of each definition, and how many they share (non-maximum: ±N).
    top = lambda v: [int(i) for i in np.argsort(v)[:10]]  # noqa: E731
    agree["top10_weighted_ends"] = top(b_ours)
    agree["top10_unweighted_ends"] = top(b_theirs)
    agree["brute_force_s"] = round(time.perf_counter() - t0, 3)
    agree["notes"] = [
        "classic_dtw weights its steps (docstring, eq. 4.1): (1,1) and (1,0) [query advances, series stays] at 2c, "
        "(0,1) [series advances] at c; dtaidistance weights every step 1 (plus `penalty` on the non-diagonal ones: "
        "0 here, 0.1 by default); so the accumulated costs differ and the best ends may too. dtaidistance's "
        "matching is sqrt(accumulated squared cost)/N — a monotone map, which changes no argmin.",
        "classic_dtw's column 0 takes the vertical step at weight 1 (cur[n] = cur[n−1] + c), not 2 as everywhere "
        "else (docstring): it matches a brute force of that code to rounding (as_coded), and differs from the "
        "docstring's recurrence only in the first few columns, whose best paths start in column 0 and step "
        "right (columns_differing_from_docstring); it matters only for an end near frame 0.",
        "relative differences of ~1e-10 are the brute force's cumulative-sum rounding.",
    ]
    out["agreement"] = agree
    out["peak_rss_mb"] = peak_rss_mb()
    return out


def machine_threads() -> int:
    import numba

    return numba.get_num_threads()


# ---------------------------------------------------------------- reconstruction (child)


def recon_child(args) -> dict:
    """One marker set's reconstruction timings (module docstring), in its own process."""
    t0 = time.perf_counter()
    from graphsvc.evaluate.mixed import join_clips
    from graphsvc.graph.file import load_graph
    from graphsvc.motion.library import load_motion
    from graphsvc.pipeline import Options, reconstruct
    from graphsvc.sensors.noise import parse_noise
    from graphsvc.sensors.simulate import simulate_marker_recording
    from graphsvc.strategies import get as get_strategy
    from graphsvc.strategies.base import prepared_index
    from graphsvc.strategies.index import index_path
    from graphsvc.strategies.ssg.strategy import _prepared_markers, used_markers, warm_up, windows_for

    import_s = time.perf_counter() - t0
    bandai = bandai_folder(args.data)
    name = args.child
    t0 = time.perf_counter()
    graph = load_graph(args.graph)
    load_s = time.perf_counter() - t0
    cached = index_path(args.graph, "ssg").is_file()
    strategy = get_strategy("ssg")
    t0 = time.perf_counter()
    index = prepared_index(strategy, graph)
    index_s = time.perf_counter() - t0
    noise = parse_noise("default")
    motions = [load_motion(clip_file(bandai, c)) for c in RECON_CLIPS]
    motion, _ = join_clips(motions, graph.rate_hz)
    rec = simulate_marker_recording(motion, name, noise, seed=0, rate_hz=RATE_HZ)
    warm_rec = simulate_marker_recording(
        load_motion(clip_file(bandai, WARM_CLIP)), name, noise, seed=1, rate_hz=RATE_HZ
    )
    options = Options(strategy="ssg")
    used, _, _, _ = used_markers(options.ssg, rec.marker_names, rec.meta)
    t0 = time.perf_counter()
    _prepared_markers(graph, index, used, None)  # the knowledge base's markers and clouds (cached per graph)
    clouds_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    warm_up()
    numba_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    reconstruct(graph, warm_rec, options)  # anything else loaded once, outside the timings
    warm_s = time.perf_counter() - t0
    runs = []
    for _ in range(args.recon_repeats):
        t0 = time.perf_counter()
        r = reconstruct(graph, rec, options)
        wall = time.perf_counter() - t0
        runs.append((wall, r.report))
    wall, report = min(runs, key=lambda x: x[0])
    T = int(report["samples"])
    input_s = T / float(graph.rate_hz)
    tm = report["timings_s"]
    w, _ = windows_for(used, options.ssg, float(graph.rate_hz))
    return {
        "marker_set": name,
        "markers": len(used.markers),
        "window_frames": w.n,
        "overlap_frames": w.o,
        "k": w.k,
        "input": {
            "clips": list(RECON_CLIPS),
            "samples": T,
            "seconds": round(input_s, 2),
            "seen": report.get("seen"),
            "offsets": report["ssg"]["offsets"]["mode"],
        },
        "one_time_s": {
            "imports": round(import_s, 3),
            "graph_load": round(load_s, 3),
            "index_load" if cached else "index_build": round(index_s, 3),
            "kb_marker_clouds": round(clouds_s, 3),
            "numba_kernels": round(numba_s, 3),
            "warm_up_run": round(warm_s, 3),
        },
        "per_input_s": {
            "wall": round(wall, 3),
            "search": tm.get("search"),
            "synthesis": tm.get("synthesis"),
            "prepare": tm.get("prepare"),
            "warm_up": tm.get("warm_up"),
            "all_runs_wall": [round(x[0], 3) for x in runs],
        },
        "seconds_per_input_second": round(wall / input_s, 4),
        "input_seconds_per_second": round(input_s / wall, 2),
        "meets_target": input_s / wall >= TARGET_INPUT_S_PER_S,
        "windows": report["windows"],
        "dtw_cells": report["dtw_cells"],
        "search_mcells_per_s": round(report["dtw_cells"] / max(tm.get("search", 0.0), 1e-9) / 1e6, 1),
        "candidate_frames": report["candidate_frames"],
        "peak_rss_mb": peak_rss_mb(),
    }


# ---------------------------------------------------------------- accuracy

EVAL_SETS = ("hands-feet", "left-foot", "head-back")
EVAL_PROTOCOLS = {  # as tools/accuracy.py: the takes' tests, and one actor's
    "takes": "*_00[14].bvh",
    "actor": "*_normal_00[14].bvh,*_masculine_00[14].bvh",
}
EVAL_GAPS = (0.0, 0.3)


def evaluate_section(bandai: Path, work: Path, jobs: int) -> dict:
    """`graphsvc evaluate --strategy ssg` on dataset 2 (a light graph of all of it, each
    test hiding its takes or its actor): every marker set without gaps and with 30 % of
    the samples in random gaps, default noise (markers σ 1 mm); and hands-feet on
    performances of six held-out clips of six actions joined (--mixed 6)."""
    kb = bandai / "dataset-2" / "data"
    graph = work / "dataset2.graph"
    exe = Path(sys.executable).with_name("graphsvc")
    cli = [str(exe)] if exe.exists() else [sys.executable, "-m", "graphsvc.cli"]
    subprocess.run(
        cli
        + [
            "build",
            str(kb),
            "--no-msv",
            "--no-interp",
            "--no-bridges",
            "--jobs",
            str(jobs),
            "--quiet",
            "-o",
            str(graph),
        ],
        check=True,
        capture_output=True,
    )
    rows = []
    runs = [(p, m, g, None) for p in EVAL_PROTOCOLS for m in EVAL_SETS for g in EVAL_GAPS]
    runs += [("takes", "hands-feet", g, 6) for g in EVAL_GAPS]  # (mixed: six held-out clips of six actions joined)
    for protocol, marker_set, gaps, mixed in runs:
        tests = EVAL_PROTOCOLS[protocol]
        out = work / f"{protocol}-{marker_set}-{gaps:g}-{mixed}.json"
        cmd = (
            cli
            + [
                "evaluate",
                str(kb),
                "--graph",
                str(graph),
                "--test",
                tests,
                "--hold-out",
                protocol,
                "--strategy",
                "ssg",
                "--markers",
                marker_set,
                "--jobs",
                str(jobs),
                "--quiet",
                "--json",
                str(out),
            ]
            + (["--gap-fraction", f"{gaps:g}"] if gaps else [])
            + (["--mixed", str(mixed)] if mixed else [])
        )
        t0 = time.perf_counter()
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            rows.append(
                {
                    "protocol": protocol,
                    "markers": marker_set,
                    "gap_fraction": gaps,
                    "mixed": mixed,
                    "error": done.stderr[-600:],
                }
            )
            continue
        run = json.loads(out.read_text())
        mean, groups = run["mean"], run.get("groups", {})
        rows.append(
            {
                "protocol": protocol,
                "markers": marker_set,
                "gap_fraction": gaps,
                "mixed": mixed,
                "clips": len(run["clips"]),
                "joint_err_cm": round(mean["joint_err_cm"], 2),
                "root_err_cm": round(mean["root_err_cm"], 2),
                "heading_err_deg": round(mean["heading_err_deg"], 2),
                "label_acc": None if mean.get("label_acc") is None else round(mean["label_acc"], 3),
                "locomotion_joint_err_cm": round(groups["locomotion"]["joint_err_cm"], 2)
                if "locomotion" in groups
                else None,
                "gestures_joint_err_cm": round(groups["gestures"]["joint_err_cm"], 2) if "gestures" in groups else None,
                "samples_per_s": mean.get("samples_per_s"),
                "wall_s": round(time.perf_counter() - t0, 1),
                "command": shlex.join(["graphsvc"] + cmd[len(cli) :]),
            }
        )
    return {"what": evaluate_section.__doc__.replace("\n    ", " ").strip(), "runs": rows}


# ---------------------------------------------------------------- main


def main() -> None:
    default_data = os.environ.get("GRAPHSVC_DATA") or str(ROOT.parent / "shared" / "data")
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument(
        "data",
        nargs="?",
        default=default_data,
        metavar="DATA",
        help="folder with bandai/dataset-{1,2}/data (default $GRAPHSVC_DATA or ../shared/data)",
    )
    parser.add_argument("--graph", help="a graph built from Bandai datasets 1 and 2 (default: build a light one)")
    parser.add_argument("--repeats", type=int, default=15, help="kernel timings: best of this many (default 15)")
    parser.add_argument(
        "--recon-repeats",
        type=int,
        default=2,
        help="reconstruction timings: best of this many runs per marker set (default 2)",
    )
    parser.add_argument("--series-frames", type=int, help="cap the kernel series at this many frames")
    parser.add_argument("--skip-dtaidistance", action="store_true", help="do not time dtaidistance")
    parser.add_argument(
        "--skip-blas-variant",
        action="store_true",
        help="do not rerun hands-feet with OPENBLAS_NUM_THREADS=1 (a diagnostic)",
    )
    parser.add_argument("--pretty", action="store_true", help="indent the JSON")
    parser.add_argument(
        "--evaluate",
        action="store_true",
        help="also the accuracy runs: evaluate on dataset 2, three marker sets, with and without gaps, "
        "hold-out takes and actor (about 10 minutes on 2 cores)",
    )
    parser.add_argument("--only-evaluate", action="store_true", help="the accuracy runs alone")
    parser.add_argument("--jobs", type=int, default=2, help="evaluate's worker processes (default 2)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(recon_child(args)), flush=True)
        return
    started = time.perf_counter()
    whole = Contention()
    bandai = bandai_folder(args.data)
    result: dict = {
        "benchmark": "ssg",
        "command": shlex.join(getattr(sys, "orig_argv", [sys.executable] + sys.argv)),
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": {**machine(), "load_average_at_start": [round(x, 2) for x in os.getloadavg()]},
        "data": str(bandai),
    }
    if args.only_evaluate:
        with tempfile.TemporaryDirectory(prefix="bench_ssg_") as tmp:
            result["accuracy"] = evaluate_section(bandai, Path(tmp), args.jobs)
        result["total_s"] = round(time.perf_counter() - started, 1)
        print(json.dumps(result, indent=2 if args.pretty else None, ensure_ascii=False), flush=True)
        return
    with tempfile.TemporaryDirectory(prefix="bench_ssg_") as tmp:
        graph_info: dict = {}
        if args.graph:
            graph_path = str(Path(args.graph).resolve())
            graph_info["path"] = graph_path
        else:
            graph_path = str(Path(tmp) / "bandai.graph")
            graph_info["built_s"] = round(build_graph_file(bandai, Path(graph_path)), 2)
            graph_info["built"] = (
                "graphsvc build dataset-1/data dataset-2/data --no-msv --no-interp --no-bridges --jobs 2"
            )
        from graphsvc.graph.file import load_graph
        from graphsvc.strategies.ssg.index import build_arrays, load_index

        t0 = time.perf_counter()
        graph = load_graph(graph_path)
        graph_info["load_s"] = round(time.perf_counter() - t0, 3)
        t0 = time.perf_counter()
        build_arrays(graph)
        graph_info["ssg_index_build_s"] = round(time.perf_counter() - t0, 3)
        t0 = time.perf_counter()
        index = load_index(graph)  # (writes the cache beside the graph if missing; the children load it)
        graph_info["ssg_index_load_or_build_s"] = round(time.perf_counter() - t0, 3)
        graph_info.update(
            {
                "nodes": graph.num_nodes,
                "kb_frames": index.frames,
                "clips": len(graph.clips),
                "rate_hz": float(graph.rate_hz),
                "kb_minutes": round(index.frames / graph.rate_hz / 60, 1),
            }
        )
        result["graph"] = graph_info
        c = Contention()
        result["kernel"] = kernel_section(graph, index, bandai, args)
        result["kernel"]["contention"] = c.report()
        del index, graph

        def child(name: str, env: dict | None = None) -> dict:
            cmd = [
                sys.executable,
                __file__,
                args.data,
                "--child",
                name,
                "--graph",
                graph_path,
                "--recon-repeats",
                str(args.recon_repeats),
            ]
            c = Contention()
            r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, **(env or {})})
            if r.returncode != 0:
                return {"marker_set": name, "error": r.stderr[-800:]}
            return {**json.loads(r.stdout.strip().splitlines()[-1]), "env": env or {}, "contention": c.report()}

        runs = [child(name) for name in RECON_SETS]
        ok = [r for r in runs if "error" not in r]
        result["reconstruction"] = {
            "target": f"≥ {TARGET_INPUT_S_PER_S:g} s of input per second on 2 cores",
            "meets_target_all": bool(ok) and len(ok) == len(runs) and all(r["meets_target"] for r in ok),
            "runs": runs,
        }
        if not args.skip_blas_variant and "OPENBLAS_NUM_THREADS" not in os.environ:
            result["reconstruction"]["diagnostic_openblas_1_thread"] = {
                "why": "OpenBLAS's worker threads busy-wait after each product and take the cores from numba's "
                "OpenMP workers in the threaded kernels that follow; graphsvc shortens their wait "
                f"(OPENBLAS_THREAD_TIMEOUT={os.environ.get('OPENBLAS_THREAD_TIMEOUT')}): this run keeps BLAS "
                "on one thread instead, for comparison",
                **child(RECON_SETS[0], {"OPENBLAS_NUM_THREADS": "1"}),
            }
        if args.evaluate:
            result["accuracy"] = evaluate_section(bandai, Path(tmp), args.jobs)
    result["parent_peak_rss_mb"] = peak_rss_mb()
    result["contention_whole_run"] = whole.report()
    busy = result["contention_whole_run"]["other_processes_cpu_share"]
    if busy > 0.1:
        result["caveat"] = (
            f"other processes took {busy:.0%} of the machine's CPU during this run: the threaded "
            "kernels (numba prange, OpenBLAS) lose most, run it again on a quiet machine"
        )
    result["total_s"] = round(time.perf_counter() - started, 1)
    print(json.dumps(result, indent=2 if args.pretty else None, ensure_ascii=False), flush=True)


if __name__ == "__main__":
    main()
