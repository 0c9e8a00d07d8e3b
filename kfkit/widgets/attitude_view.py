"""The 3-D attitude view (lab 04): a board drawn as a box in NED, replayed (``attitude_view``) or live
from a capture (``AttitudeView.live`` + ``LiveAttitude``, a filter kept running over a growing recording)."""

from __future__ import annotations

import ipywidgets as W
import numpy as np
from matplotlib.figure import Figure

from ..calibration import load_calibration
from ..filters.registry import methods
from ..frames import dcm_to_euler, enu_to_ned, quat_to_dcm
from ..plots import COLORS
from .canvas import interactive_canvas


def _enu(v_ned):
    """NED vectors (…, 3) → display coordinates (east, north, up): a right-handed frame that
    matplotlib draws upright (drawing NED with an inverted z axis would mirror it). The swap is its own inverse."""
    return enu_to_ned(v_ned)


class LiveAttitude:
    """Keeps a filter running over a growing recording: ``update(rec)`` feeds the samples newer
    than the last one it saw and returns the latest quaternion (w-x-y-z, body → NED), or None
    before any sample. A time that goes backwards (board reset, a new recording) restarts the filter.

    method and tuning go to one of :func:`kfkit.filters.estimate_attitude`'s filters ("euler-ekf", the
    Euler-angle EKF, or "mekf", the quaternion filter); ``calibration`` corrects the samples first: a
    :class:`kfkit.calibration.Calibration` (labs 02/03) for the recording's board, "auto" for
    :func:`kfkit.calibration.load_calibration` of the board named in the recording (the student's
    own file if saved, else the kit's default), or None (raw samples).
    """

    def __init__(self, method="euler-ekf", calibration=None, **tuning):
        self.method, self.tuning, self.calibration = method, tuning, calibration
        self.filter, self.t_last, self.quat, self._cal = None, -np.inf, None, None

    def _new_filter(self, rate_hz):
        kinds = methods("attitude")
        if self.method not in kinds:
            raise ValueError(f"LiveAttitude: method must be one of {', '.join(kinds)}, got {self.method!r}")
        return kinds[self.method](rate_hz=rate_hz, **self.tuning)

    def _calibration_for(self, board):
        if self.calibration is None:
            return None
        if isinstance(self.calibration, str):
            if self.calibration != "auto":
                raise ValueError(
                    f"LiveAttitude: calibration must be a Calibration, 'auto' or None, got {self.calibration!r}"
                )
            return load_calibration(board=board) if board else None
        if board is not None and self.calibration.board != board:
            raise ValueError(
                f"LiveAttitude: the calibration is for board {self.calibration.board!r} but the samples come "
                f"from {board!r}: use calibration='auto' or load_calibration(board={board!r})"
            )
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
        result = self.filter.run(gyr, acc, mag, resume=True)
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
        self.box = Poly3DCollection(
            self._polys(np.eye(3)), facecolors=colours, edgecolors="#444444", linewidths=0.6, alpha=0.55
        )
        ax.add_collection3d(self.box)
        self.ghost = None
        if self.truth is not None:
            self.ghost = Poly3DCollection(
                self._polys(np.eye(3)),
                facecolors=(0, 0, 0, 0),
                edgecolors=COLORS["truth"],
                linewidths=0.8,
                linestyles="--",
            )
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
        self.canvas = interactive_canvas(fig)
        self.status = W.HTML()
        self.timer, self.source, self.estimator, self.latest = None, None, None, None
        controls = []
        if self.quat is not None:
            n = len(self.quat)
            if self.t is None or len(self.t) != n:
                raise ValueError(
                    f"AttitudeView: t must have one time per quaternion ({n}), got "
                    f"{None if self.t is None else len(self.t)}"
                )
            if self.truth is not None and self.truth.shape != self.quat.shape:
                raise ValueError(
                    f"AttitudeView: truth must have the shape of quat {self.quat.shape}, got {self.truth.shape}"
                )
            rate = 1.0 / float(np.median(np.diff(self.t))) if n > 1 else 1.0
            stride = stride or max(1, int(round(rate / 20)))  # 20 frames per second of recording
            self.slider = W.IntSlider(
                0,
                min=0,
                max=n - 1,
                step=stride,
                description="sample",
                continuous_update=True,
                layout=W.Layout(width="420px"),
            )
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
            raise TypeError(
                f"AttitudeView.live: source must be a capture panel, a Recorder or a callable returning a "
                f"Recording, got {type(source).__name__}"
            )
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
