"""The labels of a motion graph's clips and nodes: a clip's content label (what it
shows: walk, run, bow), per-frame labels given to the build (mirrored and reversed
copies take their original's, mirrored and reversed), and each node's label."""

from __future__ import annotations

import re

import numpy as np

from graphsvc.motion.augment import mirror_label
from graphsvc.motion.skeleton import Motion

AUGMENTED_SUFFIX = r"(_mirror|_reverse)+$"  # what augmentation appends to a clip's name


def content_label(motion: Motion) -> str:
    """A clip's content label: its first label, or its name."""
    return motion.labels[0] if motion.labels else motion.name


def clip_frame_labels(motion: Motion, frame_labels: dict | None, frames: int) -> np.ndarray | None:
    """The clip's per-frame labels from `build_graph`'s frame_labels (by its name, or its
    original's for a mirrored or reversed copy), at `frames` frames (nearest), or None."""
    if not frame_labels:
        return None
    if motion.name in frame_labels:
        out = np.asarray(frame_labels[motion.name], dtype=str)
    else:
        base = re.sub(AUGMENTED_SUFFIX, "", motion.name)
        if base not in frame_labels:
            return None
        out = np.asarray(frame_labels[base], dtype=str)
        suffixes = motion.name[len(base) :]  # (mirroring and reversing commute on labels)
        if "_reverse" in suffixes:
            out = out[::-1]
        if "_mirror" in suffixes:
            out = np.array([mirror_label(x) for x in out], dtype=str)
    if len(out) != frames:  # (resampled to the graph rate)
        out = out[np.minimum(np.round(np.arange(frames) * len(out) / max(frames, 1)).astype(np.int64), len(out) - 1)]
    return out


def node_labels(per_frame, labels, label_of_clip, start, lengths, node_clip, node_frame) -> np.ndarray:
    """(N,) int32 each node's label: its clip's, or, where the clip has per-frame
    labels, that of the frame it comes from (`node_frame`, the first clip's frame for
    interpolated nodes, the source frame for bridges)."""
    if all(f is None for f in per_frame):
        return label_of_clip[node_clip]
    flat = np.concatenate(
        [
            np.full(int(lengths[k]), label_of_clip[k], dtype=np.int32)
            if f is None
            else np.array([labels.index(x) for x in f], dtype=np.int32)
            for k, f in enumerate(per_frame)
        ]
    )
    frame = np.clip(np.floor(node_frame).astype(np.int64), 0, np.asarray(lengths)[node_clip] - 1)
    return flat[np.asarray(start)[node_clip] + frame]
