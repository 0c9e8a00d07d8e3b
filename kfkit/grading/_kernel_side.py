"""Runs inside the student's kernel, sent as source text (never imported there, nothing from kfkit).

``call(user_ns, name, blob, nonce, max_numbers)`` unpickles the grader's inputs (pickled by the
grader: trusted in this direction), calls the student's function on each, and prints one line
``nonce + JSON + nonce``. Outputs are encoded as plain JSON: numbers, strings (cut to 2000
characters), lists, and tagged objects for tuples, dicts, arrays and dataclasses; anything else is
named, not sent. A case that raises ends the calls and sends the exception's class name and message
(cut to 500 characters) instead. The grader decodes that JSON with size limits and never unpickles
anything the kernel sends.

``stop(user_ns, nonce, names, message, keep)`` replaces notebook functions that timed out by stubs that raise
:class:`TimedOutEarlier` at once (``names``, or when None the function the last interrupt stopped), so a
loop is paid for once, not once per cell that calls it; ``restore(user_ns)`` puts back all but those kept.
"""

import base64
import dataclasses
import io
import json
import pickle
import sys
import types


class TooLarge(Exception):
    pass


def encode(value, budget):
    """JSON-ready copy of ``value``; ``budget`` = [numbers still allowed]."""
    budget[0] -= 1
    if budget[0] < 0:
        raise TooLarge
    if value is None or isinstance(value, (bool, int, float)):
        return value
    if isinstance(value, str):
        return value[:2000]
    type_name = type(value).__module__ + "." + type(value).__qualname__
    if type_name.startswith("numpy."):
        import numpy

        if isinstance(value, numpy.generic) and value.dtype.kind in "biuf":
            return value.item()
        if isinstance(value, numpy.ndarray) and value.dtype.kind in "biuf":
            budget[0] -= value.size
            if budget[0] < 0:
                raise TooLarge
            return {"__ndarray__": value.ravel().tolist(), "dtype": value.dtype.kind, "shape": list(value.shape)}
        if isinstance(value, numpy.ndarray) and value.dtype.kind == "O":
            return {"__ndarray__": [encode(v, budget) for v in value.ravel()], "dtype": "O", "shape": list(value.shape)}
    if isinstance(value, tuple):
        return {"__tuple__": [encode(v, budget) for v in value]}
    if isinstance(value, list):
        return [encode(v, budget) for v in value]
    if isinstance(value, dict):
        return {"__dict__": [[encode(k, budget), encode(v, budget)] for k, v in value.items()]}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            "__object__": type(value).__qualname__,
            "fields": {f.name: encode(getattr(value, f.name), budget) for f in dataclasses.fields(value)},
        }
    return {"__unsupported__": type_name}


class _Sink(io.TextIOBase):
    """Where the student's prints go during the grader's calls: counted, then dropped."""

    def writable(self):
        return True

    def write(self, text):
        return len(text)


def call(user_ns, name, blob, nonce, max_numbers):
    cases = pickle.loads(base64.b64decode(blob))
    func = user_ns.get(name)
    if func is None:
        report = {"missing": True}
    elif not callable(func):
        report = {"not_callable": type(func).__name__}
    elif str(getattr(func, "__module__", "")).split(".")[0] == "kfkit":
        report = {"kfkit_function": f"{func.__module__}.{getattr(func, '__qualname__', name)}"}
    else:
        results, budget = [], [max_numbers]
        real_out, real_err = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = _Sink()
        try:
            for args in cases:
                try:
                    out = func(**args)
                except (Exception, SystemExit) as exc:
                    try:
                        message = str(exc)[:500]
                    except Exception:
                        message = "(its message could not be shown)"
                    results.append({"raised": type(exc).__name__[:80], "message": message})
                    break
                try:
                    results.append({"out": encode(out, budget)})
                except TooLarge:
                    results.append({"too_large": max_numbers})
                    break
        finally:
            sys.stdout, sys.stderr = real_out, real_err
        report = {"results": results}
    sys.stdout.write(nonce + json.dumps(report) + nonce + "\n")
    sys.stdout.flush()


class TimedOutEarlier(Exception):
    """Raised instead of running again a notebook function that timed out earlier in this submission."""


def _notebook_function(value):
    """A function defined in the notebook (not one it imported, from kfkit or elsewhere)."""
    return isinstance(value, types.FunctionType) and getattr(value, "__module__", None) in ("__main__", None)


def _interrupted(user_ns):
    """The innermost function of the notebook running when the last cell was interrupted (a KeyboardInterrupt
    that IPython kept in ``sys.last_value``), or None; forgets that interrupt."""
    value, tb = getattr(sys, "last_value", None), getattr(sys, "last_traceback", None)
    sys.last_type = sys.last_value = sys.last_traceback = None
    if not isinstance(value, KeyboardInterrupt):
        return None
    codes = {v.__code__: k for k, v in list(user_ns.items()) if _notebook_function(v) and not k.startswith("_")}
    found = None
    while tb is not None:
        found = codes.get(tb.tb_frame.f_code, found)
        tb = tb.tb_next
    return found


def _stub(name, func, text, keep):
    def timed_out_earlier(*args, **kwargs):
        raise TimedOutEarlier(text)

    timed_out_earlier.__name__ = timed_out_earlier.__qualname__ = name
    timed_out_earlier.__kfkit_original__, timed_out_earlier.__kfkit_keep__ = func, keep
    return timed_out_earlier


def _stubs(user_ns):
    """(name, stub) of every stub in the notebook's namespace (only functions are looked at: getting an
    attribute of any other object could run the notebook's code)."""
    return [
        (k, v)
        for k, v in list(user_ns.items())
        if isinstance(v, types.FunctionType) and hasattr(v, "__kfkit_original__")
    ]


def stop(user_ns, nonce, names, message, keep):
    """Replace each function ``names`` (None: the interrupted one) of the notebook, under every name bound to
    it, by a stub raising TimedOutEarlier(``message`` with its name), kept by :func:`restore` when ``keep``;
    print the names stopped (JSON)."""
    stopped = []
    for name in [_interrupted(user_ns)] if names is None else names:
        func = user_ns.get(name) if name else None
        if not _notebook_function(func):
            continue
        stub = _stub(name, func, message.replace("{name}", name), keep)
        for key, value in list(user_ns.items()):
            if value is func:
                user_ns[key] = stub
        stopped.append(name)
    sys.stdout.write(nonce + json.dumps({"stopped": stopped}) + nonce + "\n")
    sys.stdout.flush()


def restore(user_ns):
    """Put back the functions :func:`stop` replaced (those the notebook has not redefined since), but the kept."""
    for key, stub in _stubs(user_ns):
        if not stub.__kfkit_keep__:
            user_ns[key] = stub.__kfkit_original__
