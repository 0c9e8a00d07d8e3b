"""Labs 02 and 03 end to end: what lab 00 records with the virtual board, and a phone's phyphox exports, through
the solution notebooks and kfkit.calibration, down to the calibration file lab 04 loads.
(The estimators themselves, against known simulated parameters: test_calibration.py.)"""

import re

import numpy as np
import pytest
import unit_truth
from test_calibration import PHONE, phone_export
from waiting import HANG_GUARD_S

from kfkit import allan, calibration_motions, datasets, mag_calibration, motions, rest_calibration
from kfkit import calibration as C
from kfkit.frames import (
    MAG_FIELD_LONDON,
    G,
    accel_tilt,
    declination,
    mount_matrix,
    tilt_compensated_heading,
    wrap_angle,
)
from kfkit.io import load_recording
from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml


# --- lab 00's recordings from the virtual board --------------------------------------------

NUCLEO = "nucleo-iks02a1"


@pytest.fixture(scope="module")
def lab00_recordings(tmp_path_factory):
    """What lab 00 records with the virtual board, the unit of the bundled recordings (tests/unit_truth.py): its
    guided protocols in quick mode (one board seed), plus the full-length rotations lab 03 needs."""
    from kfkit import capture
    from kfkit.capture.guided import protocol_motion

    folder = tmp_path_factory.mktemp("my_recordings")

    def record(name, out, quick):
        return capture.record_protocol(name, "virtual", folder / out, quick=quick, fast=True, seed=4, prompt=None)

    recs = {
        name: record(name, f"{name}.csv", True)
        for name in ("stationary", "six-faces", "mag-rotations", "axis-turns", "headings")
    }
    recs["mag-rotations full"] = record("mag-rotations", "mag-rotations-full.csv", False)
    return {name: load_recording(rec.path) for name, rec in recs.items()}, protocol_motion(
        "mag-rotations", 104.0, seed=4
    )


def test_lab02_analysis_on_virtual_board_recordings(lab00_recordings):
    """Lab 02's estimates from lab 00's quick rest (5 s) and faces (1 s each) find the unit the virtual board is, each
    within 4 standard deviations of white noise and bias walk (tests/unit_truth.py)."""
    from kfkit import capture

    recs, _ = lab00_recordings
    still, faces_rec = recs["stationary"], recs["six-faces"]
    assert still.meta["source"] == "capture (virtual board)" and "sim" not in still.meta  # no truth in the file
    truth = unit_truth.body_truth(still)
    rest = still.phase("stationary")
    gyr, acc = still.body("gyr")[rest], still.body("acc")[rest]
    n = len(gyr)
    assert n >= 500
    # gyro bias: the mean of the rest, and the mean over the faces' rests of the same unit
    sd = unit_truth.mean_sd(still, rest, "gyr", truth["gyro_bias_rw"])
    assert np.all(np.abs(rest_calibration.gyro_bias(gyr) - truth["gyro_bias"]) < 4 * sd)
    on_faces = np.any([faces_rec.phase(f) for f in rest_calibration.FACES], axis=0)
    sd = unit_truth.mean_sd(faces_rec, on_faces, "gyr", truth["gyro_bias_rw"])
    assert np.all(np.abs(rest_calibration.gyro_bias(faces_rec.body("gyr")[on_faces]) - truth["gyro_bias"]) < 4 * sd)
    # noise σ: the datasheet's with rounding, within 4 standard deviations of a sample σ, 1/√(2(n − 1)), plus the
    # walk's share over the record, K²T/6 of variance
    for x, sensor, walk in ((gyr, "gyr", truth["gyro_bias_rw"]), (acc, "acc", truth["accel_bias_rw"])):
        sigma = unit_truth.sample_sigma(still, sensor)
        drift = walk**2 * (n / still.rate_hz) / 6 / (2 * sigma**2)
        assert np.all(np.abs(rest_calibration.noise_std(x) / sigma - 1) < 4 / np.sqrt(2 * (n - 1)) + drift), sensor
    # six faces: the unit's accelerometer bias and scale, as the slightly tilted faces show them
    faces = {f: faces_rec.body("acc")[faces_rec.phase(f)] for f in rest_calibration.FACES}
    b, s = rest_calibration.accel_six_face(faces)
    bias, scale, sd_b, sd_s = unit_truth.six_face_target(
        faces_rec, capture.protocol_motion("six-faces", 104.0, quick=True, seed=4)
    )
    assert np.all(np.abs(b - bias) < 4 * sd_b) and np.all(np.abs(s - scale) < 4 * sd_s), (
        (b - bias) / sd_b,
        (s - scale) / sd_s,
    )
    # a bias from the level rest alone holds the scale error too: b + (s − 1) ⊙ f with f = [0, 0, −g]
    level = np.array([0.0, 0.0, -G])
    sd = unit_truth.mean_sd(still, rest, "acc", truth["accel_bias_rw"])
    assert np.all(
        np.abs(rest_calibration.accel_bias(acc, level) - (truth["accel_bias"] + (truth["accel_scale"] - 1) * level))
        < 4 * sd
    )
    taus, adev = allan.allan_deviation(gyr, still.rate_hz)
    assert taus.max() >= 1.0  # a 5 s rest still reaches τ = 1 s, so the ARW read-out works
    assert np.all(allan.angle_random_walk(taus, adev) > 0)


def test_lab03_calibration_and_heading_on_virtual_board_recordings(lab00_recordings, tmp_path, monkeypatch):
    """Lab 03's fit of the full rotations finds the unit's hard and soft iron within the fit's linearised uncertainty
    (4σ); headings come out right with the board's own calibration and with the kit's default, not without."""
    recs, motion = lab00_recordings
    quick = recs["mag-rotations"]
    with pytest.raises(rest_calibration.CalibrationError, match="cover too little of the sphere.*every orientation"):
        mag_calibration.fit_mag_calibration(
            quick.body("mag")
        )  # lab 00's 8 s quick version: the fit says what to record
    rec = recs["mag-rotations full"]
    np.testing.assert_allclose(rec.t, motion.t[: len(rec)], atol=1e-5)  # row k is sample k of the motion played
    mag = rec.body("mag")
    unit_truth.assert_mag_fit_within(rec, mag, *mag_calibration.fit_mag_calibration(mag))
    # heading against the motion the board played: tilt from the six-face-corrected accelerometer
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))  # nothing saved: calibration_for gives the kit's default
    truth_euler = motion.euler[: len(rec)]

    def rms_deg(cal):
        _, acc, mag_in = cal.apply(rec) if cal is not None else (None, rec.body("acc"), rec.body("mag"))
        roll, pitch = accel_tilt(acc)
        keep = np.isfinite(mag_in[:, 0]) & (np.abs(truth_euler[:, 1]) < np.radians(70))  # roll from gravity is defined
        psi = tilt_compensated_heading(mag_in[keep], roll[keep], pitch[keep], declination())
        return np.degrees(np.sqrt(np.mean(wrap_angle(psi - truth_euler[keep, 2]) ** 2)))

    own = C.calibrate(recs["stationary"], recs["six-faces"], rec, source="virtual board")
    assert C.calibration_for(rec) == datasets.load("calibration_nucleo-iks02a1")
    assert rms_deg(own) < 2.0 and rms_deg(C.calibration_for(rec)) < 2.0 < 10.0 < rms_deg(None)


def test_saved_calibration_from_virtual_board_is_what_lab04_loads(lab00_recordings, tmp_path, monkeypatch):
    recs, _ = lab00_recordings
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    cal = C.calibrate(
        recs["stationary"], recs["six-faces"], recs["mag-rotations full"], source="lab 02/03: virtual board"
    )
    assert cal.save() == C.user_calibration_path(NUCLEO)
    loaded = C.load_calibration(NUCLEO)  # lab 04's call
    assert loaded == cal and loaded != C.Calibration.load(C.bundled_calibration_path(NUCLEO))
    assert C.calibration_for(recs["stationary"]) == cal  # a student's own recording gets the student's calibration
    gyr, acc, mag = loaded.apply(recs["stationary"])  # lab 04's apply: the rest now reads zero rate and −g
    n = len(gyr)
    assert np.all(np.abs(gyr.mean(axis=0)) < 4 * gyr.std(axis=0) / np.sqrt(n))
    np.testing.assert_allclose(acc.mean(axis=0), [0.0, 0.0, -G], atol=6 * acc.std(axis=0).max() / np.sqrt(n) + 5e-3)


def run_solution_on(name, data_source):
    """Execute solutions/<name> with the values ``data_source`` names set in its data-source cell (the others keep
    the cell's defaults); the stored outputs, errors included."""
    import nbformat
    from nbclient import NotebookClient

    path = KIT_ROOT / "solutions" / name
    nb = nbformat.read(path, as_version=4)
    cells = [c for c in nb.cells if c.source.startswith("# ▶ DATA SOURCE")]
    assert len(cells) == 1, f"{name}: expected one data-source cell"
    cells[0].source += "\n" + "\n".join(f"{k} = {v!r}" for k, v in data_source.items())
    NotebookClient(
        nb,
        timeout=HANG_GUARD_S,
        startup_timeout=HANG_GUARD_S,
        allow_errors=True,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    ).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    errors = [f"{o.ename}: {o.evalue}" for o in outputs if o.output_type == "error"]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    return errors, text


def test_labs_02_and_03_run_top_to_bottom_on_virtual_board_recordings(lab00_recordings, tmp_path, monkeypatch):
    """Lab 00's recordings through labs 02 and 03 (all of lab 03's own: turns, full rotations, headings): the saved
    calibration holds both labs' results, and lab 03 judges the headings by what the protocol asked for."""
    from kfkit.capture.guided import HEADINGS_DEG

    recs, _ = lab00_recordings
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))  # inherited by the notebooks' kernels
    mine = {k: str(recs[k].path) for k in recs}
    errors, text = run_solution_on(
        "02_bias_and_noise.ipynb", {"STATIONARY": mine["stationary"], "SIX_FACES": mine["six-faces"]}
    )
    assert errors == [] and "Warning" not in text
    assert f"saved to {C.user_calibration_path(NUCLEO)}" in text and "true bias" not in text
    assert "no minimum inside this record" in text  # a 5 s rest: the notebook says to record longer
    errors, text = run_solution_on(
        "03_mag_alignment_heading.ipynb",
        {"AXIS_TURNS": mine["axis-turns"], "MAG_ROTATIONS": mine["mag-rotations full"], "HEADINGS": mine["headings"]},
    )
    assert errors == [] and "Warning" not in text
    assert "D from the turns: [-1  1 -1]" in text  # the IIS2MDC's 180° about y, found in the student's turns
    assert "calibrated with its own rotations" not in text and f"saved to {C.user_calibration_path(NUCLEO)}" in text
    saved = C.load_calibration(NUCLEO)  # what lab 04 loads: lab 02's rest and faces, lab 03's iron, all from the board
    assert mine["stationary"] in saved.source and mine["mag-rotations full"] in saved.source
    rot = recs["mag-rotations full"]
    truth = unit_truth.body_truth(rot)
    mag = rot.body("mag")[np.isfinite(rot["mx"])]
    sd_h, _ = unit_truth.mag_fit_sd(mag, truth["mag_hard_iron"], truth["mag_S"], unit_truth.sample_sigma(rot, "mag"))
    assert np.all(np.abs(np.array(saved.mag_hard_iron) - truth["mag_hard_iron"]) < 4 * sd_h)
    np.testing.assert_allclose(saved.gyro_bias, rest_calibration.gyro_bias(recs["stationary"].body("gyr")), rtol=1e-6)
    # the headings: RMS over every sample against the prompted headings, within the 2° once calibrated
    level = re.search(
        r"level, heading RMS error against the prompted headings: uncalibrated +([0-9.]+)°, "
        r"calibrated ([0-9.]+)°",
        text,
    )
    assert level and float(level[2]) < 2.0 < 10.0 < float(level[1]), text
    # each rest's mean against the heading asked (flat in HEADINGS_DEG's order, tilted in reverse): within 4σ of the
    # heading noise averaged over the rest, σ_ψ = σ_m / B_h (σ_m per sample, B_h the horizontal field), and of the
    # fit's hard iron, sd_h / B_h; + 0.05° of the printed rounding
    heads = recs["headings"]
    rests = [p for p in heads.phases if p["label"] == "heading_flat"]
    n = min(int((np.isfinite(heads["mx"]) & (heads.t >= p["start"]) & (heads.t < p["end"])).sum()) for p in rests)
    B_h = np.hypot(*MAG_FIELD_LONDON[:2])
    bound = np.degrees(4 * unit_truth.sample_sigma(heads, "mag") / B_h / np.sqrt(n) + 4 * sd_h.max() / B_h) + 0.05
    for label, asked in (("flat", HEADINGS_DEG), ("tilted", HEADINGS_DEG[::-1])):
        line = re.search(rf"^  {label} +(.*)$", text, re.M)
        got = re.findall(r"(\d+)°: ([+-][0-9.]+)°", line[1]) if line else []
        assert [int(want) for want, _ in got] == list(asked), text
        assert all(abs(float(err)) < bound for _, err in got), (label, got, bound)


def test_lab03_with_own_rotations_and_the_bundled_headings(lab00_recordings, tmp_path, monkeypatch):
    """Own rotations, bundled turns and headings: the bundled headings keep the bundled board's iron (its own fit) and
    their truth; lab 00's quick rotations are too short, and lab 03 stops at the fit with what to record instead."""
    recs, _ = lab00_recordings
    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    errors, text = run_solution_on(
        "03_mag_alignment_heading.ipynb",
        {"AXIS_TURNS": None, "MAG_ROTATIONS": str(recs["mag-rotations full"].path), "HEADINGS": None},
    )
    assert errors == [] and "calibrated with its own rotations" in text and "against the truth" in text
    errors, _ = run_solution_on(
        "03_mag_alignment_heading.ipynb",
        {"AXIS_TURNS": None, "MAG_ROTATIONS": str(recs["mag-rotations"].path), "HEADINGS": None},
    )
    assert errors and errors[0].startswith("CalibrationError") and "every orientation" in errors[0]


# --- a student with only a phone -----------------------------------------------------------------------------------


def test_labs_02_and_03_run_top_to_bottom_on_phone_exports(tmp_path, monkeypatch):
    """A student with only a phone: three phyphox exports (no labels, no truth) through labs 02 and 03, and the
    calibration the two labs save is the phone's, holding both labs' results."""
    from kfkit.readers import load_any
    from kfkit.unit_errors import PHONE_UNIT

    monkeypatch.setenv("KFKIT_HOME", str(tmp_path / "home"))
    exports = {
        "rest": phone_export(tmp_path / "rest", motions.stationary(120.0, 100.0), seed=11),
        "faces": phone_export(tmp_path / "faces", calibration_motions.six_faces(rate_hz=200.0, seed=12), seed=13),
        "tumbling": phone_export(
            tmp_path / "tumbling", calibration_motions.mag_rotations(rate_hz=200.0, seed=14), seed=15
        ),
    }
    mine = {k: str(v) for k, v in exports.items()}
    errors, text = run_solution_on("02_bias_and_noise.ipynb", {"STATIONARY": mine["rest"], "SIX_FACES": mine["faces"]})
    assert errors == [] and "Warning" not in text
    assert "rests found: z_down" in text and f"saved to {C.user_calibration_path(PHONE)}" in text
    errors, text = run_solution_on(
        "03_mag_alignment_heading.ipynb", {"AXIS_TURNS": None, "MAG_ROTATIONS": mine["tumbling"], "HEADINGS": None}
    )
    assert errors == [] and "Warning" not in text and f"saved to {C.user_calibration_path(PHONE)}" in text
    saved = C.load_calibration(PHONE)
    assert saved.board == PHONE and mine["rest"] in saved.source and mine["tumbling"] in saved.source
    rest = load_any(exports["rest"])
    still = rest_calibration.label_rests(rest).phase("stationary")
    np.testing.assert_allclose(
        saved.gyro_bias, rest_calibration.gyro_bias(rest.body("gyr")[still]), rtol=1e-6
    )  # lab 02's, kept
    M = mount_matrix(rest.meta["mount"]["mag"])
    np.testing.assert_allclose(saved.mag_hard_iron, M @ PHONE_UNIT["mag_hard_iron"], atol=0.05)  # lab 03's fit
    np.testing.assert_allclose(saved.accel_bias, M @ PHONE_UNIT["accel_bias"], atol=3e-3)  # six faces
