"""Student-facing checks: randomised cases against kfkit's reference, one clear line back.

    check("01.kf_predict", kf_predict)
    ✅ 01.kf_predict: 12/12 random cases
    ❌ 01.kf_predict: 3/12 random cases; first failure kf_predict(x=0.1, …): expected (…), got (…). Hint: …
    ⏳ 01.kf_predict: not attempted yet (kf_predict still raises NotImplementedError)

A :class:`Checkpoint` separates the three steps a grader must keep apart: drawing cases
(with the reference answer) in the checker's process, calling the student's function, and
judging the raw output. Each lab registers its checkpoints in its own module (``lab01``, …).
"""
from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


@dataclass
class Case:
    """One input for a student's function, with what the reference makes of it."""

    args: dict
    expected: Any
    label: str = ""


@dataclass(frozen=True)
class Checkpoint:
    """A named check of one student function.

    cases(rng) → list of :class:`Case`; judge(case, got) → None when right, else a short
    "expected … got …" text; hint points at the idea, not the answer.
    """

    name: str
    function: str
    cases: Callable[[np.random.Generator], list]
    judge: Callable[[Case, Any], str | None]
    hint: str
    points: int = 1
    what: str = "random cases"


@dataclass
class CheckResult:
    name: str
    status: str  # "passed", "failed", "not attempted", "error"
    passed: int
    total: int
    points: float
    max_points: int
    message: str = field(repr=False)

    @property
    def ok(self) -> bool:
        return self.status == "passed"

    def __str__(self) -> str:
        return self.message

    def _ipython_display_(self):
        """check() has already printed the line; show nothing more in a notebook."""


#: one module per lab, ``labNN.py`` beside this file; each registers its checkpoints on import
LABS = tuple(sorted(m.name for m in pkgutil.iter_modules(__path__) if m.name.startswith("lab")))
REGISTRY: dict[str, Checkpoint] = {}


def register(*checkpoints: Checkpoint) -> None:
    for cp in checkpoints:
        REGISTRY[cp.name] = cp


def get(name: str) -> Checkpoint:
    """The checkpoint called ``name`` (e.g. '01.kf_predict')."""
    for lab in LABS:
        importlib.import_module(f"{__name__}.{lab}")
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"no checkpoint {name!r}; known: {', '.join(sorted(REGISTRY))}") from None


def fmt(value) -> str:
    """Compact display of an input or output: numbers to 4 significant digits, long arrays summarised."""
    if isinstance(value, (tuple, list)):
        return "(" + ", ".join(fmt(v) for v in value) + ")"
    if isinstance(value, np.ndarray) and value.ndim > 0:
        if value.size <= 4:
            return "[" + ", ".join(fmt(v) for v in value.ravel()) + "]"
        return f"array of {value.size} values [{fmt(value.flat[0])}, {fmt(value.flat[1])}, …]"
    if isinstance(value, (float, np.floating)):
        return f"{float(value) + 0.0:.4g}"  # + 0.0 shows −0 as 0
    return repr(value)


def call_repr(function: str, args: dict) -> str:
    return f"{function}(" + ", ".join(f"{k}={fmt(v)}" for k, v in args.items()) + ")"


def compare(expected, got, rtol=1e-6, atol=1e-9) -> str | None:
    """None if ``got`` matches ``expected`` (same structure, numbers within tolerance), else why not."""
    if isinstance(expected, tuple):
        if not isinstance(got, (tuple, list)) or len(got) != len(expected):
            return f"expected {len(expected)} values {fmt(expected)}, got {fmt(got)}"
        for e, g in zip(expected, got):
            if compare(e, g, rtol, atol) is not None:
                return f"expected {fmt(expected)}, got {fmt(tuple(got))}"
        return None
    try:
        g = np.asarray(got, dtype=float)
    except (TypeError, ValueError):
        return f"expected a number or array like {fmt(expected)}, got {type(got).__name__} {fmt(got)}"
    e = np.asarray(expected, dtype=float)
    if g.shape != e.shape:
        return f"expected shape {e.shape}, got shape {g.shape}"
    if not np.allclose(g, e, rtol=rtol, atol=atol, equal_nan=True):
        return f"expected {fmt(expected)}, got {fmt(got)}"
    return None


def matches(rtol=1e-6, atol=1e-9) -> Callable:
    """The judge that compares the answer with ``case.expected`` (:func:`compare` at these tolerances)."""
    return lambda case, got: compare(case.expected, got, rtol=rtol, atol=atol)


def run_checkpoint(cp: Checkpoint, answer: Callable, seed=None) -> CheckResult:
    """Run every case of ``cp`` on ``answer``; stop describing at the first failure."""
    cases = cp.cases(np.random.default_rng(seed))
    total, passed, first_failure = len(cases), 0, None
    head = f"{cp.name}: "
    for case in cases:
        try:
            got = answer(**case.args)
        except NotImplementedError:
            msg = f"⏳ {head}not attempted yet ({cp.function} still raises NotImplementedError: fill it in, run its cell, then this one)"
            return CheckResult(cp.name, "not attempted", 0, total, 0, cp.points, msg)
        except Exception as exc:  # the student's code failed: report it, never crash the notebook
            msg = f"❌ {head}{call_repr(cp.function, case.args)} raised {type(exc).__name__}: {exc}. Hint: {cp.hint}"
            return CheckResult(cp.name, "error", passed, total, 0, cp.points, msg)
        problem = cp.judge(case, got)
        if problem is None:
            passed += 1
        elif first_failure is None:
            first_failure = f"{case.label or call_repr(cp.function, case.args)}: {problem}"
    if passed == total:
        return CheckResult(cp.name, "passed", passed, total, cp.points, cp.points, f"✅ {head}{passed}/{total} {cp.what}")
    msg = f"❌ {head}{passed}/{total} {cp.what}; first failure {first_failure}. Hint: {cp.hint}"
    return CheckResult(cp.name, "failed", passed, total, 0, cp.points, msg)


def check(name: str, answer: Callable, seed=None) -> CheckResult:
    """Check the student's function ``answer`` against checkpoint ``name``; print and return the result."""
    result = run_checkpoint(get(name), answer, seed)
    print(result.message)
    return result
