"""`kfkit demo tilt`: $ATT lines, the virtual board's attitude option, the game's core, the CLI."""
import math
import time

import numpy as np
import pytest
import serial

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


def read_lines(board, n_lines, timeout=20.0):
    with serial.Serial(board.port, 115200, timeout=1) as port:
        port.write(b"h")
        lines, t_end = [], time.monotonic() + timeout
        while len(lines) < n_lines and time.monotonic() < t_end:
            line = port.readline()
            if line:
                lines.append(line)
    return lines


def test_virtual_board_emits_att_lines_that_track_the_truth():
    motion = driving_motion()
    with VirtualBoard(board="mpu6050", motion=motion, attitude=True, realtime=False, loop=False, seed=3) as board:
        lines = read_lines(board, 1 + 199 + 2 * 1801)  # header, 199 samples alone, then sample + $ATT pairs
    header = parse_line(lines[0])
    assert header.board == "mpu6050" and header.params["messages"] == "ATT"
    samples, atts, seq_of_att = [], [], []
    for line in lines[1:]:
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

@pytest.mark.parametrize("roll, pitch, want", [
    (0.0, 0.0, (0.0, 0.0)),
    (1.9, -1.9, (0.0, 0.0)),          # inside the 2° dead zone
    (30.0, -30.0, (1.0, 1.0)),        # full right, full throttle (nose down)
    (-45.0, 60.0, (-1.0, -1.0)),      # clipped
    (16.0, 9.0, (0.5, -0.25)),        # (16 − 2) / 28, −(9 − 2) / 28
    (float("nan"), 5.0, (0.0, -3 / 28)),
])
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


# --- the command ----------------------------------------------------------------------------------------

def test_demo_runs_headless_against_the_virtual_board(capsys):
    assert main(["demo", "tilt", "--port", "virtual", "--seconds", "4", "--headless"]) == 0
    out = capsys.readouterr().out
    assert "$ATT lines" in out and "bad lines 0" in out


def test_demo_names_a_missing_port(capsys):
    assert main(["demo", "tilt", "--port", "/dev/kfkit-no-such-port", "--seconds", "1", "--headless"]) == 2
    assert "/dev/kfkit-no-such-port" in capsys.readouterr().err


def test_headless_needs_seconds():
    from kfkit.demo import run_tilt_demo

    with pytest.raises(ValueError, match="needs seconds"):
        run_tilt_demo("virtual", headless=True)


def test_figure_draws_a_frame(tmp_path):
    import matplotlib
    matplotlib.use("Agg")
    from kfkit.demo import tilt_figure

    class Stream:
        latest = (10.0, -12.0)

    game = RaceGame()
    fig, draw = tilt_figure(game, Stream(), 1 / 30)
    for frame in range(60):
        artists = draw(frame)
    assert game.distance > 0 and game.x > 0  # rolled right, nose down: forward and to the right
    assert "roll  +10.0°" in artists[-1].get_text()
    fig.savefig(tmp_path / "demo.png")
