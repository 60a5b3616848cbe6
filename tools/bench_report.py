#!/usr/bin/env python3
"""Benchmark: the size and the writing time of a report page for a minute of motion.

Reconstructs a procedural performance of `--seconds` (default 60) from its simulated
kelly6 sensors on a procedural graph (the demo's data), writes the page with the
reconstruction beside its truth, and prints one JSON object: the page's bytes, the
data's, three.js's, and the seconds to gather and write it.
Usage: tools/bench_report.py [--seconds 60] [--strategy viterbi|olng|...]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphsvc.graph.build import BuildOptions, build_graph  # noqa: E402
from graphsvc.motion.procedural import generate_knowledge_base, generate_performance  # noqa: E402
from graphsvc.pipeline import Options, Weights, reconstruct  # noqa: E402
from graphsvc.report.gather import clip_view  # noqa: E402
from graphsvc.report.html import data_json, three_script, write_html  # noqa: E402
from graphsvc.sensors.layout import load_layout  # noqa: E402
from graphsvc.sensors.noise import PRESETS  # noqa: E402
from graphsvc.sensors.simulate import simulate_recording  # noqa: E402
from graphsvc.strategies.sources import (  # noqa: E402
    path_readings,
    source_readings,
    timeline_from_nodes,
    timeline_from_sources,
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--strategy", default="viterbi")
    args = ap.parse_args()
    layout = load_layout("kelly6")
    kb = generate_knowledge_base(seed=0, minutes=1.0)
    graph, _ = build_graph(kb, BuildOptions(layout=layout, progress=False))
    truth, _ = generate_performance(seed=1, seconds=args.seconds)
    rec = simulate_recording(truth, layout, PRESETS["default"], seed=0)
    result = reconstruct(graph, rec, Options(strategy=args.strategy, weights=Weights(0.5, 1, 1)))
    t0 = time.perf_counter()
    if result.node_path is not None:
        timeline, virtual = timeline_from_nodes(graph, result.node_path), path_readings(graph, result.node_path)
    else:
        p = result.provenance
        timeline = timeline_from_sources([c["name"] for c in graph.clips], p.label, p.clip, p.frame, p.weight)
        virtual = source_readings(graph, p.clip, p.frame, p.weight)
    view = clip_view("performance", result.motion, timeline, rec, truth, virtual=virtual)
    doc = {"title": "bench", "clips": [view], "table": None}
    gather_s = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        write_html(Path(tmp) / "report.html", doc)
        write_s = time.perf_counter() - t0
        page = (Path(tmp) / "report.html").stat().st_size
    print(
        json.dumps(
            {
                "strategy": args.strategy,
                "seconds_of_motion": round(truth.num_frames / truth.rate_hz, 2),
                "frames": truth.num_frames,
                "joints": truth.skeleton.num_joints,
                "sensors": len(rec.sensor_names),
                "page_bytes": page,
                "data_bytes": len(data_json(doc).encode()),
                "three_js_bytes": len(three_script().encode()),
                "gather_s": round(gather_s, 3),
                "write_s": round(write_s, 3),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
