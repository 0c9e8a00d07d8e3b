"""What arrived in a capture, and where each sample sits in board time: pure bookkeeping, no thread, no port.

:class:`Timeline` places each sample ``(t_us, seq)`` of one board in time and counts what the
sequence numbers and the clock say happened between samples:

- time ``t`` (s) is ``t_us`` relative to the first sample, unwrapping the 32-bit ``micros()``:
  Δ = (t_us − t_us_prev) mod 2³², t = t_prev + Δ·10⁻⁶, rounded to whole µs (exact in the file);
- a **reset** (the board restarted) is ``t_us`` going backwards (Δ ≥ 2³¹), or a repeated header
  followed by ``seq`` restarting at 0 (the sketches send their header from ``setup()``; this catches
  a reset after 35.8 min, when Δ mod 2³² looks like a step forwards). Time then continues one
  nominal period 1/rate_hz after the last sample;
- a **gap** g = (seq − seq_prev − 1) mod 2¹⁶ > 0 counts g dropped samples; the first missing one was
  due one interval of g + 1 after the previous sample;
- Δ = 0 (the same instant twice) cannot be placed: counted malformed;
- a sample at or past ``seconds`` is not placed and ends the capture (``reached``).

The board clock's rate over the capture, r = 10⁶ · Σ(g + 1) / ΣΔ (resets left out), and the mean and
spread of Δ between consecutive samples (no gap, no reset) come from the same sums.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from .protocol import MICROS_MODULO, SEQ_MODULO


@dataclass
class CaptureStats:
    """What arrived.

    samples        sample lines recorded
    bad_checksum   lines whose ``*HH`` did not match (skipped)
    malformed      lines that are not protocol v1: cut, no ``*HH``, a non-integer, the wrong field count
    dropped        samples missing by ``seq`` (a line rejected above is also a missing sample)
    drops          [(index of the first sample after the gap, t of the first missing sample (s), how many)]
    resets         board restarts; ``reset_positions`` = index of the first sample after each
    rate_hz        effective rate (samples − 1) / duration_s, duration_s = t of the last sample
    dt_mean_us     mean board interval between consecutive samples (no gap, no reset), µs
    jitter_us      standard deviation of that interval, µs
    notes          ``#`` lines from the board other than headers (``#ERROR,…``)
    """

    samples: int = 0
    bad_checksum: int = 0
    malformed: int = 0
    dropped: int = 0
    drops: list = field(default_factory=list)
    resets: int = 0
    reset_positions: list = field(default_factory=list)
    before_header: int = 0
    messages: int = 0
    bytes: int = 0
    duration_s: float = 0.0
    rate_hz: float = float("nan")
    dt_mean_us: float = float("nan")
    jitter_us: float = float("nan")
    notes: list = field(default_factory=list)

    @property
    def bad_lines(self) -> int:
        return self.bad_checksum + self.malformed

    def as_dict(self) -> dict:
        d = asdict(self)
        d["bad_lines"] = self.bad_lines
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in d.items()}

    def __str__(self):
        drops = ", ".join(f"{n} before sample {i} (t = {t:.3f} s)" for i, t, n in self.drops[:4])
        drops += " …" if len(self.drops) > 4 else ""
        resets = ", ".join(map(str, self.reset_positions[:8])) + (" …" if len(self.reset_positions) > 8 else "")
        first = f"samples        {self.samples}"
        if self.samples > 1:
            first += f" (t = 0 … {self.duration_s:.2f} s): effective rate {self.rate_hz:.2f} Hz"
        if math.isfinite(self.dt_mean_us):
            first += f", interval {self.dt_mean_us:.1f} µs, jitter {self.jitter_us:.1f} µs rms"
        lines = [
            first,
            f"bad lines      {self.bad_lines} ({self.bad_checksum} bad checksum, {self.malformed} malformed)",
            f"dropped        {self.dropped}" + (f": {drops}" if self.drops else ""),
            f"board resets   {self.resets}" + (f", before sample {resets}" if self.resets else ""),
        ]
        return "\n".join(lines)


class Timeline:
    """Board time, drops and resets of one capture (see the module docstring for the rules).

    rate_hz   the header's nominal rate, Hz (the step across a reset is 1/rate_hz)
    seconds   stop placing samples at this board time, s (None: never)
    stats     the :class:`CaptureStats` whose ``malformed``, ``dropped``/``drops`` and ``resets``/``reset_positions``
              it counts into (and ``rate_hz``, ``dt_mean_us``, ``jitter_us`` in :meth:`summarise`)

    ``place(t_us, seq)`` returns the sample's t (s), or None when it is not placed; ``placed`` counts the
    samples placed, ``elapsed`` is the t of the last one.
    """

    def __init__(self, rate_hz: float, seconds: float | None = None, stats: CaptureStats | None = None):
        self.rate_hz, self.seconds = float(rate_hz), seconds
        self.stats = stats if stats is not None else CaptureStats()
        self.last = None  # (t_us, seq, t) of the last sample placed
        self.placed = 0
        self.reached = False  # ``seconds`` of board time have arrived
        self._header_again = False
        self._dt_sum = self._dt_sq = 0.0
        self._dt_n = 0
        self._span_us = self._span_periods = 0  # board time and sample periods between samples, resets left out

    @property
    def elapsed(self) -> float:
        """Board time of the last sample placed, s (0 before any)."""
        return self.last[2] if self.last else 0.0

    def header_again(self):
        """The board sent its header again (an answer to 'h', or a restart): a ``seq`` back at 0 next is a reset."""
        self._header_again = True

    def place(self, t_us: int, seq: int) -> float | None:
        """The board time t (s) of the sample ``(t_us, seq)``, counting a reset or a gap before it; None (not
        placed) for the same ``t_us`` as the last sample (counted malformed) or a sample at or past ``seconds``."""
        s, prev = self.stats, self.last
        header_again, self._header_again = self._header_again, False
        reset, gap, dt_us = False, 0, 0
        if prev is None:
            t = 0.0
        else:
            dt_us = (t_us - prev[0]) % MICROS_MODULO
            gap = (seq - prev[1] - 1) % SEQ_MODULO
            if dt_us == 0:  # the same instant twice: not a sample we can place in time
                s.malformed += 1
                return None
            reset = dt_us >= MICROS_MODULO // 2 or (header_again and seq == 0 and gap != 0)  # the board restarted
            t = round(prev[2] + (1.0 / self.rate_hz if reset else dt_us * 1e-6), 6)  # whole µs: exact in the file
        if self.seconds is not None and t >= self.seconds - 1e-9:
            self.reached = True  # this sample is past the end: it counts for nothing
            return None
        if reset:
            s.resets += 1
            s.reset_positions.append(self.placed)
        elif gap:  # the first missing sample was due one interval (of gap + 1) after the previous one
            s.dropped += gap
            s.drops.append((self.placed, round(prev[2] + dt_us * 1e-6 / (gap + 1), 6), gap))
        if prev is not None and not reset:  # a gap of g missing samples spans g + 1 periods
            self._span_us += dt_us
            self._span_periods += gap + 1
            if not gap:
                self._dt_sum += dt_us
                self._dt_sq += dt_us * dt_us
                self._dt_n += 1
        self.last = (t_us, seq, t)
        self.placed += 1
        return t

    def clock_rate_hz(self) -> float:
        """The board clock's sample rate over the samples placed, Hz (NaN before two): r = 10⁶ · Σ(g + 1) / ΣΔ_us,
        a gap of g missing samples counting g + 1 periods and a reset none, to 6 significant digits (≤ 5 ppm,
        below a crystal's tolerance). Timestamp jitter σ_t enters only at the ends: √2·σ_t / duration."""
        return float(f"{1e6 * self._span_periods / self._span_us:.6g}") if self._span_us else float("nan")

    def summarise(self):
        """Set the stats' effective rate (placed − 1) / elapsed and the mean and standard deviation of Δ (µs)."""
        s = self.stats
        if self.placed > 1 and self.elapsed > 0:
            s.rate_hz = (self.placed - 1) / self.elapsed
        if self._dt_n:
            mean = self._dt_sum / self._dt_n
            s.dt_mean_us = mean
            s.jitter_us = math.sqrt(max(self._dt_sq / self._dt_n - mean * mean, 0.0))
