"""Runs inside the student's kernel, sent as source text (never imported there, nothing from kfkit).

``call(user_ns, name, blob, nonce, max_numbers)`` unpickles the grader's inputs (pickled by the
grader: trusted in this direction), calls the student's function on each, and prints one line
``nonce + JSON + nonce``. Outputs are encoded as plain JSON: numbers, strings (cut to 2000
characters), lists, and tagged objects for tuples, dicts, arrays and dataclasses; anything else is
named, not sent. A case that raises ends the calls and sends the exception's class name and message
(cut to 500 characters) instead. The grader decodes that JSON with size limits and never unpickles
anything the kernel sends.
"""
import base64
import dataclasses
import io
import json
import pickle
import sys


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
        return {"__object__": type(value).__qualname__,
                "fields": {f.name: encode(getattr(value, f.name), budget) for f in dataclasses.fields(value)}}
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
