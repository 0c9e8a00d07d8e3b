"""The bundled recordings under ``data/``: how each is made, loading by name, regeneration.

Most files are seeded simulations, so ``kfkit data regenerate`` rebuilds them all and
``kfkit data regenerate --check`` fails when a shipped file differs from what the code makes.
The real recordings (:mod:`kfkit.real_data`) are converted from their originals by ``kfkit data real``
(``--check`` likewise); :func:`load` reads both kinds by name.
The data folder is ``data/`` beside the ``kfkit`` package; ``KFKIT_DATA`` overrides it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import attitude_motions, calibration_motions, motions, real_data, sim, vehicle
from .calibration import Calibration, calibrate
from .frames import G
from .io import Recording, load_recording, load_vehicle, recording_text, vehicle_text
from .paths import data_dir
from .phone_sim import simple_experiment_files, simulate_phone
from .readers.phyphox_export import load_phyphox
from .sensors import phone_board
from .unit_errors import MPU6050_ACCEL_BIAS, MPU6050_ACCEL_SCALE, MPU6050_GYRO_BIAS, NUCLEO_UNIT


def _roll_sine() -> Recording:
    """Lab 01: a Nucleo + X-NUCLEO-IKS02A1 rolled by hand, ±30° at 0.1 Hz, 104 Hz, 60 s."""
    motion = motions.sine_roll(
        duration=60.0,
        rate_hz=104.0,
        amplitude=np.radians(30.0),
        freq_hz=0.1,
        still=5.0,
        shakes=(22.0, 42.0),
        vibration_rms=0.3,
        seed=101,
    )
    return sim.simulate_imu(motion, board="nucleo-iks02a1", seed=102)


# Lab 04 uses the same Nucleo as labs 02 and 03 (kfkit.unit_errors.NUCLEO_UNIT), so their calibration applies.
def _attitude_tour() -> Recording:
    """Lab 04: the Nucleo turned about all axes, slid on the table, 104 Hz, 60 s."""
    return _nucleo(
        attitude_motions.attitude_tour(rate_hz=104.0, translate_accel=2.0, vibration_rms=0.1, seed=401), seed=402
    )


def _gimbal_lock() -> Recording:
    """Lab 04: the Nucleo's nose pitched up through vertical and back, then down through it, 104 Hz, 36 s."""
    return _nucleo(attitude_motions.pitch_over(rate_hz=104.0), seed=403)


def _mag_disturbance() -> Recording:
    """Lab 04: heading sweeps with a steel object near the Nucleo for 12–20 s, 104 Hz, 30 s."""
    motion = attitude_motions.yaw_sweeps(rate_hz=104.0)
    return _nucleo(motion, seed=404, mag_disturbance=attitude_motions.mag_disturbance(motion))


MPU6050_BOOT_US = 1523456  # the logger's micros() at its first sample (its README's example line)
MPU6050_STATIC_TOLERANCE_G = 0.05  # the board's static test |‖a‖ − 1 g| < 0.05 g (firmware STATIC_TOLERANCE_G)


def _mpu6050(motion, seed) -> Recording:
    rec = sim.simulate_imu(
        motion,
        board="mpu6050",
        seed=seed,
        gyro_bias=MPU6050_GYRO_BIAS,
        accel_bias=MPU6050_ACCEL_BIAS,
        accel_scale=MPU6050_ACCEL_SCALE,
    )
    return _as_logged(rec)


def _as_logged(rec) -> Recording:
    """Lab 05's recordings in the MPU6050 logger's format: beside t (s) the board's ``t_us`` (micros(), µs,
    10 000 apart at 100 Hz), the raw accelerometer norm ``acc_norm`` = ‖a_counts‖ / 16384 (g) and
    ``static_ok`` = 1 where |acc_norm − 1| < 0.05: what the board can judge, uncalibrated."""
    norm_g = np.linalg.norm(rec.counts("acc"), axis=1) * rec.meta["sensors"]["acc"]["sensitivity"] / G
    data = {"t": rec.t, "seq": rec["seq"], "t_us": MPU6050_BOOT_US + np.round(rec.t * 1e6).astype(np.int64)}
    data.update({c: rec[c] for c in ("ax", "ay", "az", "gx", "gy", "gz")})
    data["acc_norm"] = np.round(norm_g, 6)  # 1 count is 6e-5 g
    data["static_ok"] = (np.abs(data["acc_norm"] - 1.0) < MPU6050_STATIC_TOLERANCE_G).astype(np.int64)
    data.update({c: rec[c] for c in rec.columns if c.startswith("true_")})
    rec.meta["units"].update(
        {
            "t_us": "µs (board micros())",
            "acc_norm": "g (raw counts, uncalibrated)",
            "static_ok": f"1 where |acc_norm − 1| < {MPU6050_STATIC_TOLERANCE_G} g",
        }
    )
    return Recording(rec.meta, data, rec.path)


def _tilt_protocol() -> Recording:
    """Lab 05: the tilt protocol twice (pitch, roll, pitch, roll) on an MPU6050, 100 Hz, 36 s."""
    return _mpu6050(motions.tilt_protocol(axes=("pitch", "roll", "pitch", "roll"), rate_hz=100.0, seed=501), seed=502)


def _mpu6050_stationary() -> Recording:
    """Lab 05: the MPU6050 lying flat and still for 10 s (gyro bias), 100 Hz."""
    motion = motions.stationary(10.0, 100.0)
    motion.phases = [(0.0, 10.0, "stationary")]
    return _mpu6050(motion, seed=503)


def _mpu6050_six_faces() -> Recording:
    """Lab 05 (and the MPU6050's default calibration): the MPU6050 resting 5 s on each face, 100 Hz."""
    return _mpu6050(calibration_motions.six_faces(rate_hz=100.0, seed=212), seed=213)


STATIONARY_RATE_HZ = 12.5  # lab 02's long rest: the ISM330DHCX's lowest ODR keeps 40 min small


def _nucleo(motion, seed, **options) -> Recording:
    unit = {k: (np.asarray(v) if k == "mag_soft_iron" else v) for k, v in NUCLEO_UNIT.items()}
    rec = sim.simulate_imu(motion, board="nucleo-iks02a1", seed=seed, **unit, **options)
    rec.meta["sim"].update(gyro_bias_rw=NUCLEO_UNIT["gyro_bias_rw"], accel_bias_rw=NUCLEO_UNIT["accel_bias_rw"])
    return rec


def _stationary_long() -> Recording:
    """Lab 02: the Nucleo lying flat and still for 40 min at 12.5 Hz (bias, noise, Allan deviation)."""
    motion = motions.stationary(2400.0, STATIONARY_RATE_HZ)
    motion.phases = [(0.0, 2400.0, "stationary")]
    return _nucleo(motion, seed=201)


def _six_faces() -> Recording:
    """Lab 02: the Nucleo resting 5 s on each of its six faces, 104 Hz."""
    return _nucleo(calibration_motions.six_faces(rate_hz=104.0, seed=202), seed=203)


def _axis_turns() -> Recording:
    """Lab 03: flat, turned 90° about body x, y, z and back, 104 Hz."""
    return _nucleo(calibration_motions.axis_turns(rate_hz=104.0), seed=301)


def _mag_rotations() -> Recording:
    """Lab 03: slow tumbling through all orientations for 60 s, 104 Hz (hard/soft-iron calibration)."""
    return _nucleo(calibration_motions.mag_rotations(rate_hz=104.0, seed=302), seed=303)


def _headings() -> Recording:
    """Lab 03: turned through six headings flat, then tilted, 104 Hz."""
    return _nucleo(calibration_motions.heading_steps(rate_hz=104.0), seed=304)


def _calibration_nucleo():
    """The Nucleo's default calibration: lab 02's and lab 03's analyses of their bundled recordings."""
    return calibrate(
        _stationary_long(),
        _six_faces(),
        _mag_rotations(),
        source="kfkit default: labs 02/03 analyses of 02_stationary, 02_six_faces, 03_mag_rotations",
    )


def _read_calibration(path):
    return Calibration.load(path)


def _calibration_json(cal) -> str:
    return cal.to_json()


def _calibration_mpu6050():
    """The MPU6050's default calibration: lab 02's analysis of a simulated 60 s rest and six faces
    of the lab 05 board (same biases as its bundled recordings)."""
    still = _mpu6050(motions.stationary(60.0, 100.0), seed=211)
    return calibrate(
        still,
        _mpu6050_six_faces(),
        source="kfkit default: lab 02's analysis of a simulated MPU6050 (60 s at rest, six faces; lab 05's biases)",
    )


def _calibration_phone():
    """A phone's default calibration: the identity (its OS removes the gyro bias and the magnetometer's hard
    iron; the accelerometer is assumed factory-calibrated: kfkit.calibration's docstring), with the noise σ of
    the phone's sensor model (kfkit.sensors.phone_board) at the rate a phyphox simple experiment asks for."""
    board = phone_board()
    return Calibration(
        board=board.name,
        rate_hz=board.rate_hz,
        gyro_noise=[board.gyro.noise_std(board.rate_hz)] * 3,
        accel_noise=[board.accel.noise_std(board.rate_hz)] * 3,
        mag_noise=[board.mag.noise_std(board.rate_hz)] * 3,
        source="kfkit default for a phone: identity (its OS removes the gyro bias and the magnetometer's "
        "hard iron; the accelerometer is taken as factory-calibrated); noise σ of kfkit.sensors.phone_board's "
        "BMI160/AK09918-class model at 100 Hz",
    )


@dataclass(frozen=True)
class Bundled:
    """How one bundled file is made, written and read (IMU recordings by default)."""

    build: Callable[[], Any]
    text: Callable[[Any], str] = recording_text
    read: Callable[[Path], Any] = load_recording
    suffix: str = ".csv"  # the file is data/<name><suffix>


def _phone_attitude_tour() -> dict:
    """Lab 04 with a phone: the attitude tour with a phone lying flat, screen up, top edge forward, in a
    phyphox simple experiment (accelerometer, gyroscope, magnetometer at 100 Hz), exported as CSV (comma,
    decimal point): {file in the export folder: text}, plus the truth (``kfkit_truth.csv``)."""
    motion = attitude_motions.attitude_tour(rate_hz=400.0, translate_accel=2.0, vibration_rms=0.1, seed=401)
    return simple_experiment_files(simulate_phone(motion, seed=405))


def _read_phone_export(path) -> Recording:
    return load_phyphox(path, require=("acc", "gyr", "mag"))


def _slalom_20kmh() -> Recording:
    """Lab 06: from a crawl (1 m/s) up to 20 km/h, slalom through 10 cones 9 m apart, back to a crawl; 100 Hz."""
    return vehicle.simulate_drive(vehicle.slalom(20.0, cone_spacing=9.0, peak_ay=3.0, start_kmh=3.6), seed=601)


def _slalom_80kmh() -> Recording:
    """Lab 06: slalom at 80 km/h through 10 cones 18 m apart; 100 Hz."""
    return vehicle.simulate_drive(vehicle.slalom(80.0, cone_spacing=18.0, peak_ay=4.0), seed=602)


def _lane_change() -> Recording:
    """Lab 06: double lane change (3.5 m) at 60 km/h braking gently to 50 km/h; 100 Hz."""
    return vehicle.simulate_drive(vehicle.lane_change(60.0, end_kmh=50.0), seed=603)


#: name → how to make it; the file is ``data/<name>.csv``
BUNDLED = {
    "01_roll_sine": Bundled(_roll_sine),
    "05_tilt_protocol": Bundled(_tilt_protocol),
    "05_stationary": Bundled(_mpu6050_stationary),
    "05_six_faces": Bundled(_mpu6050_six_faces),
    "04_attitude_tour": Bundled(_attitude_tour),
    "04_gimbal_lock": Bundled(_gimbal_lock),
    "04_mag_disturbance": Bundled(_mag_disturbance),
    "06_slalom_20kmh": Bundled(_slalom_20kmh, text=vehicle_text, read=load_vehicle),
    "06_slalom_80kmh": Bundled(_slalom_80kmh, text=vehicle_text, read=load_vehicle),
    "06_lane_change": Bundled(_lane_change, text=vehicle_text, read=load_vehicle),
    "02_stationary": Bundled(_stationary_long),
    "02_six_faces": Bundled(_six_faces),
    "03_axis_turns": Bundled(_axis_turns),
    "03_mag_rotations": Bundled(_mag_rotations),
    "03_headings": Bundled(_headings),
    "calibration_nucleo-iks02a1": Bundled(
        _calibration_nucleo, text=_calibration_json, read=_read_calibration, suffix=".json"
    ),
    "calibration_mpu6050": Bundled(
        _calibration_mpu6050, text=_calibration_json, read=_read_calibration, suffix=".json"
    ),
    "calibration_phone-phyphox": Bundled(
        _calibration_phone, text=_calibration_json, read=_read_calibration, suffix=".json"
    ),
    # a folder (suffix ""): ``text`` gives {file in the folder: text}
    "04_phone_attitude_tour": Bundled(_phone_attitude_tour, text=dict, read=_read_phone_export, suffix=""),
}


def _entry(name: str):
    entry = BUNDLED.get(name) or real_data.REAL.get(name)
    if entry is None:
        raise ValueError(
            f"no bundled recording {name!r}; simulated: {', '.join(BUNDLED)}; real: {', '.join(real_data.REAL)}"
        )
    return entry


def build(name: str):
    """Build the bundled recording ``name`` from its seeded simulation (a real one from its original)."""
    if name in real_data.REAL:
        return real_data.REAL[name].build(real_data.shared_dir())
    return _entry(name).build()


def load(name: str):
    """Load the bundled recording ``name`` (e.g. '01_roll_sine') from the data folder."""
    entry = _entry(name)
    path = data_dir() / f"{name}{entry.suffix}"
    if not path.exists():
        rebuild = "data real (from the originals)" if name in real_data.REAL else "data regenerate"
        raise FileNotFoundError(f"bundled recording missing: {path}. Rebuild it with: python -m kfkit {rebuild}")
    return entry.read(path)


def regenerate(check: bool = False, directory=None) -> list[str]:
    """Rebuild every bundled recording; with ``check``, write nothing and list the files that differ."""
    folder = Path(directory) if directory is not None else data_dir()
    report = []
    for name, entry in BUNDLED.items():
        path = folder / f"{name}{entry.suffix}"
        text = entry.text(entry.build())
        files = text if isinstance(text, dict) else {None: text}  # a dict: the files of a folder
        if check:
            report += _check_files(path, files)
        else:
            for rel, content in files.items():
                target = path if rel is None else path / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_text(content, encoding="utf-8", newline="\n")
            report.append(str(path))
    return report


def convert_real(check: bool = False, source=None, directory=None) -> tuple[list[str], list[str]]:
    """Rebuild the real files (:data:`kfkit.real_data.REAL`) from the originals under ``source``
    (default :func:`kfkit.real_data.shared_dir`).

    Returns (report, skipped): with ``check`` the report lists bundled files that differ from the
    conversion (nothing is written), else the files written; ``skipped`` names the originals not found.
    """
    source = Path(source) if source is not None else real_data.shared_dir()
    folder = Path(directory) if directory is not None else data_dir()
    report, skipped = [], []
    for name, entry in real_data.REAL.items():
        if not (source / entry.origin).is_file():
            skipped.append(f"{name}: no original at {source / entry.origin}")
            continue
        path = folder / f"{name}{entry.suffix}"
        text = entry.text(entry.build(source))
        if check:
            report += _check_files(path, {None: text})
        else:
            path.write_text(text, encoding="utf-8", newline="\n")
            report.append(str(path))
    return report, skipped


def _check_files(path: Path, files: dict) -> list[str]:
    """What differs between the shipped ``path`` and ``files`` ({None: text} for one file, else
    {path inside the folder: text}): missing, changed, or (in a folder) not made by the simulation."""
    report = []
    for rel, text in files.items():
        target = path if rel is None else path / rel
        if not target.exists():
            report.append(f"{target} is missing")
        elif (old := target.read_text(encoding="utf-8")) != text:
            report.append(f"{target} differs from what its simulation makes now: {_first_difference(old, text)}")
    if None not in files and path.is_dir():
        report += [
            f"{p} is not made by the simulation: delete it"
            for p in sorted(path.rglob("*"))
            if p.is_file() and p.relative_to(path).as_posix() not in files
        ]
    return report


def _first_difference(old: str, new: str) -> str:
    for i, (a, b) in enumerate(zip(old.splitlines(), new.splitlines()), start=1):
        if a != b:
            col = next((j for j, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            lo = max(0, col - 30)
            return (
                f"first at line {i}, column {col + 1}: shipped …{a[lo : col + 30]!r}…, "
                f"regenerated …{b[lo : col + 30]!r}…"
            )
    return f"line counts differ ({len(old.splitlines())} shipped, {len(new.splitlines())} regenerated)"
