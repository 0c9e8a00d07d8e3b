"""The capture panel driven from code (as its buttons and timer would) against the virtual board."""
import time

import pytest
import serial.tools.list_ports

from kfkit.io import load_recording
from kfkit.widgets import capture_panel


@pytest.fixture
def panel(monkeypatch, tmp_path):
    monkeypatch.setattr(serial.tools.list_ports, "comports", lambda include_links=False: [])
    p = capture_panel(out_dir=tmp_path, quick=True, fast=True)
    yield p
    p.stop()


def run_until_done(p, timeout=20.0):
    deadline = time.monotonic() + timeout
    while p.recorder is not None and time.monotonic() < deadline:
        p.refresh()  # what the canvas timer calls on the kernel's main thread
        time.sleep(0.05)
    assert p.recorder is None


def test_defaults_to_the_virtual_board_without_boards(panel):
    assert panel.port.value == "virtual" and panel.port.options[-1][1] == "virtual"


def test_guided_tilt_protocol_records_labelled_phases(panel, tmp_path):
    panel.protocol.value = "tilt"
    assert panel.board.value == "mpu6050" and panel.out.value.endswith("05_tilt_protocol.csv")
    panel.record()
    assert panel.recorder is not None and panel.record_button.disabled
    run_until_done(panel)
    rec = load_recording(tmp_path / "05_tilt_protocol.csv")
    assert {p["label"] for p in rec.phases} == {"pitch_0", "pitch_90", "roll_0", "roll_90"}
    assert len(rec) == len(panel.recording) == round(panel.seconds.value * 100)
    assert "done" in panel.status.value and panel.progress.value == 1.0
    assert len(panel.lines["acc"][0].get_xdata()) > 0  # the live plot was drawn


def test_stop_early_clips_phases_and_saves(panel, tmp_path):
    panel.fast = False  # real time, so that stop() comes before the end
    panel.protocol.value = "mag-rotations"
    panel.record()
    time.sleep(1.0)
    panel.refresh()
    panel.stop()
    rec = load_recording(tmp_path / "03_mag_rotations.csv")
    (phase,) = rec.phases
    assert phase["end"] <= rec.t[-1] + 0.011 and len(rec) < panel.seconds.value * 104
    assert 0.0 < panel.coverage.value <= 1.0


def test_error_is_shown_not_raised(panel, monkeypatch, tmp_path):
    panel.port.options = [("nowhere", "/dev/ttyNOPE"), ("virtual", "virtual")]
    panel.port.value = "/dev/ttyNOPE"
    panel.record()
    assert panel.recorder is None and "not found" in panel.status.value


def test_timer_drives_the_panel_in_a_real_kernel(tmp_path):
    """In ipykernel the canvas timer fires on the kernel's main thread between cells: the panel
    records, redraws and saves with nobody calling refresh()."""
    from jupyter_client.manager import start_new_kernel

    km, kc = start_new_kernel(kernel_name="python3", cwd=str(tmp_path))
    try:
        def run(code):
            reply = kc.execute_interactive(code, timeout=60, output_hook=lambda msg: outputs.append(msg))
            assert reply["content"]["status"] == "ok", outputs

        outputs = []
        run("import threading, time\nfrom kfkit.widgets import capture_panel\n"
            "p = capture_panel(out_dir='rec', interval_ms=100)\np.port.value = 'virtual'\np.seconds.value = 1.0\n"
            "calls = []\nreal = p.refresh\n"
            "p.refresh = lambda: (calls.append(threading.current_thread() is threading.main_thread()), real())\n"
            "p.timer.remove_callback(real)\np.timer.add_callback(p.refresh)\np.record()")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            time.sleep(0.5)  # the kernel is idle here: only its event loop runs the timer
            outputs = []
            run("print(p.recording is not None and len(p.recording), len(calls), all(calls))")
            printed = "".join(m["content"].get("text", "") for m in outputs if m["msg_type"] == "stream")
            if not printed.startswith("False"):
                break
        samples, ticks, main_thread = printed.split()
        assert int(samples) == 104 and int(ticks) >= 3 and main_thread == "True"
        assert (tmp_path / "rec" / "capture.csv").exists()
    finally:
        kc.stop_channels()
        km.shutdown_kernel(now=True)
