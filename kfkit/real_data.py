"""The bundled real recordings: excerpts of BROAD and of a race-track log, converted from the originals.

Every other file in ``data/`` is a seeded simulation (:mod:`kfkit.datasets`). These are real sensors:

- BROAD (Laidig, Caruso, Cereatti, Seel, "BROAD — a benchmark for robust inertial orientation
  estimation", Data 6(7), 2021, doi:10.3390/data6070072; CC BY 4.0): a Myon aktos-t IMU at 285.7 Hz
  with optical motion capture as the truth. Each excerpt becomes a kit recording (``# kfkit-recording
  v1``) with ``true_roll/pitch/yaw`` from the motion capture (empty where the markers were not seen).
- The first half of a Stanford race-track log published with the sideslip estimators of Leanza, Reina
  and Blanco-Claraco (MIT licence): a ``# kfkit-vehicle v1`` file with the measured sideslip as
  ``true_beta``.

:func:`convert` rebuilds them from the originals (``$KFKIT_SHARED_DATA``, default ``../shared/data``
beside the kit) and, with ``check``, reports any bundled file that differs from what the conversion makes
now (``python -m kfkit data real --check``), like ``kfkit data regenerate --check`` for the simulations.

What the conversion changes, and why:

- **Frame.** The IMU's own frame has z up (flat, it reads +g). The kit's body frame is forward-right-down,
  so every sensor gets the mounting matrix M_bs = diag(1, −1, −1) (180° about x) and the truth is
  R_nb = R_ns·M_bsᵀ: flat and still reads roll = pitch = 0 like every other kit recording.
- **Counts.** The kit's format stores integer counts and a sensitivity: 1e-5 rad/s, 1e-4 m/s² and
  1e-3 µT per count, 100, 39 and 74 times finer than the sensor's own steps (1.06e-3 rad/s,
  3.9e-3 m/s², 0.074 µT), so the rounding adds at most 0.5 % of a sensor step.
- **Rate.** Most labs run at 100 Hz. ``rate_hz=100`` resamples by 7/20 with :func:`scipy.signal.resample_poly`
  and the kit's own anti-alias filter (:func:`antialias_fir`: a linear-phase Kaiser FIR, pass band to
  40 Hz within 0.2 %, at least 60 dB down from the new Nyquist frequency 50 Hz, so nothing above 50 Hz
  folds back into the band the labs look at; zero delay). The truth quaternion is interpolated
  (slerp between the two neighbouring motion-capture samples, none across a gap), not filtered.
  Lab 02's rest keeps the native 285.7 Hz: its noise is what it measures.
- **Phases.** BROAD's ``movement`` flag becomes the phases ``rest`` and ``movement`` (its error metrics use
  the movement phases).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
import scipy.signal

from .frames import dcm_to_quat, quat_slerp, quat_to_dcm, quat_to_euler
from .io import Recording, load_recording, load_vehicle, recording_text, vehicle_text
from .paths import KIT_ROOT
from .readers.broad import load_broad
from .readers.vehicle_csv import load_vehicle_csv

BROAD_CITATION = (
    'BROAD: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD — A Benchmark for Robust Inertial '
    'Orientation Estimation", Data 6(7), 2021, doi:10.3390/data6070072; CC BY 4.0'
)
RACETRACK_CITATION = (
    "Stanford race-track log of 2014-02-22 as published with the sideslip-angle-vehicle-estimation "
    "estimators of F. Leanza, G. Reina, J. L. Blanco-Claraco; MIT licence"
)
#: SI per count of the converted BROAD columns (see the module doc)
BROAD_SENSITIVITY = {"gyr": (1e-5, "rad/s"), "acc": (1e-4, "m/s^2"), "mag": (1e-3, "uT")}
#: body ← IMU: the IMU's z points up, the kit's body z down
BROAD_MOUNT = np.diag([1.0, -1.0, -1.0])
PASS_HZ, STOP_HZ, STOP_DB = 40.0, 50.0, 60.0


def shared_dir() -> Path:
    """Where the originals are: ``$KFKIT_SHARED_DATA`` or ``../shared/data`` beside the kit."""
    return Path(os.environ.get("KFKIT_SHARED_DATA") or KIT_ROOT.parent / "shared" / "data")


def antialias_fir(fs_hz: float, pass_hz: float = PASS_HZ, stop_hz: float = STOP_HZ, atten_db: float = STOP_DB):
    """A linear-phase low-pass FIR at ``fs_hz`` (Kaiser window, odd length): flat to ``pass_hz``,
    at least ``atten_db`` down from ``stop_hz`` (Kaiser's formula for the length and β)."""
    numtaps, beta = scipy.signal.kaiserord(atten_db, (stop_hz - pass_hz) / (0.5 * fs_hz))
    numtaps |= 1  # odd: a whole-sample delay, which resample_poly removes
    return scipy.signal.firwin(numtaps, 0.5 * (pass_hz + stop_hz), window=("kaiser", beta), fs=fs_hz)


def resample(x, fs_hz: float, rate_hz: float):
    """``x`` (N, …) sampled at ``fs_hz`` → at ``rate_hz`` (sample k at k/rate_hz s, as x[0] at 0 s),
    through :func:`antialias_fir`. The rates must have a small rational ratio (BROAD → 100 Hz: 7/20)."""
    ratio = Fraction(rate_hz / fs_hz).limit_denominator(1000)
    if abs(float(ratio) - rate_hz / fs_hz) > 1e-9 * rate_hz / fs_hz:
        raise ValueError(f"cannot resample {fs_hz} Hz to {rate_hz} Hz: no ratio p/q with q ≤ 1000")
    up, down = ratio.numerator, ratio.denominator
    h = antialias_fir(fs_hz * up)
    return scipy.signal.resample_poly(x, up, down, axis=0, window=h, padtype="line")


def slerp_at(q, fs_hz: float, t):
    """Unit quaternions ``q`` (N, 4, w-x-y-z, NaN rows = unseen) sampled at ``fs_hz``, interpolated at times
    ``t`` (s) by slerp between the two neighbouring samples; NaN where either neighbour is NaN."""
    pos = np.asarray(t) * fs_hz
    i = np.clip(np.floor(pos + 1e-9).astype(int), 0, len(q) - 2)
    frac = np.clip(pos - i, 0.0, 1.0)
    a, b = q[i], q[i + 1]
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    out = np.full((len(pos), 4), np.nan)
    out[ok] = quat_slerp(a[ok], b[ok], frac[ok])
    return out


def _phases(movement, t) -> list[dict]:
    """BROAD's movement flag (bool per sample) → phases ``rest``/``movement`` (s, end excluded)."""
    edges = np.flatnonzero(np.diff(movement.astype(int))) + 1
    starts, ends = np.r_[0, edges], np.r_[edges, len(t)]
    dt = float(np.median(np.diff(t)))
    return [
        {
            "label": "movement" if movement[s] else "rest",
            "start": round(float(t[s]), 6),
            "end": round(float(t[e - 1] + dt), 6),
        }
        for s, e in zip(starts, ends)
    ]


@dataclass(frozen=True)
class BroadExcerpt:
    """One BROAD trial, cut to [start, end) s of the trial, at ``rate_hz`` (None: the native 285.7 Hz)."""

    trial: str
    start: float
    end: float
    rate_hz: float | None
    what: str

    def build(self, source: Path) -> Recording:
        rec = load_broad(source / "broad" / f"{self.trial}.mat")
        fs = rec.meta["rate_hz"]
        signals = {s: np.column_stack([rec[s[0] + a] for a in "xyz"]) for s in ("gyr", "acc", "mag")}
        q_ns = np.column_stack([rec[f"true_q{c}"] for c in "wxyz"])  # IMU → NED
        if self.rate_hz is None:
            rate, t_all = fs, rec.t
            movement = rec["movement"]
        else:
            rate = self.rate_hz
            signals = {s: resample(v, fs, rate) for s, v in signals.items()}
            t_all = np.arange(len(signals["gyr"])) / rate
            q_ns = slerp_at(q_ns, fs, t_all)
            movement = rec["movement"][np.minimum(np.rint(t_all * fs).astype(int), len(rec.t) - 1)]
        keep = (t_all >= self.start - 1e-9) & (t_all < self.end - 1e-9)
        t = np.round(t_all[keep] - t_all[keep][0], 9)
        data = {"t": t, "seq": np.arange(len(t), dtype=np.int64) % 65536}
        for s, prefix in (("acc", "a"), ("gyr", "g"), ("mag", "m")):
            counts = np.rint(signals[s][keep] / BROAD_SENSITIVITY[s][0]).astype(np.int64)
            for i, axis in enumerate("xyz"):
                data[prefix + axis] = counts[:, i]
        seen = np.isfinite(q_ns[keep]).all(axis=1)
        euler = np.full((len(t), 3), np.nan)
        q_nb = dcm_to_quat(quat_to_dcm(q_ns[keep][seen]) @ BROAD_MOUNT.T)
        euler[seen] = quat_to_euler(q_nb)
        for i, name in enumerate(("true_roll", "true_pitch", "true_yaw")):
            data[name] = euler[:, i]
        mount = BROAD_MOUNT.tolist()
        resampled = (
            f"resampled from {fs:.7g} Hz to {rate:g} Hz (scipy.signal.resample_poly, the kit's anti-alias FIR: "
            f"flat to {PASS_HZ:g} Hz, ≥ {STOP_DB:g} dB down from {STOP_HZ:g} Hz; truth by slerp)"
            if self.rate_hz
            else f"native rate {fs:.7g} Hz, not resampled"
        )
        meta = {
            "board": "broad-myon-aktos-t",
            "rate_hz": rate,
            "source": "BROAD",
            "trial": self.trial,
            "description": self.what,
            "excerpt": {"from_s": self.start, "to_s": round(self.start + t[-1] + 1 / rate, 6)},
            "units": {
                "t": "s",
                "sensors": "counts (see sensors.*.sensitivity)",
                "true_*": "rad, body → NED from optical motion capture; empty where the markers were not seen",
            },
            "sensors": {
                s: {"chip": "Myon aktos-t", "sensitivity": sens, "unit": unit}
                for s, (sens, unit) in BROAD_SENSITIVITY.items()
            },
            "mount": {"acc": mount, "gyr": mount, "mag": mount},
            "phases": _phases(movement[keep], t),
            "license": BROAD_CITATION,
            "changes": f"cut to {self.start:g}–{self.end:g} s of the trial; {resampled}; body frame forward-right-down "
            "(mounting diag(1, −1, −1)); SI values stored as integer counts of the sensitivities above; "
            "'movement' flag → phases",
        }
        return Recording(meta, data)


def _racetrack(source: Path) -> Recording:
    """The race-track half as a vehicle recording: t from 0, the log's signals renamed, β truth."""
    columns = {
        "t": "t_s",
        "delta": "steer_road_wheel_rad",
        "yaw_rate": "yaw_rate_rad_s",
        "ay": "ay_cg_m_s2",
        "vx": "vx_m_s",
        "true_beta": "beta_true_rad",
        "true_vy": "vy_m_s",
    }
    raw = load_vehicle_csv(source / "racetrack" / "racetrack_first_half.csv", columns)  # t from 0, SI
    t0 = float(raw.meta["t0"])
    data = {name: np.asarray(raw[name], dtype=float) for name in columns}
    data["t"] = np.round(data["t"], 6)
    meta = {
        "rate_hz": 100.0,
        "source": "race track (real car)",
        "description": "a real car on a race track, 275 s: speed 16–61 m/s, lateral acceleration up to 1.1 g "
        "(half a second's mean; single samples of the vibrating body reach 1.7 g), sideslip measured by "
        "the vehicle's reference instrumentation",
        "axes": "ISO 8855 (x forward, y left, z up)",
        "units": {
            "t": "s",
            "delta": "rad (road wheel)",
            "yaw_rate": "rad/s",
            "ay": "m/s^2 (at the CG)",
            "vx": "m/s",
            "true_beta": "rad (measured)",
            "true_vy": "m/s (measured, at the CG)",
        },
        # the parameters its authors published with their estimators (C_f, C_r chosen for their linear model, not
        # measured); no friction coefficient was published: vehicle.peak_friction gives the one the log shows
        "vehicle": {
            "m": 982.0,
            "Iz": round(982.0 / 12.0 * (1.7**2 + 4.09**2), 1),
            "a": 1.33,
            "b": 1.07,
            "Cf": 70_000.0,
            "Cr": 120_000.0,
        },
        "log_time_offset_s": t0,
        "license": RACETRACK_CITATION,
        "changes": f"the first half of the log (t = {t0:g}–{t0 + data['t'][-1]:g} s), time from 0; columns renamed"
        " to the "
        "kit's (t_s→t, steer_road_wheel_rad→delta, yaw_rate_rad_s→yaw_rate, ay_cg_m_s2→ay, vx_m_s→vx, "
        "beta_true_rad→true_beta, vy_m_s→true_vy); values unchanged (100 Hz, SI)",
    }
    return Recording(meta, data)


@dataclass(frozen=True)
class RealFile:
    """How one bundled real file is made from the originals, written and read."""

    build: Callable[[Path], Recording]
    origin: str  # the original under the shared data folder
    text: Callable[[Recording], str] = recording_text
    read: Callable[[Path], Recording] = load_recording
    suffix: str = ".csv"


def _broad(trial, start, end, rate_hz, what) -> RealFile:
    return RealFile(BroadExcerpt(trial, start, end, rate_hz, what).build, f"broad/{trial}.mat")


#: name → how to make it from the originals; the file is ``data/<name>.csv``
REAL = {
    "01_broad_slow_rotation": _broad(
        "02_undisturbed_slow_rotation_B",
        0.0,
        186.0,
        100.0,
        "BROAD trial 02: 40 s at rest, slow rotations by hand (40–100 s mostly about x, then about "
        "all axes), 33 s at rest",
    ),
    "02_broad_rest": _broad(
        "02_undisturbed_slow_rotation_B",
        0.0,
        39.0,
        None,
        "BROAD trial 02: the IMU lying still for 39 s before the rotations (native rate)",
    ),
    "03_broad_attached_magnet": _broad(
        "34_disturbed_attached_magnet_3cm",
        0.0,
        169.0,
        100.0,
        "BROAD trial 34: at rest, then medium-speed motions about all axes with a magnet "
        "attached to the board 3 cm from the IMU, then at rest",
    ),
    "04_broad_fast_rotation": _broad(
        "06_undisturbed_fast_rotation_A",
        0.0,
        171.0,
        100.0,
        "BROAD trial 06: 38 s at rest, fast rotations by hand about all axes (up to ~16 rad/s), 10 s at rest",
    ),
    "04_broad_stationary_magnet": _broad(
        "28_disturbed_stationary_magnet_A",
        0.0,
        184.0,
        100.0,
        "BROAD trial 28: at rest, then medium-speed motions near a small magnet placed at a fixed spot, then at rest",
    ),
    "05_broad_rotation_breaks": _broad(
        "04_undisturbed_slow_rotation_with_breaks_A",
        0.0,
        213.0,
        100.0,
        "BROAD trial 04: 30 s at rest, slow rotations with three rests of ~10 s between them, 36 s at rest",
    ),
    "06_racetrack": RealFile(_racetrack, "racetrack/racetrack_first_half.csv", text=vehicle_text, read=load_vehicle),
}
