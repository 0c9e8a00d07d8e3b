"""What every lab 04 attitude filter takes, starts from and returns.

check_inputs   gyr (rad/s), acc (m/s²), mag (µT, NaN rows = no new sample), (N, 3) each, checked
first_mag_row  the first magnetometer row that is a sample
hold_last_sample  the magnetometer with each NaN row holding the last sample (for filters that want every row)
tilt_heading   the first attitude [φ, θ, ψ] from one accelerometer and magnetometer sample
learn_field    the reference field m_n from the first magnetometer samples
AttitudeRun    the :class:`FilterRun` of an attitude filter, with quat, euler, bias and the attitude covariance
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..frames import (
    MAG_FIELD_LONDON,
    G,
    accel_tilt,
    declination,
    euler_to_dcm,
    euler_to_quat,
    quat_to_euler,
    tilt_compensated_heading,
)
from .contract import FilterRun


@dataclass
class AttitudeRun(FilterRun):
    """An attitude filter's history over a recording, one row per sample (a :class:`FilterRun`).

    x, x_prior  (N, 3) [φ, θ, ψ] (rad) for ``euler-ekf``; (N, 7) [q (w-x-y-z, body → NED, w ≥ 0), gyro
                bias (rad/s)] for ``mekf``
    P, P_prior  the filter's error covariance, as its ``step`` gives it: (N, 3, 3) of [φ, θ, ψ], rad², for
                ``euler-ekf``; (N, 6, 6) of the error state [δθ (small rotation in NED, rad), δb (rad/s)] for
                ``mekf``. :attr:`P_attitude` is the 3×3 attitude block of both, for NEES and σ plots
    y         (N, 6) innovations z − h(x⁻), NaN where not used: for euler-ekf accel (m/s²) in 0–2 and mag
              (µT) in 3–5; for mekf the accelerometer's north and east (m/s²) in 0–1, the heading (rad) in 2
              and the zero-rate update's gyro x, y, z (rad/s) in 3–5
    S         (N, 6, 6) their covariances (NaN where not used)
    nis       (N,) normalised innovation squared yᵀ S⁻¹ y over the rows used
    accel_gated (N,) True where the accelerometer rows were inflated: |‖f‖ − g| > accel_gate (euler-ekf), or
              linear acceleration that at least doubled the accelerometer's variance (mekf)
    mag_used  (N,) True where a magnetometer update was made
    mag_gated (N,) True where a magnetometer sample was not used: a disturbed field or a heading
              outlier (mekf; all False for euler-ekf)
    at_rest   (N,) True where the rest detector found the IMU still (mekf: zero-rate updates); None for euler-ekf
    method    "euler-ekf" or "mekf"
    """

    nis: np.ndarray = None
    accel_gated: np.ndarray = None
    mag_used: np.ndarray = None
    mag_gated: np.ndarray = None
    at_rest: np.ndarray = None
    method: str = "euler-ekf"

    @cached_property
    def quat(self) -> np.ndarray:
        """(N, 4) attitude quaternion w-x-y-z, body (sensor) → NED, w ≥ 0."""
        return self.x[:, :4] if self.method == "mekf" else euler_to_quat(self.x)

    @cached_property
    def euler(self) -> np.ndarray:
        """(N, 3) [roll, pitch, yaw], rad."""
        return quat_to_euler(self.quat) if self.method == "mekf" else self.x

    @property
    def bias(self) -> np.ndarray:
        """(N, 3) gyro bias estimate, rad/s (mekf; zeros for euler-ekf, which has no bias state)."""
        return self.x[:, 4:] if self.method == "mekf" else np.zeros((len(self.x), 3))

    @cached_property
    def P_attitude(self) -> np.ndarray:
        """(N, 3, 3) covariance of the attitude error, rad²: of [φ, θ, ψ] for ``euler-ekf``; of the small rotation
        error δθ in the NED frame (R_true = Exp(δθ) R_est; δθ_D is the heading error) for ``mekf``, the attitude
        block of its 6×6 P."""
        return self.P[:, :3, :3]

    @property
    def dof(self) -> np.ndarray:
        """Innovation entries used per sample (the χ² degrees of freedom of ``nis``):
        3 or 6 for euler-ekf; for mekf 2 (accelerometer), + 1 (heading), + 3 (zero-rate update at rest)."""
        return np.sum(~np.isnan(self.y), axis=1)


def check_inputs(gyr, acc, mag):
    """Validate (N, 3) float arrays in SI units; returns them as float arrays (mag may be None)."""
    arrays = {}
    for name, arr, unit in (("gyr", gyr, "rad/s"), ("acc", acc, "m/s²"), ("mag", mag, "µT")):
        if arr is None:
            if name != "mag":
                raise ValueError(f"{name} is required ({unit}, shape (N, 3))")
            arrays[name] = None
            continue
        a = np.asarray(arr, dtype=float)
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name} must have shape (N, 3) in {unit}, got {a.shape}")
        arrays[name] = a
    gyr, acc, mag = arrays["gyr"], arrays["acc"], arrays["mag"]
    n = len(gyr)
    if n == 0:
        raise ValueError("gyr holds no samples")
    for name, a in (("acc", acc), ("mag", mag)):
        if a is not None and len(a) != n:
            raise ValueError(f"{name} has {len(a)} rows but gyr has {n}: the sensors must share one sample clock")
    for name, a in (("gyr", gyr), ("acc", acc)):
        bad = np.flatnonzero(~np.isfinite(a).all(axis=1))
        if bad.size:
            raise ValueError(
                f"{name} row {bad[0]} is not finite ({a[bad[0]].tolist()}); only mag may have NaN rows "
                f"(no new sample) — interpolate or drop gaps in {name}"
            )
    acc_norm = float(np.median(np.linalg.norm(acc, axis=1)))
    if acc_norm < 3.0:
        raise ValueError(
            f"acc looks like it is in g, not m/s²: median ‖f‖ = {acc_norm:.3g} (expected ≈ {G}); multiply by {G}"
        )
    if acc_norm > 50.0:
        raise ValueError(
            f"acc median ‖f‖ = {acc_norm:.3g} m/s² is far from g = {G}: are the units m/s² (not counts or mg)?"
        )
    if np.abs(gyr).max() > 40.0:
        raise ValueError(
            f"gyr reaches {np.abs(gyr).max():.3g}: that is more than 2000 °/s in rad/s — is it in °/s? "
            f"multiply by π/180"
        )
    if mag is not None:
        if np.isnan(mag).all():
            mag = None
        else:
            partial = np.flatnonzero(np.isnan(mag).any(axis=1) & ~np.isnan(mag).all(axis=1))
            if partial.size:
                raise ValueError(
                    f"mag row {partial[0]} is partly NaN ({mag[partial[0]].tolist()}): a row is either a whole "
                    f"sample or all NaN (no new sample)"
                )
            mag_norm = float(np.nanmedian(np.linalg.norm(mag, axis=1)))
            if not 5.0 < mag_norm < 200.0:
                hint = (
                    " (gauss? multiply by 100)"
                    if 0.05 < mag_norm < 2
                    else " (tesla? multiply by 1e6)"
                    if mag_norm < 1e-3
                    else ""
                )
                raise ValueError(f"mag median ‖m‖ = {mag_norm:.3g} is not a geomagnetic field in µT (25–65 µT){hint}")
    return gyr, acc, mag


def first_mag_row(mag):
    """Index of the first magnetometer row that is a sample (not NaN), or None."""
    if mag is None:
        return None
    rows = np.flatnonzero(~np.isnan(mag).any(axis=1))
    return int(rows[0]) if rows.size else None


def hold_last_sample(mag):
    """mag (N, 3) µT with each NaN row (no new sample) replaced by the last sample before it, for filters that want
    a value every row (VQF, ahrs, imufusion); rows before the first sample stay NaN."""
    mag = np.asarray(mag, dtype=float)
    fresh = ~np.isnan(mag).any(axis=1)
    return mag[np.maximum.accumulate(np.where(fresh, np.arange(len(mag)), 0))]


def tilt_heading(acc, mag, field_n=MAG_FIELD_LONDON):
    """Initial [φ, θ, ψ] (rad) from one accelerometer (m/s²) and magnetometer (µT) sample.

    Tilt from the specific force, heading ψ = atan2(−m_y', m_x') + atan2(m_E, m_N) from the
    tilt-compensated field m' = Ry(θ) Rx(φ) m_b, rotated by the reference field's declination so
    that ψ is measured in the same NED frame as ``field_n``. ``mag`` None or NaN → ψ = 0.
    """
    roll, pitch = accel_tilt(acc)
    if mag is None or np.isnan(mag).any():
        return np.array([roll, pitch, 0.0])
    return np.array([roll, pitch, tilt_compensated_heading(mag, roll, pitch, declination(field_n))])


def learn_field(acc, mag, samples=50):
    """A reference field m_n = [H, 0, Z] (µT, magnetic NED: north is magnetic north) learned from
    the first ``samples`` magnetometer rows: each is tilt-compensated with its accelerometer tilt,
    and the horizontal magnitude H and vertical Z are averaged."""
    acc = np.asarray(acc, dtype=float)
    mag = np.asarray(mag, dtype=float)
    rows = np.flatnonzero(~np.isnan(mag).any(axis=1))[:samples]
    if rows.size == 0:
        raise ValueError("learn_field: the magnetometer has no sample (all rows NaN)")
    roll, pitch = accel_tilt(acc[rows])
    R_nb = euler_to_dcm(np.stack([roll, pitch, np.zeros_like(roll)], axis=-1))
    m_level = np.einsum("nij,nj->ni", R_nb, mag[rows])
    return np.array([np.hypot(m_level[:, 0], m_level[:, 1]).mean(), 0.0, m_level[:, 2].mean()])
