"""PNG plots of input streams (what `graphsvc demo` shows of the simulated sensors)."""

from __future__ import annotations

import numpy as np

from graphsvc.fileio import atomic_path
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.recording import Recording


def plot_recording(rec: Recording, path, title: str = "", contacts: np.ndarray | None = None) -> None:
    """One panel per sensor (x, y, z in g over time), then the ground track if any.
    contacts: optional (T, 2) bool flags shaded behind the sensor panels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    S = rec.num_sensors
    panels = S + (1 if rec.ground_position is not None else 0)
    fig, axes = plt.subplots(panels, 1, figsize=(10, 1.6 * panels + 0.8), squeeze=False)
    t = rec.timestamps_s
    for s in range(S):
        ax = axes[s, 0]
        if contacts is not None:
            for side, colour in ((0, "#cfe8ff"), (1, "#ffe0c7")):
                ax.fill_between(t, -100, 100, where=contacts[:, side], color=colour, step="mid", linewidth=0)
        for k, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(t, rec.accelerations[:, s, k] / GRAVITY, color=colour, linewidth=0.8, label="xyz"[k])
        finite = rec.accelerations[:, s][np.isfinite(rec.accelerations[:, s])] / GRAVITY
        span = max(1.5, float(np.abs(finite).max()) * 1.1) if finite.size else 1.5
        ax.set_ylim(-span, span)
        ax.set_ylabel(f"{rec.sensor_names[s]}\n[g]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_xlim(t[0], t[-1])
        if s == 0:
            ax.legend(loc="upper right", fontsize=7, ncol=3)
    if rec.ground_position is not None:
        ax = axes[-1, 0]
        ax.plot(rec.ground_position[:, 0], rec.ground_position[:, 1], ".", markersize=1.5)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [m]", fontsize=8)
        ax.set_ylabel("z [m]", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[S - 1, 0].set_xlabel("time [s]", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    # Fixed metadata: the same recording gives the same PNG bytes.
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90, metadata={"Software": None})
    plt.close(fig)
