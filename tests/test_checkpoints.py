"""Checkpoints pass the reference, fail wrong answers with a useful line, and never crash."""
import numpy as np
import pytest

from kfkit import filters
from kfkit.checkpoints import REGISTRY, check, compare, get, run_checkpoint


def reference_run_kf(gyro_rate, roll_acc, dt, q, r, x0, P0):
    run = filters.roll_kf(gyro_rate, roll_acc, dt, q, r, x0, P0)
    return run.x, run.P, run.y, run.S


RIGHT = {
    "01.accel_roll": lambda ay, az: np.arctan2(-ay, -az),
    "01.kf_predict": filters.roll_kf_predict,
    "01.kf_update": filters.roll_kf_update,
    "01.run_kf": reference_run_kf,
    "01.kf_beats_sensors": reference_run_kf,
}


def test_every_registered_lab01_checkpoint_has_a_right_answer_here():
    get("01.accel_roll")  # loads the registries
    assert {n for n in REGISTRY if n.startswith("01.")} == set(RIGHT)


@pytest.mark.parametrize("name", sorted(RIGHT))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_reference_answers_pass(name, seed):
    result = run_checkpoint(get(name), RIGHT[name], seed)
    assert result.ok, result.message
    assert result.message.startswith(f"✅ {name}: {result.total}/{result.total}")
    assert result.points == result.max_points > 0


def test_atan2_off_by_pi_is_named():
    result = run_checkpoint(get("01.accel_roll"), lambda ay, az: np.arctan2(ay, az), seed=0)
    assert result.status == "failed" and "180° off" in result.message and "Hint:" in result.message
    assert result.points == 0


def test_predict_that_forgets_q_fails_with_expected_and_got():
    result = run_checkpoint(get("01.kf_predict"), lambda x, P, omega, dt, q: (x + omega * dt, P), seed=0)
    assert result.status == "failed"
    assert "value 2 of 2: expected" in result.message and ", got " in result.message and "kf_predict(x=" in result.message


def test_update_returning_two_values_is_explained():
    result = run_checkpoint(get("01.kf_update"), lambda x, P, z, r: (x, P), seed=0)
    assert "expected 4 values" in result.message


def test_run_kf_that_skips_updates_fails_the_bundled_recording():
    def gyro_only(gyro_rate, roll_acc, dt, q, r, x0, P0):
        x = filters.integrate_rate(gyro_rate, dt, x0)
        return x, np.zeros_like(x), np.zeros_like(x), np.zeros_like(x)

    result = run_checkpoint(get("01.kf_beats_sensors"), gyro_only)
    assert result.status == "failed" and "is not below" in result.message


def test_not_attempted(capsys):
    def stub(**kwargs):
        raise NotImplementedError()

    result = check("01.kf_update", stub)
    assert result.status == "not attempted" and result.points == 0
    assert "not attempted yet" in capsys.readouterr().out


def test_student_exception_is_reported_not_raised():
    result = run_checkpoint(get("01.kf_predict"), lambda x, P, omega, dt, q: 1 / 0, seed=0)
    assert result.status == "error" and "ZeroDivisionError" in result.message


def test_unknown_checkpoint_lists_known_ones():
    with pytest.raises(KeyError, match="01.kf_predict"):
        get("01.nope")


def test_compare_structure_and_tolerance():
    assert compare((1.0, np.array([1.0, 2.0])), (1.0 + 1e-12, [1.0, 2.0])) is None
    assert compare(np.zeros(3), np.zeros(4)) == "shape mismatch: expected shape (3,), got shape (4,)"
    assert compare(1.0, "one").startswith("expected a number")
    assert compare(1.0, 1.1) is not None
