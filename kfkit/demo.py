"""``kfkit demo tilt``: steer a car down a winding road by tilting the board.

The board (``firmware/mpu6050_tilt_kf``) sends ``$ATT,roll_deg,pitch_deg*HH`` lines; the virtual
board sends the same lines computed by the Python reference (``VirtualBoard(attitude=True)``).
Roll steers (right side down → right), pitch is the throttle (nose down → faster), like tilting a
game controller. The core is headless and testable: :func:`controls` maps angles to commands,
:class:`RaceGame` advances the game, :class:`AttitudeStream` reads the lines in a thread.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field

import numpy as np

from . import sim
from .capture.protocol import BadLine, Message, Sample, parse_line
from .frames import euler_rates_to_body_rates

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
    score   metres driven on the road; ``off_road_s`` counts the time spent beside it
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
    history: list = field(default_factory=list, repr=False)

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
        self.history.append((self.distance, self.x))
        return self


class AttitudeStream:
    """Reads ``$ATT`` lines from a serial port in a thread; ``.latest`` is (roll_deg, pitch_deg) or None.

    ``port`` is anything pyserial opens (``serial_for_url``); counts lines by kind in ``.counts``.
    """

    def __init__(self, port, baud=115200):
        import serial

        self.serial = serial.serial_for_url(port, baudrate=baud, timeout=0.2)
        self.latest = None
        self.counts = {"ATT": 0, "samples": 0, "bad": 0, "other": 0}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="kfkit-demo-attitude", daemon=True)

    def __enter__(self):
        self.serial.write(b"h")  # wakes the virtual board; a real board resends its header
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self.serial.close()

    def _run(self):
        while not self._stop.is_set():
            try:
                line = self.serial.readline()
            except Exception:  # unplugged: keep the last attitude, stop reading
                return
            if not line:
                continue
            item = parse_line(line)
            if isinstance(item, Message) and item.tag == "ATT" and len(item.values) == 2:
                self.latest = item.values
                self.counts["ATT"] += 1
            elif isinstance(item, Sample):
                self.counts["samples"] += 1
            elif isinstance(item, BadLine):
                self.counts["bad"] += item.kind != "empty"
            else:
                self.counts["other"] += 1


def driving_motion(rate_hz=100.0, duration=62.5, still=2.5) -> sim.Motion:
    """What the virtual board plays: 2.5 s still (the sketch's gyro bias), then a hand steering left and
    right (roll ±20°, 12 s period) while dipping the nose 0…10° (throttle, 10 s period); whole cycles,
    so it loops smoothly."""
    t = sim.sample_times(duration, rate_hz)
    moving = t > still
    s = np.clip(t - still, 0.0, None)
    w1, w2 = 2 * np.pi / 12.0, 2 * np.pi / 10.0
    roll, roll_dot = np.radians(20.0) * np.sin(w1 * s), np.radians(20.0) * w1 * np.cos(w1 * s) * moving
    pitch, pitch_dot = -np.radians(5.0) * (1 - np.cos(w2 * s)), -np.radians(5.0) * w2 * np.sin(w2 * s) * moving
    euler = np.column_stack([roll, pitch, np.zeros_like(t)])
    euler_dot = np.column_stack([roll_dot, pitch_dot, np.zeros_like(t)])
    return sim.Motion(t, rate_hz, euler, euler_rates_to_body_rates(euler, euler_dot), np.zeros((len(t), 3)),
                      "a hand steering: roll ±20°, nose down 0…10°", [(0.0, still, "stationary")])


def run_tilt_demo(port, seconds=None, headless=False, fps=30.0, baud=115200, out=print) -> RaceGame:
    """Play the game from ``port`` (a serial port, or "virtual") for ``seconds`` (None: until the window closes).

    ``headless`` runs the same loop without a window (tests, CI) and prints a summary.
    """
    import time
    from contextlib import ExitStack

    if headless and seconds is None:
        raise ValueError("run_tilt_demo: a headless run needs seconds")
    game, dt = RaceGame(), 1.0 / fps
    with ExitStack() as stack:
        if port == "virtual":
            from .capture.virtual import VirtualBoard

            board = stack.enter_context(VirtualBoard(board="mpu6050", motion=driving_motion(), attitude=True))
            port = board.port
        stream = stack.enter_context(AttitudeStream(port, baud))
        if headless:
            t_end = time.monotonic() + seconds
            while time.monotonic() < t_end:
                time.sleep(dt)
                if stream.latest is not None:
                    game.update(*controls(*stream.latest), dt)
        else:
            _window(game, stream, dt, seconds)
        out(f"$ATT lines {stream.counts['ATT']}, samples {stream.counts['samples']}, bad lines {stream.counts['bad']}; "
            f"distance {game.distance:.0f} m, score {game.score:.0f}, off road {game.off_road_s:.1f} s")
    return game


def tilt_figure(game, stream, dt):
    """The game's figure (road from above, the car, roll and pitch) and ``draw(frame)``, which advances
    the game by one frame of dt seconds with the stream's latest attitude and redraws."""
    import matplotlib.pyplot as plt

    from .plots import COLORS

    fig, ax = plt.subplots(figsize=(5, 7), layout="constrained")
    ahead = np.linspace(-20, 80, 200)
    (left,) = ax.plot([], [], color=COLORS["truth"], lw=2)
    (right,) = ax.plot([], [], color=COLORS["truth"], lw=2)
    (car,) = ax.plot([], [], "s", color=COLORS["bound"], ms=12)
    text = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", family="monospace")
    ax.set_xlim(-20, 20)
    ax.set_ylim(-20, 80)
    ax.set_xlabel("lateral position (m)")
    ax.set_ylabel("road ahead (m)")
    ax.set_title("roll steers, nose down accelerates")

    def draw(_frame=None):
        if stream.latest is not None:
            game.update(*controls(*stream.latest), dt)
        center = road_center(game.distance + ahead)
        left.set_data(center - game.half_width, ahead)
        right.set_data(center + game.half_width, ahead)
        car.set_data([game.x], [0.0])
        roll, pitch = stream.latest or (float("nan"), float("nan"))
        text.set_text(f"roll {roll:+6.1f}°  pitch {pitch:+6.1f}°\nspeed {game.speed * 3.6:5.0f} km/h  score {game.score:6.0f}"
                      + ("" if game.on_road else "\nOFF ROAD"))
        return left, right, car, text

    return fig, draw


def _window(game, stream, dt, seconds):
    """Animate :func:`tilt_figure` in a matplotlib window until it is closed (or ``seconds`` have passed)."""
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    fig, draw = tilt_figure(game, stream, dt)
    fig.canvas.manager.set_window_title("kfkit demo tilt")
    frames = None if seconds is None else int(seconds / dt)
    animation = FuncAnimation(fig, draw, frames=frames, interval=dt * 1000, blit=False, repeat=False)
    plt.show()
    return animation
