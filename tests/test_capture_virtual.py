"""End to end over a pseudo-terminal: the virtual board with each fault kind, the recorder,
the streamed file, the CLI. Expected statistics come from the fault positions, not from the code."""
import json
import os
import threading

import numpy as np
import pytest

import kfkit.capture as C
from kfkit import sim
from kfkit.cli import main
from kfkit.frames import G, MAG_FIELD_LONDON
from kfkit.io import load_recording

RATE = 1000.0
N = 200  # samples the board makes in SECONDS of board time
SECONDS = N / RATE


@pytest.fixture(autouse=True)
def no_leaks():
    """Every test closes its threads and file descriptors."""
    fds, threads = set(os.listdir("/proc/self/fd")), threading.active_count()
    yield
    for t in threading.enumerate():
        if t.name.startswith("kfkit-"):
            t.join(5)
    assert threading.active_count() <= threads
    assert set(os.listdir("/proc/self/fd")) <= fds | {f for f in os.listdir("/proc/self/fd") if not f.isdigit()}


def record(faults=None, board="nucleo-iks02a1", out=None, seconds=SECONDS, **options):
    vb = C.VirtualBoard(rate_hz=RATE, board=board, faults=faults, realtime=False, seed=3)
    rec = C.Recorder(vb, out=out, seconds=seconds, no_data_s=0.4, garbage_s=0.3, **options)
    with rec:
        assert rec.wait(10)
    return rec


def test_clean_stream_physics_and_time():
    rec = record(board="nucleo-iks02a1")
    s, r = rec.stats, rec.recording()
    assert (s.samples, s.bad_lines, s.dropped, s.resets) == (N, 0, 0, 0)
    np.testing.assert_allclose(r.t, np.arange(N) / RATE, atol=1e-6)  # t_us rounds to whole µs
    np.testing.assert_array_equal(r["seq"], np.arange(N))
    assert s.rate_hz == pytest.approx(RATE, rel=1e-5) and s.jitter_us < 1.0
    acc = r.body("acc").mean(axis=0)  # at rest and level: f_b = [0, 0, −g] (± the board's bias)
    np.testing.assert_allclose(acc, [0.0, 0.0, -G], atol=0.25)
    mag = r.body("mag")
    fresh = np.isfinite(mag[:, 0])
    # IIS2MDC at 50 Hz beside 1 kHz samples: a new reading on 1 sample in 20, counting the first
    assert fresh.sum() == (N - 1) * 50 // 1000 + 1
    np.testing.assert_allclose(np.linalg.norm(mag[fresh], axis=1).mean(), np.linalg.norm(MAG_FIELD_LONDON), rtol=0.03)


def test_each_fault_gives_exactly_its_statistics():
    rec = record(faults={"corrupt": [10, 20], "drop": [30, 31, 32], "truncate": [40], "reset": [100]})
    s = rec.stats
    assert s.bad_checksum == 2 and s.malformed == 1
    # missing samples: 2 corrupted + 3 dropped + 1 truncated; received indices shift by the losses before them
    assert s.dropped == 6 and s.samples == N - 6
    assert s.drops == [(10, 0.011, 1), (19, 0.021, 1), (28, 0.033, 3), (35, 0.041, 1)]
    assert s.resets == 1 and s.reset_positions == [100 - 6]
    seq = rec.recording()["seq"]
    assert seq[94] == 0 and seq[93] == 99  # seq restarts at the reset


def test_random_faults_are_counted_consistently():
    rec = record(faults={"corrupt": 0.05, "drop": 0.05})
    s = rec.stats
    made = s.samples + s.dropped
    assert s.bad_checksum > 0 and s.dropped > s.bad_checksum
    assert made == N  # every sample the board made is either received or counted as dropped


def test_micros_wrap_keeps_time_continuous():
    vb = C.VirtualBoard(rate_hz=RATE, board="mpu6050", realtime=False, start_us=2**32 - 50_500)
    with C.Recorder(vb, seconds=0.1) as rec:
        rec.wait(10)
    r = rec.recording()
    assert rec.stats.resets == 0 and len(r) == 100
    np.testing.assert_allclose(r.t, np.arange(100) / RATE, atol=1e-6)


def test_disconnect_keeps_every_sample_on_disk(tmp_path):
    out = tmp_path / "cut.csv"
    vb = C.VirtualBoard(rate_hz=RATE, realtime=False, faults={"disconnect": 150, "drop": [5]})
    rec = C.Recorder(vb, out=out, seconds=10).start()
    try:
        assert rec.wait(10)
        assert isinstance(rec.error, C.BoardDisconnectedError)
        streamed = load_recording(out)  # before stop(): what the streaming writer put on disk
        assert len(streamed) == 149
    finally:
        with pytest.raises(C.BoardDisconnectedError, match=f"after 149 samples.*saved in {out}"):
            rec.stop()
    final = load_recording(out)
    assert len(final) == 149 and final.meta["capture"]["stats"]["dropped"] == 1


def test_wrong_baud_names_the_expected_rate():
    with pytest.raises(C.WrongBaudError, match="wrong baud rate.*115200 baud.*open at 9600.*baud=115200"):
        record(faults={"garbage": True}, baud=9600)


def test_silent_board_says_check_the_sketch():
    with pytest.raises(C.NoDataError, match="nothing received.*sketch is flashed"):
        record(faults={"silent": True})


def test_second_recorder_on_the_same_port_is_busy():
    with C.VirtualBoard(rate_hz=RATE, realtime=False) as vb:
        with C.Recorder(vb.port, seconds=0.01) as first:
            with pytest.raises(C.PortBusyError, match="busy"):
                C.Recorder(vb.port).start()
            first.wait(5)


def test_commands_h_and_s():
    import serial

    with C.VirtualBoard(rate_hz=RATE, board="mpu6050") as vb, serial.Serial(vb.port, timeout=1) as port:
        port.write(b"h")
        assert C.parse_line(port.readline()).board == "mpu6050"  # first contact: header, then samples
        assert isinstance(C.parse_line(port.readline()), C.Sample)
        port.write(b"s")  # stop
        port.timeout = 0.2
        while port.read(4096):
            pass
        assert port.read(1) == b""
        port.write(b"h")
        port.timeout = 1
        assert isinstance(C.parse_line(port.readline()), C.Header)


def test_guided_motion_phases_reach_the_recording(tmp_path):
    motion = C.protocol_motion("six-faces", 208.0, quick=True)
    r = C.capture("virtual", seconds=len(motion.t) / 208.0, out=tmp_path / "faces.csv",
                  virtual=dict(motion=motion, realtime=False))
    loaded = load_recording(tmp_path / "faces.csv")
    assert {p["label"] for p in loaded.phases} == {"x_up", "x_down", "y_up", "y_down", "z_up", "z_down"}
    f = loaded.body("acc")[loaded.phase("x_up")].mean(axis=0)  # x up reads +g of specific force
    np.testing.assert_allclose(f, [G, 0.0, 0.0], atol=0.3)
    assert len(r) == len(motion.t)


def test_protocol_steps_cover_the_motion():
    motion = sim.tilt_protocol(rate_hz=100.0, hold=1.0, move=0.5)
    steps = C.protocol_steps("tilt", motion)
    assert steps[0][:3] == (0.0, 1.0, "pitch_0") and steps[1][2] is None
    assert all(a[1] == pytest.approx(b[0]) for a, b in zip(steps, steps[1:]))
    assert steps[-1][1] == pytest.approx(len(motion.t) / 100.0)


def test_sphere_coverage():
    rng = np.random.default_rng(0)
    v = rng.normal(size=(5000, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    assert C.sphere_coverage(v + [0.3, -0.2, 0.1]) == 1.0  # a hard-iron offset smaller than the field
    assert C.sphere_coverage(v + [3.0, -2.0, 1.0], center=[3.0, -2.0, 1.0]) == 1.0
    assert C.sphere_coverage(np.tile([1.0, 0.0, 0.0], (100, 1)) + rng.normal(0, 1e-3, (100, 3))) == 1 / 26


def test_cli_capture_virtual_json(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["capture", "--port", "virtual", "--seconds", "0.1", "--rate", "500", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["samples"] == 50 and result["bad_lines"] == 0 and result["dropped"] == 0 and result["resets"] == 0
    assert result["out"] == str(out.resolve()) and len(load_recording(out)) == 50


def test_cli_capture_error_exit_code(tmp_path, capsys):
    assert main(["capture", "--port", "/dev/ttyNOPE", "--out", str(tmp_path / "x.csv")]) == 2
    assert "/dev/ttyNOPE not found" in capsys.readouterr().err


def test_cli_guided_protocol_on_the_virtual_board(tmp_path, capsys):
    out = tmp_path / "faces.csv"
    assert main(["capture", "--port", "virtual", "--protocol", "six-faces", "--quick", "--fast", "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    rec = load_recording(out)
    assert result["samples"] == len(rec) == round(13.5 * 104) and result["board"] == "nucleo-iks02a1"
    assert {p["label"] for p in rec.phases} == {"x_up", "x_down", "y_up", "y_down", "z_up", "z_down"}


def test_record_protocol_on_a_real_port_labels_phases_from_the_prompts(tmp_path):
    """A port that is not "virtual" gets its phases from the prompt timeline (here a pty board at rest)."""
    prompts = []
    with C.VirtualBoard(rate_hz=100.0, board="mpu6050", realtime=False) as vb:
        rec = C.record_protocol("tilt", vb.port, tmp_path / "tilt.csv", quick=True, prompt=prompts.append)
    steps = C.protocol_steps("tilt", C.protocol_motion("tilt", 100.0, quick=True))
    assert [(p["start"], p["end"], p["label"]) for p in rec.phases] == [(a, b, lab) for a, b, lab, _ in steps if lab]
    assert prompts and "level" in prompts[0]
