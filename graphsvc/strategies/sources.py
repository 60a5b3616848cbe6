"""Where each frame of a reconstruction comes from, as a report tells it: the timeline
of its source clips and kinds (`timeline_from_nodes` for a path of graph nodes,
`timeline_from_sources` for frames made of several knowledge-base sources, as OLNG's and
SSG's are, `timeline_from_labels` from label runs alone), the virtual readings its frames
were scored against (`path_readings`, `source_readings`) and its provenance compacted for
the report JSON (`compact_sources`, what `pipeline.synthesize_files` writes and
`timeline_from_sources` reads back). Used by `graphsvc synthesize --report`, the
evaluation's kept clips (`evaluate.keep`) and the report page (`report`).
"""

from __future__ import annotations

import numpy as np

from graphsvc.graph.model import (
    EDGE_BRIDGE,
    EDGE_INTERP,
    EDGE_ORIGINAL,
    EDGE_SLOW,
    EDGE_SPEEDUP,
    EDGE_TRANSITION,
    NODE_BRIDGE,
    NODE_INTERP,
    NODE_ORIGINAL,
    NODE_SLOW,
)
from graphsvc.strategies.results import label_runs

# A frame's kind on the timeline: the source clip played as captured, at another speed,
# through an interpolated (blended) segment, over a bridge between actions, or a blend of
# several sources (OLNG, SSG).
KINDS = ("original", "speed", "interpolated", "bridge", "blend")


def path_edges(graph, nodes) -> np.ndarray:
    """(T,) the graph edge entering each frame of a node path (−1: none — the first
    frame, or a jump no edge makes)."""
    nodes = np.asarray(nodes, dtype=np.int64)
    out = np.full(nodes.size, -1, dtype=np.int64)
    for t in range(1, nodes.size):
        a, b = int(nodes[t - 1]), int(nodes[t])
        lo, hi = int(graph.incoming[b]), int(graph.incoming[b + 1])
        k = lo + int(np.searchsorted(np.asarray(graph.edge_src[lo:hi]), a))
        if k < hi and int(graph.edge_src[k]) == a:
            out[t] = k
    return out


def path_readings(graph, nodes) -> np.ndarray:
    """(T, S, 3) m/s² the virtual readings a node path was scored against: each
    entering edge's metadata (NaN where no edge enters)."""
    edges = path_edges(graph, nodes)
    acc = np.asarray(graph.edge_acc, dtype=np.float64)[np.maximum(edges, 0)]
    acc[edges < 0] = np.nan
    return acc


def source_readings(graph, clip: np.ndarray, frame: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """(T, S, 3) m/s² the virtual readings of frames made of several knowledge-base
    sources (OLNG, SSG): per frame the weighted mean of its sources' readings — each
    source frame's original node's entering edge in its clip (NaN where none)."""
    clip = np.asarray(clip, dtype=np.int64)
    weight = np.where(clip >= 0, np.asarray(weight, dtype=np.float64), 0.0)
    frame = np.rint(np.asarray(frame, dtype=np.float64)).astype(np.int64)
    original = np.flatnonzero(np.asarray(graph.edge_kind) == EDGE_ORIGINAL)
    dst = np.asarray(graph.edge_dst)[original].astype(np.int64)
    keep = np.asarray(graph.node_kind)[dst] == NODE_ORIGINAL
    original, dst = original[keep], dst[keep]
    span = int(np.asarray(graph.node_frame).max(initial=0)) + 2
    keys = np.asarray(graph.node_clip)[dst].astype(np.int64) * span + np.rint(np.asarray(graph.node_frame)[dst]).astype(
        np.int64
    )
    order = np.argsort(keys, kind="stable")
    keys, original = keys[order], original[order]
    want = np.maximum(clip, 0) * span + frame
    at = np.clip(np.searchsorted(keys, want), 0, max(len(keys) - 1, 0))
    found = (len(keys) > 0) & (keys[at] == want) & (weight > 0) if len(keys) else np.zeros(want.shape, bool)
    S = np.asarray(graph.edge_acc).shape[1]
    acc = np.asarray(graph.edge_acc, dtype=np.float64)[original[at]] if len(keys) else np.zeros(want.shape + (S, 3))
    w = np.where(found, weight, 0.0)
    total = w.sum(axis=1)
    out = np.einsum("tk,tksc->tsc", w, np.where(found[..., None, None], acc, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = out / total[:, None, None]
    out[total <= 0] = np.nan
    return out


def timeline_from_nodes(graph, nodes) -> dict:
    """The timeline of a path of graph nodes: runs of one source clip and kind
    ({start, frames, clip, label, kind, from_frame}), the frames entered by a
    transition (another clip, or a jump within one), and the labels as runs."""
    nodes = np.asarray(nodes, dtype=np.int64)
    T = nodes.size
    clip = np.asarray(graph.node_clip)[nodes].astype(np.int64)
    src = np.asarray(graph.node_frame)[nodes].astype(np.float64)
    nkind = np.asarray(graph.node_kind)[nodes]
    edges = path_edges(graph, nodes)
    ekind = np.where(edges >= 0, np.asarray(graph.edge_kind)[np.maximum(edges, 0)], 255).astype(np.int64)
    kind = np.zeros(T, dtype=np.int64)
    kind[(nkind == NODE_SLOW) | (ekind == EDGE_SLOW) | (ekind == EDGE_SPEEDUP)] = 1
    kind[(nkind == NODE_INTERP) | (ekind == EDGE_INTERP)] = 2
    kind[(nkind == NODE_BRIDGE) | (ekind == EDGE_BRIDGE)] = 3
    jump = np.zeros(T, dtype=bool)
    jump[1:] = (ekind[1:] == EDGE_TRANSITION) | (ekind[1:] == 255) | (clip[1:] != clip[:-1])
    labels = [str(graph.labels[int(k)]) for k in np.asarray(graph.node_label)[nodes]]
    names = [str(c["name"]) for c in graph.clips]
    segments = []
    start = 0
    for t in range(1, T + 1):
        if t == T or jump[t] or kind[t] != kind[start] or clip[t] != clip[start]:
            segments.append(
                {
                    "start": start,
                    "frames": t - start,
                    "clip": names[clip[start]],
                    "label": labels[start],
                    "kind": KINDS[kind[start]],
                    "from_frame": round(float(src[start]), 1),
                }
            )
            start = t
    return {
        "segments": segments,
        "transitions": [int(t) for t in np.flatnonzero(jump)],
        "labels": label_runs(labels),
        "neighbours": None,
    }


def timeline_from_sources(
    clip_names, labels, clip: np.ndarray, frame: np.ndarray, weight: np.ndarray, rows: int = 8
) -> dict:
    """The timeline of frames made of several knowledge-base sources (OLNG's
    neighbourhood, SSG's cross-fades): runs of the heaviest source's clip (kind
    "blend" where a frame has more than one source), the frames where that clip
    changes, the labels as runs, and `neighbours`: the `rows` clips of most total
    weight, each with its weight in every frame as one digit 0–9 a frame."""
    clip = np.asarray(clip, dtype=np.int64)
    weight = np.where(clip >= 0, np.asarray(weight, dtype=np.float64), 0.0)
    T = clip.shape[0]
    top = np.argmax(weight, axis=1)
    lead = clip[np.arange(T), top]
    lead_frame = np.asarray(frame, dtype=np.float64)[np.arange(T), top]
    blended = (weight > 0).sum(axis=1) > 1
    labels = [str(v) for v in labels]
    segments = []
    start = 0
    for t in range(1, T + 1):
        if t == T or lead[t] != lead[start] or blended[t] != blended[start]:
            segments.append(
                {
                    "start": start,
                    "frames": t - start,
                    "clip": clip_names[lead[start]] if lead[start] >= 0 else "",
                    "label": labels[start],
                    "kind": "blend" if blended[start] else "original",
                    "from_frame": round(float(lead_frame[start]), 1),
                }
            )
            start = t
    changes = [int(t) for t in range(1, T) if lead[t] != lead[t - 1]]
    totals: dict[int, float] = {}
    for c, w in zip(clip.ravel(), weight.ravel()):
        if c >= 0 and w > 0:
            totals[int(c)] = totals.get(int(c), 0.0) + float(w)
    chosen = sorted(totals, key=lambda c: (-totals[c], c))[:rows]
    neighbours = {"clips": [clip_names[c] for c in chosen], "weights": []}
    for c in chosen:
        w = np.where(clip == c, weight, 0.0).sum(axis=1)
        neighbours["weights"].append("".join(str(int(v)) for v in np.clip(np.rint(w * 9.0), 0, 9)))
    return {"segments": segments, "transitions": changes, "labels": label_runs(labels), "neighbours": neighbours}


def timeline_from_labels(runs: list[dict]) -> dict:
    """A timeline from label runs alone (no graph to name the sources)."""
    segments = [
        {
            "start": int(r["start_frame"]),
            "frames": int(r["frames"]),
            "clip": "",
            "label": str(r["label"]),
            "kind": "original",
            "from_frame": 0.0,
        }
        for r in runs
    ]
    return {"segments": segments, "transitions": [s["start"] for s in segments[1:]], "labels": runs, "neighbours": None}


def compact_sources(provenance, top: int = 4) -> dict:
    """A reconstruction's provenance for a report JSON: per frame its `top` heaviest
    sources' clip, frame (0.1) and weight (0.001), heaviest first (clip −1: none)."""
    w = np.where(provenance.clip >= 0, provenance.weight, -1.0)
    order = np.argsort(-w, axis=1, kind="stable")[:, :top]
    rows = np.arange(w.shape[0])[:, None]
    clip = np.where(w[rows, order] > 0, provenance.clip[rows, order], -1)
    return {
        "clip": clip.astype(int).tolist(),
        "frame": np.round(provenance.frame[rows, order].astype(float), 1).tolist(),
        "weight": np.round(np.clip(w[rows, order], 0.0, None), 3).tolist(),
    }
