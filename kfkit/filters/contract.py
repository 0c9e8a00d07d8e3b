"""The filter contract: what every kfkit filter takes, keeps and returns (tests/test_filter_contract.py holds
every filter to it).

    Filter          reset, step → Step, run → FilterRun (the Protocol)
    TunedFilter     a Filter with a sample period ``dt`` and a ``<Filter>Settings`` dataclass (every lab's filter)
    Step            one sample: x, P, y, S and the prior x⁻, P⁻
    FilterRun       a recording: the same, one row per sample
    State           x and P between samples (a filter with more memory subclasses it)
    sample_period   dt (s) from ``dt`` or ``rate_hz``, checked
    shaped          an x0 or P0 as a float array of the filter's shape, checked
    configure       a settings dataclass with keyword changes on top
    check_settings  the one validation of a settings dataclass (called by each one's ``__post_init__``)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

MAX_DT = 1.0  # s: the kit's filters run at 10 Hz–1 kHz; a longer "dt" is a rate passed where dt goes


@dataclass(frozen=True)
class Step:
    """What one ``step`` of any kfkit filter returns; unpacks as ``x, P, y, S = f.step(...)``.

    x        state after the update, (n,)            P        its covariance, (n, n)
    y        innovation z − h(x⁻), (m,)              S        its covariance, (m, m); y, S NaN where no update was made
    x_prior  state after the prediction x⁻, (n,)     P_prior  its covariance P⁻, (n, n)

    P is the covariance of the filter's error state, the same in ``step``, ``run`` and ``state``. Scalar
    filters (lab 01) hold floats in the same places.
    """

    x: Any
    P: Any
    y: Any
    S: Any
    x_prior: Any = None
    P_prior: Any = None

    def __iter__(self):
        return iter((self.x, self.P, self.y, self.S))


@dataclass
class FilterRun:
    """A filter's history over a recording, one row per sample: ``run`` is the ``step`` of every sample, stacked.

    x, P              estimates after the update, (N, n) and (N, n, n) — (N,) each for a scalar filter
    y, S              innovations z − h(x⁻) and their covariances, (N, m), (N, m, m) — or (N,); NaN where no update
    x_prior, P_prior  the predictions x⁻, P⁻ of every sample (what an RTS smoother and the prior NEES need)
    """

    x: np.ndarray
    P: np.ndarray
    y: np.ndarray
    S: np.ndarray
    x_prior: np.ndarray = None
    P_prior: np.ndarray = None


@dataclass
class State:
    """What a filter carries from one sample to the next: x and its covariance P (x None: not started yet,
    the first samples give it)."""

    x: Any
    P: Any


@runtime_checkable
class Filter(Protocol):
    """The contract of every kfkit filter.

    reset(x0=None, P0=None)       put the state at the start. The constructor's x0, P0 are the start; a reset's
                                  x0 or P0 replaces that part of it (for later resets and runs too); None keeps it.
                                  An x0 left None is taken from the data: the first sample (``step``) or the first
                                  samples that hold the measurement (``run``).
    step(*sample) → Step          one predict + update; a NaN measurement skips its update
    run(*recording, resume=False) → FilterRun
                                  a ``step`` per sample, stacked: from the start (``reset()`` first) or, with
                                  ``resume=True``, from where the last step or run left off (a recording fed in
                                  pieces gives what one run gives)
    state                         a dataclass: what the filter carries between samples (its P is Step's P)

    An unknown keyword is a TypeError, here and in the constructor.
    """

    state: Any

    def reset(self, x0=None, P0=None) -> None: ...

    def step(self, *sample) -> Step: ...

    def run(self, *recording, resume: bool = False) -> FilterRun: ...


@runtime_checkable
class TunedFilter(Filter, Protocol):
    """A lab's filter: a :class:`Filter` constructed as ``Filter(dt, settings, *, rate_hz=None, x0=None, P0=None,
    **changes)``.

    dt        sample period, s (or ``rate_hz``, Hz, where a recording gives a rate; not both)
    settings  a frozen ``<Filter>Settings`` dataclass, every field with meaning, unit and default in its docstring's
              table; keyword ``changes`` apply on top
              (``RollKF(0.01, r=1e-4)`` = ``RollKF(0.01, RollKFSettings(r=1e-4))``)
    """

    dt: float
    settings: Any


def sample_period(owner, dt=None, rate_hz=None) -> float:
    """The sample period dt (s) from exactly one of ``dt`` (s) and ``rate_hz`` (Hz), both checked."""
    if (dt is None) == (rate_hz is None):
        raise TypeError(
            f"{owner}: give the sample period dt (s) or the sample rate rate_hz (Hz), "
            f"{'not both' if dt is not None else 'got neither'}"
        )
    name, value = ("dt", dt) if rate_hz is None else ("rate_hz", rate_hz)
    if not _is_number(value) or not value > 0:
        raise ValueError(f"{owner}: {name} must be a positive number, got {value!r}")
    dt = float(dt) if rate_hz is None else 1.0 / float(rate_hz)
    if dt > MAX_DT:
        raise ValueError(
            f"{owner}: dt = {dt:g} s is longer than {MAX_DT:g} s; if {dt:g} is a sample rate, pass rate_hz={dt:g}"
        )
    return dt


def shaped(owner, name, value, shape) -> np.ndarray:
    """``value`` (an x0 or P0) as a new float array of ``shape``, or a ValueError naming the owner, the name and both
    shapes."""
    arr = np.array(value, dtype=float)
    if arr.size == math.prod(shape):
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise ValueError(f"{owner}: {name} must have shape {shape}, got {np.shape(value)}")
    return arr


def configure(settings_cls, settings, changes, owner):
    """The settings a filter runs with: ``settings`` (default ``settings_cls()``) with the keyword
    ``changes`` applied, as VQF's ``params`` + keyword overrides. Unknown names are an error."""
    base = settings_cls() if settings is None else settings
    if not isinstance(base, settings_cls):
        raise TypeError(f"{owner}: settings must be a {settings_cls.__name__}, got {type(base).__name__}")
    names = [f.name for f in fields(settings_cls)]
    unknown = sorted(set(changes) - set(names))
    if unknown:
        raise TypeError(
            f"{owner}: unknown setting {', '.join(unknown)}; {settings_cls.__name__} has {', '.join(names)}"
        )
    return replace(base, **changes) if changes else base


def _is_number(value) -> bool:
    return (
        isinstance(value, (int, float, np.integer, np.floating))
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


def check_settings(settings, positive=(), non_negative=(), optional=(), flags=(), choices=None):
    """Validate a settings dataclass: each field is in exactly one of the groups

    positive      a finite number > 0          non_negative  a finite number ≥ 0
    flags         True or False                choices       {field: allowed values}

    and ``optional`` names fields of the first two that may also be None. A ValueError names the settings class,
    the field, what was expected and what it got; a field in no group (or in two) is a TypeError.
    """
    choices = choices or {}
    owner = type(settings).__name__
    groups = [set(positive), set(non_negative), set(flags), set(choices)]
    names = [f.name for f in fields(settings)]
    counted = {name: sum(name in g for g in groups) for name in names}
    bad = [name for name, n in counted.items() if n != 1] + sorted(set().union(*groups, optional) - set(names))
    if bad:
        raise TypeError(f"{owner}: check_settings must put each field in one group; wrong for {', '.join(bad)}")
    for name in names:
        value = getattr(settings, name)
        if value is None and name in optional:
            continue
        if name in choices:
            ok, expected = value in choices[name], "one of " + ", ".join(map(str, choices[name]))
        elif name in flags:
            ok, expected = isinstance(value, bool), "True or False"
        else:
            zero_ok = name in non_negative
            ok = _is_number(value) and (value >= 0 if zero_ok else value > 0)
            expected = ("a number ≥ 0" if zero_ok else "a positive number") + (" or None" if name in optional else "")
        if not ok:
            raise ValueError(f"{owner}: {name} must be {expected}, got {value!r}")


def require_positive(owner, zero_ok=(), none_ok=(), **values):
    """Raise ValueError naming the first value that is not a finite number > 0 (≥ 0 for names in ``zero_ok``;
    None allowed for names in ``none_ok``): the check of a constructor's plain numbers (the capture
    :class:`~kfkit.capture.recorder.Recorder`'s); a settings dataclass has :func:`check_settings`."""
    for name, value in values.items():
        if value is None and name in none_ok:
            continue
        if not (_is_number(value) and (value >= 0 if name in zero_ok else value > 0)):
            what = "a number ≥ 0" if name in zero_ok else "a positive number"
            raise ValueError(f"{owner}: {name} must be {what}{' or None' if name in none_ok else ''}, got {value!r}")
