"""Where real markers sit on their segments, estimated from the input.

A marker set's offsets are nominal; a performer's markers sit where their skin put
them, and the knowledge base's bones are not theirs. Given a reconstruction with the
nominal offsets — for each input frame the knowledge-base frame it was matched to and
the transform that placed it — each seen marker's position is carried into that
frame's carrier segment (the inverse placement, then the carrier's inverse world
pose), and the marker's offset is the per-axis median over the frames of the fitting
span (robust to the frames matched badly). The reconstruction is then run again with
the fitted offsets, and the fit repeated on it, up to `FIT_ROUNDS` times or until the
offsets settle (the frames matched with wrong offsets are themselves a little off). A marker seen in fewer than `MIN_FRAMES` frames keeps its nominal
offset; a fitted offset further than `MAX_MOVE_M` from the nominal one is not believed
either (the match, not the marker, is off).
"""

from __future__ import annotations

import numpy as np

from graphsvc.motion import quat
from graphsvc.sensors.markers import MarkerSet, MarkerSpec
from graphsvc.strategies.ssg.index import SsgIndex

MIN_FRAMES = 5
MAX_MOVE_M = 0.25
FIT_SPAN_S = 10.0  # the offsets are fitted on the input's first seconds
FIT_ROUNDS = 3  # reconstruct, fit, reconstruct again: at most this many fits
FIT_SETTLED_M = 0.002  # … or until no offset moves more than this


def fit_offsets(
    index: SsgIndex,
    carrier: np.ndarray,
    nominal: np.ndarray,
    points: np.ndarray,
    seen: np.ndarray,
    anchors,
    anchor: np.ndarray,
    frame: np.ndarray,
    weight: np.ndarray,
) -> np.ndarray:
    """(M, 3) offsets in the carriers' frames. carrier (M,) joints; nominal (M, 3);
    points (T, M, 3), seen (T, M) the input; anchor, frame, weight (T, 2) the
    reconstruction's sources (`SsgDecoder.sources`), the heavier one used."""
    T, M = seen.shape
    main = np.argmax(weight, axis=1)
    rows = np.arange(T)
    a = anchor[rows, main]
    f = np.clip(np.rint(frame[rows, main]).astype(np.int64), 0, index.frames - 1)
    ok = a >= 0
    theta = np.array([anchors[i].theta if i >= 0 else 0.0 for i in a])
    t = np.array([[anchors[i].tx, 0.0, anchors[i].tz] if i >= 0 else [0.0, 0.0, 0.0] for i in a]).reshape(-1, 3)
    back = quat.about_y(-theta)  # input → the source clip's world
    out = np.array(nominal, dtype=np.float64, copy=True)
    for j in range(M):
        use = seen[:, j] & ok
        if use.sum() < MIN_FRAMES:
            continue
        k = quat.rotate(back[use], points[use, j] - t[use])
        c = carrier[j]
        local = quat.inv_rotate(index.world_rot[f[use], c].astype(np.float64), k - index.world_pos[f[use], c])
        fit = np.median(local, axis=0)
        if np.linalg.norm(fit - nominal[j]) <= MAX_MOVE_M:
            out[j] = fit
    return out


def fitted_set(marker_set: MarkerSet, local: np.ndarray) -> MarkerSet:
    """The set with each marker at its fitted offset on its carrier (a set file
    `--markers` reads back, for a live stream of the same performer)."""
    return MarkerSet(
        f"{marker_set.name}-fitted",
        tuple(
            MarkerSpec(m.name, m.segment, offset_m=tuple(round(float(v), 5) for v in local[j]))
            for j, m in enumerate(marker_set.markers)
        ),
    )
