"""The standard figures every lab uses, labelled with units, in colour-blind-safe colours.

Angles come in radians (the kit's unit) and are shown in degrees. Colours are the
Okabe–Ito palette; line styles differ too, so the figures survive greyscale printing.
Each function draws on the given axes (or a new figure) and returns the figure.

A recording of your own has no truth: every helper that takes ``truth`` accepts None and says so
in the figure or the table (:data:`NO_TRUTH`) instead of failing, so a notebook cell needs no branch.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from .frames import euler_to_quat
from .metrics import angle_error, attitude_errors, chi2_bounds, fraction_inside, nis, rmse

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
XYZ = (("kf", "-"), ("bound", "--"), ("band", "-."))  # (colour, style) of x, y, z or roll, pitch, yaw
EULER = ("roll", "pitch", "yaw")
NO_TRUTH = "no truth in this recording"


def apply_style():
    """Notebook-wide defaults: readable sizes, light grid, tight layout."""
    plt.rcParams.update(
        {
            "figure.figsize": (9.0, 3.6),
            "figure.dpi": 100,
            "figure.constrained_layout.use": True,
            "axes.grid": True,
            "grid.alpha": 0.3,
            "axes.spines.top": False,
            "axes.spines.right": False,
            "font.size": 10,
            "legend.frameon": False,
            "lines.linewidth": 1.3,
        }
    )


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


def compare_values(
    t,
    truth,
    estimates: dict,
    ax=None,
    ylabel="v_y",
    unit="m/s",
    convert=np.asarray,
    title=None,
    shade=(),
    shade_label="shaded",
):
    """Truth and several estimates of one quantity against time (s), shown as ``convert(values)`` in ``unit``.

    ``estimates`` maps a label to (values, kind) or just values; kind picks the colour
    ('accel', 'gyro', 'kf', 'other'). ``truth`` None (a recording without truth): estimates only.
    ``shade`` windows [(t0, t1)] (s) are marked and named ``shade_label`` in the legend.
    """
    fig, ax = _axes(ax)
    if truth is not None:
        ax.plot(t, convert(truth), color=COLORS["truth"], lw=2.2, alpha=0.55, label="truth", zorder=1)
    for i, (label, value) in enumerate(estimates.items()):
        values, kind = value if isinstance(value, tuple) else (value, "other")
        ax.plot(
            t,
            convert(values),
            color=COLORS[kind],
            ls=STYLES.get(kind, "-"),
            label=label,
            alpha=0.85 if kind == "accel" else 1.0,
            lw=0.9 if kind == "accel" else 1.4,
            zorder=2 + i,
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{ylabel} ({unit})")
    mark_windows(ax, shade, label=shade_label)
    legend_on_top(ax, ncols=min(5, len(estimates) + 2))
    if title:
        ax.set_title(title)
    return fig


def compare_angles(t, truth, estimates: dict, ax=None, ylabel="roll", title=None, shade=(), shade_label="shaded"):
    """Truth and several estimates of one angle (rad) against time (s), shown in degrees (:func:`compare_values`)."""
    return compare_values(t, truth, estimates, ax, ylabel, "°", np.degrees, title, shade, shade_label)


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

    window: samples in the moving average (default: one second's worth, at least 10). NaN values (no
    update at that step) are left out of the average, so the average at step k is over the n_k valid
    samples of its window, and its bounds are those of n_k values: χ²⁻¹(α/2; n_k·dof)/n_k … χ²⁻¹(1 − α/2;
    n_k·dof)/n_k (fewer samples, a wider band: a magnetometer on every other row halves n_k).
    """
    fig, ax = _axes(ax)
    values = np.asarray(values, dtype=float)
    if window is None:
        window = max(10, int(round(1.0 / np.median(np.diff(t)))))
    ax.plot(t, values, ".", ms=1.5, color=COLORS["gyro"], alpha=0.5, label="NIS per step")
    valid = np.where(np.isnan(values), 0.0, values)
    counts = np.convolve(~np.isnan(values), np.ones(window), "same").round()
    n = np.where(counts > 0, counts, np.nan)  # samples in each average; none: no average, no bounds
    average = np.convolve(valid, np.ones(window), "same") / n
    ax.plot(t, average, color=COLORS["kf"], lw=1.5, label=f"{window}-sample average (of its valid samples)")
    _, hi1 = chi2_bounds(dof, 1, alpha)
    lo, hi = chi2_bounds(dof, n, alpha)
    ax.axhline(hi1, color=COLORS["bound"], ls=":", lw=1, label=f"{100 * (1 - alpha):.0f} % bound, one step ({hi1:.2f})")
    ax.fill_between(
        t, lo, hi, color=COLORS["bound"], alpha=0.12, lw=0, label=f"{100 * (1 - alpha):.0f} % bounds, average"
    )
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


# --- helpers that make a notebook cell one call (labs 01–06) -----------------------------------------------


def no_truth(ax, what):
    """Say in ``ax`` that ``what`` needs the truth this recording does not have."""
    ax.text(0.5, 0.5, f"{NO_TRUTH}: {what}", transform=ax.transAxes, ha="center", va="center", color=COLORS["truth"])


def windows_of(phases, label):
    """The (start, end) windows (s) of the phases called ``label``; ``phases`` as ``Recording.phases``
    ([{"label", "start", "end"}]) or [(start, end, label)]."""
    return [(a, b) for a, b, name in _phase_tuples(phases) if name == label]


def windows_where(t, mask):
    """The (start, end) windows (s) of each run of samples where ``mask`` is True (e.g. a filter's low-speed guard)."""
    edges = np.flatnonzero(np.diff(np.concatenate(([0], np.asarray(mask, dtype=np.int8), [0]))))
    return [(t[a], t[b - 1]) for a, b in zip(edges[::2], edges[1::2])]


def _phase_tuples(phases):
    return [(p["start"], p["end"], p["label"]) if isinstance(p, dict) else tuple(p) for p in phases or ()]


def label_phases(ax, phases, skip=("stationary",)):
    """Name each phase (``Recording.phases`` or [(start, end, label)], s) above ``ax``, at its middle."""
    for a, b, label in _phase_tuples(phases):
        if label not in skip:
            ax.text(
                (a + b) / 2,
                1.0,
                label.replace("_", " "),
                transform=ax.get_xaxis_transform(),
                ha="center",
                va="bottom",
                fontsize=8,
                color="0.3",
            )


def break_wraps(angle):
    """A copy of ``angle`` (rad) with NaN where it wraps by more than π, so a line plot draws no jump."""
    out = np.array(angle, dtype=float)
    out[1:][np.abs(np.diff(out, axis=0)) > np.pi] = np.nan
    return out


def xyz(ax, t, values, name, unit, scale=1.0, axes="xyz"):
    """The three columns of ``values`` (N, 3) times ``scale`` against t (s), one colour and style each;
    rows with NaN (a magnetometer without a new sample) are left out, not drawn as gaps."""
    values = np.asarray(values, dtype=float) * scale
    rows = ~np.isnan(values).any(axis=1)
    for i, (axis, (kind, style)) in enumerate(zip(axes, XYZ)):
        ax.plot(np.asarray(t)[rows], values[rows, i], color=COLORS[kind], ls=style, lw=0.8, label=f"{name} {axis}")
    ax.set_ylabel(f"{name} ({unit})")
    return ax.figure


def imu_signals(t, gyr, acc, mag=None, shade=(), shade_label="shaded", phases=(), title=None):
    """Gyro (rad/s, shown in °/s), accelerometer (m/s²) and magnetometer (µT, if given) in stacked panels
    sharing time (s); ``shade`` windows [(t0, t1)] marked, ``phases`` named above the first panel."""
    signals = [(gyr, "gyro", "°/s", np.degrees(1.0)), (acc, "accel", "m/s²", 1.0)]
    signals += [] if mag is None else [(mag, "mag", "µT", 1.0)]
    fig, axes = plt.subplots(len(signals), 1, sharex=True, figsize=(9.0, 2.35 * len(signals)))
    for ax, (values, name, unit, scale) in zip(axes, signals):
        xyz(ax, t, values, name, unit, scale)
        mark_windows(ax, shade, label=shade_label)
        legend_on_top(ax, ncols=4, fontsize=8)
    label_phases(axes[0], phases)
    axes[-1].set_xlabel("time (s)")
    if title:
        fig.suptitle(title, y=1.02)
    return fig


def compare_euler(t, truth, estimates: dict, shade=(), title=None):
    """Roll, pitch and yaw (rad, shown in °) in three panels: :func:`compare_angles` on each, wraps not drawn
    as jumps, one legend on top. ``truth`` (N, 3) or None; ``estimates`` maps a label to ((N, 3), kind)."""
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(9.0, 8.0))
    for i, ax in enumerate(axes):
        compare_angles(
            t,
            None if truth is None else break_wraps(np.asarray(truth)[:, i]),
            {label: (break_wraps(np.asarray(v)[:, i]), kind) for label, (v, kind) in estimates.items()},
            ax=ax,
            ylabel=EULER[i],
        )
        ax.set_xlabel("")
        if i:
            ax.get_legend().remove()
        mark_windows(ax, shade, label=None)
    axes[-1].set_xlabel("time (s)")
    axes[0].legend(loc="upper right", ncols=4, fontsize=8)
    if title:
        fig.suptitle(title)
    return fig


def tilt_panels(t, truth, estimates: dict, known=None, shade=(), title=None):
    """Roll and pitch (rad, shown in °) in two panels sharing time (s), :func:`compare_angles` on each:
    ``truth`` (N, ≥2: roll, pitch) or None, ``estimates`` mapping a label to ((roll, pitch), kind), ``known``
    (roll, pitch) a protocol's angles (NaN outside its holds) as markers, ``shade`` windows on the roll panel;
    one legend for both panels, below them."""
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(9.0, 5.4))
    for i, ax in enumerate(axes):
        compare_angles(
            t,
            None if truth is None else np.asarray(truth)[:, i],
            {label: (v[i], kind) for label, (v, kind) in estimates.items()},
            ax=ax,
            ylabel=EULER[i],
        )
        if known is not None:
            ax.plot(
                t,
                np.degrees(known[i]),
                ls="none",
                marker="s",
                ms=1.5,
                color=COLORS["bound"],
                label="protocol (holds)",
                zorder=1.5,
            )  # under the estimates, over the truth
        ax.get_legend().remove()
        ax.set_xlabel("")
    mark_windows(axes[0], shade, label=None)
    axes[-1].set_xlabel("time (s)")
    if title:
        fig.suptitle(title)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=4, fontsize=8)
    return fig


def euler_errors(t, estimate, truth, P, label="EKF", title="errors and the filter's own ±2σ"):
    """Roll, pitch and yaw errors (rad, shown in °) each with the filter's ±2√P_ii band (:func:`error_band`);
    ``truth`` None: one panel saying there is no error to show."""
    if truth is None:
        fig, ax = plt.subplots(figsize=(9.0, 1.6))
        ax.set_axis_off()
        no_truth(ax, f"no {label} error to plot (the NIS needs none)")
        return fig
    err = angle_error(estimate, truth)
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(9.0, 7.0))
    for i, ax in enumerate(axes):
        error_band(t, err[:, i], np.asarray(P)[:, i, i], ax=ax, ylabel=f"{EULER[i]} error", label=f"{label} error")
        ax.set_xlabel("")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"{label} {title}")
    return fig


def nees_plot(t, values, dof=3, ax=None, alpha=0.05):
    """NEES εᵀP⁻¹ε per step (–, log scale) with its one-step (1 − alpha) χ² bound and its mean ``dof``;
    ``values`` None (no truth): the panel says so."""
    fig, ax = _axes(ax)
    if values is None:
        no_truth(ax, "no NEES")
    else:
        ax.plot(t, values, ".", ms=1.5, color=COLORS["gyro"], alpha=0.5, label="NEES per step")
    ax.set_yscale("log")
    ax.axhline(
        chi2_bounds(dof, 1, alpha)[1],
        color=COLORS["bound"],
        ls=":",
        lw=1,
        label=f"{100 * (1 - alpha):.0f} % bound, one step",
    )
    ax.axhline(dof, color=COLORS["truth"], lw=0.8, alpha=0.6)
    ax.set_ylim(1e-4, 1e3)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("NEES (–)")
    ax.legend(loc="lower right", ncols=2, fontsize=8)
    return fig


def consistency_panels(t, nees, nis_sets: dict, nees_dof=3, shade=(), phases=()):
    """NEES (:func:`nees_plot`, None without truth) over one NIS panel per entry of ``nis_sets``
    ({name: (values, dof)}, NaN where that kind of update did not happen), sharing time (s)."""
    fig, axes = plt.subplots(1 + len(nis_sets), 1, sharex=True, figsize=(9.0, 2.7 * (1 + len(nis_sets))))
    nees_plot(t, nees, nees_dof, ax=axes[0])
    for ax, (name, (values, dof)) in zip(axes[1:], nis_sets.items()):
        nis_plot(t, values, dof=dof, ax=ax)
        ax.set_ylabel(f"NIS, {name} (–)")
    for ax in axes:
        mark_windows(ax, shade, label=None)
        ax.set_xlabel("")
    label_phases(axes[0], phases)
    axes[-1].set_xlabel("time (s)")
    return fig


def sweep(
    values, rmses: dict, xlabel, ylabel="RMSE (°)", marks: dict | None = None, ax=None, references: dict | None = None
):
    """RMSE (°) against a tuning value on log–log axes: ``rmses`` maps a label to one RMSE per value;
    ``marks`` maps a label to a value drawn as a vertical line (the datasheet's, the best);
    ``references`` maps a label to (RMSE (°), kind), a horizontal line in that kind's colour (a sensor alone)."""
    fig, ax = _axes(ax)
    for (label, r), (kind, style), marker in zip(rmses.items(), XYZ * 2, "os^vD<"):
        ax.loglog(values, r, marker=marker, ls=style, ms=3, color=COLORS[kind], label=label)
    for (label, x), style in zip((marks or {}).items(), (":", "-.", "--")):
        ax.axvline(x, color=COLORS["truth"], ls=style, lw=1.0, label=label)
    for label, (y, kind) in (references or {}).items():
        ax.axhline(y, color=COLORS[kind], ls=STYLES[kind], lw=1.0, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(loc="upper center", ncols=4, fontsize=8)
    return fig


def allan(ax, taus, adev, unit, scale=1.0, white=None, walk=None, arw=None, minimum=None, title=None):
    """Allan deviation σ(τ) of x, y, z ((M, 3), SI, times ``scale`` to show ``unit``) against cluster time τ (s),
    log–log, with the noise models in black: ``white`` (name, N) the white noise N/√τ (slope −½), ``walk``
    (name, K) the bias random walk K√(τ/3) (slope +½), left out when K is None (no simulation, no K);
    ``arw`` the N read at τ = 1 s and ``minimum`` (τ_min, σ_min) per axis, as points. No legend: one for
    several panels is the caller's (``fig.legend``)."""
    taus, adev = np.asarray(taus, dtype=float), np.asarray(adev, dtype=float) * scale
    for i, (axis, (kind, style)) in enumerate(zip("xyz", XYZ)):
        ax.loglog(taus, adev[:, i], color=COLORS[kind], ls=style, label=axis)
    if white is not None:
        ax.loglog(
            taus,
            white[1] * scale / np.sqrt(taus),
            color=COLORS["truth"],
            ls=(0, (6, 2, 1, 2, 1, 2)),
            lw=1,
            label=f"{white[0]} N/√τ (slope −½)",
        )
    if walk is not None and walk[1] is not None:
        ax.loglog(
            taus,
            walk[1] * scale * np.sqrt(taus / 3),
            ":",
            color=COLORS["truth"],
            lw=1.4,
            label=f"{walk[0]} K√(τ/3) (+½)",
        )
    if arw is not None:
        ax.plot([1.0], [arw * scale], "o", color=COLORS["truth"], label="ARW read at τ = 1 s")
    if minimum is not None:
        ax.plot(
            minimum[0],
            np.asarray(minimum[1]) * scale,
            "s",
            color=COLORS["truth"],
            mfc="white",
            label="minimum = 0.664·B",
        )
    ax.set(xlabel="cluster time τ (s)", ylabel=f"Allan deviation ({unit})", ylim=(0.5 * adev.min(), 2 * adev.max()))
    if title:
        ax.set_title(title)
    return ax.figure


def rmse_table(
    estimates: dict, truth, columns=EULER, rotation=False, width=26, hint="", title="RMSE (°)", note="", out=print
):
    """Print the RMSE (°) of each estimate against ``truth`` (rad), one row each, one column per angle;
    ``rotation``: also the RMSE of the total rotation error (°) between the Euler ZYX attitudes.
    ``title`` heads the label column, ``note`` ends the header line.
    ``truth`` None: one line saying there is no RMSE (``hint`` says what to look at instead).
    Returns {label: RMSE per column (°)}, or None without truth."""
    if truth is None:
        out(f"{NO_TRUTH}: no RMSE" + (f"; {hint}" if hint else ""))
        return None
    truth = np.asarray(truth, dtype=float)
    header = f"{title:{width}s} " + " ".join(f"{c:>6s}" for c in columns)
    out(header + (f" {'rotation':>9s}" if rotation else "") + note)
    table = {}
    for label, estimate in estimates.items():
        table[label] = np.atleast_1d(np.degrees(rmse(angle_error(estimate, truth), 0.0)))
        row = f"{label:{width}s} " + " ".join(f"{v:6.2f}" for v in table[label])
        if rotation:
            total = attitude_errors(euler_to_quat(estimate), euler_to_quat(truth))[0]
            row += f" {np.degrees(rmse(total, 0.0)):9.2f}"  # NaN rows (truth unseen) left out
        out(row)
    return table


def consistency_table(nees, nis_sets: dict, nees_dof=3, alpha=0.05, out=print):
    """Print the mean NEES and each NIS set's mean against what a consistent filter gives (its dof), with the
    (1 − alpha) χ² bounds of the mean and the fraction of steps inside the one-step bounds; NaN steps
    (no such update, no truth at that step) left out. ``nees`` None: one line saying it needs the truth."""
    level = f"{100 * (1 - alpha):.0f} %"
    if nees is None:
        out(f"{'NEES':13s} needs the truth: none in this recording")
    else:
        nees = np.asarray(nees, dtype=float)
        nees = nees[~np.isnan(nees)]
        out(
            f"{'NEES':13s} mean {np.mean(nees):6.2f} (expected {nees_dof}); "
            f"{100 * fraction_inside(nees, nees_dof, alpha):3.0f} % of samples inside the one-step {level} bounds"
        )
    for name, (values, dof) in nis_sets.items():
        v = np.asarray(values, dtype=float)
        v = v[~np.isnan(v)]
        lo, hi = chi2_bounds(dof, len(v), alpha)
        out(
            f"{'NIS (' + name + ')':13s} mean {v.mean():6.2f} (expected {dof}, {level} bounds of the mean {lo:.2f} … "
            f"{hi:.2f}); {100 * fraction_inside(v, dof, alpha):3.0f} % of samples inside the one-step {level} bounds"
        )


# --- a recording's own signals, its labelled phases shaded (labs 00, 02) -------------------------------------

SENSOR_PLOT = {
    "acc": ("specific force", "m/s²", 1.0),
    "gyr": ("angular rate", "°/s", np.degrees(1.0)),
    "mag": ("magnetic field", "µT", 1.0),
}  # body() is SI: m/s², rad/s (shown in °/s), µT


def recording_signal(ax, rec, sensor, title=None):
    """One sensor of a ``Recording`` in the body frame against time (s) (:func:`xyz`, units of
    :data:`SENSOR_PLOT`), its phases shaded; a run of windows with one label (six headings) is named once,
    above the axes, names on two rows so that neighbours do not overlap. One phase only: shaded, not named."""
    name, unit, scale = SENSOR_PLOT[sensor]
    xyz(ax, rec.t, rec.body(sensor), name, unit, scale)
    runs = []
    for p in rec.phases:
        ax.axvspan(p["start"], p["end"], color=COLORS["other"], alpha=0.12, lw=0)
        if runs and runs[-1][2] == p["label"]:
            runs[-1][1] = p["end"]
        else:
            runs.append([p["start"], p["end"], p["label"]])
    for j, (a, b, label) in enumerate(runs if len(runs) > 1 else []):
        ax.text(
            (a + b) / 2,
            1.02 + 0.12 * (j % 2),
            label.replace("_", " "),
            ha="center",
            va="bottom",
            fontsize=7,
            transform=ax.get_xaxis_transform(),
        )
    ax.set_title(title, pad=34 if len(runs) > 1 else 6, fontsize=10)
    ax.set_xlabel("time (s)")
    return ax.figure


def recording_grid(panels: dict, ncols=2, title=None):
    """Several recordings side by side, ``panels`` mapping a panel title to (recording, sensor), each drawn by
    :func:`recording_signal`; one legend for the x, y, z body axes every panel shares."""
    rows = -(-len(panels) // ncols)
    fig, axes = plt.subplots(rows, ncols, figsize=(5.2 * ncols, 2.9 * rows), squeeze=False)
    for ax, (name, (rec, sensor)) in zip(axes.flat, panels.items()):
        recording_signal(ax, rec, sensor, title=name)
    for ax in axes.flat[len(panels) :]:
        ax.set_visible(False)
    fig.legend(axes[0, 0].get_lines(), [f"{axis} (body)" for axis in "xyz"], loc="outside lower center", ncols=3)
    if title:
        fig.suptitle(title)
    return fig


def recording_signals(rec, title=None):
    """Every sensor a ``Recording`` has, body frame, in :func:`imu_signals`' stacked panels (an MPU6050 has no
    magnetometer: two panels), its phases named."""
    mag = rec.body("mag") if "mag" in rec.meta["sensors"] else None
    return imu_signals(rec.t, rec.body("gyr"), rec.body("acc"), mag, phases=rec.phases, title=title)


# --- a vehicle drive: what a production car measures (lab 06) ------------------------------------------------

VEHICLE_PLOT = (
    ("delta", "δ (°)", np.degrees(1.0), "steering δ (road wheel)", "kf"),
    ("yaw_rate", "r (°/s)", np.degrees(1.0), "yaw-rate gyro", "gyro"),
    ("ay", "a_y (m/s²)", 1.0, "lateral accelerometer", "accel"),
    ("vx", "V_x (km/h)", 3.6, "speed from wheel speeds", "other"),
)  # column, axis label, scale from SI


def vehicle_signals(rec, title=None):
    """A vehicle ``Recording``'s steering, yaw rate, lateral acceleration and speed (ISO 8855, SI columns)
    in stacked panels sharing time, in the units of :data:`VEHICLE_PLOT`."""
    fig, axes = plt.subplots(len(VEHICLE_PLOT), 1, sharex=True, figsize=(9, 7.5))
    for ax, (column, ylabel, scale, label, kind) in zip(axes, VEHICLE_PLOT):
        ax.plot(rec.t, rec[column] * scale, color=COLORS[kind], lw=1.0, label=label)
        ax.set_ylabel(ylabel)
        ax.legend(loc="lower center" if column == "vx" else "upper right", fontsize=8)
    axes[-1].set_xlabel("time (s)")
    if title:
        fig.suptitle(title)
    return fig
