"""What crosses between the grader and a student's kernel.

Grader → kernel: the cases' inputs, pickled (cloudpickle when they hold lambdas; the kernel may
trust the grader) inside a code cell
that runs ``_kernel_side.call`` in a private namespace. Kernel → grader: one line of JSON between
two copies of a random nonce (:func:`extract`), a report of each case's output, or of what it raised
(class name and message), and :func:`decode` turns each output into None, bools, ints, floats, strings,
lists, tuples, dicts, bool/int/unsigned/float arrays, object arrays of these, :class:`Returned` for
dataclasses and :class:`Unsupported` for any other type (sent as its name only); nothing is ever
unpickled or evaluated, and sizes are capped: numbers in the kernel (:data:`MAX_NUMBERS`), characters
here before parsing (:data:`MAX_PAYLOAD`).
"""

from __future__ import annotations

import base64
import json
import pickle
import secrets
import types
from pathlib import Path

import numpy as np

KERNEL_SIDE = (Path(__file__).with_name("_kernel_side.py")).read_text()
MAX_NUMBERS = 2_000_000  # numbers one checkpoint's outputs may hold
MAX_PAYLOAD = 64 << 20  # characters of JSON accepted from the kernel for one checkpoint
TIMED_OUT_EARLIER = "TimedOutEarlier"  # what a stopped function raises (see _kernel_side.stop)
DTYPES = {"b": np.bool_, "i": np.int64, "u": np.uint64, "f": np.float64}


class Unsupported:
    """Stands for a returned object of a type the grader does not transport (shown by its name)."""

    def __init__(self, type_name: str):
        self.type_name = type_name

    def __repr__(self):
        return f"<{self.type_name} object>"


class Returned(types.SimpleNamespace):
    """A dataclass the student returned, rebuilt as attributes (``got.x`` works in a judge)."""


class WireError(ValueError):
    pass


def call_code(function: str, cases_args: list[dict], nonce: str) -> str:
    """Source of the cell that calls ``function`` on each input dict inside the kernel."""
    try:
        data = pickle.dumps(cases_args, protocol=4)
    except (pickle.PicklingError, AttributeError, TypeError):  # lambdas in the inputs (e.g. h(x) of lab 04)
        import cloudpickle

        data = cloudpickle.dumps(cases_args, protocol=4)
    return _kernel_code("call", function, base64.b64encode(data).decode(), nonce, MAX_NUMBERS)


def stop_code(names: list[str] | None, message: str, nonce: str, keep: bool) -> str:
    """Source of the cell that replaces the notebook's functions ``names`` (None: the one the last interrupt
    stopped) by stubs raising :data:`TIMED_OUT_EARLIER` with ``message`` (``{name}`` filled in), left in place
    by :func:`restore_code` when ``keep``; its report (:func:`extract`) is ``{"stopped": [names]}``."""
    return _kernel_code("stop", nonce, names, message, keep)


def restore_code() -> str:
    """Source of the cell that puts back every function :func:`stop_code` replaced, except the kept ones."""
    return _kernel_code("restore")


def _kernel_code(entry: str, *args) -> str:
    """A cell calling ``_kernel_side.<entry>(the notebook's namespace, *args)`` in a namespace of its own."""
    return (
        "(lambda g: (exec(compile(g['__src__'], '<kfkit-grader>', 'exec'), g), "
        f"g[{entry!r}](globals(){''.join(f', {a!r}' for a in args)})))"
        f"({{'__name__': '__kfkit_grader__', '__src__': {KERNEL_SIDE!r}}});"
    )


def new_nonce() -> str:
    return "KFKIT" + secrets.token_hex(16)


def extract(stdout: str, nonce: str) -> dict:
    """The report line the kernel printed between two nonces (the last one, if several)."""
    end = stdout.rfind(nonce)
    start = stdout.rfind(nonce, 0, end) if end > 0 else -1
    if start < 0:
        raise WireError("the kernel sent no result")
    text = stdout[start + len(nonce) : end]
    if len(text) > MAX_PAYLOAD:
        raise WireError(f"the result is larger than {MAX_PAYLOAD >> 20} MB")
    try:
        report = json.loads(text)
    except (ValueError, RecursionError) as exc:
        raise WireError(f"the result is not valid JSON ({type(exc).__name__})") from None
    if not isinstance(report, dict):
        raise WireError("the result is not a JSON object")
    return report


def decode(obj, depth=0):
    """Python value of an encoded output (see ``_kernel_side.encode``); WireError if malformed."""
    if depth > 50:
        raise WireError("the output is nested too deeply")
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    if isinstance(obj, list):
        return [decode(v, depth + 1) for v in obj]
    if not isinstance(obj, dict) or len(obj) == 0:
        raise WireError("malformed output")
    if "__tuple__" in obj:
        return tuple(decode(v, depth + 1) for v in _list(obj["__tuple__"]))
    if "__dict__" in obj:
        items = _list(obj["__dict__"])
        if not all(isinstance(kv, list) and len(kv) == 2 for kv in items):
            raise WireError("malformed dict")
        out = {}
        for k, v in items:
            key = decode(k, depth + 1)
            try:
                out[key] = decode(v, depth + 1)
            except TypeError:
                raise WireError("unhashable dict key") from None
        return out
    if "__ndarray__" in obj:
        return _array(obj, depth)
    if "__object__" in obj:
        fields = obj.get("fields")
        if not isinstance(fields, dict) or not all(
            isinstance(k, str) and k.isidentifier() and not k.startswith("__") for k in fields
        ):
            raise WireError("malformed object")
        return Returned(**{k: decode(v, depth + 1) for k, v in fields.items()})
    if "__unsupported__" in obj:
        return Unsupported(str(obj["__unsupported__"])[:120])
    raise WireError("malformed output")


def _list(value) -> list:
    if not isinstance(value, list):
        raise WireError("malformed output")
    return value


def _array(obj, depth) -> np.ndarray:
    data, kind, shape = _list(obj["__ndarray__"]), obj.get("dtype"), _list(obj.get("shape"))
    if not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape) or len(shape) > 32:
        raise WireError("malformed array shape")
    if int(np.prod(shape, dtype=np.int64)) != len(data):
        raise WireError("array data does not match its shape")
    if kind == "O":
        out = np.empty(len(data), dtype=object)
        out[:] = [decode(v, depth + 1) for v in data]
        return out.reshape(shape)
    if kind not in DTYPES:
        raise WireError("unknown array type")
    if not all(isinstance(v, (int, float)) for v in data):
        raise WireError("array holds non-numbers")
    try:
        return np.array(data, dtype=DTYPES[kind]).reshape(shape)
    except (OverflowError, ValueError):
        raise WireError("array values out of range") from None
