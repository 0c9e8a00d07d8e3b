"""Lab 02 (bias and noise): what its notebook calls beyond the library.

The data source (:func:`load`: the bundled rest, the real IMU's, or the student's own recording or phyphox export),
the simulation's truth the notebook and its checkpoints compare with (:func:`gyro_bias_truth`, :func:`noise_truth`,
:func:`six_face_truth`, :func:`noise_model_truth`), and the plumbing of its figures and tables (:func:`allan_xyz`,
:func:`phone_export`, :func:`row`).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from .. import datasets, phone_sim, readers, rest_calibration
from ..frames import G, euler_to_dcm, mount_matrix
from ..sensors import board as get_board

NOISE_CHECK_S = 120.0  # s of 02_stationary the noise check uses: the bias wander adds < 0.2 % to σ over it


# --- the data ---------------------------------------------------------------------------------------------------


def load(path, bundled, mount="flat"):
    """The recording the data-source cell names: None → the bundled ``bundled``; "real" → a real IMU at rest
    (``02_broad_rest``, section 8); a path → the student's recording or phyphox export (``mount``: how the phone
    lies), its rests found and labelled when it has no labels (an export)."""
    if path is None:
        return datasets.load(bundled)
    if path == "real":
        return datasets.load("02_broad_rest")
    rec = readers.load_any(path, mount=mount)
    return rec if rec.phases else rest_calibration.label_rests(rec)


def at_rest(rec):
    """The samples of ``rec``'s 'stationary' phase (bool (N,)); all of them when it has none."""
    if any(p["label"] == "stationary" for p in rec.phases):
        return rec.phase("stationary")
    return np.ones(len(rec), dtype=bool)


def datasheet(rec):
    """The gyro's and accelerometer's datasheet specs of ``rec``'s board, (None, None) for an IMU the kit has none
    for (the real Myon of section 8)."""
    try:
        spec = get_board(rec.meta["board"])
    except ValueError:
        return None, None
    return spec.gyro, spec.accel


def allan_xyz(allan_deviation, x, rate_hz, taus):
    """The student's 1-D ``allan_deviation`` on each axis of an (N, 3) signal: (M, 3)."""
    return np.column_stack([allan_deviation(x[:, i], rate_hz, taus) for i in range(3)])


def phone_export(motion, seed, unit=None):
    """A phone through ``motion``, simulated, exported as phyphox does and read back as the student's own export
    would be."""
    with tempfile.TemporaryDirectory() as folder:
        files = phone_sim.simple_experiment_files(phone_sim.simulate_phone(motion, seed=seed, unit=unit))
        return readers.load_phyphox(phone_sim.write_export(files, Path(folder) / "phone"))


def row(quantity, measured, true=None, datasheet=""):
    """Print one line of the wrap-up table: three axes measured, the simulation's truth (if known), the datasheet."""
    cells = " ".join(f"{v:8.3g}" for v in measured)
    truth = " ".join(f"{v:8.3g}" for v in true) if true is not None else "—".center(26)
    print(f"{quantity:30s} {cells}   {truth}   {datasheet}")


# --- the simulation's truth --------------------------------------------------------------------------------------


def gyro_bias_truth(rec):
    """The simulation's gyro bias in the body frame (rad/s) and the standard uncertainty of a mean
    over the recording: √(σ²/N + K²T/3), white noise σ plus a bias random walk of density K."""
    sim = rec.meta["sim"]
    truth = mount_matrix(rec.meta["mount"]["gyr"]) @ np.asarray(sim["gyro_bias"])
    sigma = rec.body("gyr").std(axis=0, ddof=1)
    T = len(rec) / rec.rate_hz
    return truth, np.sqrt(sigma**2 / len(rec) + sim.get("gyro_bias_rw", 0.0) ** 2 * T / 3)


def noise_truth(rec, sensor):
    """The per-sample white-noise σ (3,) the simulator gave ``sensor`` ('gyr' or 'acc') at the recording's
    rate — datasheet density · √rate, with rounding to counts adding LSB²/12 — and the standard uncertainty
    of a sample standard deviation over the first :data:`NOISE_CHECK_S` seconds, σ/√(2(n − 1))."""
    spec = getattr(get_board(rec.meta["board"]), {"gyr": "gyro", "acc": "accel"}[sensor])
    lsb = rec.meta["sensors"][sensor]["sensitivity"]
    sigma = np.full(3, np.sqrt(spec.noise_std(rec.rate_hz) ** 2 + lsb**2 / 12))
    n = int(min(len(rec), NOISE_CHECK_S * rec.rate_hz))
    return sigma, sigma / np.sqrt(2 * (n - 1)), n


def noise_model_truth(rec):
    """The gyro's white-noise density N (rad/√s: the datasheet's, with the rounding to counts, LSB²/12 per sample,
    as a density) and rate random walk K (rad/s/√s) the simulation of ``rec`` was made with: what the Allan fit
    reads."""
    sigma, _, _ = noise_truth(rec, "gyr")
    return float(sigma[0]) / np.sqrt(rec.rate_hz), float(rec.meta["sim"]["gyro_bias_rw"])


def six_face_truth(rec):
    """The simulation's accelerometer bias (body, m/s²) and scale, as the six-face estimator sees them,
    with their standard uncertainties: (bias, scale, u_bias, u_scale).

    Axis i reads s_i·f_i + b_i, so with f̄⁺, f̄⁻ the mean true specific force of its up and down faces the
    estimator targets b_i + s_i (f̄⁺_i + f̄⁻_i)/2 and s_i (f̄⁺_i − f̄⁻_i)/(2g): the true b and s, moved by the
    known tilt of the simulated table (second order, well under 0.1 mg here). The uncertainty is statistical:
    white noise σ/√(2n) over the two faces, plus the bias random walk K√(T/3) over the recording.
    """
    sim = rec.meta["sim"]
    M = mount_matrix(rec.meta["mount"]["acc"])
    bias = M @ np.asarray(sim["accel_bias"])
    scale = np.abs(M) @ np.asarray(sim.get("accel_scale", [1.0, 1.0, 1.0]))
    R_bn = np.swapaxes(euler_to_dcm(rec.truth()), -1, -2)
    f_true = R_bn @ np.array([0.0, 0.0, -G])
    up, down = (
        np.array([f_true[rec.phase(f"{a}_{w}"), i].mean() for i, a in enumerate("xyz")]) for w in ("up", "down")
    )
    acc = rec.body("acc")
    n = min(int(rec.phase(f).sum()) for f in rest_calibration.FACES)
    sigma = np.mean([acc[rec.phase(f)].std(axis=0, ddof=1) for f in rest_calibration.FACES], axis=0)
    T = len(rec) / rec.rate_hz
    walk = sim.get("accel_bias_rw", 0.0) * np.sqrt(T / 3)
    u_bias = np.sqrt(sigma**2 / (2 * n) + walk**2)
    return bias + scale * (up + down) / 2, scale * (up - down) / (2 * G), u_bias, u_bias / G
