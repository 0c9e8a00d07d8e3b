"""Lab 04's solution run top to bottom on the other data sources its data-source cell takes: a student's own
phyphox export (no truth, no labelled phases; the phone path and its calibration) and the bundled real recording.
(The bundled phone recording's budget is held at kfkit level by tests/test_phyphox.py, and section 12 of every
run prints the phone's RMSE, which the export run below checks.)"""

import re

import numpy as np
import pytest
from test_calibration_labs import run_solution_on

from kfkit import attitude_motions, phone_sim
from kfkit.phone_sim import simulate_phone

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

LAB = "04_ekf_attitude.ipynb"


def rmse_row(text, name):
    """The roll, pitch, yaw RMSE (°) of the wrap-up table's row ``name``."""
    match = re.search(rf"^{re.escape(name)}\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+[\d.]+$", text, re.MULTILINE)
    assert match, f"no wrap-up row {name!r} in the output"
    return np.array([float(v) for v in match.groups()])


def test_lab04_runs_on_a_phone_export_without_truth(tmp_path):
    """A student's own phyphox export of the tour (accelerometer, gyroscope, magnetometer): no truth, no labels."""
    motion = attitude_motions.attitude_tour(rate_hz=400.0, translate_accel=2.0, vibration_rms=0.1, seed=61)
    files = phone_sim.simple_experiment_files(simulate_phone(motion, seed=62))
    files.pop(phone_sim.TRUTH_FILE)
    export = phone_sim.write_export(files, tmp_path / "phyphox tour")
    errors, text = run_solution_on(LAB, {"RECORDING": str(export)})
    assert errors == [] and "Warning" not in text
    assert "board phone-phyphox" in text and "no truth in this recording" in text
    assert "NEES          needs the truth" in text and "NIS (6 rows)  mean" in text  # the NIS needs no truth
    assert "EKF (yours), calibrated" not in text  # no RMSE table without a truth
    assert "phone, EKF (yours): RMSE" in text  # section 12 still runs on the bundled phone recording


def test_lab04_runs_on_the_bundled_real_recording():
    """RECORDING = "real": BROAD trial 06 through the whole lab (its truth has gaps, every row has a magnetometer
    sample, no slide is labelled, no calibration file exists for its IMU)."""
    errors, text = run_solution_on(LAB, {"RECORDING": "real"})
    assert errors == [] and "Warning" not in text
    assert "board broad-myon-aktos-t: 17100 samples at 100 Hz" in text
    assert "calibration: BROAD: calibrated by its authors; gyro bias = mean of the first rest" in text
    assert "needs a labelled slide and the truth" in text  # section 10's slide figure says why it is skipped
    assert re.search(r"^NEES\s+mean\s+[\d.]+ \(expected 3\)", text, re.MULTILINE)  # the truth's gaps left out
    assert "04_broad_fast_rotation" in text  # the wrap-up table is the real recording's
    assert rmse_row(text, "EKF (yours), calibrated").shape == (3,)
    assert "✅ 04.real_ekf" in text  # section 14 runs whatever the data source
