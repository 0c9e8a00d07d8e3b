"""The notebooks as CI sees them: every hand-out in labs/ runs to its end unfilled; labs/ are current
(data/: test_datasets).

Each hand-out runs once per session (:func:`ran`); the tests of one lab's hand-out that read that run live here too,
so they share it. nbval validates solutions/ separately (pytest collects solutions/*.ipynb with --nbval-lax).

Oracles: the hand-out's own stubs (every skip note must name one of them) and the solution notebook's stored outputs,
which nbval validates (a cell that runs in the hand-out must print exactly them).
"""

import functools

import nbformat
import pytest
from handouts import NEEDS, NOTE, execute, printed, stubs

from kfkit.authoring import make_labs
from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

LABS = sorted((KIT_ROOT / "labs").glob("*.ipynb"))


#: per hand-out, what cells that need no exercise print: with every exercise unfilled they must still run
MUST_RUN = {
    "00_setup_and_capture": [
        "recording from: ",
        "samples,   5.0 s, 0 bad, 0 dropped → 02_stationary.csv",
        "files: Gyroscope.csv, Accelerometer.csv, Magnetometer.csv",
    ],
    "01_roll_kf_1d": ["RMS rates while it turns", "columns: t, seq"],
    "02_bias_and_noise": ["first sample, accel counts", "samples at rest, 12.5 Hz"],
    "05_tilt_bias_kf": ["3600 samples at 100 Hz"],
    "06_sideslip_kf": [
        "units of the copied model: A[0,0] ok, A[0,1] WRONG, A[1,0] WRONG",
        "low-speed guard active for 7% of the samples",
        "measured a_y ÷ the linear tyres' a_y",
    ],
}
EXERCISE_CELL = ("this cell is an exercise", "an exercise cell not filled in yet")


@functools.cache
def ran(path) -> nbformat.NotebookNode:
    """The hand-out at ``path`` after Run All as handed out."""
    return execute(nbformat.read(path, as_version=4))


@pytest.mark.parametrize("path", LABS, ids=[p.stem for p in LABS])
def test_handout_runs_to_its_end_with_its_exercises_unfilled(path):
    """Run All on a hand-out as handed out (issue 18): no error anywhere; each cell the exercise guard skips names
    one of the hand-out's own stubs (or is an exercise cell); the cells that need no exercise run; every check says
    'not attempted yet' and none passes; no warning."""
    nb = ran(path)
    left = stubs(nb)
    notes = [(i, m) for i, c in enumerate(nb.cells) if c.cell_type == "code" for m in NOTE.findall(printed(c))]
    assert notes, f"{path.name}: nothing was skipped in a hand-out with stubs: is the exercise guard loaded?"
    for i, why in notes:
        named = set(NEEDS.findall(why))
        assert (named and named <= left) or (not named and why.endswith(EXERCISE_CELL)), (
            f"cell {i}: the note names {sorted(named)}, not one of the stubs {sorted(left)}: {why}"
        )
    everything = "".join(printed(c) for c in nb.cells if c.cell_type == "code")
    for text in MUST_RUN.get(path.stem, []):
        assert text in everything, f"{path.name}: a cell that needs no exercise did not run: {text!r} missing"
    assert "not attempted yet" in everything, "checkpoint cells should say 'not attempted yet' on an unfilled lab"
    assert "✅" not in everything, "a checkpoint passed on a lab with no answers: a check that cannot fail"
    warnings = [
        printed(c)[:200]
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.output_type == "stream" and o.name == "stderr" and "Warning" in o.text
    ]
    assert warnings == []


def test_labs_are_generated_from_current_solutions():
    assert make_labs(KIT_ROOT / "solutions", KIT_ROOT / "labs", check=True) == []


def test_solution_notebooks_have_no_warnings_or_errors():
    for path in sorted((KIT_ROOT / "solutions").glob("*.ipynb")):
        nb = nbformat.read(path, as_version=4)
        for i, cell in enumerate(nb.cells):
            for out in cell.get("outputs", []):
                assert out.output_type != "error", f"{path.name} cell {i} stored an error"
                assert not (out.output_type == "stream" and out.name == "stderr"), (
                    f"{path.name} cell {i} wrote to stderr: {out.text[:200]}"
                )


LAB04 = KIT_ROOT / "labs" / "04_ekf_attitude.ipynb"


def test_lab04_handout_names_its_exercises_in_every_skip_note():
    """Its five exercise functions are stubs, and every skip note names only them."""
    exercises = stubs(nbformat.read(LAB04, as_version=4))
    assert {"euler_rates", "ekf_predict", "measurement", "jacobian", "run_ekf"} <= exercises
    notes = [why for cell in ran(LAB04).cells if cell.cell_type == "code" for why in NOTE.findall(printed(cell))]
    assert notes, "nothing was skipped: are the stubs still stubs?"
    for why in notes:
        named = NEEDS.findall(why)
        assert named and set(named) <= exercises, why


def test_lab04_handout_cells_that_need_no_exercise_print_what_the_solution_prints():
    """A cell the guard lets run prints exactly what the solution's (nbval-checked) cell prints."""
    handout, solution = ran(LAB04), nbformat.read(KIT_ROOT / "solutions" / LAB04.name, as_version=4)
    mine_cells = [c for c in handout.cells if "my-prediction" not in c.metadata.get("tags", [])]  # the student's own
    assert len(solution.cells) == len(mine_cells)
    compared = 0
    for mine, want in zip(mine_cells, solution.cells):
        text = printed(mine)
        if mine.cell_type != "code" or NOTE.search(text) or "check(" in mine.source:
            continue
        if "# NBVAL_CHECK_OUTPUT" in want.source:
            assert text == printed(want), mine.source[:200]
            compared += 1
    assert compared >= 5
    # what the guard must let through: the σ_a sweep (it needs rmse_deg, not the EKF) and kfkit's runs on BROAD
    sweep = next(c for c in handout.cells if c.cell_type == "code" and c.source.startswith("sigmas_a = "))
    drawn = next(c for c in handout.cells if c.cell_type == "code" and "plots.sweep(" in c.source)
    assert "best σ_a" in printed(sweep) and any(o.output_type == "display_data" for o in drawn.outputs)
    broad = next(c for c in handout.cells if c.cell_type == "code" and "real_runs, mekf_real = {}, {}" in c.source)
    assert not NOTE.search(printed(broad))
