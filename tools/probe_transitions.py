#!/usr/bin/env python3
"""Probe: transition search (graphsvc.graph.transitions) on real motion files.

Prints one JSON object: frames, contact-change frames, kd-tree candidate pairs,
transitions found and seconds per stage. Usage:

    tools/probe_transitions.py [PATHS...] [--threshold 0.05] [--k K] [--max-per-source M] [--bruteforce]

PATHS are files, folders or glob patterns (default ../shared/data/bandai). Loading,
FK, features and contacts are timed separately from the search; the data is only
read, never copied.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphsvc.graph import transitions as tr
from graphsvc.graph.distance import concat_features, pose_features, window_frames
from graphsvc.motion import signals
from graphsvc.motion.joints import canonical_indices, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.library import find_motion_files, load_motion


def prepare(path):
    """One clip → (pose features, contacts (F, 2), changes (F,))."""
    motion = load_motion(path)
    _, world_pos = motion_fk(motion)
    canon = world_pos[:, canonical_indices(motion.skeleton)]
    contacts = signals.foot_contacts(world_pos, joint_map(motion.skeleton), motion.rate_hz)
    return pose_features(canon, window_frames(motion.rate_hz)), contacts, signals.contact_changes(contacts)


def main() -> None:
    default = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai"
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("paths", nargs="*", default=[str(default)])
    parser.add_argument("--threshold", type=float, default=tr.DEFAULT_THRESHOLD_M, help="RMS metres")
    parser.add_argument("--k", type=int, default=None, help="cap on kd-tree neighbours per frame")
    parser.add_argument("--exclude-within", type=int, default=tr.DEFAULT_EXCLUDE_WITHIN)
    parser.add_argument("--local-min-radius", type=int, default=tr.DEFAULT_LOCAL_MIN_RADIUS)
    parser.add_argument("--max-per-source", type=int, default=None)
    parser.add_argument("--bruteforce", action="store_true", help="also run the all-pairs reference")
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()

    files = find_motion_files(args.paths)
    t0 = time.perf_counter()
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        clips = list(pool.map(prepare, files))
    t1 = time.perf_counter()
    features = concat_features([c[0] for c in clips])
    contacts = np.concatenate([c[1] for c in clips])
    changes = np.concatenate([c[2] for c in clips])
    lengths = np.array([c[0].num_frames for c in clips])
    clip_of_frame = np.repeat(np.arange(len(clips)), lengths)
    frame_in_clip = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    rules = {
        "exclude_same_clip_within": args.exclude_within,
        "local_min_radius": args.local_min_radius,
        "max_per_source": args.max_per_source,
    }

    t2 = time.perf_counter()
    fr = tr.kb_frames(features, contacts, changes, clip_of_frame, frame_in_clip, lengths)
    pairs = tr.indexed_pairs(features, fr, args.threshold, k=args.k)
    t3 = time.perf_counter()
    found = tr.transitions_from_pairs(features, fr, pairs, args.threshold, **rules)
    t4 = time.perf_counter()
    src_clip, dst_clip = clip_of_frame[found.src], clip_of_frame[found.dst]
    result = {
        "probe": "transitions",
        "files": len(files),
        "frames": int(lengths.sum()),
        "change_frames": int(fr.is_change.sum()),
        "threshold_m": args.threshold,
        "k": args.k,
        "candidate_pairs": int(pairs.shape[0]),
        "transitions": len(found),
        "cross_clip": int(np.sum(src_clip != dst_clip)),
        "clips_with_out_edge": int(np.unique(src_clip).size),
        "clips_without_changes": int(np.sum(np.bincount(clip_of_frame[fr.is_change], minlength=len(clips)) == 0)),
        "distance_m_quantiles": [round(float(q), 4) for q in np.quantile(found.distance, [0.1, 0.5, 0.9])]
        if len(found)
        else [],
        "load_fk_features_s": round(t1 - t0, 3),
        "index_s": round(t3 - t2, 3),
        "exact_rules_s": round(t4 - t3, 3),
        "search_s": round(t4 - t2, 3),
    }
    if args.bruteforce:
        t5 = time.perf_counter()
        ref = tr.find_transitions_bruteforce(
            features, contacts, changes, clip_of_frame, frame_in_clip, lengths, threshold_m=args.threshold, **rules
        )
        result["bruteforce_s"] = round(time.perf_counter() - t5, 3)
        result["bruteforce_equal"] = bool(np.array_equal(ref.src, found.src) and np.array_equal(ref.dst, found.dst))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
