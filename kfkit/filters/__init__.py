"""Reference filters, one module per lab's model; everything is importable from ``kfkit.filters``.

    linear    KalmanFilter (Joseph form), run_kf → FilterRun(x, P, y, S)
    roll      lab 01: scalar roll filter
"""
from .linear import FilterRun, KalmanFilter, run_kf
from .roll import integrate_rate, roll_kf, roll_kf_predict, roll_kf_steady_state, roll_kf_update
