"""PNG plots of input streams (what `graphsvc demo` shows of the simulated sensors)."""

from __future__ import annotations

import numpy as np

from graphsvc.fileio import atomic_writer
from graphsvc.sensors.accelerometer import GRAVITY
from graphsvc.sensors.recording import Recording


def plot_recording(rec: Recording, path, title: str = "", contacts: np.ndarray | None = None) -> None:
    """`recording_figure` under `title`, written as a PNG to `path` atomically."""
    save_figure(recording_figure(rec, contacts), path, title)


def recording_figure(rec: Recording, contacts: np.ndarray | None = None):
    """A matplotlib figure of a recording: one panel per sensor (x, y, z in m/s², the
    recording's unit and the report page's, over time, at least ±1.5 g = ±14.7 m/s²);
    a strip of foot contacts when `contacts` ((T, 2) bool, left then right) is given;
    the ground track if any."""
    import matplotlib  # (here, not at start-up: only the plots need it)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    S = rec.num_sensors
    t = rec.timestamps_s
    heights = ([0.5] if contacts is not None else []) + [1.0] * S + ([2.0] if rec.ground_position is not None else [])
    fig, axes = plt.subplots(
        len(heights),
        1,
        figsize=(10, 1.5 * sum(heights) + 0.8),
        squeeze=False,
        gridspec_kw={"height_ratios": heights},
    )
    axes = list(axes[:, 0])
    if contacts is not None:
        ax = axes.pop(0)
        for row, (side, colour) in enumerate((("left", "tab:blue"), ("right", "tab:orange"))):
            ax.fill_between(
                t, 1 - row - 0.9, 1 - row - 0.1, where=contacts[:, row], color=colour, step="mid", linewidth=0
            )
        ax.set_yticks([0.5, -0.5], ["left foot", "right foot"], fontsize=7)
        ax.set_ylim(-1, 1)
        ax.set_xlim(t[0], t[-1])
        ax.tick_params(labelsize=7, labelbottom=False)
        ax.set_title("foot contacts", fontsize=8, loc="left")
    for s in range(S):
        ax = axes[s]
        for k, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            ax.plot(t, rec.accelerations[:, s, k], color=colour, linewidth=0.8, label="xyz"[k])
        finite = rec.accelerations[:, s][np.isfinite(rec.accelerations[:, s])]
        span = max(1.5 * GRAVITY, float(np.abs(finite).max()) * 1.1) if finite.size else 1.5 * GRAVITY
        ax.set_ylim(-span, span)
        ax.set_ylabel(f"{rec.sensor_names[s]}\n[m/s²]", fontsize=8)
        ax.tick_params(labelsize=7, labelbottom=s == S - 1)
        ax.set_xlim(t[0], t[-1])
        if s == 0:
            ax.legend(loc="upper right", fontsize=7, ncol=3)
    axes[S - 1].set_xlabel("time [s]", fontsize=8)
    if rec.ground_position is not None:
        ax = axes[S]
        ax.plot(rec.ground_position[:, 0], rec.ground_position[:, 1], ".", markersize=1.5)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x [m]", fontsize=8)
        ax.set_ylabel("ground track\nz [m]", fontsize=8)
        ax.tick_params(labelsize=7)
    return fig


def save_figure(fig, path, title: str = "") -> None:
    """Title, lay out and write a matplotlib figure as PNG, atomically, then close it.
    No software/date metadata: the same data gives the same PNG bytes."""
    import matplotlib.pyplot as plt

    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_writer(path) as f:
        fig.savefig(f, format="png", dpi=90, metadata={"Software": None})
    plt.close(fig)
