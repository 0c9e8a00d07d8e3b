"""The standard figures every lab uses, labelled with units, in colour-blind-safe colours.

Angles come in radians (the kit's unit) and are shown in degrees. Colours are the
Okabe–Ito palette; line styles differ too, so the figures survive greyscale printing.
Each function draws on the given axes (or a new figure) and returns the figure.
"""
from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from .metrics import chi2_bounds, nis

# Okabe & Ito (2008), "Color Universal Design".
COLORS = {
    "truth": "#000000",
    "accel": "#E69F00",  # orange
    "gyro": "#56B4E9",  # sky blue
    "kf": "#0072B2",  # blue
    "band": "#009E73",  # bluish green
    "bound": "#D55E00",  # vermillion
    "other": "#CC79A7",  # reddish purple
}
STYLES = {"truth": "-", "accel": "-", "gyro": "--", "kf": "-", "other": "-."}


def apply_style():
    """Notebook-wide defaults: readable sizes, light grid, tight layout."""
    plt.rcParams.update({
        "figure.figsize": (9.0, 3.6), "figure.dpi": 100, "figure.constrained_layout.use": True,
        "axes.grid": True, "grid.alpha": 0.3, "axes.spines.top": False, "axes.spines.right": False,
        "font.size": 10, "legend.frameon": False, "lines.linewidth": 1.3,
    })


def _axes(ax):
    """``ax`` and its figure, or a new single-panel figure."""
    if ax is not None:
        return ax.figure, ax
    fig, ax = plt.subplots(figsize=(9.0, 3.4))
    return fig, ax


def legend_on_top(ax, ncols, fontsize=None, headroom=0.25):
    """A one-row legend in the upper right, with y headroom so it covers no data."""
    lo, hi = ax.get_ylim()
    ax.set_ylim(lo, hi + headroom * (hi - lo))
    ax.legend(loc="upper right", ncols=ncols, fontsize=fontsize)


def mark_windows(ax, windows, label="sideways shake"):
    """Shade time windows [(t0, t1), …] (s) on ``ax``, labelled once in the legend."""
    for i, (t0, t1) in enumerate(windows):
        ax.axvspan(t0, t1, color=COLORS["other"], alpha=0.15, lw=0, label=label if i == 0 else None)


def compare_angles(t, truth, estimates: dict, ax=None, ylabel="roll", title=None):
    """Truth and several estimates of one angle (rad) against time (s), shown in degrees.

    ``estimates`` maps a label to (values, kind) or just values; kind picks the colour
    ('accel', 'gyro', 'kf', 'other').
    """
    fig, ax = _axes(ax)
    if truth is not None:
        ax.plot(t, np.degrees(truth), color=COLORS["truth"], lw=2.2, alpha=0.55, label="truth", zorder=1)
    for i, (label, value) in enumerate(estimates.items()):
        values, kind = value if isinstance(value, tuple) else (value, "other")
        ax.plot(t, np.degrees(values), color=COLORS[kind], ls=STYLES.get(kind, "-"), label=label,
                alpha=0.85 if kind == "accel" else 1.0, lw=0.9 if kind == "accel" else 1.4, zorder=2 + i)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{ylabel} (°)")
    legend_on_top(ax, ncols=min(5, len(estimates) + 2))
    if title:
        ax.set_title(title)
    return fig


def error_band(t, err, variance, ax=None, ylabel="roll error", label="KF error"):
    """Estimation error (rad) with the filter's own ±2σ band (σ = √P), in degrees.

    A consistent filter keeps about 95 % of the error inside the band.
    """
    fig, ax = _axes(ax)
    two_sigma = 2.0 * np.degrees(np.sqrt(variance))
    ax.fill_between(t, -two_sigma, two_sigma, color=COLORS["band"], alpha=0.25, lw=0, label="±2σ (filter's P)")
    ax.plot(t, np.degrees(err), color=COLORS["kf"], lw=0.9, label=label)
    inside = np.mean(np.abs(np.degrees(err)) <= two_sigma)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{ylabel} (°)")
    ax.legend(loc="upper left", ncols=2, title=f"{100 * inside:.0f} % inside ±2σ")
    return fig


def innovations(t, y, S, ax=None, ylabel="innovation"):
    """Innovations y = z − H x⁻ (rad) with ±2√S, in degrees; NaN (skipped updates) left as gaps."""
    fig, ax = _axes(ax)
    bound = 2.0 * np.degrees(np.sqrt(S))
    ax.fill_between(t, -bound, bound, color=COLORS["band"], alpha=0.25, lw=0, label="±2√S")
    ax.plot(t, np.degrees(y), color=COLORS["kf"], lw=0.7, label="y = z − x⁻")
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{ylabel} (°)")
    ax.legend(loc="upper right", ncols=2)
    return fig


def nis_plot(t, values, dof=1, window=None, ax=None, alpha=0.05):
    """NIS per step with its (1 − alpha) χ² bounds, and a moving average with the bounds of an average.

    window: samples in the moving average (default: one second's worth, at least 10).
    """
    fig, ax = _axes(ax)
    values = np.asarray(values, dtype=float)
    if window is None:
        window = max(10, int(round(1.0 / np.median(np.diff(t)))))
    ax.plot(t, values, ".", ms=1.5, color=COLORS["gyro"], alpha=0.5, label="NIS per step")
    valid = np.where(np.isnan(values), 0.0, values)
    counts = np.convolve(~np.isnan(values), np.ones(window), "same")
    with np.errstate(invalid="ignore", divide="ignore"):
        average = np.convolve(valid, np.ones(window), "same") / counts
    ax.plot(t, average, color=COLORS["kf"], lw=1.5, label=f"{window}-sample average")
    _, hi1 = chi2_bounds(dof, 1, alpha)
    lo, hi = chi2_bounds(dof, window, alpha)
    ax.axhline(hi1, color=COLORS["bound"], ls=":", lw=1, label=f"{100 * (1 - alpha):.0f} % bound, one step ({hi1:.2f})")
    ax.axhspan(lo, hi, color=COLORS["bound"], alpha=0.12, lw=0, label=f"{100 * (1 - alpha):.0f} % bounds, average")
    ax.axhline(dof, color=COLORS["truth"], lw=0.8, alpha=0.6)
    ax.set_yscale("log")
    ax.set_ylim(1e-4, max(10 * hi1, 2 * np.nanmax(average, initial=0.0)))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("NIS (–)")
    ax.legend(loc="lower right", ncols=2, fontsize=8)
    return fig


def consistency(t, err, variance, y, S, dof=1, title=None):
    """Three stacked panels sharing time: error ±2σ, innovations ±2√S, NIS with χ² bounds.

    ``err`` None (a recording without truth): the two panels that need none, innovations and NIS.
    """
    panels = 2 if err is None else 3
    fig, axes = plt.subplots(panels, 1, sharex=True, figsize=(9.0, 2.5 * panels))
    if err is not None:
        error_band(t, err, variance, ax=axes[0])
    innovations(t, y, S, ax=axes[-2])
    nis_plot(t, nis(y, S), dof=dof, ax=axes[-1])
    for ax in axes[:-1]:
        ax.set_xlabel("")
    if title:
        fig.suptitle(title)
    return fig
