"""The clips `graphsvc evaluate --keep-motions DIR` keeps, for `graphsvc report`: each
evaluated clip's reconstruction, truth, simulated input, and a small JSON of what the page
shows beside them (timeline, per-frame errors, labels, constraints, virtual readings), so
the page needs no graph (`report.load.kept_view` reads them back)."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np

from graphsvc.evaluate.metrics import error_arrays
from graphsvc.fileio import write_text_atomic
from graphsvc.motion.bvh import write_bvh
from graphsvc.sensors.recording import save_recording


def kept_name(name: str, key: str) -> str:
    """A file-name stem for a kept evaluation clip: its name, safe on any file
    system, and a key that tells clips of one name apart."""
    return (re.sub(r"[^A-Za-z0-9._-]+", "_", str(name)).strip("._") or "clip")[:80] + f"_{key}"


def keep_clip(
    folder: Path,
    stem: str,
    motion,
    truth,
    rec,
    timeline: dict,
    per_frame: dict,
    labels,
    constraints=(),
    virtual: np.ndarray | None = None,
) -> dict:
    """Write one evaluated clip into `folder`: the reconstruction (STEM.bvh), the truth
    at the graph rate (STEM.truth.bvh), the simulated input (STEM.rec) and STEM.json
    (timeline, per-frame errors and labels, and the path's virtual readings (T, S, 3)
    as float32 base64 when the path was of graph nodes). Returns the file names
    (relative to `folder`) for the evaluation's row."""
    folder = Path(folder)
    files = {"output": f"{stem}.bvh", "truth": f"{stem}.truth.bvh", "recording": f"{stem}.rec", "view": f"{stem}.json"}
    write_bvh(folder / files["output"], motion, scale=100.0)
    write_bvh(folder / files["truth"], truth, scale=100.0)
    save_recording(rec, folder / files["recording"])
    doc = {
        "name": motion.name,
        "timeline": timeline,
        "per_frame": error_arrays(per_frame),
        "labels": [str(v) for v in labels],
        "constraints": list(constraints or []),
    }
    if virtual is not None:  # (little-endian float32, base64, as the page's other arrays)
        f32 = base64.b64encode(np.ascontiguousarray(virtual, dtype="<f4").tobytes()).decode("ascii")
        doc["virtual"] = {"shape": list(virtual.shape), "f32": f32}
    write_text_atomic(folder / files["view"], json.dumps(doc, sort_keys=True, separators=(",", ":")) + "\n")
    return files
