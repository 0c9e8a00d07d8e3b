"""The capture panel (lab 00): record from a board, a phone or the virtual board, with a guided protocol,
live signals, progress and statistics."""

from __future__ import annotations

from pathlib import Path

import ipywidgets as W
import numpy as np
from matplotlib.figure import Figure

from .. import sensors
from ..capture import (
    PROTOCOLS,
    CaptureError,
    Recorder,
    dataset_name,
    find_boards,
    protocol_motion,
    protocol_steps,
    sphere_coverage,
)
from ..capture.guided import protocol_capture_options, step_at
from ..plots import COLORS
from .canvas import interactive_canvas

_LIVE_SENSORS = (
    ("acc", "accelerometer (m/s²)", 1.0),
    ("gyr", "gyro (°/s)", 180.0 / np.pi),
    ("mag", "magnetometer (µT)", 1.0),
)
_AXIS_COLORS = (COLORS["accel"], COLORS["band"], COLORS["kf"])  # x, y, z (Okabe–Ito)
_AXIS_STYLES = ("-", "--", "-.")


class LiveSignals:
    """The capture panel's figure: accelerometer, gyro and magnetometer, body frame, SI (gyro in °/s),
    over the last ``window_s`` seconds. ``update(snapshot)`` sets the lines; the caller draws the canvas."""

    def __init__(self, fig, window_s=5.0):
        self.fig, self.window_s = fig, window_s
        self.axes = fig.subplots(3, 1, sharex=True)
        self.lines = {}
        for ax, (sensor, label, _) in zip(self.axes, _LIVE_SENSORS):
            self.lines[sensor] = [
                ax.plot([], [], color=c, ls=ls, lw=1.0, label=f"{axis}")[0]
                for c, ls, axis in zip(_AXIS_COLORS, _AXIS_STYLES, "xyz")
            ]
            ax.set_ylabel(label, fontsize=8)
            ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=7)  # beside the live data
        self.axes[-1].set_xlabel("time (s)")

    def update(self, snap) -> bool:
        """Show ``snap`` (a Recording); False (nothing changed) until it has samples and sensors."""
        if not len(snap) or "sensors" not in snap.meta:
            return False
        t = snap.t
        for ax, (sensor, _, scale) in zip(self.axes, _LIVE_SENSORS):
            if sensor not in snap.meta["sensors"]:
                continue
            values = snap.body(sensor) * scale
            keep = np.isfinite(values[:, 0])  # magnetometer: only the rows with a new reading
            for i, line in enumerate(self.lines[sensor]):
                line.set_data(t[keep], values[keep, i])
            ax.relim()
            ax.autoscale_view()
        self.axes[-1].set_xlim(max(t[-1] - self.window_s, 0.0), max(t[-1], self.window_s))
        return True


class CapturePanel:
    """Record from a board or the virtual board: port, board, baud, guided protocol, duration, record/stop,
    a progress bar, the live signals of the last ``window_s`` seconds, statistics and the saved file.

    The live plot is redrawn by a timer of the figure's canvas (``canvas.new_timer``), which runs on
    the kernel's main thread (ipykernel's event loop); the recorder's reader thread never draws. The
    timer runs only while a capture does. ``record()``, ``stop()`` and ``refresh()`` do from code what
    the buttons and the timer do; ``on_record`` callbacks run when a capture starts (a live 3-D view).
    A guided protocol labels its phases in the recording and saves it under the name labs 02–05
    look for (``kfkit.capture.dataset_name``: e.g. ``05_six_faces.csv`` for an MPU6050).
    """

    def __init__(self, out_dir="my_recordings", window_s=5.0, interval_ms=200, quick=False, fast=False):
        # quick: the protocols' short durations; fast: the virtual board runs faster than real time
        self.out_dir, self.window_s, self.quick, self.fast = Path(out_dir), window_s, quick, fast
        self.recorder, self.recording, self.steps = None, None, None
        self.on_record = []  # callables run when a capture starts (AttitudeView.live follows the panel with one)
        self.boards = {b.port: b for b in find_boards()}
        options = [(str(b), b.port) for b in self.boards.values()] + [
            ("phone (phyphox remote access)", "phone"),
            ("virtual board (simulated)", "virtual"),
        ]
        style, wide = {"description_width": "initial"}, W.Layout(width="330px")
        self.port = W.Dropdown(
            options=options,
            value=next((b.port for b in self.boards.values() if b.known), "virtual"),
            description="port",
            style=style,
            layout=W.Layout(width="460px"),
        )
        self.board = W.Dropdown(options=["nucleo-iks02a1", "mpu6050"], description="board", style=style)
        self.phone = W.Text(
            placeholder="192.168.0.42:8080", description="phone address", style=style
        )  # as phyphox shows it
        self.baud = W.Dropdown(
            options=[115200, 230400, 460800, 921600, 9600], value=115200, description="baud", style=style
        )
        self.protocol = W.Dropdown(
            options=[("free recording", None)] + [(p.title, name) for name, p in PROTOCOLS.items()],
            description="protocol",
            style=style,
            layout=W.Layout(width="460px"),
        )
        self.seconds = W.BoundedFloatText(
            value=30.0,
            min=0.5,
            max=7200.0,
            step=1.0,
            description="duration (s)",
            style=style,
            layout=W.Layout(width="200px"),
        )
        self.out = W.Text(value=str(self.out_dir / "capture.csv"), description="save as", style=style, layout=wide)
        self._auto_out = self.out.value  # the name the panel chose; one typed by the user is kept
        self.record_button = W.Button(description="record", icon="circle", button_style="danger")
        self.stop_button = W.Button(description="stop", icon="stop", disabled=True)
        self.progress = W.FloatProgress(value=0.0, min=0.0, max=1.0, description="0 %", style=style)
        self.coverage = W.FloatProgress(
            value=0.0,
            min=0.0,
            max=1.0,
            description="sphere coverage 0 %",
            style=style,
            layout=W.Layout(visibility="hidden"),
        )
        self.prompt, self.status = W.HTML(), W.HTML()
        self.record_button.on_click(lambda _: self.record())
        self.stop_button.on_click(lambda _: self.stop())
        self.port.observe(lambda _: self._port_changed(), names="value")
        self.protocol.observe(lambda _: self._protocol_changed(), names="value")
        self.board.observe(lambda _: self._settings_changed(), names="value")

        self.live = LiveSignals(Figure(figsize=(9.0, 5.4), layout="constrained"), window_s)
        self.axes, self.lines = self.live.axes, self.live.lines
        self.canvas = interactive_canvas(self.live.fig)
        self.timer = self.canvas.new_timer(interval=interval_ms)
        self.timer.add_callback(self.refresh)
        self._port_changed()
        self.widget = W.VBox(
            [
                W.HBox([self.port, self.board, self.phone]),
                W.HBox([self.protocol, self.baud]),
                W.HBox([self.seconds, self.out, self.record_button, self.stop_button]),
                W.HBox([self.progress, self.coverage]),
                self.prompt,
                self.canvas,
                self.status,
            ]
        )

    # -- settings ---------------------------------------------------------------------------------
    def _port_changed(self):
        """A detected board fixes the board type (from its USB ID); the virtual board lets you pick it."""
        found = self.boards.get(self.port.value)
        virtual = self.port.value == "virtual"
        if found is not None and found.known:
            self.board.value = found.board
        self.board.layout.display = None if virtual or (found is not None and not found.known) else "none"
        phone = self.port.value == "phone"
        self.baud.layout.display = "none" if virtual or phone else None
        self.phone.layout.display = None if phone else "none"
        self._protocol_changed()

    def _protocol_changed(self):
        name = self.protocol.value
        self.coverage.layout.visibility = "visible" if name == "mag-rotations" else "hidden"
        if name is not None and self.port.value == "virtual":
            p = PROTOCOLS[name]
            one_lab = len(set(p.datasets.values())) == 1  # every board saves it for the same lab (not so: stationary)
            if one_lab and p.board != self.board.value:
                self.board.value = p.board  # the board its lab uses (observing board calls _settings_changed)
                return
        self._settings_changed()

    def _settings_changed(self):
        """Duration, file name and the first instruction for the chosen protocol and board."""
        name = self.protocol.value
        if name is None:
            self._name_file("capture")
            self.prompt.value = ""
            return
        try:
            self._name_file(dataset_name(name, self.board.value))
        except ValueError as e:
            self.prompt.value = f"<b style='color:{COLORS['bound']}'>❌ {e}</b>"
            return
        motion = protocol_motion(name, self._rate(), quick=self.quick)
        self.seconds.value = round(len(motion.t) / motion.rate_hz, 2)
        first = protocol_steps(name, motion)[0][3]
        self.prompt.value = (
            "the virtual board follows the prompts by itself"
            if self.port.value == "virtual"
            else f"before you press record: <b>{first}</b>"
        )

    def _name_file(self, stem):
        """Save as ``out_dir/stem.csv`` unless the user typed a name of their own."""
        if self.out.value == self._auto_out:
            self.out.value = self._auto_out = str(self.out_dir / f"{stem}.csv")

    def _rate(self) -> float:
        return sensors.board(self.board.value).rate_hz

    # -- recording ----------------------------------------------------------------------------------
    def record(self):
        """Start recording with the panel's settings (the record button)."""
        if self.recorder is not None:
            return
        options, name = {}, self.protocol.value
        self.steps = None
        port = (
            self.port.value
            if self.port.value != "phone"
            else f"phyphox://{self.phone.value.strip().removeprefix('http://')}"
        )
        try:
            if name is not None:
                _, self.steps, options = protocol_capture_options(
                    name, port, self.board.value, quick=self.quick, fast=self.fast
                )
            elif self.port.value == "virtual":
                options["virtual"] = {"board": self.board.value, "realtime": not self.fast}
            self.recorder = Recorder(
                port, self.baud.value, self.out.value, seconds=self.seconds.value, **options
            ).start()
        except (CaptureError, ValueError) as e:
            self.recorder = None
            self._show_error(e)
            return
        self.recording = None
        self.record_button.disabled, self.stop_button.disabled = True, False
        self.progress.value, self.progress.description, self.coverage.value = 0.0, "0 %", 0.0
        self.status.value = f"recording from {self.recorder.description} …"
        self.timer.start()
        for callback in list(self.on_record):
            callback()

    def stop(self):
        """Stop now (the stop button); what arrived is saved."""
        if self.recorder is not None:
            self._finish()

    def _finish(self, draw=True):
        self.timer.stop()
        rec, self.recorder = self.recorder, None
        self.record_button.disabled, self.stop_button.disabled = False, True
        completed = rec.done.is_set() and rec.error is None  # the reader ended by itself: all the seconds arrived
        try:
            stats = rec.stop()
        except CaptureError as e:
            self._show_error(e)
            stats = rec.stats
        if draw:
            self._draw(rec)
        if completed and rec.elapsed > 0:
            self.progress.value, self.progress.description = 1.0, "100 %"
        if rec.stats.samples:
            self.recording = rec.recording()
            saved = f"saved {len(self.recording)} samples to <code>{rec.out}</code>"
            if rec.header is not None and rec.header.board != self.board.value:
                saved += f" (the board says it is a {rec.header.board}, not a {self.board.value}: rename the file)"
        else:
            saved = "nothing to save"
        text = str(stats).replace("\n", "<br>")
        if rec.error is None:
            self.status.value = f"<b>done</b>: {saved}<br><pre style='line-height:1.2'>{text}</pre>"
        else:
            self.status.value += f"<br><pre style='line-height:1.2'>{text}</pre>"
        if self.steps:  # the guided protocol's last instruction no longer applies: say how it ended
            if completed:
                ended = f"✅ {self.protocol.label} finished"
            else:
                ended = f"⏹ {self.protocol.label} stopped at {rec.elapsed:.1f} of {self.seconds.value:g} s"
            self.prompt.value = f"<b>{ended}</b>: {saved}"

    def _show_error(self, error):
        self.status.value = f"<b style='color:{COLORS['bound']}'>❌ {error}</b>"

    def refresh(self) -> None:
        """One timer tick: progress, prompt, statistics, coverage and the live plot; finish when done.
        Returns None (a timer callback); an unexpected error stops the capture (what arrived is saved) and is shown."""
        rec = self.recorder
        if rec is None:
            self.timer.stop()
            return None
        try:
            self._tick(rec)
        except Exception as e:  # a timer callback has no one to raise to: stop, keep the data, say why
            self.timer.stop()
            try:
                if self.recorder is not None:  # (the error may have come from _finish itself)
                    self._finish(draw=False)  # (drawing may be what failed)
            finally:
                self._show_error(
                    f"the panel stopped on an unexpected error ({e!r}); what arrived is saved in {rec.out}"
                )
        return None

    def _tick(self, rec):
        fraction = min(rec.elapsed / self.seconds.value, 1.0)
        self.progress.value, self.progress.description = fraction, f"{100 * fraction:.0f} %"
        if self.steps:
            start, end, _, prompt = step_at(self.steps, rec.elapsed)
            self.prompt.value = f"<b>{prompt}</b> &nbsp; ({max(end - rec.elapsed, 0.0):.0f} s)"
        s = rec.stats
        self.status.value = (
            f"{rec.description}: {s.samples} samples, {s.bad_lines} bad lines, {s.dropped} dropped, {s.resets} resets"
        )
        self._draw(rec)
        if self.protocol.value == "mag-rotations" and rec.columns and "mx" in rec.columns:
            snapshot = rec.recording()
            if "mag" in snapshot.meta.get("sensors", {}):
                self.coverage.value = sphere_coverage(snapshot.body("mag"))
                self.coverage.description = f"sphere coverage {100 * self.coverage.value:.0f} %"
        if rec.done.is_set():
            self._finish()

    def _draw(self, rec):
        """Redraw the last ``window_s`` seconds of ``rec`` (a Recorder)."""
        if self.live.update(rec.recording(last_seconds=self.window_s)):
            self.canvas.draw_idle()

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)


def capture_panel(out_dir="my_recordings", window_s=5.0, interval_ms=200, quick=False, fast=False) -> CapturePanel:
    """A :class:`CapturePanel`: pick a port (or the virtual board) and a guided protocol, press record."""
    return CapturePanel(out_dir=out_dir, window_s=window_s, interval_ms=interval_ms, quick=quick, fast=fast)
