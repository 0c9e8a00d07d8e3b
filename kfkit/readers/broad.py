"""BROAD, a public benchmark of inertial orientation estimation: one trial's ``.mat`` file as a Recording.

Laidig et al., "BROAD — a benchmark for robust inertial orientation estimation", Data 6(7), 2021
(CC BY 4.0): 39 trials of a Myon aktos-t IMU with optical motion capture as the truth. Lab 04 and
``benchmarks/bench_attitude.py`` compare the kit's filters on it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io

from ..frames import enu_to_ned_quat, quat_to_euler
from ..io import Recording, RecordingError, positive_number

BROAD_FIELDS = ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate")


def load_broad(path) -> Recording:
    """Read one BROAD trial (Laidig et al., "BROAD — a benchmark for robust inertial orientation
    estimation", Data 6(7), 2021; CC BY 4.0) from its ``.mat`` file into a :class:`Recording`.

    The file holds ``imu_gyr`` (rad/s), ``imu_acc`` (m/s², specific force), ``imu_mag`` (µT), all
    (N, 3) in the IMU's own frame (z up: it reads +g when flat), ``opt_quat`` (N, 4) w-x-y-z, IMU →
    ENU, already aligned to the IMU frame and to the magnetic ENU frame the dataset's own
    evaluation compares filters in (NaN where the optical markers were not seen), ``movement``
    (N, 1) the samples its error metrics use, and ``sampling_rate`` (Hz).

    The recording's sensor columns are SI floats (sensitivity 1, identity mounting: body = the IMU
    frame, so ``rec.body('gyr')`` etc. return the file's arrays); truth is converted to NED:
    ``true_qw … true_qz`` (IMU → NED, NaN in gaps), ``true_roll/pitch/yaw`` from them, and the
    ``movement`` column (bool). Errors name the file and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no BROAD trial at {path}")
    try:
        raw = scipy.io.loadmat(path)
    except NotImplementedError:  # scipy's answer to a v7.3 file, which is HDF5 inside
        raise RecordingError(
            path,
            None,
            "a MATLAB v7.3 (HDF5) .mat file: BROAD trials are v5 .mat files; "
            "re-save it in MATLAB with save(name, '-v7') or use the trial from the dataset",
        ) from None
    except Exception as e:  # noqa: BLE001 — a damaged file makes scipy's reader raise anything (IndexError, zlib.error, …)
        raise RecordingError(
            path, None, f"not a readable MATLAB .mat file, or a damaged one ({type(e).__name__}: {e})"
        ) from None
    missing = [f for f in BROAD_FIELDS if f not in raw]
    if missing:
        raise RecordingError(
            path, None, f"not a BROAD trial: missing field(s) {', '.join(missing)}; expected {', '.join(BROAD_FIELDS)}"
        )

    def numeric(name):
        try:
            return np.asarray(raw[name], dtype=float)
        except (ValueError, TypeError):
            raise RecordingError(
                path, None, f"field {name!r} must be numeric, got MATLAB class {np.asarray(raw[name]).dtype}"
            ) from None

    arrays = {}
    for name, width in (("imu_gyr", 3), ("imu_acc", 3), ("imu_mag", 3), ("opt_quat", 4)):
        a = numeric(name)
        if a.ndim != 2 or a.shape[1] != width:
            raise RecordingError(path, None, f"field {name!r} must have shape (N, {width}), got {a.shape}")
        arrays[name] = a
    n = len(arrays["imu_gyr"])
    if n < 2:
        raise RecordingError(path, None, f"field 'imu_gyr' has {n} rows: a trial needs at least 2 samples")
    for name, a in arrays.items():
        if len(a) != n:
            raise RecordingError(path, None, f"field {name!r} has {len(a)} rows but imu_gyr has {n}")
    movement = numeric("movement").reshape(-1)
    if movement.size != n:
        raise RecordingError(path, None, f"field 'movement' has {movement.size} entries but imu_gyr has {n} rows")
    if not np.isin(movement, (0.0, 1.0)).all():
        raise RecordingError(
            path, None, f"field 'movement' must hold 0 or 1, got {movement[~np.isin(movement, (0.0, 1.0))][0]}"
        )
    rates = numeric("sampling_rate").reshape(-1)
    if rates.size != 1 or not positive_number(float(rates[0])):
        raise RecordingError(
            path, None, f"field 'sampling_rate' must be one positive finite number (Hz), got {rates.tolist()}"
        )
    rate = float(rates[0])
    for name in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat"):  # NaN rows are gaps (no mag sample, markers unseen)
        a = arrays[name]
        finite = np.isfinite(a).all(axis=1)
        bad = ~finite if name in ("imu_gyr", "imu_acc") else ~finite & ~np.isnan(a).all(axis=1)
        if bad.any():
            raise RecordingError(
                path, None, f"field {name!r} row {np.argmax(bad)} is not finite: {a[np.argmax(bad)].tolist()}"
            )
        if name == "opt_quat":
            with np.errstate(over="ignore"):  # a garbled 1e300 overflows to inf: still "not a unit quaternion"
                off = finite & (np.abs(np.linalg.norm(np.where(finite[:, None], a, 0.0), axis=1) - 1.0) > 0.01)
            if off.any():
                raise RecordingError(
                    path,
                    None,
                    f"field 'opt_quat' row {np.argmax(off)} is not a unit quaternion "
                    f"(norm {np.linalg.norm(a[np.argmax(off)]):.4g})",
                )

    q_ned = enu_to_ned_quat(arrays["opt_quat"])
    q_ned /= np.linalg.norm(q_ned, axis=1, keepdims=True)

    euler = quat_to_euler(q_ned)
    data = {"t": np.arange(n) / rate, "seq": np.arange(n, dtype=np.int64) % 65536}
    for prefix, key in (("g", "imu_gyr"), ("a", "imu_acc"), ("m", "imu_mag")):
        for i, axis in enumerate("xyz"):
            data[prefix + axis] = arrays[key][:, i]
    for i, name in enumerate(("true_roll", "true_pitch", "true_yaw")):
        data[name] = euler[:, i]
    for i, name in enumerate(("true_qw", "true_qx", "true_qy", "true_qz")):
        data[name] = q_ned[:, i]
    data["movement"] = movement.astype(bool)
    info = raw.get("info")
    description = str(np.asarray(info).reshape(-1)[0]) if info is not None and np.size(info) else ""
    identity = np.eye(3).tolist()
    meta = {
        "board": "broad-myon-aktos-t",
        "rate_hz": rate,
        "source": "BROAD",
        "trial": path.stem,
        "description": description,
        "units": {"t": "s", "gyr": "rad/s", "acc": "m/s^2", "mag": "uT", "true_*": "rad; true_q*: w-x-y-z IMU → NED"},
        "sensors": {
            "acc": {"sensitivity": 1.0, "unit": "m/s^2"},
            "gyr": {"sensitivity": 1.0, "unit": "rad/s"},
            "mag": {"sensitivity": 1.0, "unit": "uT"},
        },
        "mount": {"acc": identity, "gyr": identity, "mag": identity},
        "license": "CC BY 4.0, Laidig et al., Data 6(7), 2021, doi:10.3390/data6070072",
    }
    return Recording(meta, data, path)
