"""`kfkit demo tilt`: $ATT lines, the virtual board's attitude option, the game's core, the CLI."""

import math
import time

import numpy as np
import pytest
import serial
from waiting import HANG_GUARD_S

from kfkit.capture import Message, VirtualBoard, encode_message, parse_line
from kfkit.cli import main
from kfkit.demo import RaceGame, controls, driving_motion, road_center

# --- $ATT lines ---------------------------------------------------------------------------------


def test_att_line_round_trip_and_checksum():
    line = encode_message("ATT", (12.5, -3.25))
    body = b"ATT,12.50,-3.25"
    assert line == b"$" + body + b"*%02X\n" % np.bitwise_xor.reduce(np.frombuffer(body, np.uint8))
    assert parse_line(line) == Message("ATT", (12.5, -3.25))
    bad = line.replace(b"12.50", b"12.51")
    assert parse_line(bad).kind == "checksum"


def read_lines(board, n_lines):
    with serial.Serial(board.port, 115200, timeout=1) as port:
        port.write(b"h")
        lines, t_end = [], time.monotonic() + HANG_GUARD_S  # a busy machine sends late, not never
        while len(lines) < n_lines and time.monotonic() < t_end:
            line = port.readline()
            if line:
                lines.append(line)
    return lines


def test_virtual_board_emits_att_lines_that_track_the_truth():
    motion = driving_motion()
    with VirtualBoard(board="mpu6050", motion=motion, attitude=True, realtime=False, loop=False, seed=3) as board:
        lines = read_lines(board, 2 + 199 + 2 * 1801)  # header, #NOTE, 199 samples alone, then sample + $ATT pairs
    header = parse_line(lines[0])
    assert header.board == "mpu6050" and header.params["messages"] == "ATT"
    assert "keep the board still" in parse_line(lines[1]).text  # as the sketch, while it measures the gyro bias
    samples, atts, seq_of_att = [], [], []
    for line in lines[2:]:
        item = parse_line(line)
        if isinstance(item, Message):
            atts.append(item.values)
            seq_of_att.append(samples[-1].seq)
        else:
            samples.append(item)
    assert len(samples) == 2000
    # none while the sketch measures the gyro bias (2 s = 200 samples), then one after every sample
    assert seq_of_att[0] == 199 and len(atts) == 2000 - 199
    est = np.radians(np.array(atts))
    truth = motion.euler[np.array(seq_of_att), :2]
    err = np.degrees(np.sqrt(np.mean((est - truth) ** 2, axis=0)))
    assert np.all(err < 3.0), err  # uncalibrated accelerometer biases of a few tens of mg
    assert np.degrees(np.ptp(truth[:, 0])) > 30  # the motion does steer


# --- the game's core --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "roll, pitch, want",
    [
        (0.0, 0.0, (0.0, 0.0)),
        (1.9, -1.9, (0.0, 0.0)),  # inside the 2° dead zone
        (30.0, -30.0, (1.0, 1.0)),  # full right, full throttle (nose down)
        (-45.0, 60.0, (-1.0, -1.0)),  # clipped
        (16.0, 9.0, (0.5, -0.25)),  # (16 − 2) / 28, −(9 − 2) / 28
        (float("nan"), 5.0, (0.0, -3 / 28)),
    ],
)
def test_controls(roll, pitch, want):
    assert controls(roll, pitch) == pytest.approx(want)


def test_full_throttle_speed_follows_the_first_order_law():
    game = RaceGame()
    dt, n = 0.01, 150  # 1.5 s: the car is still on the road (~8 m along it)
    for _ in range(n):
        game.update(0.0, 1.0, dt)
    t = n * dt
    v = game.a_max / game.drag * (1 - math.exp(-game.drag * t))  # v' = a − drag·v from rest
    assert game.speed == pytest.approx(v, rel=0.01)
    assert game.distance > 0 and game.score == pytest.approx(game.distance)  # the road starts straight ahead


def test_steering_leaves_the_road_and_slows_the_car():
    game = RaceGame(speed=20.0, x=float(road_center(0.0)))
    for _ in range(300):
        game.update(1.0, 1.0, 0.01)
    assert game.x > road_center(game.distance) + game.half_width and not game.on_road
    assert game.off_road_s > 0 and game.speed <= game.v_max / 3 + 1e-9


def test_bad_dt():
    with pytest.raises(ValueError, match="dt must be positive, got 0"):
        RaceGame().update(0.0, 0.0, 0)


# --- the stream and the game, end to end --------------------------------------------------------------


@pytest.mark.slow
def test_att_lines_from_the_virtual_board_drive_the_game_by_board_time():
    """The whole path without a window: virtual board → pty → AttitudeStream → controls → RaceGame."""
    from kfkit.demo import run_tilt_demo

    lines = []
    game = run_tilt_demo("virtual", seconds=40.0, headless=True, fast=True, out=lines.append)
    assert game.time == pytest.approx(40.0)  # one 1/100 s step per $ATT line, however fast they came
    assert game.distance > 100 and game.speed > 0  # nose down: throttle
    assert "bad lines 0" in lines[0] and "40." in lines[0]


def test_the_virtual_hand_steers_both_ways():
    """driving_motion rolls ±20°: the attitudes the sketch's twin sends steer right and left of the start."""
    from contextlib import ExitStack

    from kfkit.demo import advance, open_stream

    game, xs = RaceGame(), []
    with ExitStack() as stack:
        stream = open_stream(stack, "virtual", fast=True)
        deadline = time.monotonic() + HANG_GUARD_S  # a hang guard: the game's time is the board's
        while game.time < 20.0 and time.monotonic() < deadline:
            if advance(game, stream):
                xs.append(game.x)
            time.sleep(0.01)
    assert game.time >= 20.0
    steps = np.diff(xs)
    assert steps.max() > 0 and steps.min() < 0  # moved right at one time, left at another


def test_stream_says_why_there_are_no_att_lines(monkeypatch):
    """A board running mpu6050_logger sends samples only; the demo names the port and the sketch to flash."""
    import kfkit.demo as demo

    monkeypatch.setattr(demo, "NO_ATTITUDE_S", 1.0)
    with (
        VirtualBoard(board="mpu6050", realtime=False) as board,  # raw samples, no attitude=True
        pytest.raises(
            demo.DemoError, match=f"{board.port} sends samples but no \\$ATT lines: flash firmware/mpu6050_tilt_kf"
        ),
    ):
        demo.run_tilt_demo(board.port, seconds=5.0, headless=True)
    with (
        VirtualBoard(board="mpu6050", faults={"silent": True}) as board,
        pytest.raises(demo.DemoError, match=f"nothing received from {board.port}"),
    ):
        demo.run_tilt_demo(board.port, seconds=5.0, headless=True)


def test_unplugged_board_is_named():
    import kfkit.demo as demo

    motion = driving_motion()
    with (
        VirtualBoard(
            board="mpu6050", motion=motion, attitude=True, realtime=False, loop=False, faults={"disconnect": 700}
        ) as board,
        pytest.raises(demo.DemoError, match=f"{board.port} stopped sending .*: board unplugged\\?"),
    ):
        demo.run_tilt_demo(board.port, seconds=30.0, headless=True)


# --- the command ----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_demo_runs_headless_against_the_virtual_board(capsys):
    assert main(["demo", "tilt", "--port", "virtual", "--seconds", "30", "--headless", "--fast"]) == 0
    out = capsys.readouterr().out
    assert "$ATT lines" in out and "bad lines 0" in out and "30.0 s driven" in out


def test_demo_in_real_time_against_the_virtual_board(capsys):
    assert main(["demo", "tilt", "--port", "virtual", "--seconds", "1", "--headless"]) == 0
    assert "1.0 s driven" in capsys.readouterr().out


def test_demo_names_a_missing_port(capsys):
    assert main(["demo", "tilt", "--port", "/dev/kfkit-no-such-port", "--seconds", "1", "--headless"]) == 2
    assert "cannot open /dev/kfkit-no-such-port" in capsys.readouterr().err


def test_fast_is_only_for_the_virtual_board(capsys):
    assert main(["demo", "tilt", "--port", "/dev/ttyUSB0", "--seconds", "1", "--headless", "--fast"]) == 2
    assert "--fast is for --port virtual" in capsys.readouterr().err


def test_headless_needs_seconds():
    from kfkit.demo import run_tilt_demo

    with pytest.raises(ValueError, match="needs seconds"):
        run_tilt_demo("virtual", headless=True)


class FakeStream:
    """What tilt_figure reads from an AttitudeStream: 60 attitudes queued, rolled right and nose down."""

    def __init__(self, attitudes=((10.0, -12.0),) * 60, problem=None):
        self.queue, self.rate_hz, self.error, self.problem = list(attitudes), 100.0, None, problem
        self.latest = attitudes[-1] if attitudes else None

    def take(self, limit=None):
        out, self.queue = self.queue[:limit], self.queue[len(self.queue[:limit]) :]
        return out

    def waiting_for(self):
        return self.problem


def test_figure_draws_a_frame(tmp_path):
    from kfkit.demo import tilt_figure

    game = RaceGame(speed=10.0)
    fig, draw = tilt_figure(game, FakeStream())
    artists = draw()
    assert game.time == pytest.approx(0.6) and game.x > 0  # 60 lines at 100 Hz: rolled right, moved right
    assert "roll  +10.0°" in artists[-1].get_text()
    draw()
    assert game.time == pytest.approx(0.6)  # nothing new: the game waits for the board
    fig.savefig(tmp_path / "demo.png")


def test_figure_shows_why_it_waits():
    from kfkit.demo import tilt_figure

    _, draw = tilt_figure(RaceGame(), FakeStream((), problem="/dev/ttyUSB0 sends samples but no $ATT lines: flash it"))
    assert "no $ATT lines: flash it" in draw()[-1].get_text().replace("\n", " ")


@pytest.mark.filterwarnings("ignore:Passing unrecognized arguments:DeprecationWarning")  # ipympl's toolbar
def test_notebook_panel_drives_the_game_from_the_virtual_board():
    from kfkit.demo import TiltDemoPanel

    panel = TiltDemoPanel("virtual", fast=True)
    try:
        deadline = time.monotonic() + 120  # a safety net: the game advances by board time
        while panel.game.time < 3.0 and time.monotonic() < deadline:
            panel.refresh()
            time.sleep(0.05)
        assert panel.game.time >= 3.0 and panel.stream.counts["bad"] == 0
        assert "roll" in panel.fig.axes[0].texts[0].get_text()
    finally:
        panel.close()


@pytest.mark.slow
def test_demo_window_opens_and_closes_after_its_seconds(tmp_path):
    """The real window (TkAgg) under a virtual X server, where Debian's xvfb is installed."""
    import os
    import shutil
    import subprocess
    import sys

    pytest.importorskip("tkinter")
    if shutil.which("xvfb-run") is None:
        pytest.skip("xvfb-run is not installed (apt-get install xvfb): the window path is not tried here")
    env = {**os.environ, "MPLBACKEND": "TkAgg"}
    run = subprocess.run(
        ["xvfb-run", "-a", sys.executable, "-m", "kfkit", "demo", "tilt", "--port", "virtual", "--seconds", "3"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert run.returncode == 0, run.stderr
    assert "bad lines 0" in run.stdout and " s driven" in run.stdout


@pytest.mark.filterwarnings("ignore:Passing unrecognized arguments:DeprecationWarning")  # ipympl's toolbar
def test_notebook_panel_timer_stops_when_the_board_is_unplugged_and_after_close():
    """Through matplotlib's timer (TimerBase._on_timer): the tick returns None, draws the reason once the board is
    gone and stops; after close() the drive button cannot restart it."""
    from kfkit.demo import TiltDemoPanel

    board = VirtualBoard(
        board="mpu6050", motion=driving_motion(), attitude=True, realtime=False, loop=False, faults={"disconnect": 400}
    ).start()
    try:
        panel = TiltDemoPanel(board.port)
        panel.timer.start()
        deadline = time.monotonic() + 120  # a safety net
        while panel.timer._timer is not None and time.monotonic() < deadline:
            panel.timer._on_timer()
            time.sleep(0.01)
        assert panel.timer._timer is None and panel.timer.callbacks == [(panel.refresh, (), {})]
        assert "board unplugged?" in panel.fig.axes[0].texts[0].get_text().replace("\n", " ")
        panel.close()
        panel.start()
        assert panel.timer._timer is None
    finally:
        board.close()
