"""Lab 05's hand-out runs to its end half done (issue 18): up to run_kf, without tune, the final and question 5's
function (unfilled:
``tests/test_notebooks.py``, for every lab).

Oracles: the hand-out's own stubs (every skip note must name one of them, the one the cell truly waits for) and the
solution notebook's stored outputs, which nbval validates (every cell the half-done hand-out runs prints exactly them).
"""

import re

import nbformat
import pytest
from handouts import NEEDS, NOTE, execute, half_done, printed, stubs

from kfkit.authoring import MY_PREDICTION_TAG
from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

SOLUTION = KIT_ROOT / "solutions" / "05_tilt_bias_kf.ipynb"
LAB = KIT_ROOT / "labs" / "05_tilt_bias_kf.ipynb"
WRITTEN = {"to_body", "accel_tilt", "kf_predict", "kf_update", "run_kf"}


@pytest.fixture(scope="module")
def partly():
    nb = half_done(LAB, WRITTEN)
    return stubs(nb), execute(nb)


def skip_notes(nb) -> dict[int, str]:
    notes = {}
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "code":
            found = NOTE.findall(printed(cell))
            if found:
                notes[i] = found[0]
    return notes


def test_every_skip_note_names_an_unwritten_function(partly):
    left, nb = partly
    notes = skip_notes(nb)
    assert notes, "nothing was skipped in a hand-out with stubs: the guard is not loaded"
    for i, why in notes.items():
        named = NEEDS.findall(why)
        assert named and set(named) <= left, (
            f"cell {i}: the note names {named}, not one of the stubs {sorted(left)}: {why}"
        )


def test_half_done_hand_out_prints_what_the_solution_printed_and_skips_only_what_needs_tune(partly):
    left, nb = partly
    assert left == {"tune", "estimate_tilt", "q_for_time_constant"}
    solution = nbformat.read(SOLUTION, as_version=4)
    # the student's "My prediction" cells aside, the hand-out has the solution's cells
    nb = nbformat.from_dict(
        dict(nb, cells=[c for c in nb.cells if MY_PREDICTION_TAG not in c.metadata.get("tags", [])])
    )
    assert [c.cell_type for c in nb.cells] == [c.cell_type for c in solution.cells]
    notes = skip_notes(nb)
    not_attempted = [i for i, c in enumerate(nb.cells) if c.cell_type == "code" and "not attempted yet" in printed(c)]
    assert [re.findall(r"05\.\w+", nb.cells[i].source) for i in not_attempted] == [
        ["05.tune"],
        ["05.final"],
        ["05.time_constant"],
    ]
    for i, (ran, stored) in enumerate(zip(nb.cells, solution.cells)):
        if ran.cell_type == "code" and i not in notes and i not in not_attempted:
            assert printed(ran) == printed(stored), f"cell {i} printed something else than the solution"
    skipped_sources = " ".join(nb.cells[i].source for i in notes)
    assert "single_axis_stretch" not in skipped_sources and "left_out_rates(w_r" not in skipped_sources, (
        "section 12's real IMU needs no tune: it must run"
    )
    assert any("c into the model" in printed(c) for c in nb.cells), "section 12.2's table needs no tune: it must print"
