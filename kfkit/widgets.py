"""ipywidgets UIs: filter tuning with log-scale sliders; the 3-D attitude view (lab 04), replayed
(``attitude_view``) or live from a recorder (``AttitudeView.live`` + ``LiveAttitude``); the capture
panel (lab 00, ``capture_panel``).

The tuning figure is an ipympl canvas created for this panel only, so the rest of a
notebook keeps the inline backend (static PNGs that survive in saved outputs) while
this figure redraws in place without flicker when a slider moves.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import ipywidgets as W
import matplotlib
import numpy as np
from matplotlib.figure import Figure

from .filters.attitude import quat_to_dcm
from .frames import dcm_to_euler
from .metrics import angle_error, rmse
from .plots import COLORS, STYLES, legend_on_top


def _interactive_canvas(fig):
    """Attach an ipympl canvas to ``fig`` without switching the notebook's backend."""
    backend = matplotlib.get_backend()
    from ipympl.backend_nbagg import Canvas, FigureManager  # importing ipympl selects its backend…

    if matplotlib.get_backend() != backend:
        matplotlib.use(backend)  # …so hand the notebook its own back

    canvas = Canvas(fig)
    with warnings.catch_warnings():
        # ipympl's own bug (matplotlib/ipympl#611, #488): Toolbar.__init__ calls DOMWidget.__init__, whose
        # cooperative super() reaches NavigationToolbar2WebAgg.__init__ without its canvas; traitlets catches
        # the TypeError and warns. The toolbar is then built by its explicit second __init__ call and works.
        warnings.filterwarnings("ignore", r"Passing unrecognized arguments to super\(Toolbar\)\.__init__\(\)",
                                DeprecationWarning)
        FigureManager(canvas, 0)
    canvas.header_visible = False
    canvas.footer_visible = False
    canvas.toolbar_position = "right"
    return canvas


class TuningPanel:
    """Sliders for a filter's tuning values, a figure of truth vs estimate, and the RMSE.

    ``run(**values)`` must return the estimated angle (rad) at the times ``t``. Moving a
    slider re-runs it and redraws. ``set(**values)`` does the same from code. ``truth`` None
    (a recording of your own): the estimate and the references only, and no RMSE (NaN).
    """

    def __init__(self, run, t, truth, sliders: dict, references: dict | None = None,
                 ylabel="roll", label="KF"):
        self.run, self.t, self.truth = run, np.asarray(t), None if truth is None else np.asarray(truth)
        self.sliders = {
            name: W.FloatLogSlider(value=v0, base=10, min=np.log10(lo), max=np.log10(hi), step=0.05,
                                   description=name, readout_format=".1e", continuous_update=True,
                                   style={"description_width": "initial"}, layout=W.Layout(width="420px"))
            for name, (v0, lo, hi) in sliders.items()
        }
        self.status = W.HTML()
        fig = Figure(figsize=(9.0, 4.8), layout="constrained")
        self.ax, self.ax_err = fig.subplots(2, 1, sharex=True, height_ratios=[2, 1])
        if self.truth is not None:
            self.ax.plot(self.t, np.degrees(self.truth), color=COLORS["truth"], lw=2.2, alpha=0.55, label="truth")
        for name, (values, kind) in (references or {}).items():
            self.ax.plot(self.t, np.degrees(values), color=COLORS[kind], ls=STYLES.get(kind, "-"), lw=0.8,
                         alpha=0.6, label=name)
        (self.line,) = self.ax.plot(self.t, np.zeros_like(self.t), color=COLORS["kf"], lw=1.4, label=label)
        (self.err_line,) = self.ax_err.plot(self.t, np.zeros_like(self.t), color=COLORS["kf"], lw=0.9)
        self.ax.set_ylabel(f"{ylabel} (°)")
        legend_on_top(self.ax, ncols=4, fontsize=8)
        self.ax_err.set_ylabel(f"{label} error (°)")
        self.ax_err.set_xlabel("time (s)")
        if self.truth is None:
            self.ax_err.text(0.5, 0.5, "no truth in this recording: no error to show", transform=self.ax_err.transAxes,
                             ha="center", va="center", color=COLORS["truth"])
        self.canvas = _interactive_canvas(fig)
        self._quiet = False
        self.redraw()
        for slider in self.sliders.values():
            slider.observe(lambda change: self._quiet or self.redraw(), names="value")
        self.widget = W.VBox([W.HBox(list(self.sliders.values()), layout=W.Layout(flex_flow="row wrap")),
                              self.status, self.canvas])

    @property
    def values(self) -> dict:
        return {name: s.value for name, s in self.sliders.items()}

    def set(self, **values):
        """Set slider values from code, then re-run and redraw once; returns the RMSE (rad)."""
        self._quiet = True
        try:
            for name, value in values.items():
                self.sliders[name].value = value
        finally:
            self._quiet = False
        return self.redraw()

    def redraw(self):
        """Re-run the filter with the sliders' values, redraw, and return the RMSE (rad)."""
        estimate = np.asarray(self.run(**self.values), dtype=float)
        self.line.set_ydata(np.degrees(estimate))
        shown = ", ".join(f"{k} = {v:.2e}" for k, v in self.values.items())
        if self.truth is None:
            self.rmse = float("nan")
            self.status.value = f"no truth in this recording, so no RMSE: judge the estimate against the references &nbsp; ({shown})"
            self.canvas.draw_idle()
            return self.rmse
        err = angle_error(estimate, self.truth)
        self.rmse = float(rmse(err, 0.0))
        self.err_line.set_ydata(np.degrees(err))
        limit = max(1.0, np.nanpercentile(np.abs(np.degrees(err)), 99.5) * 1.2)
        self.ax_err.set_ylim(-limit, limit)
        self.status.value = f"<b>RMSE = {np.degrees(self.rmse):.2f}°</b> &nbsp; ({shown})"
        self.canvas.draw_idle()
        return self.rmse

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)


def tune(run, t, truth, sliders: dict, references: dict | None = None, ylabel="roll", label="KF") -> TuningPanel:
    """A :class:`TuningPanel`: ``sliders`` maps a name to (initial, min, max) on a log scale.

    Example: ``tune(lambda q, r: roll_kf(w, z, dt, q, r).x, t, truth, {"q": (1e-6, 1e-9, 1e-2), "r": (1e-3, 1e-6, 1)})``
    """
    return TuningPanel(run, t, truth, sliders, references, ylabel, label)


# --- live 3-D attitude view (lab 04) --------------------------------------------------------

def _enu(v_ned):
    """NED vectors (…, 3) → display coordinates (east, north, up): a right-handed frame that
    matplotlib draws upright (drawing NED with an inverted z axis would mirror it)."""
    v = np.asarray(v_ned, dtype=float)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


class LiveAttitude:
    """Keeps a filter running over a growing recording: ``update(rec)`` feeds the samples newer
    than the last one it saw and returns the latest quaternion (w-x-y-z, body → NED), or None
    before any sample. A time that goes backwards (board reset, a new recording) restarts the filter.

    method and tuning go to :class:`kfkit.filters.EulerAttitudeEKF` ("euler-ekf") or the
    quaternion filter ("mekf"); ``calibration`` corrects the samples first: a
    :class:`kfkit.calibration.Calibration` (labs 02/03) for the recording's board, "auto" for
    :func:`kfkit.calibration.load_calibration` of the board named in the recording (the student's
    own file if saved, else the kit's default), or None (raw samples).
    """

    def __init__(self, method="euler-ekf", calibration=None, **tuning):
        self.method, self.tuning, self.calibration = method, tuning, calibration
        self.filter, self.t_last, self.quat, self._cal = None, -np.inf, None, None

    def _new_filter(self, rate_hz):
        from .filters.attitude import EulerAttitudeEKF, MultiplicativeEKF

        kinds = {"euler-ekf": EulerAttitudeEKF, "mekf": MultiplicativeEKF}
        if self.method not in kinds:
            raise ValueError(f"LiveAttitude: method must be one of {', '.join(kinds)}, got {self.method!r}")
        return kinds[self.method](rate_hz, **self.tuning)

    def _calibration_for(self, board):
        if self.calibration is None:
            return None
        if isinstance(self.calibration, str):
            if self.calibration != "auto":
                raise ValueError(f"LiveAttitude: calibration must be a Calibration, 'auto' or None, got {self.calibration!r}")
            from .calibration import load_calibration

            return load_calibration(board=board) if board else None
        if board is not None and self.calibration.board != board:
            raise ValueError(f"LiveAttitude: the calibration is for board {self.calibration.board!r} but the samples come "
                             f"from {board!r}: use calibration='auto' or load_calibration(board={board!r})")
        return self.calibration

    def update(self, rec):
        if rec is None or len(rec) == 0:
            return self.quat
        t = rec.t
        if t[-1] < self.t_last:  # the board restarted its clock
            self.filter, self.t_last = None, -np.inf
        new = t > self.t_last
        if not new.any():
            return self.quat
        if self.filter is None:
            self.filter, self._cal = self._new_filter(rec.rate_hz), self._calibration_for(rec.meta.get("board"))
        mag = rec.body("mag")[new] if "mag" in rec.meta.get("sensors", {}) else None
        gyr, acc = rec.body("gyr")[new], rec.body("acc")[new]
        if self._cal is not None:
            gyr, acc, mag = self._cal.apply((gyr, acc) if mag is None else (gyr, acc, mag))
        result = self.filter.run(gyr, acc, mag)
        self.t_last, self.quat = float(t[new][-1]), result.quat[-1]
        return self.quat


class AttitudeView:
    """A board drawn as a box with its body axes (x forward, y right, z down) in NED, on an
    ipympl canvas. Updates move the existing artists (cheap); nothing is re-created.

    - replay: ``AttitudeView(t, quat)`` with quaternions (N, 4, w-x-y-z, body → NED), a Play
      button and a time slider; ``truth`` (N, 4) adds a wire-frame ghost of the true attitude.
    - live: ``AttitudeView.live(source)`` follows a capture panel (:func:`capture_panel`: whatever it
      is recording, the virtual board or a real one), a :class:`kfkit.capture.Recorder`, or any
      ``source()`` returning the latest Recording, polled by a timer on the kernel's thread.
    ``show(k)`` draws sample k; ``draw(q, t)`` draws any quaternion; ``close()`` stops and removes it.
    """

    SIZE = (0.8, 0.5, 0.1)  # box length along body x, y, z (display units)
    AXES = (("x forward", "kf"), ("y right", "bound"), ("z down", "band"))

    def __init__(self, t=None, quat=None, truth=None, stride=None, title="board attitude"):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        self.t = None if t is None else np.asarray(t, dtype=float)
        self.quat = None if quat is None else np.asarray(quat, dtype=float)
        self.truth = None if truth is None else np.asarray(truth, dtype=float)
        fig = Figure(figsize=(5.2, 4.6), layout="constrained")
        ax = fig.add_subplot(projection="3d")
        self.ax, self.title = ax, title
        lx, ly, lz = (s / 2 for s in self.SIZE)
        self._corners = np.array([[sx * lx, sy * ly, sz * lz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        self._faces = [[0, 1, 3, 2], [4, 5, 7, 6], [0, 1, 5, 4], [2, 3, 7, 6], [0, 2, 6, 4], [1, 3, 7, 5]]
        colours = ["#dddddd"] * 6
        colours[0] = "#999999"  # the top face (−z, "up" on the board) darker
        self.box = Poly3DCollection(self._polys(np.eye(3)), facecolors=colours, edgecolors="#444444",
                                    linewidths=0.6, alpha=0.55)
        ax.add_collection3d(self.box)
        self.ghost = None
        if self.truth is not None:
            self.ghost = Poly3DCollection(self._polys(np.eye(3)), facecolors=(0, 0, 0, 0), edgecolors=COLORS["truth"],
                                          linewidths=0.8, linestyles="--")
            ax.add_collection3d(self.ghost)
        self.axis_lines, self.axis_labels = [], []
        for name, kind in self.AXES:
            (line,) = ax.plot([0, 0], [0, 0], [0, 0], color=COLORS[kind], lw=2.5, label=name)
            self.axis_lines.append(line)
            self.axis_labels.append(ax.text(0, 0, 0, name.split()[0], color=COLORS[kind], fontsize=10, weight="bold"))
        self.ned_labels = []
        for v, name in (([1, 0, 0], "north"), ([0, 1, 0], "east"), ([0, 0, 1], "down")):  # the NED frame, fixed
            e = _enu(np.array(v, float)) * 0.95
            ax.plot([0, e[0]], [0, e[1]], [0, e[2]], color="#888888", lw=0.8, ls=":")
            self.ned_labels.append(ax.text(*(e * 1.08), name, color="#666666", fontsize=9))
        ax.set_xlim(-0.9, 0.9), ax.set_ylim(-0.9, 0.9), ax.set_zlim(-0.9, 0.9)
        ax.set_box_aspect((1, 1, 1), zoom=1.5)
        ax.set_axis_off()  # no panes, ticks or grid: the NED tripod is the reference, and redraws cost half
        ax.view_init(elev=22, azim=-120)
        ax.legend(loc="upper left", fontsize=8, title="body axes", title_fontsize=8)
        self.canvas = _interactive_canvas(fig)
        self.status = W.HTML()
        self.timer, self.source, self.estimator, self.latest = None, None, None, None
        controls = []
        if self.quat is not None:
            n = len(self.quat)
            if self.t is None or len(self.t) != n:
                raise ValueError(f"AttitudeView: t must have one time per quaternion ({n}), got "
                                 f"{None if self.t is None else len(self.t)}")
            if self.truth is not None and self.truth.shape != self.quat.shape:
                raise ValueError(f"AttitudeView: truth must have the shape of quat {self.quat.shape}, got {self.truth.shape}")
            rate = 1.0 / float(np.median(np.diff(self.t))) if n > 1 else 1.0
            stride = stride or max(1, int(round(rate / 20)))  # 20 frames per second of recording
            self.slider = W.IntSlider(0, min=0, max=n - 1, step=stride, description="sample",
                                      continuous_update=True, layout=W.Layout(width="420px"))
            self.play = W.Play(value=0, min=0, max=n - 1, step=stride, interval=50, description="play")
            W.jslink((self.play, "value"), (self.slider, "value"))
            self.slider.observe(lambda change: self.show(change["new"]), names="value")
            controls = [W.HBox([self.play, self.slider])]
            self.show(0)
        else:
            self.draw(np.array([1.0, 0.0, 0.0, 0.0]), None)
        self.widget = W.VBox(controls + [self.status, self.canvas])

    def _polys(self, R_nb):
        corners = _enu(self._corners @ R_nb.T)
        return [corners[f] for f in self._faces]

    def draw(self, q, t=None, q_truth=None):
        """Move the box, the axes and their labels to quaternion ``q`` (w-x-y-z, body → NED)."""
        R = quat_to_dcm(q)
        self.box.set_verts(self._polys(R))
        error = ""
        if self.ghost is not None and q_truth is not None:
            R_true = quat_to_dcm(q_truth)
            self.ghost.set_verts(self._polys(R_true))
            angle = np.degrees(np.arccos(np.clip((np.trace(R_true.T @ R) - 1.0) / 2.0, -1.0, 1.0)))
            error = f" &nbsp; (dashed: truth, {angle:.1f}° away)"
        for i, (line, label) in enumerate(zip(self.axis_lines, self.axis_labels)):
            tip = _enu(R[:, i]) * (0.85 if i == 0 else 0.65)
            line.set_data_3d([0, tip[0]], [0, tip[1]], [0, tip[2]])
            label.set_position_3d(tip * 1.12)
        roll, pitch, yaw = np.degrees(dcm_to_euler(R))
        when = "" if t is None else f"t = {t:6.2f} s &nbsp; "
        self.status.value = f"{when}roll {roll:+6.1f}°, pitch {pitch:+5.1f}°, yaw {yaw:+6.1f}°{error}"
        self.canvas.draw_idle()

    def show(self, k):
        """Draw sample ``k`` of the replayed recording."""
        k = int(k)
        self.draw(self.quat[k], self.t[k], None if self.truth is None else self.truth[k])

    @classmethod
    def live(cls, source, estimator=None, interval_ms=100, start=True, seconds=2.0, **view_options):
        """A view that polls ``source`` every ``interval_ms`` on the kernel's main thread and draws
        the attitude that ``estimator.update(rec)`` returns (default: a :class:`LiveAttitude`, Euler
        EKF). ``source``: a :class:`CapturePanel` (its recording while it records; the view starts with
        each of its captures), a Recorder, or a callable returning the latest Recording; the last
        ``seconds`` of it are read each tick. The timer stops by itself once the capture has ended
        (after drawing its last attitude), failed, or the view is closed. Start and stop buttons;
        ``poll()`` does one tick; ``latest`` is the last attitude drawn (w-x-y-z) or None."""
        view = cls(**view_options)
        view.source, view.estimator = _LiveSource(source, seconds), estimator or LiveAttitude()
        view.timer = view.canvas.new_timer(interval=interval_ms)
        view.timer.add_callback(view.poll)
        run, stop = W.Button(description="start", icon="play"), W.Button(description="stop", icon="stop")
        run.on_click(lambda _: view.start())
        stop.on_click(lambda _: view.timer.stop())
        view.widget = W.VBox([W.HBox([run, stop]), view.status, view.canvas])
        view.source.follow(view.start)
        if start:
            view.start()
        return view

    def start(self):
        """Start polling the live source (nothing to follow yet, as a capture panel before record: wait for it)."""
        if self.source.waiting():
            self.status.value = "waiting for the capture panel to record …"
            return
        self.timer.start()

    def poll(self) -> None:
        """One live tick (the timer's callback, so it returns None: matplotlib's timer removes a callback that
        returns 0 and cannot compare an array): read the source, feed the estimator, draw ``self.latest``.
        Stops the timer once the source has ended (its last samples drawn), on an error (shown in the
        status line), or when the view was closed."""
        if self.canvas.comm is None:  # the view was closed (close(), or its widget)
            self.timer.stop()
            return None
        try:
            ended = self.source.ended()  # before reading: the snapshot then holds everything it will ever hold
            rec = self.source.snapshot()
            q = self.estimator.update(rec)
        except Exception as e:  # a timer callback has no one to raise to: show it, stop polling
            self.timer.stop()
            self.status.value = f"<b style='color:{COLORS['bound']}'>❌ {e}</b>"
            return None
        if q is not None and q is not self.latest and rec is not None and len(rec):
            self.latest = q
            self.draw(q, float(rec.t[-1]))
        if ended:
            self.timer.stop()
        return None

    def close(self):
        """Stop the timer, stop following the source, and close the widgets."""
        if self.timer is not None:
            self.timer.stop()
        if self.source is not None:
            self.source.follow(None)
        self.widget.close()
        self.canvas.close()

    def _repr_mimebundle_(self, **kwargs):
        return self.widget._repr_mimebundle_(**kwargs)


class _LiveSource:
    """What a live view follows: a CapturePanel, a Recorder or a callable returning the latest Recording (or None).

    ``snapshot()`` the last ``seconds`` of it; ``ended()`` True once no new sample can come (a recorder's reader has
    stopped; a panel has finished its capture); ``waiting()`` True while a panel has not started recording;
    ``follow(callback)`` calls back when a panel starts a new capture (None: stop following)."""

    def __init__(self, source, seconds):
        self.panel = self.recorder = self.function = None
        if hasattr(source, "recorder") and hasattr(source, "record"):  # a CapturePanel: follow what it records
            self.panel = source
        elif hasattr(source, "recording") and callable(source.recording):  # a Recorder
            self.recorder = source
        elif callable(source):
            self.function = source
        else:
            raise TypeError(f"AttitudeView.live: source must be a capture panel, a Recorder or a callable returning a "
                            f"Recording, got {type(source).__name__}")
        self.seconds, self._callback = seconds, None

    def snapshot(self):
        if self.function is not None:
            return self.function()
        if self.recorder is not None:
            return self.recorder.recording(last_seconds=self.seconds)
        rec = self.panel.recorder
        if rec is None:  # finished: the saved recording (or None: never recorded, or nothing arrived)
            return self.panel.recording
        return rec.recording(last_seconds=self.seconds)

    def ended(self) -> bool:
        if self.recorder is not None:
            return self.recorder.done.is_set()
        return self.panel is not None and self.panel.recorder is None

    def waiting(self) -> bool:
        return self.panel is not None and self.panel.recorder is None

    def follow(self, callback):
        if self.panel is None:
            return
        if self._callback is not None and self._callback in self.panel.on_record:
            self.panel.on_record.remove(self._callback)
        self._callback = callback
        if callback is not None:
            self.panel.on_record.append(callback)


def attitude_view(t, quat, truth=None, stride=None) -> AttitudeView:
    """Replay quaternions (N, 4, w-x-y-z, body → NED) at times t (s) as a 3-D board; see :class:`AttitudeView`."""
    return AttitudeView(t, quat, truth, stride)


# --- capture panel (kfkit.capture) ----------------------------------------------------------------
_LIVE_SENSORS = (("acc", "accelerometer (m/s²)", 1.0), ("gyr", "gyro (°/s)", 180.0 / np.pi), ("mag", "magnetometer (µT)", 1.0))
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
            self.lines[sensor] = [ax.plot([], [], color=c, ls=ls, lw=1.0, label=f"{axis}")[0]
                                  for c, ls, axis in zip(_AXIS_COLORS, _AXIS_STYLES, "xyz")]
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
        from .capture import PROTOCOLS, find_boards

        # quick: the protocols' short durations; fast: the virtual board runs faster than real time
        self.out_dir, self.window_s, self.quick, self.fast = Path(out_dir), window_s, quick, fast
        self.recorder, self.recording, self.steps = None, None, None
        self.on_record = []  # callables run when a capture starts (AttitudeView.live follows the panel with one)
        self.boards = {b.port: b for b in find_boards()}
        options = [(str(b), b.port) for b in self.boards.values()] + [("phone (phyphox remote access)", "phone"),
                                                                       ("virtual board (simulated)", "virtual")]
        style, wide = {"description_width": "initial"}, W.Layout(width="330px")
        self.port = W.Dropdown(options=options, value=next((b.port for b in self.boards.values() if b.known), "virtual"),
                               description="port", style=style, layout=W.Layout(width="460px"))
        self.board = W.Dropdown(options=["nucleo-iks02a1", "mpu6050"], description="board", style=style)
        self.phone = W.Text(placeholder="192.168.0.42:8080", description="phone address", style=style)  # as phyphox shows it
        self.baud = W.Dropdown(options=[115200, 230400, 460800, 921600, 9600], value=115200, description="baud", style=style)
        self.protocol = W.Dropdown(options=[("free recording", None)] + [(p.title, name) for name, p in PROTOCOLS.items()],
                                   description="protocol", style=style, layout=W.Layout(width="460px"))
        self.seconds = W.BoundedFloatText(value=30.0, min=0.5, max=7200.0, step=1.0, description="duration (s)",
                                          style=style, layout=W.Layout(width="200px"))
        self.out = W.Text(value=str(self.out_dir / "capture.csv"), description="save as", style=style, layout=wide)
        self._auto_out = self.out.value  # the name the panel chose; one typed by the user is kept
        self.record_button = W.Button(description="record", icon="circle", button_style="danger")
        self.stop_button = W.Button(description="stop", icon="stop", disabled=True)
        self.progress = W.FloatProgress(value=0.0, min=0.0, max=1.0, description="0 %", style=style)
        self.coverage = W.FloatProgress(value=0.0, min=0.0, max=1.0, description="sphere coverage 0 %",
                                        style=style, layout=W.Layout(visibility="hidden"))
        self.prompt, self.status = W.HTML(), W.HTML()
        self.record_button.on_click(lambda _: self.record())
        self.stop_button.on_click(lambda _: self.stop())
        self.port.observe(lambda _: self._port_changed(), names="value")
        self.protocol.observe(lambda _: self._protocol_changed(), names="value")
        self.board.observe(lambda _: self._settings_changed(), names="value")

        self.live = LiveSignals(Figure(figsize=(9.0, 5.4), layout="constrained"), window_s)
        self.axes, self.lines = self.live.axes, self.live.lines
        self.canvas = _interactive_canvas(self.live.fig)
        self.timer = self.canvas.new_timer(interval=interval_ms)
        self.timer.add_callback(self.refresh)
        self._port_changed()
        self.widget = W.VBox([
            W.HBox([self.port, self.board, self.phone]), W.HBox([self.protocol, self.baud]),
            W.HBox([self.seconds, self.out, self.record_button, self.stop_button]),
            W.HBox([self.progress, self.coverage]), self.prompt, self.canvas, self.status])

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
        from .capture import PROTOCOLS

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
        from .capture import dataset_name, protocol_motion, protocol_steps

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
        self.prompt.value = ("the virtual board follows the prompts by itself" if self.port.value == "virtual"
                             else f"before you press record: <b>{first}</b>")

    def _name_file(self, stem):
        """Save as ``out_dir/stem.csv`` unless the user typed a name of their own."""
        if self.out.value == self._auto_out:
            self.out.value = self._auto_out = str(self.out_dir / f"{stem}.csv")

    def _rate(self) -> float:
        from .sensors import board

        return board(self.board.value).rate_hz

    # -- recording ----------------------------------------------------------------------------------
    def record(self):
        """Start recording with the panel's settings (the record button)."""
        from .capture import CaptureError, Recorder
        from .capture.guided import protocol_capture_options

        if self.recorder is not None:
            return
        options, name = {}, self.protocol.value
        self.steps = None
        port = self.port.value if self.port.value != "phone" else f"phyphox://{self.phone.value.strip().removeprefix('http://')}"
        try:
            if name is not None:
                _, self.steps, options = protocol_capture_options(name, port, self.board.value,
                                                                  quick=self.quick, fast=self.fast)
            elif self.port.value == "virtual":
                options["virtual"] = {"board": self.board.value, "realtime": not self.fast}
            self.recorder = Recorder(port, self.baud.value, self.out.value, seconds=self.seconds.value,
                                     **options).start()
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
        from .capture import CaptureError

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
                self._show_error(f"the panel stopped on an unexpected error ({e!r}); what arrived is saved in {rec.out}")
        return None

    def _tick(self, rec):
        fraction = min(rec.elapsed / self.seconds.value, 1.0)
        self.progress.value, self.progress.description = fraction, f"{100 * fraction:.0f} %"
        if self.steps:
            from .capture.guided import step_at

            start, end, _, prompt = step_at(self.steps, rec.elapsed)
            self.prompt.value = f"<b>{prompt}</b> &nbsp; ({max(end - rec.elapsed, 0.0):.0f} s)"
        s = rec.stats
        self.status.value = (f"{rec.description}: {s.samples} samples, {s.bad_lines} bad lines, "
                             f"{s.dropped} dropped, {s.resets} resets")
        self._draw(rec)
        if self.protocol.value == "mag-rotations" and rec.columns and "mx" in rec.columns:
            from .capture import sphere_coverage

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
