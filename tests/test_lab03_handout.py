"""Lab 03's hand-out as a student meets it (issue 18), in one Jupyter kernel: Run All goes to the end with the
exercises unfilled, and every skipped cell says which of the lab's exercises it waits for; then the student fills
the exercises in, one at a time in the lab's order, and re-runs the cells whose notes named it. The oracle is the
solution notebook: what ran before anything was filled in, and everything at the end, prints what it prints."""

import ast
import re

import nbformat
import pytest
from handouts import printed
from nbclient import NotebookClient
from waiting import HANG_GUARD_S

from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

LAB = KIT_ROOT / "labs" / "03_mag_alignment_heading.ipynb"
SOLUTION = KIT_ROOT / "solutions" / "03_mag_alignment_heading.ipynb"
SKIPPED = "⏭  skipped:"
NOT_ATTEMPTED = "not attempted yet"
WAITS_FOR = re.compile(r"(\w+) (?:\(not written yet\)|still raises NotImplementedError)")


def waits_for(cell) -> str | None:
    """The exercise a skipped cell's note (or a check's 'not attempted') names, else None (the cell ran)."""
    text = printed(cell)
    if not (text.startswith(SKIPPED) or NOT_ATTEMPTED in text):
        return None
    found = WAITS_FOR.findall(text)
    assert found, f"a note that names no exercise: {text!r}"
    return found[-1]  # "needs run_all, which calls kf_update (not written yet)": the stub is the last name


def test_run_all_reaches_the_end_then_filling_each_exercise_in_gives_the_solutions_output():
    lab, solution = nbformat.read(LAB, as_version=4), nbformat.read(SOLUTION, as_version=4)
    mine = [c.get("id") for c in lab.cells if "my-prediction" not in c.metadata.get("tags", [])]
    assert mine == [c.get("id") for c in solution.cells], "labs/03 is stale: make-labs"
    by_id = {c.get("id"): c for c in solution.cells}
    solution.cells = [by_id.get(c.get("id"), c) for c in lab.cells]  # index i: the lab's cell and the solution's
    code = [i for i, c in enumerate(lab.cells) if c.cell_type == "code"]
    stubs = {
        i: next(n.name for n in ast.parse(lab.cells[i].source).body if isinstance(n, ast.FunctionDef))
        for i in code
        if "raise NotImplementedError()" in lab.cells[i].source
    }
    assert sorted(stubs.values()) == [
        "alignment_from_turns",
        "counts_to_ut",
        "flat_heading",
        "hard_iron_budget_ut",
        "mag_calibration",
        "tilt_heading",
    ]
    client = NotebookClient(
        lab,
        timeout=HANG_GUARD_S,
        startup_timeout=HANG_GUARD_S,
        allow_errors=False,
        kernel_name="python3",
        resources={"metadata": {"path": str(LAB.parent)}},
    )
    with client.setup_kernel():
        for i in code:  # Run All on the hand-out: any error raises CellExecutionError
            client.execute_cell(lab.cells[i], i)

        ran = []
        for i in code:
            cell, want = lab.cells[i], printed(solution.cells[i])
            assert not any(o.get("name") == "stderr" for o in cell.outputs), f"cell {i} wrote to stderr"
            exercise = waits_for(cell)
            if exercise is None:
                assert printed(cell) == want, f"cell {i} ran on the hand-out but printed other than the solution"
                ran.append(i)
            else:
                assert exercise in stubs.values(), f"cell {i} waits for {exercise}, not one of this lab's exercises"
        everything_ran = "".join(printed(lab.cells[i]) for i in ran)
        for needs_no_exercise in ("sphere coverage", "turn about x", "the magnet is on from"):
            assert needs_no_exercise in everything_ran  # the kit's own fit check, BROAD's turns, the magnet window

        for k, name in stubs.items():  # fill each exercise in, then re-run what its notes named
            lab.cells[k].source = solution.cells[k].source
            client.execute_cell(lab.cells[k], k)
            for i in code:
                if waits_for(lab.cells[i]) == name:
                    client.execute_cell(lab.cells[i], i)

    differ = [i for i in code if printed(lab.cells[i]) != printed(solution.cells[i])]
    assert differ == [], f"after filling every exercise in, cells {differ} print other than the solution"
    figures = [
        sum("image/png" in o.get("data", {}) for o in nb.cells[i].outputs) for nb in (lab, solution) for i in code
    ]
    assert figures[: len(code)] == figures[len(code) :]


def test_room_to_think_questions_at_the_end_a_prediction_before_the_tilted_headings():
    """One Questions section, the lab's last (after its heading cell only the numeric question's exercise, its check
    and its print), each question naming its section and one model answer each (every figure explained in the very
    next cell: ``tests/test_solutions_layout.py``); the prompt to predict comes before anything shows how the tilted
    board's headings come out (the table before the key figure prints its errors)."""
    cells = nbformat.read(SOLUTION, as_version=4).cells
    questions_at = [
        i for i, c in enumerate(cells) if c.cell_type == "markdown" and "## " in c.source and "Questions" in c.source
    ]
    assert questions_at == [len(cells) - 5]
    assert "hard_iron_budget_ut" in cells[-3].source and "03.hard_iron_budget" in cells[-2].source
    asked, answers = cells[questions_at[0]].source.split("### BEGIN SOLUTION")
    questions = re.findall(r"^\d+\. (.*)", asked, flags=re.M)
    assert re.match(r"## \d+\. Questions\n", asked) and questions and all(q.startswith("*Section") for q in questions)
    assert len(re.findall(r"^\d+\. ", answers, flags=re.M)) == len(questions)
    table = next(i for i, c in enumerate(cells) if c.cell_type == "code" and "tilted rests (roll" in c.source)
    figure = next(i for i, c in enumerate(cells) if c.cell_type == "code" and "Tilted rests:" in c.source)
    assert cells[table - 1].source.startswith("**Predict before you run:**") and table + 1 == figure
