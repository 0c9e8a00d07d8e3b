"""Every kfkit filter keeps the contract of kfkit.filters.contract, checked the same way for each.

The filters are the registry's (kfkit.filters.registry.FILTERS) and the general KalmanFilter; a test finds
every class in kfkit.filters with a step and a run, so a filter left out of the registry fails here. Each check
compares a filter with itself in another form (run against its stacked steps, a run in two pieces against one
run, a start given to the constructor against one given to reset); the filters' own tests hold their numbers to
independent oracles (filterpy, scipy, finite differences, χ² bounds).
"""

import dataclasses
import inspect
import pkgutil
from importlib import import_module

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import kfkit.filters
from kfkit import datasets
from kfkit.filters import KalmanFilter
from kfkit.filters.contract import Filter, FilterRun, Step, TunedFilter
from kfkit.filters.registry import FILTERS
from kfkit.frames import MAG_FIELD_LONDON, G

FIELD = np.array(MAG_FIELD_LONDON)


def roll_case():
    rng = np.random.default_rng(1)
    w, z = rng.normal(0.0, 0.5, 120), rng.normal(0.2, 0.1, 120)
    z[7::13] = np.nan
    return {"make": lambda **kw: FILTERS["roll-kf"].cls(**{"dt": 0.01, **kw}), "data": (w, z), "x0": 0.3, "P0": 0.02}


def tilt_case():
    rng = np.random.default_rng(2)
    w, z, ok = rng.normal(0.0, 0.5, 120), rng.normal(0.2, 0.1, 120), rng.random(120) > 0.3
    z[5::17] = np.nan
    return {
        "make": lambda **kw: FILTERS["tilt-bias-kf"].cls(**{"dt": 0.01, "accel_gating": "inflate", **kw}),
        "data": (w, z, ok),
        "x0": (0.3, 0.01),
        "P0": [[0.02, 0.001], [0.001, 0.005]],
    }


def attitude_data(n=200, rate_hz=100.0):
    """A board turning smoothly (scipy's rotations): gyro (rad/s), specific force (m/s²), field (µT) with noise,
    the magnetometer at half rate (NaN rows; the first sample has one)."""
    rng = np.random.default_rng(3)
    t = np.arange(n) / rate_hz
    omega = np.column_stack([0.4 * np.sin(2.0 * t), 0.3 * np.cos(1.5 * t), 0.5 + 0.2 * np.sin(t)])
    rot = [Rotation.from_euler("ZYX", [0.5, 0.2, -0.1])]
    for w in omega[:-1]:
        rot.append(rot[-1] * Rotation.from_rotvec(w / rate_hz))
    rot = Rotation.concatenate(rot)
    acc = rot.inv().apply([0.0, 0.0, -G]) + rng.normal(0.0, 0.05, (n, 3))
    mag = rot.inv().apply(FIELD) + rng.normal(0.0, 0.5, (n, 3))
    mag[1::2] = np.nan
    return omega + rng.normal(0.0, 0.005, (n, 3)), acc, mag


def euler_case(name):
    return lambda: {
        "make": lambda **kw: FILTERS[name].cls(**{"rate_hz": 100.0, "field_n": FIELD, **kw}),
        "data": attitude_data(),
        "x0": (-0.05, 0.25, 0.4),
        "P0": np.diag([2e-3, 2e-3, 1e-2]),
    }


def mekf_case():
    q0 = Rotation.from_euler("ZYX", [0.4, 0.25, -0.05]).as_quat()[[3, 0, 1, 2]]
    return {
        "make": lambda **kw: FILTERS["mekf"].cls(**{"rate_hz": 100.0, "field_n": FIELD, **kw}),
        "data": attitude_data(),
        "x0": np.r_[q0, 1e-3, -2e-3, 5e-4],
        "P0": np.diag([2e-3, 2e-3, 1e-2, 1e-5, 1e-5, 1e-5]),
        "consider": True,
    }


def sideslip_case(name):
    def case():
        rec = datasets.load("06_slalom_20kmh").head(6.0)  # starts from rest: the low-speed guard, then the model
        t = rec.t + np.random.default_rng(4).uniform(-2e-4, 2e-4, len(rec))  # a logger's jittery clock
        return {
            "make": lambda **kw: FILTERS[name].cls(**{"dt": 0.01, **kw}),
            "data": (t, rec["delta"], rec["yaw_rate"], rec["ay"], rec["vx"]),
            "samples": sideslip_samples,
            "x0": (0.01, 0.02),
            "P0": np.diag([1e-4, 2e-4]),
        }

    return case


def sideslip_samples(data):
    """A sideslip filter's step arguments: (δ, r, a_y, V_x, dt), dt from the timestamps and the nominal one first."""
    t, *signals = data
    return list(zip(*signals, [None] + np.diff(t).tolist()))


def kalman_case():
    rng = np.random.default_rng(5)
    F, H, B = np.array([[1.0, 0.01], [0.0, 0.98]]), np.array([[1.0, 0.0]]), np.array([[0.0], [0.01]])
    zs, us = rng.normal(0.0, 1.0, (80, 1)), rng.normal(0.0, 1.0, (80, 1))
    zs[9::11] = np.nan

    def make(x0=None, P0=None, **kw):
        return KalmanFilter(
            F,
            H,
            np.diag([1e-4, 1e-3]),
            [[0.1]],
            np.zeros(2) if x0 is None else x0,
            np.eye(2) if P0 is None else P0,
            B=B,
            **kw,
        )

    return {"make": make, "data": (zs, us), "x0": (0.5, -0.2), "P0": np.diag([0.3, 0.1])}


CASES = {
    "roll-kf": roll_case,
    "euler-ekf": euler_case("euler-ekf"),
    "euler-ekf-steps": euler_case("euler-ekf-steps"),
    "mekf": mekf_case,
    "tilt-bias-kf": tilt_case,
    "sideslip-kf": sideslip_case("sideslip-kf"),
    "sideslip-ekf": sideslip_case("sideslip-ekf"),
    "kalman-filter": kalman_case,
}
TUNED = [name for name in CASES if name in FILTERS]


def filters_for(tuned_only=False):
    """The case names a check runs on: every filter, or the lab filters (the registry's) only."""
    return TUNED if tuned_only else list(CASES)


def samples(case):
    return case.get("samples", lambda data: list(zip(*data)))(case["data"])


def stacked(steps):
    """The steps' fields as arrays, one row per step (what run must return)."""
    return {
        name: np.array([getattr(s, name) for s in steps], dtype=float)
        for name in ("x", "P", "y", "S", "x_prior", "P_prior")
    }


def assert_rows_equal(run, expected, names):
    """run's ``names`` equal the expected arrays; the unrolled Euler EKF equals its NumPy steps to rounding."""
    for name in names:
        got = getattr(run, name)
        assert got is not None, f"run.{name} is None"
        np.testing.assert_allclose(
            np.asarray(got, dtype=float), expected[name], rtol=1e-9, atol=1e-13, equal_nan=True, err_msg=f"run.{name}"
        )


def concatenated(runs):
    return {
        name: np.concatenate([getattr(r, name) for r in runs]) for name in ("x", "P", "y", "S", "x_prior", "P_prior")
    }


# --- every filter is covered ----------------------------------------------------------------------------------


def filter_classes():
    """Every class defined in a kfkit.filters module that has a step and a run."""
    found = set()
    for info in pkgutil.iter_modules(kfkit.filters.__path__):
        module = import_module(f"kfkit.filters.{info.name}")
        found |= {
            c
            for _, c in inspect.getmembers(module, inspect.isclass)
            if c.__module__ == module.__name__
            and not getattr(c, "_is_protocol", False)
            and callable(getattr(c, "step", None))
            and callable(getattr(c, "run", None))
        }
    return found


def test_every_filter_class_is_registered_and_checked_here():
    """TiltAttitude (kfkit.filters.tilt) is not a filter of its own: the firmware's twin, two TiltBiasKFs on raw
    counts, whose step returns the angles; it has no run."""
    registered = {entry.cls for entry in FILTERS.values()}
    assert filter_classes() == registered | {KalmanFilter}
    assert set(CASES) == set(FILTERS) | {"kalman-filter"}


# --- the contract ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", filters_for())
def test_keeps_the_protocol_and_its_state_is_a_dataclass(name):
    case = CASES[name]()
    f = case["make"]()
    assert isinstance(f, TunedFilter if name in FILTERS else Filter)
    f.step(*samples(case)[0])
    assert dataclasses.is_dataclass(f.state)


@pytest.mark.parametrize("name", filters_for())
def test_run_is_the_stacked_steps(name):
    case = CASES[name]()
    run = case["make"]().run(*case["data"])
    f = case["make"]()
    steps = [f.step(*s) for s in samples(case)]
    assert isinstance(run, FilterRun) and all(isinstance(s, Step) for s in steps)
    assert_rows_equal(run, stacked(steps), ("x", "y", "S"))


@pytest.mark.parametrize("name", filters_for())
def test_P_is_the_same_in_step_run_and_state(name):
    case = CASES[name]()
    run = case["make"]().run(*case["data"])
    f = case["make"]()
    steps = [f.step(*s) for s in samples(case)]
    assert_rows_equal(run, stacked(steps), ("P",))
    np.testing.assert_array_equal(f.state.P, steps[-1].P)


@pytest.mark.parametrize("name", filters_for())
def test_run_keeps_the_prior_of_every_step(name):
    """x⁻, P⁻ are the stacked steps' and an update never adds variance: no component's variance grows, and
    P⁻ − P is positive semidefinite. Not the latter for a filter with "consider" (Schmidt) updates (the MEKF's
    heading update keeps its gain off the tilt): with the gain zero on the considered part c of a = P Hᵀ,
    P⁻ − P = [[a_e a_eᵀ, a_e a_cᵀ], [a_c a_eᵀ, 0]] / S, which is indefinite when a_c ≠ 0."""
    case = CASES[name]()
    run = case["make"]().run(*case["data"])
    f = case["make"]()
    assert_rows_equal(run, stacked([f.step(*s) for s in samples(case)]), ("x_prior", "P_prior"))
    assert run.x_prior.shape == run.x.shape and run.P_prior.shape == run.P.shape
    gain = (run.P_prior - run.P).reshape(len(run.P), *np.shape(run.P[0]) or (1, 1))
    tol = -1e-12 * np.abs(run.P_prior).max()
    assert np.diagonal(gain, axis1=1, axis2=2).min() > tol
    if not case.get("consider"):
        assert np.linalg.eigvalsh(gain).min() > tol


@pytest.mark.parametrize("name", filters_for())
def test_run_starts_from_the_constructors_x0_and_P0(name):
    """The start given to the constructor is where run starts (RollKF, TiltBiasKF, SideslipKF and SideslipEKF used
    to drop it in run), and it matters."""
    case = CASES[name]()
    start = {"x0": case["x0"], "P0": case["P0"]}
    run = case["make"](**start).run(*case["data"])
    f = case["make"](**start)
    assert_rows_equal(run, stacked([f.step(*s) for s in samples(case)]), ("x", "P", "x_prior", "P_prior"))
    default = case["make"]().run(*case["data"])
    assert not np.allclose(run.x_prior[0], default.x_prior[0]) and not np.allclose(run.P_prior[0], default.P_prior[0])


@pytest.mark.parametrize("name", filters_for())
def test_reset_sets_the_start_of_every_later_run(name):
    case = CASES[name]()
    start = {"x0": case["x0"], "P0": case["P0"]}
    first = case["make"](**start).step(*samples(case)[0])  # the first step from that start
    f = case["make"]()
    f.reset(**start)
    for _ in range(2):  # the second run starts there again, not where the first ended
        assert_starts_like(f.run(*case["data"]), first)
    g = case["make"](**start)
    g.step(*samples(case)[1])
    g.reset()  # back to the constructor's start
    assert_starts_like(g.run(*case["data"]), first)


def assert_starts_like(run, step):
    for name in ("x_prior", "P_prior", "x", "P"):
        np.testing.assert_allclose(getattr(run, name)[0], getattr(step, name), rtol=1e-9, atol=1e-15, err_msg=name)


@pytest.mark.parametrize("name", filters_for())
def test_a_recording_resumed_in_pieces_is_one_run(name):
    case = CASES[name]()
    whole = case["make"]().run(*case["data"])
    f, k = case["make"](), len(case["data"][0]) // 3
    pieces = [f.run(*(a[:k] for a in case["data"])), f.run(*(a[k:] for a in case["data"]), resume=True)]
    got = concatenated(pieces)
    for name_ in ("x", "P", "y", "S", "x_prior", "P_prior"):
        np.testing.assert_allclose(
            got[name_], getattr(whole, name_), rtol=1e-9, atol=1e-13, equal_nan=True, err_msg=name_
        )


@pytest.mark.parametrize("name", filters_for())
def test_an_unknown_keyword_is_a_type_error(name):
    case = CASES[name]()
    with pytest.raises(TypeError):
        case["make"](no_such_setting=1.0)
    f = case["make"]()
    with pytest.raises(TypeError):
        f.run(*case["data"], no_such_option=True)
    with pytest.raises(TypeError):
        f.step(*samples(case)[0], no_such_option=True)


@pytest.mark.parametrize("name", filters_for(tuned_only=True))
def test_time_is_dt_or_rate_hz(name):
    case = CASES[name]()
    by_dt, by_rate = case["make"](dt=0.01, rate_hz=None), case["make"](dt=None, rate_hz=100.0)
    assert by_dt.dt == pytest.approx(0.01, rel=1e-15) and by_rate.dt == pytest.approx(0.01, rel=1e-15)
    with pytest.raises(TypeError, match="dt .* or .* rate_hz"):
        case["make"](dt=0.01, rate_hz=100.0)
    with pytest.raises(ValueError, match="pass rate_hz=100"):
        case["make"](dt=100.0, rate_hz=None)  # a rate where dt goes


@pytest.mark.parametrize("name", filters_for(tuned_only=True))
def test_settings_are_a_frozen_dataclass_named_for_the_filter(name):
    f = CASES[name]()["make"]()
    settings = f.settings
    assert dataclasses.is_dataclass(settings) and type(settings).__dataclass_params__.frozen
    assert type(settings).__name__ in {c.__name__ + "Settings" for c in type(f).__mro__[:-1]}
    first = next(f.name for f in dataclasses.fields(settings) if isinstance(f.default, float))
    changed = dataclasses.replace(settings, **{first: 2 * getattr(settings, first)})
    assert (
        CASES[name]()["make"](settings=changed).settings
        == changed
        == CASES[name]()["make"](**{first: 2 * getattr(settings, first)}).settings
    )
