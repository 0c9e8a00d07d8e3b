"""A board's sensor calibration: the :class:`Calibration` labs 02 and 03 save and labs 04 and 05 load.

Everything works in the body frame (FRD) and SI units (rad/s, m/s², µT). A :class:`Calibration`
holds the results of labs 02 and 03 and corrects raw body-frame measurements:

    gyro   ω = ω_raw − b_g
    accel  f = (f_raw − b_a) / s_a          (per axis)
    mag    m = S (m_raw − h)                (h hard iron, S symmetric soft-iron correction)

It is saved as a small JSON file. :func:`load_calibration` finds the right one for a board: an
explicit path, else the student's own file saved by labs 02/03 (:func:`user_calibration_path`),
else the bundled default in ``data/`` (made by ``kfkit data regenerate`` from the labs' analyses
of the bundled simulations). :func:`calibration_for` picks the one that belongs to a recording: the
bundled default for the bundled recordings, the student's own for theirs.

**A phone** (board ``"phone-phyphox"``) comes calibrated by its OS, and the kit's default for it is the
identity, with the noise σ of the phone's sensor model (:func:`kfkit.sensors.phone_board`)
(``data/calibration_phone-phyphox.json``):

- gyro bias 0: Android's ``TYPE_GYROSCOPE``, which phyphox reads, "MUST be calibrated and compensated while
  in use" (Android CDD §7.3.4; AOSP "Sensor types": base sensors carry bias and temperature compensation,
  ``TYPE_GYROSCOPE_UNCALIBRATED`` is the one without); phyphox on iOS reads CoreMotion's device-motion
  rotation rate, whose bias Core Motion removes. What is left is a few hundredths of °/s, which lab 02 measures.
- hard iron 0, soft iron I: phyphox reads the calibrated field (``TYPE_MAGNETIC_FIELD``, hard iron removed
  online; ``TYPE_MAGNETIC_FIELD_UNCALIBRATED`` only if an experiment asks; iOS: device motion's calibrated
  field), so an ellipsoid fit (lab 03) finds what the OS left, about 1 µT.
- accelerometer bias 0, scale 1: an assumption. The CDD (§7.3.1) only recommends calibrating the accelerometer
  in use, and iOS gives phyphox the raw accelerometer; a phone's six faces (lab 02) measure its offsets.

Student-saved phone calibrations (labs 02 and 03) replace it as for a board.

The measurements are made in :mod:`kfkit.rest_calibration` (gyro bias, noise σ, accelerometer bias and six faces,
the rests of an unlabelled recording), :mod:`kfkit.allan` (the Allan deviation's N, B and K) and
:mod:`kfkit.mag_calibration` (hard and soft iron); :func:`calibrate` runs them on a board's recordings. The lab
notebooks call them as ``calibration.…``, so they are importable from here too.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .allan import (  # noqa: F401 (lab 02's notebook calls calibration.allan_taus, bias_instability, …)
    BIAS_INSTABILITY_FACTOR,
    allan_deviation,
    allan_noise_fit,
    allan_taus,
    angle_random_walk,
    bias_instability,
)
from .frames import G
from .mag_calibration import apply_mag_calibration, fit_mag_calibration
from .paths import bundled_calibration_path, data_dir, user_calibration_path
from .rest_calibration import (  # noqa: F401 (lab 02's notebook calls calibration.label_rests)
    FACES,
    CalibrationError,
    accel_bias,
    accel_six_face,
    gyro_bias,
    label_rests,
    noise_std,
)
from .sensors import board as get_board

NOISE_WINDOW_S = 10.0  # s: noise σ over windows this short leaves the bias wander out
ACCEL_SCALE_RANGE = (0.5, 2.0)  # what six faces can give: each axis must read beyond ±g/2 (accel_six_face)
MAX_SOFT_IRON_CONDITION = 1e3  # eigenvalue ratio of S beyond which the correction is (nearly) singular


def _zeros():
    return [0.0, 0.0, 0.0]


@dataclass
class Calibration:
    """One board's calibration, body frame FRD, SI units (µT for the magnetometer).

    gyro_bias (rad/s), gyro_noise (rad/s, σ per sample at ``rate_hz``), gyro_bias_walk (rad/s/√s: the bias's
    random walk K, read on a long rest's Allan curve; 0 = not measured), accel_bias (m/s²),
    accel_scale (1), accel_noise (m/s², σ per sample at ``rate_hz``), mag_hard_iron (µT),
    mag_soft_iron (3×3), mag_noise (µT, σ per magnetometer sample), source (how it was made).
    """

    board: str = "nucleo-iks02a1"
    rate_hz: float = 104.0
    gyro_bias: list = field(default_factory=_zeros)
    gyro_noise: list = field(default_factory=_zeros)
    gyro_bias_walk: list = field(default_factory=_zeros)
    accel_bias: list = field(default_factory=_zeros)
    accel_scale: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    accel_noise: list = field(default_factory=_zeros)
    mag_hard_iron: list = field(default_factory=_zeros)
    mag_soft_iron: list = field(default_factory=lambda: np.eye(3).tolist())
    mag_noise: list = field(default_factory=_zeros)
    source: str = ""

    SHAPES = {
        "gyro_bias": (3,),
        "gyro_noise": (3,),
        "gyro_bias_walk": (3,),
        "accel_bias": (3,),
        "accel_scale": (3,),
        "accel_noise": (3,),
        "mag_hard_iron": (3,),
        "mag_soft_iron": (3, 3),
        "mag_noise": (3,),
    }

    def __post_init__(self):
        """Checks every field: shapes, finite, noise ≥ 0, accel_scale within :data:`ACCEL_SCALE_RANGE`,
        S symmetric positive definite with eigenvalue ratio ≤ :data:`MAX_SOFT_IRON_CONDITION`, rate_hz > 0."""
        if not isinstance(self.board, str) or not self.board:
            raise CalibrationError(f"Calibration.board must be a board name, got {self.board!r}")
        if not isinstance(self.source, str):
            raise CalibrationError(f"Calibration.source must be text, got {self.source!r}")
        if (
            isinstance(self.rate_hz, bool)
            or not isinstance(self.rate_hz, (int, float, np.number))
            or not (np.isfinite(self.rate_hz) and self.rate_hz > 0)
        ):
            raise CalibrationError(f"Calibration.rate_hz must be a positive finite number (Hz), got {self.rate_hz!r}")
        for name, shape in self.SHAPES.items():
            try:
                value = np.asarray(getattr(self, name), dtype=float)
            except (ValueError, TypeError):
                raise CalibrationError(
                    f"Calibration.{name}: expected numbers of shape {shape}, got {getattr(self, name)!r}"
                ) from None
            if value.shape != shape:
                raise CalibrationError(f"Calibration.{name}: expected shape {shape}, got {value.shape}")
            if not np.isfinite(value).all():
                raise CalibrationError(f"Calibration.{name}: holds NaN or inf: {value.tolist()}")
            setattr(
                self,
                name,
                [float(f"{v:.9g}") for v in value.ravel()]
                if value.ndim == 1
                else [[float(f"{v:.9g}") for v in row] for row in value],
            )
        lo, hi = ACCEL_SCALE_RANGE
        if not all(lo <= s <= hi for s in self.accel_scale):
            raise CalibrationError(
                f"Calibration.accel_scale must lie within {lo:g} … {hi:g} (1 = exact; it divides the "
                f"reading), got {self.accel_scale}"
            )
        for name in ("gyro_noise", "gyro_bias_walk", "accel_noise", "mag_noise"):
            if min(getattr(self, name)) < 0:
                raise CalibrationError(
                    f"Calibration.{name} is a noise level: it cannot be negative, got {getattr(self, name)}"
                )
        S = np.asarray(self.mag_soft_iron)
        w = np.linalg.eigvalsh((S + S.T) / 2)
        if (
            not np.allclose(S, S.T, rtol=1e-6, atol=1e-9 * np.abs(S).max())
            or w[0] <= 0
            or w[-1] > MAX_SOFT_IRON_CONDITION * w[0]
        ):
            raise CalibrationError(
                f"Calibration.mag_soft_iron must be symmetric positive definite and not (nearly) singular "
                f"(eigenvalues {', '.join(f'{x:.3g}' for x in w)}), got {self.mag_soft_iron}: "
                f"fit it again with fit_mag_calibration"
            )
        self.rate_hz = float(self.rate_hz)

    @property
    def gyro_density(self) -> np.ndarray:
        """The gyro's white-noise density N = σ/√rate (rad/s/√Hz = rad/√s), per axis: what a Q is made from."""
        return np.asarray(self.gyro_noise) / np.sqrt(self.rate_hz)

    def to_json(self) -> str:
        """The JSON text ``save`` writes (one field per line, 9 significant digits)."""
        return json.dumps(asdict(self), indent=1, ensure_ascii=False) + "\n"

    @classmethod
    def from_json(cls, text: str, where="calibration") -> Calibration:
        """A calibration file's text. Stricter than the constructor: every field but ``source`` must be
        there (no default stands in for a measurement) and the board must be one the kit knows. A noise σ
        of 0 means "not measured" (a board without magnetometer, a lab that saved before measuring it); a file from
        before ``gyro_bias_walk`` existed reads it as 0."""
        try:
            d = json.loads(text.removeprefix("\ufeff"))
        except json.JSONDecodeError as e:
            raise CalibrationError(f"{where}: not valid JSON ({e.msg}, line {e.lineno})") from None
        if not isinstance(d, dict):
            raise CalibrationError(f"{where}: expected a JSON object of calibration fields")
        unknown = sorted(set(d) - set(cls.__dataclass_fields__))
        if unknown:
            raise CalibrationError(f"{where}: unknown fields {', '.join(unknown)}")
        missing = [f for f in cls.__dataclass_fields__ if f not in d and f not in ("source", "gyro_bias_walk")]
        if missing:
            raise CalibrationError(
                f"{where}: missing fields {', '.join(missing)}: a calibration file needs every "
                f"measurement; save one again from labs 02/03 (Calibration.save)"
            )
        try:
            cal = cls(**d)
            get_board(cal.board)
            return cal
        except (CalibrationError, ValueError) as e:
            raise CalibrationError(f"{where}: {e}") from None

    def save(self, path=None) -> Path:
        """Write the JSON file; by default where :func:`load_calibration` looks for the student's own.

        A different calibration already there is kept as ``<name>.previous.json`` (one step back),
        so re-running a lab never silently loses the last one.
        """
        path = Path(path) if path is not None else user_calibration_path(self.board)
        path.parent.mkdir(parents=True, exist_ok=True)
        text = self.to_json()
        if path.exists() and path.read_text(encoding="utf-8") != text:
            path.replace(path.with_name(f"{path.stem}.previous.json"))
        path.write_text(text, encoding="utf-8", newline="\n")
        return path

    @classmethod
    def load(cls, path) -> Calibration:
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no calibration file at {path}")
        try:
            text = path.read_bytes().decode("utf-8")
        except UnicodeDecodeError as e:
            raise CalibrationError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
        return cls.from_json(text, where=str(path))

    def apply(self, rec_or_arrays):
        """Corrected body-frame (gyr, acc, mag) from a Recording or a tuple (gyr, acc[, mag]) of (N, 3).

        ω = ω_raw − b_g,  f = (f_raw − b_a) / s_a,  m = S (m_raw − h); mag is None when absent.
        """
        if hasattr(rec_or_arrays, "body"):
            rec = rec_or_arrays
            board = rec.meta.get("board")
            if board is not None and board != self.board:
                raise CalibrationError(
                    f"this calibration is for board {self.board!r}, the recording is from {board!r}: "
                    f"use load_calibration(board={board!r})"
                )
            arrays = (rec.body("gyr"), rec.body("acc"), rec.body("mag") if "mag" in rec.meta.get("mount", {}) else None)
        else:
            arrays = tuple(rec_or_arrays) + (None,) * (3 - len(tuple(rec_or_arrays)))
            if len(arrays) != 3:
                raise CalibrationError(f"apply: expected (gyr, acc) or (gyr, acc, mag), got {len(arrays)} arrays")
        gyr, acc, mag = (None if a is None else np.asarray(a, dtype=float) for a in arrays)
        for name, a in (("gyr", gyr), ("acc", acc), ("mag", mag)):
            if a is not None and (a.ndim not in (1, 2) or a.shape[-1] != 3):
                raise CalibrationError(f"apply: {name} must have shape (3,) or (N, 3), got {a.shape}")
        gyr = None if gyr is None else gyr - np.asarray(self.gyro_bias)
        acc = None if acc is None else (acc - np.asarray(self.accel_bias)) / np.asarray(self.accel_scale)
        mag = None if mag is None else apply_mag_calibration(mag, self.mag_hard_iron, self.mag_soft_iron)
        return gyr, acc, mag


def load_calibration(board="nucleo-iks02a1", path=None) -> Calibration:
    """The calibration labs 04/05 use: ``path`` if given, else the student's own (saved by labs 02/03,
    :func:`user_calibration_path`), else the bundled default for ``board`` in ``data/`` (a phone,
    ``"phone-phyphox"``: the identity its OS calibration leaves, see the module docstring)."""
    if path is not None:
        return Calibration.load(path)
    get_board(board)  # an unknown board name: ValueError naming the known ones
    for candidate in (user_calibration_path(board), bundled_calibration_path(board)):
        if candidate.exists():
            return Calibration.load(candidate)
    raise FileNotFoundError(
        f"no calibration for {board!r}: neither {user_calibration_path(board)} nor the bundled "
        f"{bundled_calibration_path(board)} exists. Rebuild the bundled one with: python -m kfkit data regenerate"
    )


def calibration_for(rec) -> Calibration:
    """The calibration that belongs to recording ``rec``.

    The kit's bundled recordings (files in ``data/``) are simulations of one unit per board, so they get
    that unit's bundled default, whatever the student has saved; any other recording (the student's own)
    gets :func:`load_calibration` for its board: their saved file, else the bundled default.
    """
    board = rec.meta.get("board")
    if rec.path is not None and Path(rec.path).resolve().parent == data_dir().resolve():
        return Calibration.load(bundled_calibration_path(board))
    return load_calibration(board)


def noise_at_rate(sigma, rate_from, rate_to):
    """White noise σ per sample measured at ``rate_from`` (Hz) scaled to ``rate_to``: σ·√(rate_to/rate_from).

    The sensor's property is the density N = σ/√rate; the per-sample σ grows with the output rate.
    """
    return np.asarray(sigma, dtype=float) * np.sqrt(rate_to / rate_from)


def calibrate(stationary, six_faces=None, mag_rotations=None, rate_hz=None, field_norm=None, source="") -> Calibration:
    """The labs' analysis in one call (kfkit's reference, used to build the bundled defaults).

    stationary     a Recording of the board at rest (its 'stationary' phase if labelled), level
    six_faces      a Recording with the six face phases (optional: else bias from the level rest, scale 1)
    mag_rotations  a Recording with the 'mag_rotations' phase (optional)
    rate_hz        the rate the noise σ is given at (default: the board's streaming rate)
    """
    board = get_board(stationary.meta["board"])
    rate = float(rate_hz or board.rate_hz)
    still = _phase_or_all(stationary, "stationary")
    gyr, acc = stationary.body("gyr")[still], stationary.body("acc")[still]
    window = min(len(gyr), int(NOISE_WINDOW_S * stationary.rate_hz))
    cal = {
        "board": board.name,
        "rate_hz": rate,
        "gyro_bias": gyro_bias(gyr),
        "gyro_noise": noise_at_rate(noise_std(gyr, window), stationary.rate_hz, rate),
        "gyro_bias_walk": allan_noise_fit(*allan_deviation(gyr, stationary.rate_hz))[2],
        "accel_noise": noise_at_rate(noise_std(acc, window), stationary.rate_hz, rate),
        "accel_bias": accel_bias(acc, [0.0, 0.0, -G]),
    }
    if six_faces is not None:
        faces = {f: six_faces.body("acc")[six_faces.phase(f)] for f in FACES}
        cal["accel_bias"], cal["accel_scale"] = accel_six_face(faces)
    if "mag" in stationary.meta.get("mount", {}):
        mag = stationary.body("mag")[still]
        cal["mag_noise"] = noise_std(mag[np.isfinite(mag).all(axis=1)])
    if mag_rotations is not None:
        mag = mag_rotations.body("mag")[_phase_or_all(mag_rotations, "mag_rotations")]
        cal["mag_hard_iron"], cal["mag_soft_iron"] = fit_mag_calibration(mag, field_norm)
    return Calibration(**cal, source=source)


def _phase_or_all(rec, label):
    return rec.phase(label) if any(p["label"] == label for p in rec.phases) else np.ones(len(rec), dtype=bool)
