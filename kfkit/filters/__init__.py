"""Reference filters, one module per lab's model, all after one contract (:mod:`kfkit.filters.contract`).

The contract (x-io Fusion's and VQF's shape: settings with units and defaults, then steps):

* construct with the sample period ``dt`` (or ``rate_hz``), a frozen ``<Filter>Settings`` dataclass whose every
  field has a meaning, a unit and a default, and the start ``x0``, ``P0``; keyword changes apply on top of the
  settings (``TiltBiasKF(0.01, r=1e-4)`` = ``TiltBiasKF(0.01, TiltBiasKFSettings(r=1e-4))``);
* ``step(...)`` takes one sample and returns a :class:`Step` ``(x, P, y, S)`` with the prior ``x_prior, P_prior``;
* ``run(..., resume=False)`` filters a recording from the start and returns a :class:`FilterRun` (the steps,
  stacked) or a subclass whose named properties read it (``TiltRun.angle``, ``SideslipRun.beta``,
  ``AttitudeRun.euler``); ``reset(x0, P0)`` goes back to the start; ``state`` is a dataclass.

    contract  Filter, TunedFilter (the Protocols), Step, FilterRun, State; sample_period, configure, check_settings
    registry  FILTERS (every lab filter by name), methods (a front door's filters)
    linear    KalmanFilter (Joseph form: predict, update, step, run)
    roll      lab 01: RollKF + RollKFSettings; the textbook forms roll_kf_predict, roll_kf_update, roll_kf
    tilt      lab 05: TiltBiasKF + TiltBiasKFSettings ([angle, gyro bias] per axis, accelerometer gating) → TiltRun;
              the textbook forms tilt_kf_predict, tilt_kf_update, tilt_kf (any 2×2 Q); TiltAttitude, roll and
              pitch from raw counts as the mpu6050_tilt_kf sketch computes them
    sideslip  lab 06: SideslipKF + SideslipKFSettings (bicycle-model KF, D-term, low-speed guard) → SideslipRun;
              the lesson's other estimators (kinematic integration, the copied kinematic KF)
    sideslip_ekf       SideslipEKF + SideslipEKFSettings: the same model with saturating tyres (the race-track fix)
    sideslip_estimate  estimate_sideslip (the EKF by default, the KF with model=linear_model), compare_estimators
    attitude        lab 04's front door estimate_attitude, over:
    attitude_run    AttitudeRun (quat, euler, bias from x; P_attitude), check_inputs, tilt_heading, learn_field
    euler_ekf       EulerAttitudeEKF + EulerAttitudeEKFSettings and the textbook step functions (run = a loop over step)
    euler_ekf_fast  FastEulerAttitudeEKF: the same filter unrolled on floats, held equal by a test
    mekf            MultiplicativeEKF + MultiplicativeEKFSettings, its MultiplicativeEKFState and named steps
    mag_gate        MagGate, the MEKF's magnetic-disturbance gate
    error_covariance   the MEKF's 6×6 covariance as 36 floats: its prediction and sequential scalar updates
                       with consider (Schmidt) blocks, the arithmetic written out

The names in ``__all__`` below are importable from ``kfkit.filters``; the helpers (``tilt_heading``,
``learn_field``, ``jacobian_rows``, ``MagGate``, …) from their own modules.
"""

from .attitude import estimate_attitude
from .attitude_run import AttitudeRun
from .contract import Filter, FilterRun, State, Step, TunedFilter
from .euler_ekf import (
    EulerAttitudeEKF,
    EulerAttitudeEKFSettings,
    attitude_jacobian,
    attitude_measurement,
    euler_ekf_predict,
    euler_ekf_update,
    euler_process_noise,
)
from .euler_ekf_fast import FastEulerAttitudeEKF
from .linear import KalmanFilter
from .mekf import MultiplicativeEKF, MultiplicativeEKFSettings
from .registry import FILTERS
from .roll import RollKF, RollKFSettings, integrate_rate, roll_kf, roll_kf_predict, roll_kf_steady_state, roll_kf_update
from .sideslip import (
    SideslipKF,
    SideslipKFSettings,
    SideslipRun,
    copied_kinematic_kf,
    kinematic_sideslip,
    sideslip_step,
)
from .sideslip_ekf import SideslipEKF, SideslipEKFSettings
from .sideslip_estimate import compare_estimators, estimate_sideslip
from .tilt import (
    TiltAttitude,
    TiltBiasKF,
    TiltBiasKFSettings,
    TiltRun,
    accel_static_ok,
    protocol_angles,
    tilt_kf,
    tilt_kf_predict,
    tilt_kf_update,
)

__all__ = [
    "estimate_attitude",
    "AttitudeRun",
    "Filter",
    "FilterRun",
    "State",
    "Step",
    "TunedFilter",
    "EulerAttitudeEKF",
    "EulerAttitudeEKFSettings",
    "attitude_jacobian",
    "attitude_measurement",
    "euler_ekf_predict",
    "euler_ekf_update",
    "euler_process_noise",
    "FastEulerAttitudeEKF",
    "KalmanFilter",
    "MultiplicativeEKFSettings",
    "MultiplicativeEKF",
    "FILTERS",
    "RollKF",
    "RollKFSettings",
    "integrate_rate",
    "roll_kf",
    "roll_kf_predict",
    "roll_kf_steady_state",
    "roll_kf_update",
    "SideslipKF",
    "SideslipKFSettings",
    "SideslipRun",
    "copied_kinematic_kf",
    "kinematic_sideslip",
    "sideslip_step",
    "SideslipEKF",
    "SideslipEKFSettings",
    "compare_estimators",
    "estimate_sideslip",
    "TiltAttitude",
    "TiltBiasKF",
    "TiltBiasKFSettings",
    "TiltRun",
    "accel_static_ok",
    "protocol_angles",
    "tilt_kf",
    "tilt_kf_predict",
    "tilt_kf_update",
]
