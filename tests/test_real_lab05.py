"""Lab 05 on the real recording (issue 17): the helpers it uses, the claims section 12 makes (checked with kfkit's
own TiltBiasKF, an implementation independent of the notebook's loop), the notebook's section-12 functions against
that oracle, and the whole notebook run with SOURCE = "real"."""
from dataclasses import replace

import numpy as np
import pytest

from kfkit import datasets, filters, metrics
from kfkit.checkpoints import lab05
from kfkit.frames import G, accel_tilt, wrap_angle
from kfkit.io import Recording
from kfkit.paths import KIT_ROOT
from kfkit.real_data import PASS_HZ, STOP_HZ
from test_checkpoints_every import solution_namespace
from waiting import HANG_GUARD_S


@pytest.fixture(scope="module")
def real():
    return datasets.load(lab05.REAL)


def in_windows(rec, windows):
    mask = np.zeros(len(rec), dtype=bool)
    for a, b in windows:
        mask |= (rec.t >= a) & (rec.t < b)
    return mask


def test_rest_windows_hold_only_the_gyro_noise(real):
    """Each trimmed rest is still: the gyro's spread is its noise, which the native rest of lab 02 gives, scaled to
    the band the 100 Hz anti-alias filter keeps (σ·√(f_c / f_Nyquist), f_c between its pass and stop edges); 1.5×
    leaves room for noise that is not white. BROAD's own rests, untrimmed, spread 3–7 times more."""
    native = datasets.load("02_broad_rest")
    kept = np.sqrt(0.5 * (PASS_HZ + STOP_HZ) / (0.5 * native.rate_hz))
    bar = 1.5 * np.std(native.body("gyr"), axis=0) * kept
    windows = lab05.rest_windows(real)
    assert len(windows) == 5  # trial 04: the first rest, three breaks, the last rest
    moving = real.phase("movement")
    for a, b in windows:
        m = in_windows(real, [(a, b)])
        assert not (m & moving).any()
        assert (np.std(real.body("gyr")[m], axis=0) < bar).all(), (a, b)
    untrimmed = in_windows(real, lab05.rest_windows(real, trim=0.0))
    assert (np.std(real.body("gyr")[untrimmed], axis=0) > bar).any()  # the trim is what makes them still


def test_known_angles_of_the_protocol_are_its_holds():
    tilt = datasets.load("05_tilt_protocol")
    for got, want in zip(lab05.known_angles(tilt), filters.protocol_angles(tilt)):
        np.testing.assert_array_equal(got, want)


def test_known_angles_of_a_real_recording_are_the_motion_capture_in_its_rests(real):
    roll, pitch = lab05.known_angles(real)
    rests = in_windows(real, lab05.rest_windows(real))
    np.testing.assert_array_equal(np.isnan(roll), ~rests | np.isnan(real["true_roll"]))
    np.testing.assert_array_equal(roll[rests], real["true_roll"][rests])
    np.testing.assert_array_equal(pitch[rests], real["true_pitch"][rests])
    # an independent oracle: at rest the accelerometer's tilt is the same angle, within its calibration and the
    # markers' alignment (a degree is a generous bound for a calibrated IMU: 1° of tilt is 17 mg)
    acc_roll, acc_pitch = accel_tilt(real.body("acc"))
    assert abs(np.degrees(np.nanmean(acc_roll - roll))) < 1.0
    assert abs(np.degrees(np.nanmean(acc_pitch - pitch))) < 1.0


def test_known_angles_without_protocol_or_truth_say_what_is_missing():
    still = datasets.load("05_stationary")
    rec = Recording(dict(still.meta, phases=[{"label": "rest", "start": 0.0, "end": 5.0}]),
                    {k: v for k, v in still.data.items() if not k.startswith("true_")})
    with pytest.raises(KeyError, match="no tilt-protocol phases"):
        lab05.known_angles(rec)


def coupled_run(w, z, ok, left_out, dt, q0, r):
    """kfkit's TiltBiasKF step by step with q_θ = q0 + (left_out·dt)² and the accelerometer angle taken nearest the
    prediction: section 12's filter, written independently of the notebook. Returns [angle, bias] (N, 2)."""
    kf = filters.TiltBiasKF(dt, q_angle=q0, q_bias=1e-4 * q0, r=r, accel_gating="skip")
    kf.reset((z[0], 0.0), np.diag([r, 0.1 ** 2]))
    out = np.empty((len(z), 2))
    for k in range(len(z)):
        kf.settings = replace(kf.settings, q_angle=q0 + (left_out[k] * dt) ** 2)
        angle, bias = kf.state.x
        predicted = angle + (w[k] - bias) * dt
        out[k] = kf.step(w[k], predicted + wrap_angle(z[k] - predicted), ok[k]).x
    return out


def left_out_oracle(w, roll, pitch):
    """φ̇ − p and θ̇ − q written out (ZYX Euler kinematics), |θ| ≤ 60° in tan θ."""
    tan_pitch = np.tan(np.clip(pitch, -np.radians(60), np.radians(60)))
    return (tan_pitch * (w[:, 1] * np.sin(roll) + w[:, 2] * np.cos(roll)),
            w[:, 1] * (np.cos(roll) - 1.0) - w[:, 2] * np.sin(roll))


@pytest.fixture(scope="module")
def section12(real):
    """Section 12's inputs (the lab's recipe measured on the first rest) and both filters per axis, run by kfkit."""
    f, w, dt = real.body("acc"), real.body("gyr"), 1.0 / real.rate_hz
    first = in_windows(real, lab05.rest_windows(real)[:1])
    roll, pitch = accel_tilt(f)
    r = float(np.mean([np.var(a) for a in accel_tilt(f[first])]))
    q0 = float(np.mean(np.var(w[first, :2], axis=0))) * dt ** 2
    ok = filters.accel_static_ok(f)
    gates = (ok & (np.hypot(f[:, 1], f[:, 2]) >= 0.5 * G), ok)
    left_out = left_out_oracle(w - np.mean(w[first], axis=0), roll, pitch)
    runs = {}
    for i, (name, z) in enumerate((("roll", roll), ("pitch", pitch))):
        constant = filters.TiltBiasKF(dt, q_angle=q0, q_bias=1e-4 * q0, r=r, accel_gating="skip", x0=(z[0], 0.0),
                                      P0=np.diag([r, 0.1 ** 2])).run(w[:, i], z, gates[i])
        runs[name] = (constant.x, coupled_run(w[:, i], z, gates[i], left_out[i], dt, q0, r), z)
    return runs


def moving_rmse_deg(real, est, col):
    truth = real.truth()
    m = real.phase("movement") & ((np.abs(truth[:, 1]) < np.radians(60)) if col == 0 else True)
    return np.degrees(metrics.rmse(metrics.angle_error(est[m], truth[m, col]), 0.0))


def test_section12_the_gyro_noise_recipe_fails_on_motion_about_all_axes(real, section12):
    """The lab's recipe (q from the gyro noise alone) lets its bias state run off by degrees per second (the gyro's
    bias is 0.1 °/s) and its angles by tens of degrees while the board turns about all axes."""
    last = in_windows(real, lab05.rest_windows(real)[-1:])
    for col, name in enumerate(("roll", "pitch")):
        constant, _, _ = section12[name]
        assert abs(np.degrees(constant[-1, 1] - np.mean(real.body("gyr")[last, col]))) > 1.0, name
        assert moving_rmse_deg(real, constant[:, 0], col) > 20.0, name


def test_section12_covering_the_coupling_keeps_the_bias_at_the_rests(real, section12):
    """With q_θ covering the left-out rates, the bias state at the end of every rest lies within the rests' walk
    (the span of their means, which q_b = 10⁻⁴ q0 is too stiff to follow) plus 3 standard errors of that rest's
    mean (from its 1-s means) of the rest's own mean; the angles while moving come near the accelerometer's error
    (within 1.5×), not tens of degrees off."""
    gyr = real.body("gyr")
    windows = lab05.rest_windows(real)
    for col, name in enumerate(("roll", "pitch")):
        _, coupled, z = section12[name]
        means, errors = [], []
        for a, b in windows:
            rest = gyr[in_windows(real, [(a, b)]), col]
            seconds = rest[: len(rest) // 100 * 100].reshape(-1, 100).mean(axis=1)
            means.append(rest.mean())
            errors.append(np.std(seconds, ddof=1) / np.sqrt(len(seconds)))
        walk = np.ptp(means)
        for (a, b), mean, error in zip(windows, means, errors):
            end = np.flatnonzero(real.t < b)[-1]
            assert abs(coupled[end, 1] - mean) < walk + 3 * error, (name, a, b)
        accel_alone = moving_rmse_deg(real, z, col)
        assert moving_rmse_deg(real, coupled[:, 0], col) < 1.5 * accel_alone, name


def test_notebook_section12_functions_match_the_oracle(real, section12):
    """The notebook's left_out_rates (through frames.body_rates_to_euler_rates) and run_kf_moving (through the student's
    kf_predict/kf_update, here the model answers) agree with this file's independent versions."""
    ns = solution_namespace("05")
    f, w, dt = real.body("acc"), real.body("gyr"), 1.0 / real.rate_hz
    roll, pitch = accel_tilt(f)
    for got, want in zip(ns["left_out_rates"](w, roll, pitch), left_out_oracle(w, roll, pitch)):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    window = slice(3000, 7000)  # the first rest's end and the first movement: a Python loop, so not all of it
    first = in_windows(real, lab05.rest_windows(real)[:1])
    r = float(np.mean([np.var(a) for a in accel_tilt(f[first])]))
    q0 = float(np.mean(np.var(w[first, :2], axis=0))) * dt ** 2
    ok = filters.accel_static_ok(f)
    left = left_out_oracle(w - np.mean(w[first], axis=0), roll, pitch)[0]
    args = (w[window, 0], roll[window], ok[window], left[window], dt, q0, r)
    got = ns["run_kf_moving"](*args, [roll[window][0], 0.0], np.diag([r, 0.1 ** 2]))
    np.testing.assert_allclose(got, coupled_run(*args), rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_lab05_runs_on_the_real_recording():
    """SOURCE = "real": every cell of the solution runs on the BROAD recording (no six faces, no protocol holds,
    not an MPU6050), without errors or warnings, and the checkpoints still pass."""
    nbformat = pytest.importorskip("nbformat")
    from nbclient import NotebookClient

    path = KIT_ROOT / "solutions" / "05_tilt_bias_kf.ipynb"
    nb = nbformat.read(path, as_version=4)
    source = next(c for c in nb.cells if c.cell_type == "code" and c.source.startswith('SOURCE = "bundled"'))
    source.source = source.source.replace('SOURCE = "bundled"', 'SOURCE = "real"', 1)
    NotebookClient(nb, timeout=HANG_GUARD_S, startup_timeout=HANG_GUARD_S, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    printed = ""
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            assert not (out.output_type == "stream" and out.name == "stderr"), out.text[:300]
            printed += out.get("text", "")
    assert "BROAD trial 04" in printed and "❌" not in printed and "✅ 05.final" in printed
