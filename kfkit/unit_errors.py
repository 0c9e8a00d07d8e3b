"""The simulated unit of each board: the errors of the one physical part the kit's simulations play.

A real sensor has a bias, scale errors, hard and soft iron, and biases that wander; a simulation picks
values for them. The kit simulates one unit per board, so every bundled recording of a board, the
virtual board (``kfkit.capture.VirtualBoard(unit="bundled")``) and the virtual phone share that unit's
errors, and what labs 02/03 measure on one recording calibrates the others. Each unit is a dict of
:func:`kfkit.sim.simulate_imu` keywords (sensor frame, SI: rad/s, m/s², µT; walks per √s):

- :data:`NUCLEO_UNIT`  the Nucleo + X-NUCLEO-IKS02A1 of labs 02–04,
- :data:`MPU6050_UNIT` the GY-521 of lab 05,
- :data:`PHONE_UNIT`   a phone after its OS's own calibration,

gathered by board name in :data:`BOARD_UNITS`; :func:`resolve_unit` checks a unit given by hand.
"""

from __future__ import annotations

import numpy as np

from .sensors import PHONE_BOARD

# Labs 02 and 03: one Nucleo + X-NUCLEO-IKS02A1, so all its recordings share the same imperfections
# (sensor frame, SI): biases inside the datasheet's typical offsets, accelerometer scale errors of a few
# 0.1 %, and the hard/soft iron of the board's own parts (µT). The bias random walks are small, like a
# sensor whose Allan minimum lies near a minute (gyro: ≈ 4 °/h at τ ≈ 35 s) and two minutes
# (accelerometer: ≈ 11 µg at τ ≈ 55 s). Lab 04 uses the same Nucleo, so their calibration applies.
NUCLEO_UNIT = {
    "gyro_bias": tuple(np.radians([0.35, -0.60, 0.20])),  # rad/s
    "accel_bias": (0.045, -0.060, 0.080),  # m/s²
    "accel_scale": (1.004, 0.997, 1.006),
    "gyro_bias_rw": 4.4e-6,  # rad/s/√s
    "accel_bias_rw": 1.8e-5,  # m/s²/√s
    "mag_hard_iron": (12.0, -8.0, 5.0),  # µT
    "mag_soft_iron": ((1.08, 0.04, -0.02), (0.04, 0.95, 0.03), (-0.02, 0.03, 1.02)),
}

# Lab 05: one MPU6050 (GY-521) in one session, so its three recordings share the biases
# (sensor frame, SI): gyro a few °/s, accelerometer 15–25 mg, inside the datasheet's tolerances.
MPU6050_GYRO_BIAS = tuple(np.radians([-2.5, 1.8, 0.9]))  # rad/s
MPU6050_ACCEL_BIAS = (0.20, -0.15, 0.25)  # m/s²
MPU6050_ACCEL_SCALE = (1.015, 0.99, 1.01)  # sensitivity errors, within the datasheet's ±3 %

#: Bias random-walk densities K of each board's unit (gyro rad/s/√s, accelerometer m/s²/√s). With white
#: noise of density N the Allan deviation σ²(τ) = N²/τ + K²τ/3 is lowest at τ = √3·N/K, at σ = (2NK/√3)^½.
BIAS_RANDOM_WALK = {
    "nucleo-iks02a1": (NUCLEO_UNIT["gyro_bias_rw"], NUCLEO_UNIT["accel_bias_rw"]),
    # a consumer part: gyro minimum ≈ 9 °/h at τ ≈ 8 s, accelerometer ≈ 70 µg at τ ≈ 70 s
    "mpu6050": (2.0e-5, 1.0e-4),
}

# The bundled 05_* recordings (10–48 s) were made with sim.simulate_imu's default walks (1e-4 on both,
# a gyro walk 5× what a long rest of such a part shows); the unit's own walks are BIAS_RANDOM_WALK's.
MPU6050_UNIT = {
    "gyro_bias": MPU6050_GYRO_BIAS,
    "accel_bias": MPU6050_ACCEL_BIAS,
    "accel_scale": MPU6050_ACCEL_SCALE,
    "gyro_bias_rw": BIAS_RANDOM_WALK["mpu6050"][0],
    "accel_bias_rw": BIAS_RANDOM_WALK["mpu6050"][1],
}

#: A phone after the OS's own calibration (phone frame, SI; assumptions, not measurements): the
#: gyro bias its drift compensation leaves (a few hundredths of °/s), a few mg of accelerometer
#: offset, and about 1 µT of hard iron its continuous magnetometer calibration has not removed (each
#: µT of it turns the heading by up to 3° in London's 19.5 µT horizontal field: lab 03).
PHONE_UNIT = {
    "gyro_bias": tuple(np.radians([0.03, -0.02, 0.04])),
    "accel_bias": (0.04, -0.03, 0.05),
    "mag_hard_iron": (0.6, -0.4, 0.8),
    "gyro_bias_rw": 2e-5,
    "accel_bias_rw": 2e-5,
}

#: Each board's simulated unit, by board name.
BOARD_UNITS = {"nucleo-iks02a1": NUCLEO_UNIT, "mpu6050": MPU6050_UNIT, PHONE_BOARD: PHONE_UNIT}

#: The errors a unit can have, with their shapes (``sim.simulate_imu`` keywords).
ERROR_SHAPES = {
    "gyro_bias": (3,),
    "accel_bias": (3,),
    "accel_scale": (3,),
    "gyro_scale": (3,),
    "mag_hard_iron": (3,),
    "mag_soft_iron": (3, 3),
    "gyro_bias_rw": (),
    "accel_bias_rw": (),
}


def resolve_unit(board_name: str, unit="bundled", boards=BOARD_UNITS) -> dict:
    """The sensor errors (``sim.simulate_imu`` keywords, arrays) of ``board_name`` with ``unit``:
    "bundled" → its entry in ``boards``, None → {} (an ideal sensor), a dict → itself (errors it leaves
    out are zero). Unknown keys and wrong shapes raise ValueError."""
    if isinstance(unit, str):
        if unit != "bundled":
            raise ValueError(f"unit must be 'bundled', None or a dict of sensor errors, got {unit!r}")
        if board_name not in boards:
            raise ValueError(
                f"no bundled unit for board {board_name!r} (known: {', '.join(boards)}); "
                "pass unit=None for an ideal sensor or a dict of its errors"
            )
        unit = boards[board_name]
    unit = dict(unit or {})
    unknown = sorted(set(unit) - set(ERROR_SHAPES))
    if unknown:
        raise ValueError(f"unknown sensor error(s) {', '.join(unknown)} in unit; known: {', '.join(ERROR_SHAPES)}")
    errors = {k: np.array(v, float) for k, v in unit.items()}
    for k, v in errors.items():
        if v.shape != ERROR_SHAPES[k] or not np.all(np.isfinite(v)) or (k.endswith("_rw") and v < 0):
            raise ValueError(
                f"unit {k}: expected finite values of shape {ERROR_SHAPES[k]} (a walk ≥ 0), got {unit[k]!r}"
            )
    return errors
