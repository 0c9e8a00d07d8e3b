"""Filter tuning with log-scale sliders (labs 01, 04): the estimate against truth, redrawn as a slider moves."""

from __future__ import annotations

import ipywidgets as W
import numpy as np
from matplotlib.figure import Figure

from ..metrics import angle_error, rmse
from ..plots import COLORS, STYLES, legend_on_top
from .canvas import interactive_canvas


class TuningPanel:
    """Sliders for a filter's tuning values, a figure of truth vs estimate, and the RMSE.

    ``run(**values)`` must return the estimated angle (rad) at the times ``t``. Moving a
    slider re-runs it and redraws. ``set(**values)`` does the same from code. ``truth`` None
    (a recording of your own): the estimate and the references only, no error line and no RMSE (NaN).

    Each slider starts exactly at its initial value, whatever (min, max) say: the range is widened
    to hold it (a q or r measured on a quiet board can fall below the range a lab suggests), and the
    slider's grid of 0.05 decade is laid through it, so the browser's read-out and :attr:`values` agree.
    """

    def __init__(self, run, t, truth, sliders: dict, references: dict | None = None, ylabel="roll", label="KF"):
        self.run, self.t, self.truth = run, np.asarray(t), None if truth is None else np.asarray(truth)
        self.sliders = {
            name: W.FloatLogSlider(
                value=v0,
                base=10,
                **_log_range(name, v0, lo, hi),
                description=name,
                readout_format=".1e",
                continuous_update=True,
                style={"description_width": "initial"},
                layout=W.Layout(width="420px"),
            )
            for name, (v0, lo, hi) in sliders.items()
        }
        self.status = W.HTML()
        fig = Figure(figsize=(9.0, 4.8), layout="constrained")
        self.ax, self.ax_err = fig.subplots(2, 1, sharex=True, height_ratios=[2, 1])
        if self.truth is not None:
            self.ax.plot(self.t, np.degrees(self.truth), color=COLORS["truth"], lw=2.2, alpha=0.55, label="truth")
        for name, (values, kind) in (references or {}).items():
            self.ax.plot(
                self.t, np.degrees(values), color=COLORS[kind], ls=STYLES.get(kind, "-"), lw=0.8, alpha=0.6, label=name
            )
        (self.line,) = self.ax.plot(self.t, np.zeros_like(self.t), color=COLORS["kf"], lw=1.4, label=label)
        (self.err_line,) = self.ax_err.plot(
            self.t, np.zeros_like(self.t), color=COLORS["kf"], lw=0.9, visible=self.truth is not None
        )
        self.ax.set_ylabel(f"{ylabel} (°)")
        legend_on_top(self.ax, ncols=4, fontsize=8)
        self.ax_err.set_ylabel(f"{label} error (°)")
        self.ax_err.set_xlabel("time (s)")
        if self.truth is None:
            self.ax_err.text(
                0.5,
                0.5,
                "no truth in this recording: no error to show",
                transform=self.ax_err.transAxes,
                ha="center",
                va="center",
                color=COLORS["truth"],
            )
        self.canvas = interactive_canvas(fig)
        self._quiet = False
        self.redraw()
        for slider in self.sliders.values():
            slider.observe(lambda change: self._quiet or self.redraw(), names="value")
        self.widget = W.VBox(
            [W.HBox(list(self.sliders.values()), layout=W.Layout(flex_flow="row wrap")), self.status, self.canvas]
        )

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
            self.status.value = (
                f"no truth in this recording, so no RMSE: judge the estimate against the references &nbsp; ({shown})"
            )
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


STEP = 0.05  # decades per slider step


def _log_range(name, v0, lo, hi) -> dict:
    """FloatLogSlider's min, max, step (log10) holding ``v0`` on its grid, [lo, hi] widened to hold ``v0``."""
    if not all(np.isfinite(v) and v > 0 for v in (v0, lo, hi)) or lo >= hi:
        raise ValueError(
            f"slider {name!r}: need 0 < min < max and a positive initial value, got ({v0!r}, {lo!r}, {hi!r})"
        )
    x0 = np.log10(v0)
    below = np.ceil(round((x0 - np.log10(min(lo, v0))) / STEP, 9))
    above = np.ceil(round((np.log10(max(hi, v0)) - x0) / STEP, 9))
    return {"min": x0 - below * STEP, "max": x0 + above * STEP, "step": STEP}


def tune(run, t, truth, sliders: dict, references: dict | None = None, ylabel="roll", label="KF") -> TuningPanel:
    """A :class:`TuningPanel`: ``sliders`` maps a name to (initial, min, max) on a log scale.

    Example: ``tune(lambda q, r: roll_kf(w, z, dt, q, r).x, t, truth, {"q": (1e-6, 1e-9, 1e-2), "r": (1e-3, 1e-6, 1)})``
    """
    return TuningPanel(run, t, truth, sliders, references, ylabel, label)
