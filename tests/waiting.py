"""Waiting in tests: on events, never on how fast this machine is.

A test waits for something to happen (a file to grow, a server to answer, a pixel to change, a sample
count to pass). How long that takes depends on the machine and on what else runs on it, so no test judges
a duration: :func:`wait_until` polls a condition and gives up only after :data:`HANG_GUARD_S`, a guard
against a hang (a test that would otherwise never end), far beyond any busy machine's delay. When the guard
fires, the message says what was awaited and what was last seen.
"""

from __future__ import annotations

import time

import numpy as np

#: seconds after which a wait is taken for a hang; never a judgement of speed
HANG_GUARD_S = 900.0
#: the same for Playwright, which counts in milliseconds
HANG_GUARD_MS = int(HANG_GUARD_S * 1000)


def wait_until(condition, what: str, poll_s: float = 0.05, guard_s: float = HANG_GUARD_S, sleep=time.sleep):
    """Call ``condition()`` until it returns something other than None or False (a NumPy bool counts as a bool)
    and return that; after ``guard_s`` raise AssertionError naming ``what`` and the last value seen. ``sleep``
    lets a browser test wait in the page (``page.wait_for_timeout``, which counts ``poll_s`` in ms)."""
    start = time.monotonic()
    while True:
        value = condition()
        if value is not None and not (isinstance(value, (bool, np.bool_)) and not value):
            return value
        if time.monotonic() - start > guard_s:
            raise AssertionError(f"gave up waiting for {what} after {guard_s:g} s (a hang guard); last seen: {value!r}")
        sleep(poll_s)
