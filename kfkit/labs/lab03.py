"""Lab 03's support (magnetometer alignment, calibration and heading): what its notebook calls beyond the library.

The data source (bundled, BROAD's real IMU, a student's board or phone), the gyro's bias and the local field per
source, the turns about each axis and the angles they turn, section 3's 3-D field panel, the headings protocol's
rests and prompted headings, the magnet window of BROAD trial 34 and the simulated phone's tumbling. The student's
exercises stay in the notebook.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from scipy.ndimage import median_filter, uniform_filter1d

from .. import calibration, calibration_motions, datasets, frames, phone_sim
from ..capture.guided import HEADINGS_DEG
from ..io import Recording
from ..plots import COLORS, windows_where
from ..readers import load_any, load_phyphox

REAL = "01_broad_slow_rotation"  # "real": BROAD trial 02, a hand-turned IMU with motion-capture truth (section 8)
#: the headings (rad) lab 00's protocol asks for: flat in this order, then tilted in reverse
HEADINGS_ASKED = np.radians(HEADINGS_DEG)
PLANE = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}  # the plane a turn about each axis rotates


def load(path, bundled, mount="flat") -> Recording:
    """The recording a data-source value names: None the bundled ``bundled``, "real" BROAD's :data:`REAL`, else a
    student's file or phyphox export (``mount``: how a phone is held). Refuses "real" headings (BROAD has no headings
    protocol) and a board without a magnetometer, saying what to do."""
    if path == "real" and bundled == "03_headings":
        raise ValueError(
            'HEADINGS = "real": BROAD has no headings protocol; leave it None (section 8 judges the real '
            "IMU's heading against its motion capture)"
        )
    rec = (
        datasets.load(bundled)
        if path is None
        else datasets.load(REAL)
        if path == "real"
        else load_any(path, mount=mount, require=("acc", "gyr", "mag"))
    )
    if "mag" not in rec.meta["mount"]:
        raise ValueError(
            f"{path or bundled}: board {rec.meta['board']!r} has no magnetometer; lab 03 needs the "
            "Nucleo + X-NUCLEO-IKS02A1 or a phone"
        )
    return rec


def is_broad(rec) -> bool:
    return rec.meta.get("source") == "BROAD"


def gyro_bias(rec):
    """rad/s: lab 02's calibration of the board; BROAD comes calibrated by its authors, but the gyro's bias stays:
    the mean of its rests, as lab 02 measures it."""
    if is_broad(rec):
        return rec.body("gyr")[rec.phase("rest")].mean(axis=0)
    return np.array(calibration.calibration_for(rec).gyro_bias)


def local_field(rec) -> float:
    """µT: the local field's magnitude: London's for the kit's boards and a student's (put your location's in
    ``frames.MAG_FIELD_LONDON``'s place); in BROAD's lab, the median |m| at its rests as its calibrated magnetometer
    reads it."""
    if is_broad(rec):
        return float(np.median(np.linalg.norm(rec.body("mag")[rec.phase("rest")], axis=1)))
    return float(np.linalg.norm(frames.MAG_FIELD_LONDON))


def angles_turned(rec, mag, gyr, axis, label):
    """Over the phase ``label``, a turn about ``axis``, at the rows with a new magnetometer sample: the time (s) since
    the phase began, the angle (rad) the gyro turned, and the angle the field turned back (the board turned −Δ)."""
    phase = rec.phase(label)
    fresh = np.isfinite(mag[phase, 0])
    i, j = PLANE[axis]
    field_angle = np.unwrap(np.arctan2(mag[phase][fresh, j], mag[phase][fresh, i]))
    gyro_angle = np.cumsum(gyr[phase, "xyz".index(axis)]) / rec.rate_hz  # rad, integrated over the turn
    return rec.t[phase][fresh] - rec.t[phase][0], gyro_angle[fresh], -(field_angle - field_angle[0])


def found_turns(rec, gyr, share=0.9, min_rate=0.3, smooth_s=0.5) -> Recording:
    """The recording with phases turn_x, turn_y, turn_z for one without them (BROAD): about each axis, the longest
    stretch whose rate (rad/s, averaged over smooth_s s) exceeds min_rate, at least ``share`` of it about that axis."""
    rate = uniform_filter1d(gyr, int(smooth_s * rec.rate_hz), axis=0)
    speed = np.linalg.norm(rate, axis=1)
    found = []
    for i, axis in enumerate("xyz"):
        about = (np.abs(rate[:, i]) >= share * speed) & (speed > min_rate)
        start, end = max(windows_where(rec.t, about), key=lambda w: w[1] - w[0])
        found.append({"label": f"turn_{axis}", "start": float(start), "end": float(end)})
    return Recording({**rec.meta, "phases": rec.phases + found}, rec.data, rec.path)


def field_panel(ax, data, title, colour, centre, shape, lim):
    """One 3-D panel of section 3's figure: readings (N, 3) µT as points of ``COLORS[colour]``, the surface
    centre + shape·u over unit vectors u as a wireframe (an ellipsoid; a sphere when shape = r·I), and the line from
    the origin to its centre (the hard iron), on axes of ±lim µT."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    unit = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], axis=-1)
    ax.scatter(*data[::3].T, s=2, color=COLORS[colour], depthshade=False)
    ax.plot_wireframe(
        *np.moveaxis(np.asarray(centre) + unit @ np.asarray(shape).T, -1, 0), color=COLORS["truth"], lw=0.3, alpha=0.5
    )
    ax.plot(
        *np.column_stack([np.zeros(3), centre]),
        color=COLORS["truth"],
        lw=2,
        marker="o",
        ms=4,
        label="origin → centre (the hard iron h)",
    )
    ticks = [-50, 0, 50]
    ax.set(
        xlim=(-lim, lim),
        ylim=(-lim, lim),
        zlim=(-lim, lim),
        xticks=ticks,
        yticks=ticks,
        zticks=ticks,
        xlabel="m_x (µT)",
        ylabel="m_y (µT)",
        zlabel="m_z (µT)",
        box_aspect=(1, 1, 1),
    )
    ax.set_title(title, fontsize=10)
    ax.view_init(elev=20, azim=-60)


def rests(rec, label):
    """The windows (start, end) in s labelled ``label``, in time order."""
    return sorted((p["start"], p["end"]) for p in rec.phases if p["label"] == label)


def prompted_yaw(rec):
    """The heading (rad) the headings protocol asked for at each sample of its rests, NaN between them;
    None when the recording's rests are not the protocol's six flat and six tilted ones."""
    yaw = np.full(len(rec), np.nan)
    for label, asked in (("heading_flat", HEADINGS_ASKED), ("heading_tilted", HEADINGS_ASKED[::-1])):
        if len(rests(rec, label)) != len(asked):
            return None
        for (start, end), psi in zip(rests(rec, label), asked):
            yaw[(rec.t >= start) & (rec.t < end)] = psi
    return frames.wrap_angle(yaw)  # (−π, π], as the true yaw


def rest_errors_deg(rec, psi, reference_yaw, label, rows=None):
    """The heading error (°) averaged over each rest labelled ``label``, in time order: the circular mean of
    psi − reference_yaw (rad) over the rest's rows with a magnetometer sample. ``psi`` holds every row of ``rec``, or
    only the rows where the mask ``rows`` is True."""
    if rows is not None:
        every = np.full(len(rec), np.nan)
        every[rows] = psi
        psi = every
    fresh = np.isfinite(rec.body("mag")[:, 0])
    inside = [(rec.t >= a) & (rec.t < b) & fresh for a, b in rests(rec, label)]
    return np.array([np.degrees(np.angle(np.mean(np.exp(1j * (psi[m] - reference_yaw[m]))))) for m in inside])


MAGNET_SIGMAS = 5.0  # the magnet is on where |m| (smoothed) is this many noise σ from the rests' field
MAGNET_SMOOTH_S = 0.5  # s: the running median of |m| that is judged, so single noisy samples do not count


def magnet_window(rec):
    """Where a magnet sits on the board, from |m| alone, and the field without it.

    B (µT) is the median |m| over the ``rest`` phases, σ its noise there (1.4826·MAD, robust to a few seconds
    with the magnet); the magnet is on from the first to the last sample where the running median of |m| over
    :data:`MAGNET_SMOOTH_S` lies more than :data:`MAGNET_SIGMAS`·σ from B (in between, the magnet's field can
    add to the Earth's to about B, so the samples between count too). Returns (mask (N,), B, σ)."""
    norm = np.linalg.norm(rec.body("mag"), axis=1)
    rest = norm[rec.phase("rest")]
    B = float(np.median(rest))
    sigma = float(1.4826 * np.median(np.abs(rest - B)))
    width = max(1, int(round(MAGNET_SMOOTH_S * rec.rate_hz))) | 1
    off = np.flatnonzero(np.abs(median_filter(norm, size=width, mode="nearest") - B) > MAGNET_SIGMAS * sigma)
    mask = np.zeros(len(rec), dtype=bool)
    if off.size:
        mask[off[0] : off[-1] + 1] = True
    return mask, B, sigma


def simulated_phone_tumbling(seed=31) -> Recording:
    """A simulated phone tumbled for a minute in London's field (``calibration_motions.mag_rotations`` at 200 Hz),
    exported as phyphox writes a simple experiment and read back with ``readers.load_phyphox``: what a student's phone
    gives."""
    samples = phone_sim.simulate_phone(calibration_motions.mag_rotations(rate_hz=200.0, seed=seed), seed=seed + 1)
    with tempfile.TemporaryDirectory() as folder:
        export = phone_sim.write_export(phone_sim.simple_experiment_files(samples), Path(folder) / "phone_tumbling")
        return load_phyphox(export, require=("acc", "gyr", "mag"))
