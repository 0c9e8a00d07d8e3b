"""Clocks: several sensors put on one time base, and a sample counter for jittered timestamps.

A phone's sensors each report on their own clock and rate; :class:`OneClock` puts them on the
gyroscope's time base (the accelerometer interpolated linearly at the gyro's times, a new magnetometer
sample placed in the first gyro row at or after its time, the rows in between NaN: the recording
format's "no new sample"). :class:`SampleCounter` numbers the rows of such a time base the way a board
numbers its samples (``seq``), so a gap in the timestamps shows as dropped samples and jitter does not.
Both work on pieces (a live stream) and on a whole file alike.
"""

from __future__ import annotations

import numpy as np


class OneClock:
    """Merge a phone's sensors, each on its own clock, onto the time base of one of them.

    ``base`` (default the gyroscope) gives the rows; ``interpolated`` sensors (the accelerometer)
    are interpolated linearly at the base times, so a row is kept only inside their time span;
    ``held`` sensors (the magnetometer) put each new sample in the first base row at or after its
    time (a delay of at most one base period) and leave the other rows NaN. If two held samples
    fall in one row the newer wins (counted in ``stats["mag_merged"]``).

    Samples arrive in pieces (:meth:`push`, times increasing per sensor) and rows leave in order
    (:meth:`pop`), so a file and a live stream give the same rows. Live, a row is released once the
    interpolated sensors have passed it and the held sensor has had ``hold_s`` to deliver a sample
    for it (unless it has sent nothing for ``stall_s``); a held sample that still comes later goes
    into the next row (``stats["mag_late"]``).
    """

    def __init__(self, base="gyr", interpolated=("acc",), held=("mag",), hold_s=0.05, stall_s=1.0):
        self.base, self.interpolated, self.held = base, tuple(interpolated), tuple(held)
        self.hold_s, self.stall_s = hold_s, stall_s
        self._t = {s: np.zeros(0) for s in (base, *self.interpolated, *self.held)}
        self._v = {s: np.zeros((0, 3)) for s in self._t}
        self._seen = dict.fromkeys(self._t, False)
        self._last = dict.fromkeys(self._t, -np.inf)
        self._index = 0  # base samples consumed so far (their index in the base sensor's stream)
        self._t_out = -np.inf  # time of the last row released
        self.stats = {"before_start": 0, "after_end": 0, "mag_merged": 0, "mag_late": 0, "mag_outside": 0}

    def push(self, sensor, t, values):
        """Append samples of ``sensor``: times t (N,) s, increasing, and values (N, 3)."""
        t = np.asarray(t, dtype=float)
        if not len(t):
            return
        self._t[sensor] = np.concatenate([self._t[sensor], t])
        self._v[sensor] = np.concatenate([self._v[sensor], np.asarray(values, dtype=float).reshape(-1, 3)])
        self._seen[sensor] = True
        self._last[sensor] = max(self._last[sensor], float(t[-1]))

    def pop(self, final=False):
        """Rows ready now: (t (n,), {sensor: (n, 3)}, base indices (n,)). ``final``: everything left."""
        tb = self._t[self.base]
        bound = np.inf if final else self._last[self.base]
        for s in self.interpolated:
            if not final:
                bound = min(bound, self._last[s])
        for s in self.held:
            if not final and self._seen[s] and self._last[self.base] - self._last[s] < self.stall_s:
                bound = min(bound, self._last[s] + self.hold_s)
        # rows before every interpolated sensor has started can never be interpolated
        first = max((self._t[s][0] for s in self.interpolated if len(self._t[s])), default=-np.inf)
        if any(not len(self._t[s]) for s in self.interpolated):
            if final:
                self.stats["before_start"] += len(tb)
                self._consume(len(tb))
            return self._empty()
        early = int(np.searchsorted(tb, first, side="left"))
        if early:
            self.stats["before_start"] += early
            self._consume(early)
            tb = self._t[self.base]
        last_interp = min((self._t[s][-1] for s in self.interpolated), default=np.inf)
        n = int(np.searchsorted(tb, min(bound, last_interp), side="right"))
        if final:
            self.stats["after_end"] += len(tb) - n
        t_rows = tb[:n]
        out = {self.base: self._v[self.base][:n]}
        for s in self.interpolated:
            ts, vs = self._t[s], self._v[s]
            out[s] = np.column_stack([np.interp(t_rows, ts, vs[:, i]) for i in range(3)])
        for s in self.held:
            out[s] = self._place_held(s, t_rows, final)
        index = self._index + np.arange(n)
        self._consume(len(tb) if final else n)
        if n:
            self._t_out = float(t_rows[-1])
        for s in self.interpolated:  # keep the last sample at or before the released rows
            keep = max(int(np.searchsorted(self._t[s], self._t_out, side="right")) - 1, 0)
            self._t[s], self._v[s] = self._t[s][keep:], self._v[s][keep:]
        return t_rows, out, index

    def _place_held(self, s, t_rows, final):
        n = len(t_rows)
        rows = np.full((n, 3), np.nan)
        ts, vs = self._t[s], self._v[s]
        if not n:
            return rows
        ready = ts <= t_rows[-1]
        period = np.median(np.diff(t_rows)) if n > 1 else 0.0
        late = ready & (ts <= self._t_out)
        self.stats["mag_late"] += int(late.sum())
        k = np.searchsorted(t_rows, ts[ready], side="left")
        if self._t_out == -np.inf:  # the first rows: a sample up to one period before row 0 belongs to it
            outside = ts[ready] < t_rows[0] - period
            self.stats["mag_outside"] += int(outside.sum())
            k = np.where(outside, -1, k)
        valid = k >= 0
        k, v = k[valid], vs[ready][valid]
        newest_first = slice(None, None, -1)
        row, where = np.unique(k[newest_first], return_index=True)  # the newest sample of each row
        self.stats["mag_merged"] += len(k) - len(row)
        rows[row] = v[newest_first][where]
        rest = ~ready
        if final:
            self.stats["mag_outside"] += int(rest.sum())
            rest[:] = False
        self._t[s], self._v[s] = ts[rest], vs[rest]
        return rows

    def _consume(self, n):
        self._t[self.base], self._v[self.base] = self._t[self.base][n:], self._v[self.base][n:]
        self._index += n

    def _empty(self):
        return np.zeros(0), {s: np.zeros((0, 3)) for s in self._t}, np.zeros(0, dtype=np.int64)


class SampleCounter:
    """Sample counters n_k for the times t_k (s) of a stream with nominal period ``nominal_dt`` (s),
    continuing across calls of :meth:`count` (a live stream in pieces gives what one call on the whole
    file gives).

    A timestamp carries jitter σ_t (a phone's: ~0.3 ms, 12 % of a 400 Hz period), so rounding each
    interval (k = round(Δt/T)) would call a late stamp a lost sample about once in 700 at 400 Hz.
    Instead each time is placed against a smoothed phase φ of the sample grid: after φ moves on by
    the periods counted, φ ← φ + α(t − φ) (its noise σ_t·√(α/2)), with the period
    T = (φ − t_first)/n once ``settle`` samples are in (before: ``nominal_dt``), and

        n_k = n_{k−1} + max(1, round((t_k − φ)/T))

    so a real gap shows as a step of 2 or more and jitter as steps of 1.
    """

    def __init__(self, nominal_dt: float, alpha: float = 0.1, settle: int = 20):
        if not nominal_dt > 0:
            raise ValueError(f"nominal_dt must be a positive period (s), got {nominal_dt!r}")
        self.nominal_dt, self.alpha, self.settle = float(nominal_dt), float(alpha), int(settle)
        self._grid = None  # (phase φ s, count n, first time s)

    def count(self, t) -> np.ndarray:
        """The counters (int64) of the next times t (s, increasing)."""
        out = []
        for ti in np.asarray(t, dtype=float).tolist():
            if self._grid is None:
                self._grid = (ti, 0, ti)
                out.append(0)
                continue
            phase, n, first = self._grid
            period = (phase - first) / n if n >= self.settle else self.nominal_dt
            step = max(1, round((ti - phase) / period))
            expected = phase + step * period
            self._grid = (expected + self.alpha * (ti - expected), n + step, first)
            out.append(n + step)
        return np.array(out, dtype=np.int64)
