"""The sensor plot (`graphsvc demo`'s sensors.png) in the recording's unit, m/s², as
the report page shows the readings."""

import numpy as np

from graphsvc.sensors.plot import plot_recording, recording_figure
from graphsvc.sensors.recording import Recording


def _recording() -> Recording:
    # Two sensors, 4 samples: one at rest reading +9.81 m/s² up (y), one swung to 30 m/s².
    acc = np.zeros((4, 2, 3), dtype=np.float32)
    acc[:, 0, 1] = 9.81
    acc[:, 1, 0] = [0.0, 10.0, 30.0, np.nan]
    return Recording(30.0, np.arange(4) / 30.0, ("chest", "l_forearm"), acc, ground_position=np.zeros((4, 2)))


def test_sensor_panels_plot_metres_per_second_squared():
    import matplotlib.pyplot as plt

    rec = _recording()
    fig = recording_figure(rec, contacts=np.ones((4, 2), dtype=bool))
    try:
        axes = fig.axes[1:3]  # (after the contacts strip)
        assert [ax.get_ylabel() for ax in axes] == ["chest\n[m/s²]", "l_forearm\n[m/s²]"]
        np.testing.assert_allclose(axes[0].lines[1].get_ydata(), [9.81] * 4, rtol=1e-6)  # (y: 1 g, as 9.81)
        np.testing.assert_allclose(axes[1].lines[0].get_ydata(), [0.0, 10.0, 30.0, np.nan], rtol=1e-6)
        # At least ±1.5 g (14.715 m/s²), else 10 % beyond the largest reading (30 → 33).
        np.testing.assert_allclose(axes[0].get_ylim(), (-14.715, 14.715))
        np.testing.assert_allclose(axes[1].get_ylim(), (-33.0, 33.0), rtol=1e-6)
    finally:
        plt.close(fig)


def test_plot_recording_writes_a_png(tmp_path):
    plot_recording(_recording(), tmp_path / "sensors.png", title="t")
    assert (tmp_path / "sensors.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
