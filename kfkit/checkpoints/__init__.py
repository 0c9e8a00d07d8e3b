"""Student-facing checks: randomised cases against kfkit's reference, one clear line back.

    check("01.kf_predict", kf_predict)
    ✅ 01.kf_predict: 12/12 random cases
    ❌ 01.kf_predict: 3/12 random cases; first failure kf_predict(x=0.1, …): expected (…), got (…). Hint: …
    ⏳ 01.kf_predict: not attempted yet (kf_predict still raises NotImplementedError)

A :class:`Checkpoint` separates the three steps a grader must keep apart: drawing cases
(with the reference answer) in the checker's process, calling the student's function, and
judging the raw output. Each lab registers its checkpoints in its own module (``lab01``, …); a lab with many
checkpoints may keep them in modules of their own that its ``labNN`` imports (``lab04``: ``ekf_attitude_core``,
``ekf_attitude_optional``).

The hint matches the kind of failure (:func:`failure_hint`): a checkpoint's own hint, about its idea, only
for wrong numbers; an exception gets the hint of its kind (:data:`EXCEPTION_KINDS`: a function that cannot
take arrays, shapes that do not fit, …), NaN or inf and an answer of the wrong form (count, shape, None) theirs.
"""

from __future__ import annotations

import enum
import importlib
import pkgutil
import re
import textwrap
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

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


class Status(str, enum.Enum):
    """The outcome of a checkpoint: a check's result, a gradebook row's ``status`` column, the class report's
    bars. A check ends passed, failed, error (the function raised) or not attempted; the grader adds the rest."""

    PASSED = "passed"
    FAILED = "failed"
    ERROR = "error"  # the student's function raised
    NOT_ATTEMPTED = "not attempted"  # it still raises NotImplementedError
    MISSING = "missing"  # no such function after the notebook ran
    TIMED_OUT = "timed out"  # the call, a function it calls or the whole submission ran out of time
    OVER_LIMIT = "over limit"  # the submission went over its memory or CPU-time limit
    NOT_GRADED = "not graded"  # not a notebook, or a grader error (regrade)
    REFUSED = "refused"  # not opened: a link or not a regular file in the folder graded
    UNKNOWN = "unknown"  # a row of a gradebook written before the status column, short of full points

    def __str__(self) -> str:
        return self.value


@dataclass
class CheckResult:
    name: str
    status: Status  # PASSED, FAILED, NOT_ATTEMPTED or ERROR
    passed: int
    total: int
    points: float
    max_points: int
    message: str = field(repr=False)

    @property
    def ok(self) -> bool:
        return self.status == Status.PASSED

    def __str__(self) -> str:
        return self.message

    def _ipython_display_(self):
        """check() has already printed the line; show nothing more in a notebook."""


#: one module per lab, ``labNN.py`` beside this file; importing it registers the lab's checkpoints (those of the modules
#: it imports too), in the lab's order
LABS = tuple(sorted(m.name for m in pkgutil.iter_modules(__path__) if m.name.startswith("lab")))
REGISTRY: dict[str, Checkpoint] = {}
MESSAGE_WIDTH = 100  # characters per printed line of a check


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


def fmt(value, digits: int = 4) -> str:
    """Compact display of an input or output: numbers to ``digits`` significant digits, long arrays summarised."""
    if isinstance(value, (tuple, list)):
        return "(" + ", ".join(fmt(v, digits) for v in value) + ")"
    if isinstance(value, np.ndarray) and value.ndim > 0:
        if value.size <= 4:
            return "[" + ", ".join(fmt(v, digits) for v in value.ravel()) + "]"
        return f"array of shape {value.shape} [{fmt(value.flat[0], digits)}, {fmt(value.flat[1], digits)}, …]"
    if isinstance(value, (bool, np.bool_)):
        return repr(bool(value))
    if isinstance(value, (int, np.integer)):
        return repr(int(value))  # not numpy 2's np.int64(1)
    if isinstance(value, (float, np.floating)):
        return f"{float(value) + 0.0:.{digits}g}"  # + 0.0 shows −0 as 0
    return repr(value)


def fmt_pair(expected, got) -> tuple[str, str]:
    """``expected`` and ``got`` (numbers) with the fewest significant digits (at least 4) that tell them apart."""
    for digits in range(4, 18):
        e, g = fmt(expected, digits), fmt(got, digits)
        if e != g:
            break
    return e, g


def call_repr(function: str, args: dict) -> str:
    return f"{function}(" + ", ".join(f"{k}={fmt(v)}" for k, v in args.items()) + ")"


def _count(n: int) -> str:
    return f"{n:,}"


def nonfinite_problem(got, expected=None, where="") -> str | None:
    """Why ``got`` is not an answer when it holds NaN or ±inf where ``expected`` holds a finite number (or where
    the structure of ``expected`` is unknown); None otherwise. Every judge runs after this: a comparison with
    NaN is False, so ``ours >= limit`` or ``err > tol`` would let a NaN answer through."""
    if isinstance(got, dict):
        return next((p for k, v in got.items() if (p := nonfinite_problem(v, None, f"{where}[{k!r}]"))), None)
    if isinstance(got, (tuple, list)) and not _numeric(got):
        same = isinstance(expected, (tuple, list)) and len(expected) == len(got)
        return next(
            (
                p
                for i, v in enumerate(got)
                if (p := nonfinite_problem(v, expected[i] if same else None, f"{where}output {i + 1} of {len(got)}"))
            ),
            None,
        )
    if not _numeric(got):
        return None
    g = np.asarray(got, dtype=float)
    bad = ~np.isfinite(g)
    if expected is not None and _numeric(expected):
        e = np.asarray(expected, dtype=float)
        if e.shape == g.shape:
            bad &= np.isfinite(e)
    if not bad.any():
        return None
    kinds = " or ".join(k for k, m in (("NaN", np.isnan(g)), ("inf", np.isinf(g))) if (m & bad).any())
    label = f"{where}: " if where else ""
    if g.ndim == 0:
        return f"{label}got {kinds} where a finite number is expected"
    first = np.unravel_index(int(np.argmax(bad)), g.shape)
    index = int(first[0]) if g.ndim == 1 else tuple(int(i) for i in first)
    return (
        f"{label}{_count(int(bad.sum()))} of {_count(g.size)} values are {kinds} (the first at index {index}): "
        "every value must be a finite number"
    )


def _numeric(value) -> bool:
    """True for a number or a (nested) sequence/array of numbers of one shape."""
    if isinstance(value, (str, bytes)) or value is None:
        return False
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        return False
    return a.dtype.kind in "biuf"


def _first_difference(e: np.ndarray, g: np.ndarray, rtol, atol) -> str:
    """'at index 7: expected 0.1234567, got 0.1234599' for the first element outside tolerance."""
    bad = ~np.isclose(g, e, rtol=rtol, atol=atol, equal_nan=True)
    first = np.unravel_index(int(np.argmax(bad)), e.shape)
    index = int(first[0]) if e.ndim == 1 else tuple(int(i) for i in first)
    want, have = fmt_pair(e[first], g[first])
    return f"first difference at index {index}: expected {want}, got {have}"


def compare(expected, got, rtol=1e-6, atol=1e-9) -> str | None:
    """None if ``got`` matches ``expected`` (same structure, numbers within tolerance), else why not:
    a wrong count or shape is named as such, a wrong value shows the first element that differs."""
    if isinstance(expected, tuple):
        if not isinstance(got, (tuple, list)) or len(got) != len(expected):
            n = len(got) if isinstance(got, (tuple, list)) else 1
            return f"expected {len(expected)} values {fmt(expected)}, got {n} value{'s' * (n != 1)}: {fmt(got)}"
        for i, (e, g) in enumerate(zip(expected, got)):
            problem = compare(e, g, rtol, atol)
            if problem is not None:
                return f"value {i + 1} of {len(expected)}: {problem}"
        return None
    try:
        g = np.asarray(got, dtype=float)
    except (TypeError, ValueError):
        return f"expected a number or array like {fmt(expected)}, got {type(got).__name__} {fmt(got)}"
    e = np.asarray(expected, dtype=float)
    if g.shape != e.shape:
        return f"shape mismatch: expected shape {e.shape}, got shape {g.shape}"
    if np.allclose(g, e, rtol=rtol, atol=atol, equal_nan=True):
        return None
    if e.ndim == 0:
        want, have = fmt_pair(float(e), float(g))
        text = f"expected {want}, got {have}"
    else:
        text = f"expected {fmt(e)}, got {fmt(g)}; {_first_difference(e, g, rtol, atol)}"
    if np.any(e != 0) and np.allclose(g, np.degrees(e), rtol=max(rtol, 1e-9), atol=atol):
        text += " — that is the answer in degrees: return radians"
    return text


def structural(problem: str | None) -> bool:
    """True when :func:`compare`'s ``problem`` is about the answer's form (count, shape, type), not its values."""
    return problem is not None and any(
        p in problem for p in ("shape mismatch", "expected a number or array", " values: ", " value: ")
    )  # "got 1 value: …" too


def matches(rtol=1e-6, atol=1e-9) -> Callable:
    """The judge that compares the answer with ``case.expected`` (:func:`compare` at these tolerances)."""
    return lambda case, got: compare(case.expected, got, rtol=rtol, atol=atol)


@dataclass(frozen=True)
class ExceptionKind:
    """A kind of exception a student's function raises: any class named in ``names`` (the exception's class or a
    base) whose message holds one of ``words`` (any message when empty). Matched by name and text, because the grader
    rebuilds a kernel's exception from its class name and message (:mod:`kfkit.grading.core`)."""

    names: tuple
    words: tuple
    hint: str  # may name {function} and {parameters}


#: The kinds of exception, tried in order; the first that matches gives the hint (:func:`failure_hint`).
EXCEPTION_KINDS = (
    ExceptionKind(
        ("TypeError", "ValueError"),
        ("0-dimensional arrays", "length-1 arrays", "size-1 arrays", "truth value of an array"),
        "{function} is called with NumPy arrays, whole columns at once as the lab calls it: use NumPy's "
        "functions (np.arctan2, np.sqrt, np.sin, …), not math's, which take one number, and np.where "
        "instead of an if on an array",
    ),
    ExceptionKind(
        ("ValueError", "IndexError", "LinAlgError", "AxisError"),
        (
            "broadcast",
            "core dimension",
            "not aligned",
            "reshape",
            "out of bounds",
            "too many indices",
            "dimension",
            "must be square",
            "shape",
        ),
        "two arrays' shapes do not fit together: print the shape of each input and of what you build from "
        "it (x.shape), and check the order of each matrix product (A @ B needs A's columns = B's rows)",
    ),
    ExceptionKind(
        ("TypeError",),
        ("positional argument", "keyword argument"),
        "the check calls {function}({parameters}) by these names: keep the exercise's parameters as given",
    ),
    ExceptionKind(
        ("NameError", "UnboundLocalError"),
        (),
        "a name {function} uses is not defined: define it inside the function (or run the cell that "
        "defines it first), and check its spelling",
    ),
    ExceptionKind(
        ("ZeroDivisionError",),
        (),
        "a division by zero: which input can be zero here, and what must the function give then?",
    ),
    ExceptionKind(
        ("ValueError",),
        ("math domain error",),
        "math.sqrt, asin or acos got a number outside its domain: check the sign, or clip a ratio into "
        "[−1, 1] (np.clip) where rounding can push it just outside",
    ),
)
OTHER_EXCEPTION_HINT = "run {function} yourself on the input shown, to see which line raises and why"
NONFINITE_HINT = (
    "NaN or inf comes from 0/0, a square root or arcsin of a number out of range, a log of 0, or a NaN "
    "in the inputs (a magnetometer row without a sample): print the values on that input step by step "
    "to find where it first appears"
)
NONE_HINT = "a function returns None when no return statement runs: does {function} end with return …?"
FORM_HINT = "return {form}, as the exercise's docstring says"
_FORM_WORDS = re.compile(r"\b(got shapes? \(|has shape \()")  # judges' own words for a wrong shape


def _form(expected) -> str | None:
    """'an array of shape (3,)', 'a tuple of 2 values (…)', 'one number': the form of ``expected``, None if unknown."""
    if isinstance(expected, tuple):
        forms = [_form(e) or "…" for e in expected]
        if set(forms) == {"one number"}:
            return f"a tuple of {len(forms)} numbers"
        if len(set(forms)) == 1 and forms[0].startswith("an array"):
            return f"a tuple of {len(forms)} arrays of shape {np.shape(expected[0])}"
        return f"a tuple of {len(forms)} values (" + ", ".join(forms) + ")"
    if _numeric(expected):
        shape = np.shape(expected)
        return "one number" if shape == () else f"an array of shape {shape}"
    return None


def failure_hint(
    cp: Checkpoint,
    case: Case,
    exc: BaseException | None = None,
    got=None,
    problem: str | None = None,
    nonfinite: bool = False,
) -> str:
    """The hint for the first failure of ``cp``, by its kind: an exception by :data:`EXCEPTION_KINDS`; NaN or inf;
    None returned; an answer of the wrong form (compare's count, shape or type problems, a judge's "got shape");
    and only for wrong numbers the checkpoint's own hint."""
    names = {"function": cp.function, "parameters": ", ".join(case.args)}
    if exc is not None:
        classes = {c.__name__ for c in type(exc).__mro__}
        text = str(exc)
        kind = next(
            (k for k in EXCEPTION_KINDS if classes & set(k.names) and (not k.words or any(w in text for w in k.words))),
            None,
        )
        return (kind.hint if kind is not None else OTHER_EXCEPTION_HINT).format(**names)
    if nonfinite:
        return NONFINITE_HINT
    if got is None:
        return NONE_HINT.format(**names)
    if structural(problem) or _FORM_WORDS.search(problem or ""):
        form = _form(case.expected)
        return (
            FORM_HINT.format(form=form)
            if form
            else FORM_HINT.format(form="what the exercise asks for (how many values, each of which shape)")
        )
    return cp.hint


def run_checkpoint(cp: Checkpoint, answer: Callable, seed=None) -> CheckResult:
    """Run every case of ``cp`` on ``answer``; stop describing at the first failure."""
    cases = cp.cases(np.random.default_rng(seed))
    total, passed, first_failure = len(cases), 0, None
    head = f"{cp.name}: "
    for case in cases:
        try:
            got = answer(**case.args)
        except NotImplementedError as exc:
            if getattr(exc, "stale_definition", False):  # the exercise guard set an older definition aside: it says why
                return CheckResult(cp.name, Status.NOT_ATTEMPTED, 0, total, 0, cp.points, f"⏳ {head}stale: {exc}")
            stub = traceback.extract_tb(exc.__traceback__)[
                -1
            ].name  # where it was raised: a given function may call a stub
            what = (
                cp.function
                if stub in (cp.function, getattr(answer, "__name__", None))
                else f"{cp.function} calls {stub}, which"
            )
            msg = (
                f"⏳ {head}not attempted yet ({what} still raises NotImplementedError: fill it in, run its cell, "
                f"then this one)"
            )
            return CheckResult(cp.name, Status.NOT_ATTEMPTED, 0, total, 0, cp.points, msg)
        except Exception as exc:  # the student's code failed: report it, never crash the notebook
            where = f"on {case.label}, " if case.label else ""
            msg = (
                f"❌ {head}{where}{call_repr(cp.function, case.args)} raised {type(exc).__name__}: {exc}. "
                f"Hint: {failure_hint(cp, case, exc)}"
            )
            return CheckResult(cp.name, Status.ERROR, passed, total, 0, cp.points, msg)
        nonfinite = nonfinite_problem(got, case.expected)
        returned_none = got is None and case.expected is not None  # no judge needs to see it (a missing return)
        problem = nonfinite or (
            f"got None, expected {_form(case.expected) or 'a value'}" if returned_none else cp.judge(case, got)
        )
        if problem is None:
            passed += 1
        elif first_failure is None:
            first_failure = f"{case.label or call_repr(cp.function, case.args)}: {problem}"
            hint = failure_hint(cp, case, got=got, problem=problem, nonfinite=nonfinite is not None)
    if passed == total:
        return CheckResult(
            cp.name, Status.PASSED, passed, total, cp.points, cp.points, f"✅ {head}{passed}/{total} {cp.what}"
        )
    msg = f"❌ {head}{passed}/{total} {cp.what}; first failure {first_failure}. Hint: {hint}"
    return CheckResult(cp.name, Status.FAILED, passed, total, 0, cp.points, msg)


def check(name: str, answer: Callable, seed=None) -> CheckResult:
    """Check the student's function ``answer`` against checkpoint ``name``; print and return the result."""
    result = run_checkpoint(get(name), answer, seed)
    print(wrap_message(result.message))
    return result


def wrap_message(message: str, width: int = MESSAGE_WIDTH) -> str:
    """``message`` broken into lines of at most ``width`` characters at spaces only, so that no number,
    formula or name is split (a narrow notebook would otherwise break it anywhere)."""
    return textwrap.fill(message, width, subsequent_indent="   ", break_long_words=False, break_on_hyphens=False)
