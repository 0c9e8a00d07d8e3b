"""Lab 03 on the bundled real recordings (BROAD): the magnet's window found from |m| alone, the real-data
checkpoint's bar and its classic mistakes, and the lab's data source set to "real"."""

from pathlib import Path

import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient
from scipy.spatial.transform import Rotation
from test_checkpoints_every import solution_namespace
from waiting import HANG_GUARD_S

from kfkit import datasets, mag_calibration
from kfkit.checkpoints import get, lab03, run_checkpoint
from kfkit.io import Recording
from kfkit.labs import lab03 as lab03_support

SOLUTION = Path(__file__).resolve().parents[1] / "solutions" / "03_mag_alignment_heading.ipynb"


def with_magnet(rec, start, end, h_body):
    """``rec`` with a constant field ``h_body`` (µT, body frame) added to its magnetometer for start ≤ t < end:
    a magnet fixed on the board is a hard iron, the same in the body frame however the board turns."""
    on = (rec.t >= start) & (rec.t < end)
    M = np.array(rec.meta["mount"]["mag"])  # body ← sensor; sensor = Mᵀ body
    counts = np.round((h_body @ M) / rec.meta["sensors"]["mag"]["sensitivity"]).astype(int)
    data = dict(rec.data)
    for i, column in enumerate(("mx", "my", "mz")):
        data[column] = np.where(on, rec[column] + counts[i], rec[column])
    return Recording(rec.meta, data, rec.path)


def test_an_undisturbed_trial_has_no_magnet():
    rec = datasets.load("01_broad_slow_rotation")  # BROAD trial 02: no magnet anywhere
    mask, B, sigma = lab03_support.magnet_window(rec)
    assert not mask.any()
    assert 40 < B < 50 and 0.3 < sigma < 1.0  # µT: the lab's field and the sensor's noise at rest


@pytest.mark.parametrize("h_body", [[0.0, 0.0, -8.0], [10.0, -8.0, 4.0]])
def test_the_magnet_window_is_where_a_magnet_was_added(h_body):
    """A hard iron of the size of trial 34's magnet added over a known window (starting at rest, ending while the
    board turns, where |m| crosses B) is found to within the running median's half width. (A magnet whose field
    changes |m| at rest by less than 5σ is seen only once the board turns: |m| is all the detector looks at.)"""
    rec = with_magnet(datasets.load("01_broad_slow_rotation"), 30.0, 70.0, np.array(h_body))
    mask, _, _ = lab03_support.magnet_window(rec)
    start, end = rec.t[mask][[0, -1]]
    assert (
        abs(start - 30.0) <= lab03_support.MAGNET_SMOOTH_S / 2 and abs(end - 70.0) <= lab03_support.MAGNET_SMOOTH_S / 2
    )


def test_trial_34s_magnet_goes_on_at_rest_and_off_before_the_motions_end():
    """What the lab's text says of trial 34, checked: the magnet is on before BROAD's movement phase begins
    (the gyro still reads a board at rest) and off well before it ends; the rests before and after read the
    plain field, the rest with the magnet tens of σ below it."""
    rec = datasets.load(lab03.REAL_MAGNET)
    mask, B, sigma = lab03_support.magnet_window(rec)
    on_at, off_at = rec.t[mask][[0, -1]]
    ((move_from, move_to),) = [(p["start"], p["end"]) for p in rec.phases if p["label"] == "movement"]
    assert on_at < move_from and move_to - off_at > 30.0
    assert np.linalg.norm(rec.body("gyr")[np.searchsorted(rec.t, on_at) - 10]) < 0.05  # rad/s: at rest
    norm = np.linalg.norm(rec.body("mag"), axis=1)
    rest = rec.phase("rest")
    for outside in (rest & (rec.t < on_at), rest & (rec.t > off_at)):
        assert abs(np.median(norm[outside]) - B) < 2 * sigma
    assert B - np.median(norm[rest & mask]) > 10 * sigma


def test_the_real_checkpoints_bar_lies_between_a_right_fit_and_no_fit():
    """The bar (2 × the same IMU's heading error with the magnet off) passes the kit's reference fit (an
    independent implementation: mag_calibration.fit_mag_calibration) and fails no calibration by a wide margin."""
    (case,) = get("03.real_magnet").cases(np.random.default_rng(0))
    bar = lab03.REAL_BAR_FACTOR * case.expected["off"]
    h, S = mag_calibration.fit_mag_calibration(case.args["mag"], case.args["field_norm"])
    fitted = lab03.true_tilt_heading_error(
        mag_calibration.apply_mag_calibration(case.args["mag"], h, S), case.expected["truth"]
    )
    assert fitted < bar < case.expected["on"] / 2
    assert run_checkpoint(get("03.real_magnet"), mag_calibration.fit_mag_calibration).ok


def test_the_heading_error_helper_is_scipys_yaw_on_a_rotated_field():
    """true_tilt_heading_error against scipy: the field seen from random attitudes gives 0, one turned by 5° about
    the vertical gives 5°; NaN rows of the truth are left out."""
    rng = np.random.default_rng(3)
    euler = np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50), rng.uniform(-np.pi, np.pi, 50)])
    field = np.array([16.0, 0.0, 41.0])
    rot = Rotation.from_euler("ZYX", euler[:, ::-1])
    truth = euler.copy()
    truth[7] = np.nan
    assert lab03.true_tilt_heading_error(rot.inv().apply(field), truth) == pytest.approx(0.0, abs=1e-9)
    turned = Rotation.from_euler("Z", np.radians(5.0)).apply(field)
    assert np.degrees(lab03.true_tilt_heading_error(rot.inv().apply(turned), truth)) == pytest.approx(5.0, abs=1e-9)


MISTAKES = [  # (function, text of the model answer, mistaken text): each fails on the real magnet, named
    ("mag_calibration", "return centre + scale * h, S", "return centre, S"),  # the mean of the readings as h
    ("mag_calibration", "return centre + scale * h, S", "return h, S"),  # h left in the scaled units
]


@pytest.mark.parametrize("mutate", MISTAKES, ids=[m[2] for m in MISTAKES])
def test_classic_mistakes_fail_the_real_checkpoint_and_say_why(mutate):
    mistaken = solution_namespace("03", mutate)["mag_calibration"]
    result = run_checkpoint(get("03.real_magnet"), mistaken)
    assert not result.ok and result.points == 0, result.message
    assert "is not the magnet's" in result.message and "the magnet off" in result.message, result.message


def test_a_wrong_shape_is_named():
    result = run_checkpoint(get("03.real_magnet"), lambda mag, field_norm: (np.zeros(3), np.eye(2)))
    assert "expected shapes (3,) and (3, 3), got (3,) and (2, 2)" in result.message


def test_real_headings_are_refused_with_what_to_do():
    load = lab03_support.load
    with pytest.raises(ValueError, match="BROAD has no headings protocol; leave it None"):
        load("real", "03_headings")


@pytest.mark.slow
def test_the_lab_runs_on_the_real_imu_and_finds_its_alignment():
    """AXIS_TURNS = MAG_ROTATIONS = "real": every cell runs without an error or a warning; the turns found in
    BROAD's gyro give D = I (one package), and nothing is saved as the student's calibration."""
    nb = nbformat.read(SOLUTION, as_version=4)
    cell = next(c for c in nb.cells if c.cell_type == "code" and "▶ DATA SOURCE" in c.source)
    for name in ("AXIS_TURNS", "MAG_ROTATIONS"):
        assert f"{name} = None" in cell.source
        cell.source = cell.source.replace(f"{name} = None", f'{name} = "real"')
    NotebookClient(
        nb,
        timeout=HANG_GUARD_S,
        startup_timeout=HANG_GUARD_S,
        allow_errors=False,
        kernel_name="python3",  # raises on any error, naming the cell
        resources={"metadata": {"path": str(SOLUTION.parent)}},
    ).execute()
    printed = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert "Warning" not in printed
    assert "D from the turns: [1 1 1] → M_bs(mag) = [1, -1, -1]" in printed
    assert "BROAD's IMU is not your board: its fit is not saved" in printed and "saved to" not in printed
