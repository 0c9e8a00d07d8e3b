"""Reference filters, one module per lab's model; everything is importable from ``kfkit.filters``.

    linear    KalmanFilter (Joseph form), run_kf → FilterRun(x, P, y, S)
    roll      lab 01: scalar roll filter
    sideslip  lab 06: vehicle sideslip β with a bicycle-model KF (D-term, low-speed guard)
    attitude  lab 04: Euler-angle EKF and multiplicative quaternion EKF, estimate_attitude → AttitudeResult
    tilt      lab 05: TiltBiasKF, [angle, gyro bias] per axis with accelerometer gating → TiltRun;
              TiltAttitude, roll and pitch from raw counts as the mpu6050_tilt_kf sketch computes them
"""
from .linear import FilterRun, KalmanFilter, run_kf
from .roll import integrate_rate, roll_kf, roll_kf_predict, roll_kf_steady_state, roll_kf_update
from .tilt import TiltAttitude, TiltBiasKF, TiltRun, accel_static_ok, protocol_angles
from .attitude import (AttitudeResult, EulerAttitudeEKF, MultiplicativeEKF, attitude_jacobian, attitude_measurement,
                       estimate_attitude, euler_ekf_predict, euler_ekf_update, euler_process_noise, euler_rates)
from .sideslip import (SideslipResult, compare_estimators, copied_kinematic_kf, estimate_sideslip, kinematic_sideslip,
                       sideslip_step)
