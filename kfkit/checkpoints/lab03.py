"""Checkpoints of lab 03 (magnetometer alignment, calibration and heading)."""

from __future__ import annotations

import numpy as np

from .. import calibration, datasets, mag_calibration
from ..frames import (
    MAG_FIELD_LONDON,
    accel_tilt,
    declination,
    euler_to_dcm,
    mag_heading,
    random_dcm,
    tilt_compensated_heading,
    wrap_angle,
)
from ..labs.lab03 import magnet_window
from ..metrics import angle_error, rmse
from ..sensors import iis2mdc_mag
from . import Case, Checkpoint, compare, fmt, fmt_pair, matches, register, structural

HEADING_LIMIT_DEG = 2.0  # RMS heading error allowed after calibration on the bundled recording
PROPER_SIGNS = [np.diag(d) for d in ([1, 1, 1], [-1, 1, -1], [-1, -1, 1], [1, -1, -1])]  # det +1


def _counts_cases(rng):
    sens = iis2mdc_mag().sensitivity
    return [
        Case({"counts": c}, c * sens, f"{c.shape[0]} random count triples")
        for c in (rng.integers(-3000, 3000, (int(rng.integers(1, 20)), 3)) for _ in range(6))
    ]


def _judge_counts(case, got):
    problem = compare(case.expected, got)
    if problem is None or structural(problem):
        return problem
    ratio = np.asarray(got, float).ravel() / np.where(case.expected == 0, np.nan, case.expected).ravel()
    r = np.nanmedian(ratio)
    if np.isclose(r, 0.01) or np.isclose(r, 1e-3) or np.isclose(r, 10.0):
        return problem + f" — off by ×{r:g}: 1 gauss = 100 µT and 1 mG = 0.1 µT"
    return problem


def turn_angles(rng, sense, size, direction, n=200):
    """A turn out by α (sign ``direction``) and back (gyro angle, rad) and what a magnetometer sees: sign
    ``sense``, its swing ``size`` times the gyro's (hard iron distorts the size), with noise."""
    alpha = rng.uniform(np.radians(45), np.radians(120)) * direction
    s = np.sin(np.linspace(0, np.pi, n)) ** 2
    return alpha * s, sense * alpha * s * size + rng.normal(0, 0.02, n)


#: Magnetometer swing ÷ gyro swing: every case has one axis under ½ and one over 1½, so a ratio of sizes rounded
#: to ±1 (round(Σm/Σg)) fails on every seed, and turns both ways, so a sign of Σm alone (without the gyro) fails too.
SMALL_SWING, LARGE_SWING = (0.2, 0.45), (1.6, 2.5)


def _alignment_cases(rng):
    cases = []
    for D in PROPER_SIGNS + [PROPER_SIGNS[k] for k in rng.integers(0, 4, 4)]:
        sizes = rng.permutation([rng.uniform(*SMALL_SWING), rng.uniform(*LARGE_SWING), rng.uniform(0.5, 1.5)])
        directions = rng.permutation([1, -1, rng.choice([-1, 1])])
        turns = {axis: turn_angles(rng, D[i, i], sizes[i], directions[i]) for i, axis in enumerate("xyz")}
        cases.append(
            Case({"turns": turns}, D, f"turns whose magnetometer senses are {np.diag(D).astype(int).tolist()}")
        )
    return cases


def random_ellipsoid(rng, n=400, field_norm=None, noise=0.05):
    """Readings (n, 3) µT of a field of magnitude B seen from all directions through a random soft iron
    W (symmetric, eigenvalues 0.7–1.3) and hard iron h (±30 µT), with white noise; returns (mag, h, W)."""
    B = float(np.linalg.norm(MAG_FIELD_LONDON)) if field_norm is None else field_norm
    u = random_dcm(n, rng)[:, :, 0]  # uniform directions: the first column of uniform rotations
    V = random_dcm(rng=rng)
    W = V @ np.diag(rng.uniform(0.7, 1.3, 3)) @ V.T
    h = rng.uniform(-30, 30, 3)
    return B * u @ W.T + h + rng.normal(0, noise, (n, 3)), h, W


HARD_IRON_TOL = 0.05  # µT: the reference fit is within 0.02 µT of the truth on every one of 2000 such ellipsoids
SOFT_IRON_TOL = 3e-3  # largest |S − W⁻¹| allowed; the reference stays under 1e-3


def _ellipsoid_cases(rng):
    cases = []
    for _ in range(6):
        mag, h, W = random_ellipsoid(rng)
        cases.append(Case({"mag": mag}, (h, np.linalg.inv(W)), "a random ellipsoid of 400 readings"))
    return cases


def _hard_and_soft_iron(got):
    """(h (3,), S (3, 3)) as float arrays from an answer, or (None, what is wrong with it)."""
    try:
        h, S = (np.asarray(g, dtype=float) for g in got)
    except (TypeError, ValueError) as e:
        return None, f"expected (hard_iron (3,), soft_iron (3, 3)), got something else ({e})"
    if h.shape != (3,) or S.shape != (3, 3):
        return None, f"expected shapes (3,) and (3, 3), got {h.shape} and {S.shape}"
    return h, S


def _judge_ellipsoid(case, got):
    """Against the ellipsoid's true hard iron h and soft-iron correction W⁻¹ (W symmetric), within the
    noise of a 400-reading fit, so any sound least-squares fit passes, not only the reference's."""
    h_true, S_true = case.expected
    h, S = _hard_and_soft_iron(got)
    if h is None:
        return S
    text = f"true h = {fmt(h_true)} µT, yours {fmt(h)}"
    if not np.all(np.isfinite(S)) or not np.all(np.isfinite(h)):
        return f"{text}; h or S holds NaN or inf"
    if np.abs(h - h_true).max() > HARD_IRON_TOL:
        return f"{text}: off by {np.abs(h - h_true).max():.3f} µT (allowed {HARD_IRON_TOL:g})"
    if not np.allclose(S, S.T, atol=1e-9):
        return "S is not symmetric: take the symmetric square root of A (eigh: V·diag(√w)·Vᵀ), not a Cholesky factor"
    B = np.linalg.norm(MAG_FIELD_LONDON)
    norms = np.linalg.norm((case.args["mag"] - h) @ S.T, axis=1)
    if not np.isclose(np.mean(norms), B, rtol=1e-3):
        if _like(S, np.linalg.inv(S_true)) and not _like(S, S_true):
            return (
                "S is the inverse of the correction: it holds the ellipsoid's radii (A^−½); the correction that "
                "maps the ellipsoid onto a sphere is B·A^½ (√w, not 1/√w, from eigh)"
            )
        return (
            f"the hard iron is right but calibrated norms average {np.mean(norms):.2f} µT, not B = {B:.2f}:"
            " scale S by B"
        )
    worst = np.abs(S - S_true).max()
    if worst > SOFT_IRON_TOL:
        return f"largest |S − W⁻¹| = {worst:.4f} (allowed {SOFT_IRON_TOL:g}); expected S ≈ {fmt(S_true)}"
    return None


def _tilted_reading(yaw, pitch, roll):
    """m_b = R_bn m_n of the London field (µT) for a board at (ψ, θ, φ)."""
    return np.einsum("...ji,j->...i", euler_to_dcm(np.stack([roll, pitch, yaw], axis=-1)), MAG_FIELD_LONDON)


def _like(A, B, atol=2e-2):
    """True when matrices A and B point the same way (equal after dividing each by its Frobenius norm)."""
    return np.allclose(A / np.linalg.norm(A), B / np.linalg.norm(B), atol=atol)


def _heading_cases(rng):
    """Random tilts, with declination 0 (magnetic heading) or London's (true heading); two whose magnetic heading
    plus the declination crosses +180° and −180° (an unwrapped sum leaves (−π, π]); and the (N, 3) readings with
    (N,) angles the docstring promises (the next cell passes whole recordings)."""
    D = declination()
    cases = []
    for _ in range(10):
        roll, pitch, yaw = rng.uniform(-1.2, 1.2), rng.uniform(-1.2, 1.2), rng.uniform(-np.pi, np.pi)
        decl = float(rng.choice([0.0, D]))  # 0: magnetic heading; D: true heading
        cases.append(
            Case(
                {"m_b": _tilted_reading(yaw, pitch, roll), "roll": roll, "pitch": pitch, "declination": decl},
                wrap_angle(yaw - D + decl),
            )
        )
    for magnetic, decl in ((np.pi - D / 2, D), (-np.pi + 0.05, -0.1)):
        roll, pitch = rng.uniform(-0.8, 0.8, 2)
        cases.append(
            Case(
                {"m_b": _tilted_reading(magnetic + D, pitch, roll), "roll": roll, "pitch": pitch, "declination": decl},
                wrap_angle(magnetic + decl),
                f"a magnetic heading of {np.degrees(magnetic):.2f}° with declination "
                f"{np.degrees(decl):+.2f}° (the sum crosses ±180°)",
            )
        )
    n = 25
    roll, pitch, yaw = rng.uniform(-1.2, 1.2, n), rng.uniform(-1.2, 1.2, n), rng.uniform(-np.pi, np.pi, n)
    cases.append(
        Case(
            {"m_b": _tilted_reading(yaw, pitch, roll), "roll": roll, "pitch": pitch, "declination": D},
            wrap_angle(yaw),
            f"{n} readings at once (m_b of shape ({n}, 3), roll and pitch of shape ({n},))",
        )
    )
    return cases


def _flat_cases(rng):
    cases = []
    for yaw in np.concatenate([[0.0, np.pi / 2, np.pi, -np.pi / 2], rng.uniform(-np.pi, np.pi, 6)]):
        m_b = _tilted_reading(yaw, 0.0, 0.0)
        cases.append(Case({"m_b": m_b}, mag_heading(m_b)))
    return cases


def _judge_heading(case, got):
    """Headings in (−π, π], as many as the case has readings; names the classic atan2 slips."""
    e = np.asarray(case.expected, dtype=float)
    try:
        g = np.asarray(got, dtype=float)
    except (TypeError, ValueError):
        return f"expected {'one angle' if e.ndim == 0 else f'{e.size} angles'} in rad, got {type(got).__name__}"
    if g.shape != e.shape:
        return f"shape mismatch: expected {'one angle' if e.ndim == 0 else f'shape {e.shape}'}, got shape {g.shape}"
    err = wrap_angle(g - e)
    bad = np.abs(err) >= 1e-6
    outside = (g > np.pi + 1e-9) | (g < -np.pi - 1e-9)
    k = np.unravel_index(int(np.argmax(bad | outside)), e.shape) if e.ndim else ()
    want, have = fmt_pair(e[k], g[k])
    text = f"expected {want} rad, got {have}" + (f" at index {k[0]}" if e.ndim else "")
    if not bad.any():
        return (
            None
            if not outside.any()
            else text + " — the same direction, but not wrapped to (−π, π]: wrap after adding the declination"
        )
    if np.allclose(np.abs(err), np.pi, atol=1e-6):
        return text + " — exactly 180° off: both atan2 arguments have the wrong sign"
    if np.allclose(wrap_angle(g + e), 0.0, atol=1e-6):
        return text + " — the heading turns the wrong way: check the sign of m_y"
    if np.allclose(wrap_angle(g + e - np.pi / 2), 0.0, atol=1e-6):
        return text + " — the atan2 arguments are swapped: atan2(−m_y, m_x), the east-like component first"
    if np.allclose(g, np.degrees(e), atol=1e-6):
        return text + " — that is the heading in degrees: return radians"
    return text


# --- the bundled recordings ------------------------------------------------------------------------


def heading_errors(hard_iron, soft_iron):
    """RMS heading error (rad) on 03_headings's rests with a magnetometer calibration (h, S):
    tilt-compensated, roll and pitch from the (reference-)calibrated accelerometer, declination added."""
    rec = datasets.load("03_headings")
    ref = calibration.load_calibration(
        rec.meta["board"], path=datasets.data_dir() / f"calibration_{rec.meta['board']}.json"
    )
    _, acc, _ = ref.apply(rec)
    mag = mag_calibration.apply_mag_calibration(rec.body("mag"), hard_iron, soft_iron)
    rest = (rec.phase("heading_flat") | rec.phase("heading_tilted")) & np.isfinite(mag[:, 0])
    roll, pitch = accel_tilt(acc[rest])
    psi = tilt_compensated_heading(mag[rest], roll, pitch, declination())
    return float(np.sqrt(np.mean(wrap_angle(psi - rec["true_yaw"][rest]) ** 2)))


def _calibration_recording_cases(rng):
    rec = datasets.load("03_mag_rotations")
    mag = rec.body("mag")
    before = heading_errors(np.zeros(3), np.eye(3))
    return [Case({"mag": mag[np.isfinite(mag[:, 0])]}, before, "the bundled recordings 03_mag_rotations → 03_headings")]


def _judge_heading_recording(case, got):
    try:
        h, S = (np.asarray(g, dtype=float) for g in got)
        after = heading_errors(h, S)
    except (TypeError, ValueError) as e:
        return f"expected (hard_iron (3,), soft_iron (3, 3)), got something else ({e})"
    if np.degrees(after) < HEADING_LIMIT_DEG:
        return None
    return (
        f"RMS heading error {np.degrees(after):.1f}° after your calibration (uncalibrated: "
        f"{np.degrees(case.expected):.1f}°), allowed {HEADING_LIMIT_DEG:g}°"
    )


# --- the real recording: BROAD trial 34, a magnet attached to the IMU -------------------------------------

REAL_MAGNET = "03_broad_attached_magnet"
REAL_BAR_FACTOR = 2.0  # the calibrated heading error allowed, × the same IMU's error with the magnet off


def true_tilt_heading_error(mag, truth):
    """RMS (rad) of the tilt-compensated heading of ``mag`` (N, 3) µT, body, against the motion capture's
    ``truth`` (N, 3) [roll, pitch, yaw], with the motion capture's roll and pitch (so only the magnetometer is
    judged) and no declination (BROAD's yaw is relative to the lab's magnetic north); NaN rows of the truth are
    left out."""
    psi = tilt_compensated_heading(mag, truth[:, 0], truth[:, 1])
    return float(rmse(angle_error(psi, truth[:, 2]), 0.0))


def _real_magnet_cases(rng):
    rec = datasets.load(REAL_MAGNET)
    magnet, B, _ = magnet_window(rec)
    moving = rec.phase("movement")
    mag, truth = rec.body("mag"), rec.truth()
    on, off = magnet & moving, moving & ~magnet
    budget = {
        "on": true_tilt_heading_error(mag[on], truth[on]),
        "off": true_tilt_heading_error(mag[off], truth[off]),
        "truth": truth[on],
    }
    return [Case({"mag": mag[on], "field_norm": B}, budget, "BROAD trial 34, the tumbling with the magnet on")]


def _judge_real_magnet(case, got):
    """The heading error after the student's fit against REAL_BAR_FACTOR × the error of the same IMU, same trial,
    with the magnet off (both with the motion capture's tilt). What a right fit leaves is the magnetometer's
    noise, the truth's own error and the authors' calibration residual: about that error; the factor 2 covers how
    much that error changes with the motion (trial 02's movement: 3.2°, trial 34's without the magnet: 5.4°).
    A hard iron left in (32°) or misfit by more than ≈ 2.5 µT of the 15.5 µT horizontal field fails."""
    h, S = _hard_and_soft_iron(got)
    if h is None:
        return S
    budget = case.expected
    after = true_tilt_heading_error(mag_calibration.apply_mag_calibration(case.args["mag"], h, S), budget["truth"])
    allowed = REAL_BAR_FACTOR * budget["off"]
    if after <= allowed:
        return None
    return (
        f"with your fit the heading errs by {np.degrees(after):.1f}° RMS while the magnet is on (uncalibrated "
        f"{np.degrees(budget['on']):.1f}°, the same IMU with the magnet off {np.degrees(budget['off']):.1f}°), "
        f"allowed {np.degrees(allowed):.1f}°: your hard iron h = {fmt(h)} µT is not the magnet's"
    )


# --- questions: the hard iron a heading budget allows ------------------------------------------------------


def _budget_cases(rng):
    """Fields of any strength, dip and declination (|D| 5–25°, so B_N alone is not B_h) and heading budgets of 5–30°
    (so tan ε is not sin ε): the answer is B_h·sin ε."""
    cases = []
    for _ in range(8):
        B_h, dip = rng.uniform(5.0, 35.0), rng.uniform(np.radians(-75), np.radians(75))
        decl = rng.choice([-1, 1]) * rng.uniform(np.radians(5), np.radians(25))
        field = np.array([B_h * np.cos(decl), B_h * np.sin(decl), B_h * np.tan(dip)])
        eps = rng.uniform(5.0, 30.0)
        cases.append(
            Case(
                {"field_ned": field, "max_error_deg": eps},
                B_h * np.sin(np.radians(eps)),
                f"field {fmt(field)} µT (N, E, D), at most {eps:.1f}°",
            )
        )
    return cases


def _judge_budget(case, got):
    """Within 1e-6 relative of B_h·sin ε; names the total field, B_N alone, tan for sin and degrees as radians."""
    try:
        g = float(got)
    except (TypeError, ValueError):
        return f"expected one number (µT), got {type(got).__name__}"
    want = case.expected
    if np.isclose(g, want, rtol=1e-6):
        return None
    text = f"expected {want:.4f} µT, got {g:.4f}"
    field, eps = case.args["field_ned"], np.radians(case.args["max_error_deg"])
    B_h = np.hypot(field[0], field[1])
    slips = {
        "only the horizontal field B_h = √(B_N² + B_E²) turns the heading, not the whole field |B|": np.linalg.norm(
            field
        )
        * np.sin(eps),
        "B_h = √(B_N² + B_E²): the east component is part of the horizontal field too": abs(field[0]) * np.sin(eps),
        "the worst hard iron is perpendicular to the field it leaves, not to the true field: sin ε, not tan ε": B_h
        * np.tan(eps),
        "the budget is in degrees: convert it to radians before the sine": B_h * np.sin(case.args["max_error_deg"]),
    }
    for why, value in slips.items():
        if np.isclose(g, value, rtol=1e-6):
            return f"{text} — {why}"
    return text


register(
    Checkpoint(
        "03.counts_to_ut",
        "counts_to_ut",
        _counts_cases,
        _judge_counts,
        points=1,
        hint="the IIS2MDC gives 1.5 mG per count; convert gauss to µT.",
    ),
    Checkpoint(
        "03.alignment",
        "alignment_from_turns",
        _alignment_cases,
        matches(),
        points=2,
        hint="per axis, does the magnetometer's angle go the same way as the gyro's (+1) or the opposite way "
        "(−1)? Compare signs over the whole turn (e.g. the sign of Σ gyro·mag), not the sizes.",
    ),
    Checkpoint(
        "03.mag_calibration",
        "mag_calibration",
        _ellipsoid_cases,
        _judge_ellipsoid,
        points=3,
        hint="fit the quadric [x², y², z², 2xy, 2xz, 2yz, x, y, z, 1]·p = 0 (last right singular vector), "
        "h = −Q⁻¹p_lin/2, A = Q/(hᵀQh − c), S = B·A^½ from eigh.",
    ),
    Checkpoint(
        "03.flat_heading",
        "flat_heading",
        _flat_cases,
        _judge_heading,
        points=1,
        hint="level, m_x = B_h cos ψ and m_y = −B_h sin ψ.",
    ),
    Checkpoint(
        "03.tilt_heading",
        "tilt_heading",
        _heading_cases,
        _judge_heading,
        points=2,
        hint="de-rotate by roll (about x) then pitch (about y) into the level frame, then use the flat formula "
        "and add the declination.",
    ),
    Checkpoint(
        "03.heading_error",
        "mag_calibration",
        _calibration_recording_cases,
        _judge_heading_recording,
        points=2,
        what="bundled recording",
        hint="if 03.mag_calibration passes, check that you pass only rows with a magnetometer sample (no NaN).",
    ),
    Checkpoint(
        "03.real_magnet",
        "mag_calibration",
        _real_magnet_cases,
        _judge_real_magnet,
        points=1,
        what="bundled real recording",
        hint="h is the fitted ellipsoid's centre in µT (undo the centring and scaling); the mean of the readings "
        "is that centre only when the tumbling covers the sphere evenly, which a real one never does.",
    ),
    Checkpoint(
        "03.hard_iron_budget",
        "hard_iron_budget_ut",
        _budget_cases,
        _judge_budget,
        points=1,
        hint="draw the horizontal field B_h and a hard iron h of fixed length in every direction: the reading "
        "B_h + h turns furthest from B_h when h is perpendicular to the reading, not to B_h.",
    ),
)
