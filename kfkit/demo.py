"""``kfkit demo tilt``: steer a car down a winding road by tilting the board.

The board (``firmware/mpu6050_tilt_kf``) sends ``$ATT,roll_deg,pitch_deg*HH`` lines; the virtual
board sends the same lines computed by the Python reference (``VirtualBoard(attitude=True)``).
Roll steers (right side down → right), pitch is the throttle (nose down → faster), like tilting a
game controller. The core is headless and testable: :func:`controls` maps angles to commands,
:class:`RaceGame` advances the game, :class:`AttitudeStream` reads the lines in a thread and
:func:`advance` drives the game by board time (1/rate_hz per ``$ATT`` line). Three front ends share
:func:`tilt_figure`: a matplotlib window (``kfkit demo tilt --port …``), a notebook widget
(:class:`TiltDemoPanel`) and a headless run (``--headless``, for tests and CI).
"""

from __future__ import annotations

import math
import textwrap
import threading
import time
from collections import deque
from contextlib import ExitStack
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure

from . import motions
from .capture.protocol import BadLine, Header, Message, Sample, parse_line
from .capture.virtual import VirtualBoard
from .frames import euler_rates_to_body_rates
from .plots import COLORS
from .widgets import interactive_canvas

MAX_TILT_DEG = 30.0  # tilt for full steering / full throttle
DEAD_ZONE_DEG = 2.0  # ignore small tilts (a hand is never perfectly level)


def controls(roll_deg, pitch_deg, max_tilt=MAX_TILT_DEG, dead_zone=DEAD_ZONE_DEG):
    """(steer, throttle), each in [−1, 1], from roll and pitch in degrees.

    steer = roll / max_tilt (right side down steers right); throttle = −pitch / max_tilt (nose down
    accelerates, nose up brakes), both with a dead zone around level and clipped to ±1.
    """

    def axis(angle):
        if not math.isfinite(angle):
            return 0.0
        magnitude = max(0.0, abs(angle) - dead_zone) / (max_tilt - dead_zone)
        return math.copysign(min(1.0, magnitude), angle)

    return axis(float(roll_deg)), axis(-float(pitch_deg))


def road_center(distance):
    """Lateral position (m) of the road's centre line at ``distance`` (m) along it: gentle bends, 0 at the start."""
    return 6.0 * np.sin(distance / 40.0) + 3.0 * np.sin(distance / 17.0)


@dataclass
class RaceGame:
    """A car on a winding road, seen from above. Units: m, m/s, s.

    speed   v ← v + (a_max·throttle − drag·v)·dt, within [0, v_max]; off the road v_max is 1/3
    steer   lateral speed = steer · turn_rate · v  (the car turns more at speed)
    score   metres driven on the road; ``off_road_s`` counts the time spent beside it, ``time`` all of it
    """

    half_width: float = 3.0
    v_max: float = 30.0
    a_max: float = 8.0
    drag: float = 0.15
    turn_rate: float = 0.6
    x: float = 0.0
    distance: float = 0.0
    speed: float = 0.0
    score: float = 0.0
    off_road_s: float = 0.0
    time: float = 0.0

    @property
    def on_road(self) -> bool:
        return abs(self.x - road_center(self.distance)) <= self.half_width

    def update(self, steer, throttle, dt):
        """Advance the game by dt seconds with commands steer, throttle in [−1, 1]."""
        if not dt > 0:
            raise ValueError(f"RaceGame.update: dt must be positive, got {dt}")
        steer, throttle = float(np.clip(steer, -1, 1)), float(np.clip(throttle, -1, 1))
        v_max = self.v_max if self.on_road else self.v_max / 3
        self.speed = float(np.clip(self.speed + (self.a_max * throttle - self.drag * self.speed) * dt, 0.0, v_max))
        self.x += steer * self.turn_rate * self.speed * dt
        self.distance += self.speed * dt
        if self.on_road:
            self.score += self.speed * dt
        else:
            self.off_road_s += dt
        self.time += dt
        return self


class DemoError(RuntimeError):
    """The demo cannot run; the message names the port and says what to check."""


NO_ATTITUDE_S = 5.0  # s without a $ATT line (the sketch needs 2 s for its gyro bias) before saying why


class AttitudeStream:
    """Reads a board's lines in a thread: ``$ATT,roll_deg,pitch_deg`` into a queue, samples and bad lines counted.

    ``port`` is anything pyserial opens (``serial_for_url``). ``take()`` returns the attitudes that arrived
    since the last call (so the game advances by board time, 1/rate_hz per line, whatever the frame rate);
    ``latest`` is the last one or None; ``rate_hz`` comes from the board's header (default 100 Hz);
    ``error`` says why reading stopped (the board was unplugged), else None.
    """

    def __init__(self, port, baud=115200):
        import serial

        self.port = str(port)
        try:
            self.serial = serial.serial_for_url(port, baudrate=baud, timeout=0.2)
        except (serial.SerialException, ValueError) as e:
            raise DemoError(f"cannot open {port}: {e}") from None
        self.latest, self.rate_hz, self.error = None, 100.0, None
        self.counts = {"ATT": 0, "samples": 0, "bad": 0, "other": 0}
        self._new = deque()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="kfkit-demo-attitude", daemon=True)
        self.started = None

    def __enter__(self):
        self.serial.write(b"h")  # wakes the virtual board; a real board resends its header
        self.started = time.monotonic()
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self.serial.close()

    def take(self, limit=None) -> list:
        """The (roll_deg, pitch_deg) pairs received since the last call (at most ``limit``), oldest first."""
        out = []
        while self._new and (limit is None or len(out) < limit):
            out.append(self._new.popleft())
        return out

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def waiting_for(self) -> str | None:
        """None while $ATT lines arrive (or the board may still be measuring its bias), else what is wrong.

        Samples without $ATT are judged by the board's clock (NO_ATTITUDE_S · rate_hz samples, whatever the
        host's speed); only a board that sends no sample at all is judged by the host's clock (NO_ATTITUDE_S)."""
        if self.error:
            return self.error
        if self.counts["ATT"] or self.started is None:
            return None
        if self.counts["samples"] >= NO_ATTITUDE_S * self.rate_hz:
            return (
                f"{self.port} sends samples but no $ATT lines: flash firmware/mpu6050_tilt_kf "
                f"(mpu6050_logger sends raw samples only)"
            )
        if self.counts["samples"] or time.monotonic() - self.started < NO_ATTITUDE_S:
            return None
        if self.counts["bad"]:
            return f"{self.port} sends only unreadable lines ({self.counts['bad']}): wrong baud rate? try --baud 115200"
        return (
            f"nothing received from {self.port} in {NO_ATTITUDE_S:g} s: is the board plugged in and its sketch flashed?"
        )

    def _run(self):
        while not self._stop.is_set():
            try:
                line = self.serial.readline()
            except Exception as e:  # unplugged: keep what was received, say why it stopped
                self.error = f"{self.port} stopped sending ({type(e).__name__}: {e}): board unplugged?"
                return
            if not line:
                continue
            item = parse_line(line)
            if isinstance(item, Message) and item.tag == "ATT" and len(item.values) == 2:
                self.latest = item.values
                self._new.append(item.values)
                self.counts["ATT"] += 1
            elif isinstance(item, Sample):
                self.counts["samples"] += 1
            elif isinstance(item, BadLine):
                self.counts["bad"] += item.kind != "empty"
            else:
                if isinstance(item, Header) and item.rate_hz > 0:
                    self.rate_hz = float(item.rate_hz)
                self.counts["other"] += 1


def advance(game, stream, until=None) -> int:
    """Drive ``game`` with the attitudes ``stream`` received since the last call, 1/rate_hz each, up to game time
    ``until`` (s; None: all of them). Returns how many."""
    limit = None if until is None else max(0, math.ceil(round((until - game.time) * stream.rate_hz, 6)))
    attitudes = stream.take(limit)
    for roll, pitch in attitudes:
        game.update(*controls(roll, pitch), 1.0 / stream.rate_hz)
    return len(attitudes)


def driving_motion(rate_hz=100.0, duration=62.5, still=2.5) -> motions.Motion:
    """What the virtual board plays: 2.5 s still (the sketch's gyro bias), then a hand steering left and
    right (roll ±20°, 12 s period) while dipping the nose 0…10° (throttle, 10 s period); whole cycles,
    so it loops smoothly."""
    t = motions.sample_times(duration, rate_hz)
    moving = t > still
    s = np.clip(t - still, 0.0, None)
    w1, w2 = 2 * np.pi / 12.0, 2 * np.pi / 10.0
    roll, roll_dot = np.radians(20.0) * np.sin(w1 * s), np.radians(20.0) * w1 * np.cos(w1 * s) * moving
    pitch, pitch_dot = -np.radians(5.0) * (1 - np.cos(w2 * s)), -np.radians(5.0) * w2 * np.sin(w2 * s) * moving
    euler = np.column_stack([roll, pitch, np.zeros_like(t)])
    euler_dot = np.column_stack([roll_dot, pitch_dot, np.zeros_like(t)])
    return motions.Motion(
        t,
        rate_hz,
        euler,
        euler_rates_to_body_rates(euler, euler_dot),
        np.zeros((len(t), 3)),
        "a hand steering: roll ±20°, nose down 0…10°",
        [(0.0, still, "stationary")],
    )


def open_stream(stack, port, baud=115200, fast=False) -> AttitudeStream:
    """An :class:`AttitudeStream` on ``port`` inside ``stack`` (an ExitStack); "virtual" starts a virtual board
    that plays :func:`driving_motion` and sends $ATT lines like the sketch (``fast``: faster than real time)."""
    if port == "virtual":
        board = stack.enter_context(
            VirtualBoard(board="mpu6050", motion=driving_motion(), attitude=True, realtime=not fast)
        )
        port = board.port
    return stack.enter_context(AttitudeStream(port, baud))


def run_tilt_demo(port, seconds=None, headless=False, fps=30.0, baud=115200, fast=False, out=print) -> RaceGame:
    """Play the game from ``port`` (a serial port, or "virtual") for ``seconds`` of board time (None: until the
    window closes). ``headless`` runs without a window (tests, CI) and prints a summary; ``fast`` lets the
    virtual board run faster than real time. Raises :class:`DemoError` when no $ATT lines come, saying why.
    """
    if headless and seconds is None:
        raise ValueError("run_tilt_demo: a headless run needs seconds")
    game = RaceGame()
    with ExitStack() as stack:
        stream = open_stream(stack, port, baud, fast)
        if headless:
            while game.time < seconds:
                if not advance(game, stream, until=seconds):
                    problem = stream.waiting_for()
                    if problem or not stream.alive:
                        raise DemoError(problem or f"{stream.port}: reading stopped")
                    time.sleep(0.5 / fps)
        else:
            _window(game, stream, 1.0 / fps, seconds)
        out(
            f"$ATT lines {stream.counts['ATT']}, samples {stream.counts['samples']}, bad lines {stream.counts['bad']}; "
            f"{game.time:.1f} s driven, distance {game.distance:.0f} m, score {game.score:.0f}, "
            f"off road {game.off_road_s:.1f} s" + (f"; {stream.error}" if stream.error else "")
        )
    return game


def tilt_figure(game, stream, fig=None):
    """The game's figure (road from above, the car, roll and pitch, status) and ``draw(frame=None)``, which
    advances the game by the attitudes received since the last frame (:func:`advance`) and moves the artists."""
    fig = fig or Figure(figsize=(5, 7), layout="constrained")
    ax = fig.subplots()
    ahead = np.linspace(-20, 80, 200)
    (left,) = ax.plot([], [], color=COLORS["truth"], lw=2)
    (right,) = ax.plot([], [], color=COLORS["truth"], lw=2)
    (car,) = ax.plot([], [], "s", color=COLORS["bound"], ms=12)
    text = ax.text(
        0.02, 0.98, "", transform=ax.transAxes, va="top", family="monospace", parse_math=False
    )  # "$ATT" is no TeX
    ax.set_xlim(-20, 20)
    ax.set_ylim(-20, 80)
    ax.set_xlabel("lateral position (m)")
    ax.set_ylabel("road ahead (m)")
    ax.set_title("roll steers, nose down accelerates")

    def draw(_frame=None):
        advance(game, stream)
        center = road_center(game.distance + ahead)
        left.set_data(center - game.half_width, ahead)
        right.set_data(center + game.half_width, ahead)
        car.set_data([game.x], [0.0])
        if stream.latest is None:
            status = stream.waiting_for() or "waiting for $ATT lines (keep the board still: gyro bias)"
        else:
            roll, pitch = stream.latest
            status = (
                f"roll {roll:+6.1f}°  pitch {pitch:+6.1f}°\nspeed {game.speed * 3.6:5.0f} km/h  "
                f"score {game.score:6.0f}" + ("" if game.on_road else "\nOFF ROAD")
            )
            status += f"\n{stream.error}" if stream.error else ""
        text.set_text("\n".join(textwrap.fill(part, 44) for part in status.split("\n")))
        return left, right, car, text

    return fig, draw


def _window(game, stream, dt, seconds):
    """Animate :func:`tilt_figure` in a matplotlib window until it is closed (or ``seconds`` have passed)."""
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    fig, draw = tilt_figure(game, stream, plt.figure(figsize=(5, 7), layout="constrained"))
    fig.canvas.manager.set_window_title("kfkit demo tilt")

    def frame(_):
        if seconds is not None and game.time >= seconds:
            plt.close(fig)  # ends plt.show()
        return draw()

    animation = FuncAnimation(fig, frame, interval=dt * 1000, blit=False, cache_frame_data=False)
    plt.show()
    return animation


class TiltDemoPanel:
    """The game in a notebook: an ipympl canvas redrawn by its own timer (the kernel's thread), start/stop buttons.

    ``TiltDemoPanel("virtual")`` needs no hardware (``fast``: faster than real time); ``.refresh()`` does what
    one timer tick does; ``.close()`` stops the timer, the stream and the virtual board.
    """

    def __init__(self, port="virtual", baud=115200, fps=30.0, fast=False):
        import ipywidgets as W

        self._stack = ExitStack()
        self.stream = open_stream(self._stack, port, baud, fast)
        self.game = RaceGame()
        self.fig, self.draw = tilt_figure(self.game, self.stream, Figure(figsize=(4.5, 6), layout="constrained"))
        self.canvas = interactive_canvas(self.fig)
        self.timer = self.canvas.new_timer(interval=int(1000 / fps))
        self.timer.add_callback(self.refresh)
        self.closed = False
        start, stop = W.Button(description="drive", icon="play"), W.Button(description="stop", icon="stop")
        start.on_click(lambda _: self.start())
        stop.on_click(lambda _: self.close())
        self.widget = W.VBox([W.HBox([start, stop]), self.canvas])

    def start(self):
        """Start the timer (not after close(): the stream is gone)."""
        if not self.closed:
            self.timer.start()

    def refresh(self) -> None:
        """One timer tick: advance and draw. Returns None (a timer callback). Once the stream has stopped (the board
        was unplugged) the last frame, with the reason, is drawn and the timer stops; an error stops it too."""
        try:
            self.draw()
        except Exception as e:  # a timer callback has no one to raise to: show it, stop
            self.timer.stop()
            self.fig.axes[0].texts[0].set_text(f"the demo stopped: {e!r}")
        else:
            if not self.stream.alive:
                self.timer.stop()
        self.canvas.draw_idle()
        return None

    def close(self):
        self.timer.stop()
        self.closed = True
        self._stack.close()

    def _ipython_display_(self):
        from IPython.display import display

        display(self.widget)
