"""Figures carry units; the tuning panel re-runs the filter and redraws when a value changes."""
import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from kfkit import filters, plots, widgets  # noqa: E402
from kfkit.metrics import rmse  # noqa: E402


@pytest.fixture
def signals():
    rng = np.random.default_rng(0)
    t = np.arange(600) / 100.0
    truth = 0.4 * np.sin(t)
    gyro = np.gradient(truth, t) + rng.normal(0, 0.01, t.size)
    z = truth + rng.normal(0, 0.05, t.size)
    return t, truth, gyro, z


def test_standard_figures_have_units(signals):
    t, truth, gyro, z = signals
    run = filters.roll_kf(gyro, z, 0.01, 1e-6, 0.05**2)
    fig = plots.compare_angles(t, truth, {"accel only": (z, "accel"), "KF": (run.x, "kf")})
    assert fig.axes[0].get_ylabel() == "roll (°)" and fig.axes[0].get_xlabel() == "time (s)"
    fig = plots.consistency(t, run.x - truth, run.P, run.y, run.S)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == ["roll error (°)", "innovation (°)", "NIS (–)"]


def test_tuning_panel_reruns_and_redraws(signals):
    t, truth, gyro, z = signals
    calls = []

    def run(q, r):
        calls.append((q, r))
        return filters.roll_kf(gyro, z, 0.01, q, r).x

    panel = widgets.tune(run, t, truth, {"q": (1e-6, 1e-12, 1e-2), "r": (1e-3, 1e-6, 1.0)})
    first = panel.rmse
    assert first == pytest.approx(rmse(run(1e-6, 1e-3), truth))
    before = panel.line.get_ydata().copy()
    panel.sliders["q"].value = 1e-2  # as a student's drag would
    assert calls[-1][0] == pytest.approx(1e-2)
    assert not np.allclose(panel.line.get_ydata(), before)
    assert panel.rmse != first and "RMSE" in panel.status.value
    n = len(calls)
    panel.set(q=1e-5, r=1e-2)
    assert len(calls) == n + 1, "set() should re-run the filter once, not once per slider"
