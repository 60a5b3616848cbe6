"""Presenting evaluation results: the terminal table of `graphsvc evaluate` and the
per-frame error plot of `graphsvc demo`."""

from __future__ import annotations

import numpy as np

from graphsvc.sensors.plot import save_figure


def _fmt(value, spec: str, scale: float = 1.0, none: str = "—") -> str:
    return none if value is None else format(value * scale, spec)


def format_table(summary: dict) -> str:
    """One row per clip and a mean row from `loo.summarize_run`'s dict: frames,
    joint error (cm), the joint error on the truth's bone lengths (cm, where scored),
    root error (cm), heading error (°), jitter (km/s³) and foot skate
    (cm/s) of the output and of the truth, label accuracy (%), search speed
    (samples/s), and the pose-oracle floor (cm) after the joint error when it was
    scored (`evaluate.oracle`); then, when both occur, the means of the locomotion and the gesture
    clips (`protocols.activity`)."""
    head = (
        "clip",
        "frames",
        "joint cm",
        "root cm",
        "heading °",
        "jitter out/truth",
        "skate out/truth",
        "label %",
        "samples/s",
    )

    floor = "oracle_joint_err_cm" in summary["mean"]
    if floor:
        head = (*head[:3], "oracle cm", *head[3:])
    scaled = "joint_err_scaled_cm" in summary["mean"]
    if scaled:
        head = (*head[:3], "scaled cm", *head[3:])

    def pair(r, key, spec):
        return f"{_fmt(r.get(key), spec)} / {_fmt(r.get('truth_' + key), spec)}" if key in r else "—"

    def cells(title, r):
        return (
            title,
            f"{r['frames']:,}",
            _fmt(r["joint_err_cm"], ".2f"),
            *((_fmt(r.get("joint_err_scaled_cm"), ".2f"),) if scaled else ()),
            *((_fmt(r.get("oracle_joint_err_cm"), ".2f"),) if floor else ()),
            _fmt(r["root_err_cm"], ".1f"),
            _fmt(r["heading_err_deg"], ".1f"),
            pair(r, "jitter_km_s3", ".2f"),
            pair(r, "skate_cm_s", ".1f"),
            _fmt(r["label_acc"], ".0f", 100.0, "n/a"),
            _fmt(r.get("samples_per_s"), ",.0f"),
        )

    rows = [cells(str(r.get("file") or r["name"]), r) for r in summary["clips"]]

    def summary_row(title, m):
        return cells(title, m)

    m = summary["mean"]
    means = [summary_row(f"mean of {m['clips']} clips", m)]
    groups = summary.get("groups") or {}
    if len(groups) > 1:  # (one group alone is the mean)
        means += [summary_row(f"  {name} ({g['clips']} clips)", g) for name, g in groups.items()]
    widths = [max(len(row[i]) for row in [head, *rows, *means]) for i in range(len(head))]

    def line(cells):
        return "  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    rule = "  ".join("-" * w for w in widths)
    return "\n".join([line(head), rule, *(line(r) for r in rows), rule, *(line(r) for r in means)])


def plot_errors(path, rate_hz: float, per_frame: dict, pred_labels, true_labels, title: str = "") -> None:
    """PNG of per-frame errors over time: joint error (cm) and root error (cm) in one
    panel each, heading error (°) on the root panel's right axis, and two label strips
    (true above predicted), one colour per label. per_frame: `evaluate_frames`'s
    per-frame dict ((T,) arrays); pred_labels, true_labels: (T,) strings."""
    import matplotlib  # (here, not at start-up: only the plots need it)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    joint = np.asarray(per_frame["joint_err_cm"])
    T = joint.shape[0]
    t = np.arange(T) / rate_hz
    pred = [str(x) for x in list(pred_labels)[:T]]
    true = [str(x) for x in list(true_labels)[:T]]
    names = sorted(set(pred) | set(true))
    colours = {n: plt.get_cmap("tab10")(i % 10) for i, n in enumerate(names)}

    fig, axes = plt.subplots(3, 1, figsize=(10, 6.2), sharex=True, gridspec_kw={"height_ratios": [2, 2, 1]})
    ax = axes[0]
    ax.plot(t, joint, color="tab:blue", linewidth=0.9)
    ax.axhline(float(joint.mean()), color="tab:blue", linestyle=":", linewidth=0.8)
    ax.set_ylabel("joint error\n[cm]", fontsize=8)
    ax.set_ylim(bottom=0)
    ax.text(
        0.01,
        0.9,
        f"mean {joint.mean():.1f} cm (local pose, root aligned)",
        transform=ax.transAxes,
        fontsize=7,
        va="top",
    )

    ax = axes[1]
    root = np.asarray(per_frame["root_err_cm"])
    ax.plot(t, root, color="tab:red", linewidth=0.9, label="root (ground plane)")
    ax.set_ylabel("root error\n[cm]", fontsize=8)
    ax.set_ylim(bottom=0)
    twin = ax.twinx()
    twin.plot(t, np.asarray(per_frame["heading_err_deg"]), color="tab:gray", linewidth=0.7, label="heading")
    twin.set_ylabel("heading error [°]", fontsize=8)
    twin.set_ylim(0, 180)
    twin.tick_params(labelsize=7)
    ax.legend(handles=[ax.lines[0], twin.lines[0]], loc="upper left", fontsize=7)

    ax = axes[2]
    for row, labels in ((1, true), (0, pred)):
        for name in names:
            on = np.array([lab == name for lab in labels])
            ax.fill_between(t, row + 0.1, row + 0.9, where=on, color=colours[name], step="mid", linewidth=0)
    ax.set_yticks([1.5, 0.5], ["true", "predicted"], fontsize=7)
    ax.set_ylim(0, 2)
    ax.set_xlabel("time [s]", fontsize=8)
    ax.legend(
        handles=[Patch(color=colours[n], label=n) for n in names],
        loc="upper center",
        bbox_to_anchor=(0.5, -0.55),
        ncol=min(len(names), 8),
        fontsize=7,
        frameon=False,
    )
    for a in axes:
        a.tick_params(labelsize=7)
        a.set_xlim(t[0], t[-1] if T > 1 else t[0] + 1.0 / rate_hz)
    save_figure(fig, path, title)
