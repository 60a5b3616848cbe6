#!/usr/bin/env python3
"""Mixed-action accuracy on a built graph, printed as JSON: a joined performance of
held-out clips, and an animator's constraint query.

    tools/probe_mixed.py GRAPH DATA [--clips A,B,...] [--constraint-clip C]

GRAPH: a graph built without the clips used here (e.g. Bandai dataset-2 with
`--exclude '*_004.bvh'`); DATA: the folder of the clips (e.g.
../shared/data/bandai/dataset-2/data).

1. **Joined performance**: the clips (default: walk → run → wave-left-hand →
   walk-turn-left → raise-up-both-hands → walk of the normal/masculine performer,
   takes 004) joined as `tools/join_clips.py` joins them (each clip's ground track
   shifted to start where the previous one ended, pose and heading as recorded),
   simulated with the default noise, reconstructed and scored (the evaluation metrics, labels
   per frame), once with positions (σ 10 cm) and heading (σ 10°) at weights 0.5,1,1
   and once from the accelerometers alone (start placed on the truth's, as
   `graphsvc evaluate` does without positions).
2. **Constraint query**: "run between 2 s and 5 s" on a walk (default
   walk_normal_004) with positions and heading: the share of frames labelled run inside
   2–5 s, and labelled walk before 1 s and after 6.5 s.

Any clip of the graph's knowledge base would be hidden as in `evaluate`; clips the
graph does not contain (the intended use) hide nothing.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphsvc.evaluate import loo  # noqa: E402
from graphsvc.evaluate.mixed import join_clips  # noqa: E402
from graphsvc.graph.file import load_graph  # noqa: E402
from graphsvc.motion.library import load_motion  # noqa: E402
from graphsvc.motion.resample import resample  # noqa: E402
from graphsvc.pipeline import Options, reconstruct  # noqa: E402
from graphsvc.sensors.layout import layout_from_dict  # noqa: E402
from graphsvc.sensors.noise import PRESETS  # noqa: E402
from graphsvc.strategies.options import Weights  # noqa: E402

SIX = (
    "walk_normal",
    "run_normal",
    "wave-left-hand_normal",
    "walk-turn-left_normal",
    "raise-up-both-hands_normal",
    "walk_masculine",
)


def _files(data: Path, names) -> list[Path]:
    out = []
    for n in names:
        hits = sorted(data.glob(f"*{n}*.bvh")) if not n.endswith(".bvh") else [data / n]
        hits = [h for h in hits if h.stem.endswith("_004") or n.endswith(".bvh")] or hits
        if not hits:
            raise SystemExit(f"no clip matches {n!r} in {data}")
        out.append(hits[0])
    return out


def _scores(row: dict) -> dict:
    keep = ("frames", "joint_err_cm", "root_err_cm", "heading_err_deg", "label_acc", "samples_per_s")
    return {k: round(row[k], 4) if isinstance(row[k], float) else row[k] for k in keep}


def joined(graph, files, seed: int) -> dict:
    motions = [load_motion(f) for f in files]
    truth, labels = join_clips(motions, graph.rate_hz, graph.params.get("mapping"))
    indices = [k for k in loo.match_graph_clips(graph, motions) if k is not None]
    out = {"clips": [m.name for m in motions], "seconds": round(truth.duration_s, 2), "hidden_clips": len(indices)}
    for key, setup in (
        ("positions_heading", loo.EvalSetup(PRESETS["default"], True, Options(weights=Weights(0.5, 1.0, 1.0)), seed)),
        (
            "accelerometers",
            loo.EvalSetup(replace(PRESETS["default"], position=0.0, heading="none"), False, Options(), seed),
        ),
    ):
        row = loo.evaluate_clip(graph, truth, indices, setup, labels)
        runs = []
        for lab in row["pred_labels"]:
            if not runs or runs[-1][0] != lab:
                runs.append([lab, 0])
            runs[-1][1] += 1
        out[key] = {**_scores(row), "path_labels": [f"{lab} {n / graph.rate_hz:.1f} s" for lab, n in runs]}
    return out


def constraint_query(graph, file: Path, seed: int) -> dict:
    motion = resample(load_motion(file), graph.rate_hz)
    setup = loo.EvalSetup(PRESETS["default"], True, Options(weights=Weights(0.5, 1.0, 1.0)), seed)
    rec = loo.simulate_test_input(
        motion, layout_from_dict(graph.layout), setup, graph.rate_hz, graph.params.get("mapping")
    )
    constraints = ([{"start_s": 2.0, "end_s": 5.0, "require": {"label": "run"}}],)
    result = reconstruct(graph, rec, Options(weights=Weights(0.5, 1.0, 1.0), constraints=constraints))
    labels = np.asarray(graph.labels, dtype=object)[np.asarray(graph.node_label)[result.node_path]]
    t = np.arange(labels.shape[0]) / graph.rate_hz
    inside = (t >= 2.0) & (t < 5.0)
    outside = (t < 1.0) | (t >= 6.5)
    return {
        "clip": motion.name,
        "seconds": round(motion.duration_s, 2),
        "run_inside_2_5_s": round(float(np.mean(labels[inside] == "run")), 4),
        "walk_before_1_after_6_5_s": round(float(np.mean(labels[outside] == "walk")), 4),
        "broken_constraints": result.report.get("broken_constraints"),
        "terms": result.report.get("terms"),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("graph")
    p.add_argument("data", type=Path)
    p.add_argument("--clips", help="comma-separated clip names or name parts, in order")
    p.add_argument("--constraint-clip", default="walk_normal_004")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    graph = load_graph(args.graph)
    names = args.clips.split(",") if args.clips else SIX
    out = {
        "graph": str(args.graph),
        "graph_nodes": graph.num_nodes,
        "joined": joined(graph, _files(args.data, names), args.seed),
        "constraint_query": constraint_query(graph, _files(args.data, [args.constraint_clip])[0], args.seed),
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
