"""Checked option types for the ``kfkit`` command: a bad value fails at the door, naming its option.

argparse puts the option in front of an :class:`argparse.ArgumentTypeError`'s message, so
``kfkit capture --seconds nan`` stops at once with ``argument --seconds: 'nan' is not a finite number > 0 (s)``
instead of recording forever. Every numeric option of every subcommand takes one of these types.
"""

from __future__ import annotations

import argparse
import math


def _plain(x) -> str:
    """A bound as people write it: 12000000, 0.5."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def number(kind=float, low=0.0, high=math.inf, *, include_low=False, unit=""):
    """An argparse ``type``: the text as a finite ``kind`` (``int`` or ``float``) with low < value ≤ high
    (low ≤ value with ``include_low``); otherwise an error saying what the option takes."""
    what = "a whole number" if kind is int else "a finite number"
    what += f" {'≥' if include_low else '>'} {_plain(low)}" + (f" and ≤ {_plain(high)}" if math.isfinite(high) else "")
    what += f" ({unit})" if unit else ""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and (low <= value if include_low else low < value) and value <= high):
            from .io import shown  # only now: the command starts without NumPy

            raise argparse.ArgumentTypeError(f"{shown(text)} is not {what}")
        return value

    parse.__name__ = what  # argparse's own messages name a type by it
    return parse
