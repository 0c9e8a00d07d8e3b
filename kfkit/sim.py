"""The IMU simulator: :func:`simulate_imu` turns a truth motion into the sensor counts a board would send.

A :class:`kfkit.motions.Motion` is the truth: Euler angles, body angular rate and the linear
acceleration of the board in NED. :func:`simulate_imu` produces what a board would send:

    gyro   ω_s = M_bsᵀ ω_b + b_g(t) + n_g
    accel  f_s = M_bsᵀ R_bn (a_n − g_n) + b_a(t) + n_a,      g_n = [0, 0, g]
    mag    m_s = M_bsᵀ R_bn m_n + n_m

with constant bias plus a bias random walk b(t), white noise of density N (σ = N·√rate),
quantisation to the LSB and saturation at full scale. Every random draw is seeded.

The motions are in :mod:`kfkit.motions` (rest, lab 01's roll, lab 05's tilt protocol, smooth moves),
:mod:`kfkit.attitude_motions` (lab 04) and :mod:`kfkit.calibration_motions` (labs 02 and 03); the four the lab
notebooks call as ``sim.…`` are importable from here too.
"""

from __future__ import annotations

import numpy as np

from .attitude_motions import attitude_tour  # noqa: F401 (lab 04's notebook calls sim.attitude_tour)
from .calibration_motions import six_faces  # noqa: F401 (lab 02's notebook calls sim.six_faces)
from .frames import MAG_FIELD_LONDON, G, euler_to_dcm, mount_matrix
from .io import Recording
from .motions import Motion, euler_moves, stationary  # noqa: F401 (labs 02, 04 call sim.stationary, sim.euler_moves)
from .sensors import SensorSpec
from .sensors import board as get_board


def _sensor_signal(rng, truth_s, spec: SensorSpec, rate_hz, bias, bias_rw):
    """truth (sensor frame, SI) + bias + bias random walk + white noise → counts."""
    n = len(truth_s)
    walk = np.cumsum(rng.normal(0.0, bias_rw / np.sqrt(rate_hz), (n, 3)), axis=0)
    noise = rng.normal(0.0, spec.noise_std(rate_hz), (n, 3))
    return spec.to_counts(truth_s + bias + walk + noise)


def simulate_imu(
    motion: Motion,
    board="nucleo-iks02a1",
    seed=0,
    *,
    gyro_bias=None,
    accel_bias=None,
    gyro_bias_rw=1e-4,
    accel_bias_rw=1e-4,
    field_n=MAG_FIELD_LONDON,
    mag_rate_hz=None,
    mag_disturbance=None,
    accel_scale=None,
    gyro_scale=None,
    mag_hard_iron=None,
    mag_soft_iron=None,
) -> Recording:
    """Simulate the board's IMU over ``motion`` and return a recording in counts.

    gyro_bias, accel_bias  constant biases (3,) in the sensor frame, SI; by default drawn
                           from N(0, (typical/2)²) per axis with the datasheet's typical offset;
                           or one per sample (N, 3): a bias path the caller carries from call to
                           call (the virtual board's), with *_bias_rw = 0
    *_bias_rw              bias random-walk densities (rad/s/√s, m/s²/√s); each call starts its walk
                           at 0. The defaults are large for the boards' gyros (the bundled labs 02–04
                           unit's walks at 4.4e-6): kept, since bundled recordings are made with them
    field_n                local magnetic field in NED, µT
    mag_rate_hz            magnetometer output rate; rows without a new sample are left
                           empty (NaN). Defaults to the board's.
    mag_disturbance        extra field (N, 3) in NED, µT, added to field_n sample by sample
                           (see :func:`mag_disturbance`); None adds nothing

    Imperfections a calibration removes (sensor frame; the defaults add nothing and draw no
    random numbers; given values are recorded in ``meta["sim"]``):
    accel_scale, gyro_scale  per-axis scale factors k (3,): x_s = k ⊙ x_true,s + b + …
    mag_hard_iron            hard iron h (3,), µT:  m_s = W m_true,s + h + n
    mag_soft_iron            soft iron W (3, 3)
    """
    b = get_board(board) if isinstance(board, str) else board
    rng = np.random.default_rng(seed)
    rate = float(motion.rate_hz)
    R_bn = np.swapaxes(euler_to_dcm(motion.euler), -1, -2)
    g_n = np.array([0.0, 0.0, G])
    f_b = np.einsum("nij,nj->ni", R_bn, motion.acc_n - g_n)

    def to_sensor(x_b, key):  # x_s = M_bsᵀ x_b, row-wise
        return x_b @ mount_matrix(b.mount[key])

    if gyro_bias is None:
        gyro_bias = rng.normal(0.0, b.gyro.bias_typical / 2, 3)
    if accel_bias is None:
        accel_bias = rng.normal(0.0, b.accel.bias_typical / 2, 3)
    imperfections = {}

    def scaled(x_s, scale, key):  # k ⊙ x_s, only when a scale error is asked for
        if scale is None:
            return x_s
        imperfections[key] = np.asarray(scale, float).tolist()
        return x_s * np.asarray(scale, float)

    gyr = _sensor_signal(
        rng, scaled(to_sensor(motion.omega_b, "gyr"), gyro_scale, "gyro_scale"), b.gyro, rate, gyro_bias, gyro_bias_rw
    )
    acc = _sensor_signal(
        rng, scaled(to_sensor(f_b, "acc"), accel_scale, "accel_scale"), b.accel, rate, accel_bias, accel_bias_rw
    )

    n = len(motion.t)
    data = {"t": motion.t.astype(float), "seq": np.arange(n, dtype=np.int64) % 65536}
    for key, counts in (("a", acc), ("g", gyr)):
        for i, axis in enumerate("xyz"):
            data[key + axis] = counts[:, i]
    sensors = {"acc": b.accel.metadata(), "gyr": b.gyro.metadata()}
    if b.mag is not None:
        m_b = np.einsum("nij,j->ni", R_bn, np.asarray(field_n, dtype=float))
        if mag_disturbance is not None:
            disturbance = np.asarray(mag_disturbance, dtype=float)
            if disturbance.shape != m_b.shape:
                raise ValueError(
                    f"mag_disturbance must be one NED vector per sample, shape {m_b.shape}; got {disturbance.shape}"
                )
            m_b = m_b + np.einsum("nij,nj->ni", R_bn, disturbance)
        m_s = to_sensor(m_b, "mag")
        if mag_soft_iron is not None:
            imperfections["mag_soft_iron"] = np.asarray(mag_soft_iron, float).tolist()
            m_s = m_s @ np.asarray(mag_soft_iron, float).T
        hard = 0.0
        if mag_hard_iron is not None:
            imperfections["mag_hard_iron"] = np.asarray(mag_hard_iron, float).tolist()
            hard = np.asarray(mag_hard_iron, float)
        mag = _sensor_signal(rng, m_s, b.mag, rate, hard, 0.0).astype(float)
        mag_rate = mag_rate_hz or b.mag_rate_hz or rate
        tick = np.floor(motion.t * mag_rate + 1e-9)
        fresh = np.concatenate([[True], np.diff(tick) > 0])
        mag[~fresh] = np.nan
        for i, axis in enumerate("xyz"):
            data["m" + axis] = mag[:, i]
        sensors["mag"] = b.mag.metadata()
    for i, name in enumerate(("true_roll", "true_pitch", "true_yaw")):
        data[name] = motion.euler[:, i]
    meta = {
        "board": b.name,
        "rate_hz": rate,
        "source": "simulated",
        "description": motion.description,
        "seed": seed,
        "units": {"t": "s", "sensors": "counts (see sensors.*.sensitivity)", "true_*": "rad"},
        "sensors": sensors,
        "mount": {k: v for k, v in b.mount.items() if k in sensors},
        "sim": {
            "gyro_bias": np.asarray(gyro_bias, float).tolist(),
            "accel_bias": np.asarray(accel_bias, float).tolist(),
            "field_n": list(map(float, field_n)),
            **imperfections,
        },
    }
    if motion.phases:
        meta["phases"] = [{"label": label, "start": float(t0), "end": float(t1)} for t0, t1, label in motion.phases]
    return Recording(meta, data)
