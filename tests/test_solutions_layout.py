"""The authoring rule every lab keeps (issue 18): each figure is explained in the very next cell, so a student reads
what a figure shows right under it, not after another code cell's printout.

Read from the solutions' stored outputs (they are what nbval validates and what the hand-outs are made from).
"""

import ast
import re

import nbformat
import pytest

from kfkit.paths import KIT_ROOT

SOLUTIONS = sorted((KIT_ROOT / "solutions").glob("[0-9][0-9]*_*.ipynb"))


def draws_a_figure(cell):
    return cell.cell_type == "code" and any("image/png" in o.get("data", {}) for o in cell.outputs)


def unexplained_figures(cells):
    """Indices of the cells whose figure is not followed by a markdown cell of text (a heading starts a new topic)."""
    return [
        i
        for i, cell in enumerate(cells)
        if draws_a_figure(cell)
        and not (
            i + 1 < len(cells) and cells[i + 1].cell_type == "markdown" and not cells[i + 1].source.startswith("#")
        )
    ]


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.stem)
def test_every_figure_is_explained_in_the_very_next_cell(path):
    cells = nbformat.read(path, as_version=4).cells
    assert any(map(draws_a_figure, cells)), "a solution stored without its figures: re-run it"
    assert unexplained_figures(cells) == [], f"{path.name}: these cells' figures are not explained right below them"


def test_a_figure_followed_by_a_printout_a_heading_or_nothing_is_unexplained():
    figure = nbformat.v4.new_code_cell(
        "plot()", outputs=[nbformat.v4.new_output("display_data", {"image/png": "iVBOR"})]
    )
    printout, heading, text = (
        nbformat.v4.new_code_cell("print(1)"),
        nbformat.v4.new_markdown_cell("## 2. Next"),
        nbformat.v4.new_markdown_cell("The curve falls because …"),
    )
    assert unexplained_figures([figure, text, figure, printout, text, figure, heading, figure]) == [2, 5, 7]


# --- predict, run, then read (issue 26 §1) ------------------------------------------------------------------------
NUMBER = re.compile(r"(?<![\w.])[−-]?\d+(?:[.,]\d+)?(?![\w])")


def tagged(cell, tag):
    return tag in cell.metadata.get("tags", [])


def unrevealed_predictions(cells):
    """Indices of the prompts (tagged 'predict', or saying 'Predict before you run') not answered by a cell tagged
    'reveal' after at least one code cell and before the next heading."""
    bad = []
    for i, cell in enumerate(cells):
        if cell.cell_type != "markdown" or not (tagged(cell, "predict") or "Predict before you run" in cell.source):
            continue
        if not tagged(cell, "predict"):
            bad.append(i)
            continue
        ran, answered = False, False
        for later in cells[i + 1 :]:
            if later.cell_type == "markdown" and later.source.startswith("#"):
                break
            ran = ran or later.cell_type == "code"
            if ran and tagged(later, "reveal"):
                answered = True
                break
        if not answered:
            bad.append(i)
    return bad


def numbers_given_away(solution_cells, lab_cells):
    """Numbers a hand-out's folded explanation quotes that the solution's printed outputs above it show (the bundled
    run's results, which a student has not produced yet): {lab cell index: numbers}. Small integers (0–9) are
    counts and orders, not results."""
    printed, found = "", {}
    by_id = {c.id: c for c in lab_cells}
    for cell in solution_cells:
        if cell.cell_type == "code":
            printed += "".join(o.get("text", "") for o in cell.outputs if o.get("output_type") == "stream")
        elif tagged(cell, "reveal") and cell.id in by_id:
            seen = set(NUMBER.findall(printed))
            quoted = {n for n in NUMBER.findall(by_id[cell.id].source) if n in seen and not re.fullmatch(r"\d", n)}
            if quoted:
                found[list(by_id).index(cell.id)] = sorted(quoted)
    return found


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.stem)
def test_every_prediction_is_run_then_revealed_and_the_hand_out_gives_no_number_away(path):
    solution = nbformat.read(path, as_version=4).cells
    lab = nbformat.read(KIT_ROOT / "labs" / path.name, as_version=4).cells
    assert unrevealed_predictions(solution) == [], (
        f"{path.name}: prompts without a reveal cell after the cells they ask about"
    )
    assert numbers_given_away(solution, lab) == {}, f"{path.name}: folded explanations quote the bundled run's numbers"
    for cell in lab:
        if tagged(cell, "reveal"):
            assert cell.metadata["jupyter"]["source_hidden"] is True


def test_the_prediction_rules_see_a_missing_reveal_and_a_number_given_away():
    md, code = nbformat.v4.new_markdown_cell, nbformat.v4.new_code_cell
    prompt = md("**Predict before you run.** Will it fall?", metadata={"tags": ["predict"]})
    run = code("print(0.33)", outputs=[nbformat.v4.new_output("stream", name="stdout", text="rmse 0.33\n")])
    reveal = md("It falls to 0.33 in 3 steps.", metadata={"tags": ["reveal"]})
    assert unrevealed_predictions([prompt, run, reveal]) == []
    assert unrevealed_predictions([prompt, reveal, run]) == [0]  # revealed before the run
    assert unrevealed_predictions([md("Predict before you run: …"), run, reveal]) == [0]  # untagged prompt
    assert numbers_given_away([prompt, run, reveal], [prompt, code("print(0.33)"), reveal]) == {2: ["0.33"]}


# --- each lab says how long it takes (issue 26 §9) ----------------------------------------------------------------
READING_WPM, MINUTES_PER_EXERCISE, MINUTES_PER_CODE_CELL = 200, 10, 1
STATED = re.compile(r"\*\*Time:\*\*[^\n]*?core path[^\n]*?(\d+)\s*min", re.IGNORECASE)


def core_minutes(cells) -> float:
    """A student's time on a lab's core path: its markdown read at 200 words a minute, 10 minutes per exercise cell
    (a function to write and check) and a minute per other code cell (run it, look at what it shows). Sections whose
    heading says "(optional)" are left out, down to the next heading of the same or a higher level. The rule is
    calibrated on lab 04 as it was: 169 minutes by it, where a student who did it estimated 2.5–3 hours."""
    minutes, optional_level = 0.0, None
    for cell in cells:
        heading = re.match(r"(#+)\s", cell.source) if cell.cell_type == "markdown" else None
        if heading:
            level = len(heading[1])
            if optional_level is not None and level <= optional_level:
                optional_level = None
            if optional_level is None and "(optional)" in cell.source.splitlines()[0].lower():
                optional_level = level
        if optional_level is not None:
            continue
        if cell.cell_type == "markdown":
            minutes += len(re.findall(r"\w+", cell.source)) / READING_WPM
        elif cell.cell_type == "code":
            minutes += MINUTES_PER_EXERCISE if "### BEGIN SOLUTION" in cell.source else MINUTES_PER_CODE_CELL
    return minutes


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.stem)
def test_each_lab_states_its_core_time_and_keeps_to_two_hours(path):
    cells = nbformat.read(path, as_version=4).cells
    stated = STATED.search(cells[0].source)
    assert stated, f"{path.name}: the first cell must say '**Time:** … core path … N min' (and what is optional)"
    estimate = core_minutes(cells)
    assert estimate <= int(stated[1]) <= 120, f"{path.name}: states {stated[1]} min, the core path needs {estimate:.0f}"
    assert int(stated[1]) <= 1.5 * estimate + 10, f"{path.name}: states {stated[1]} min for {estimate:.0f} min of work"


def test_core_minutes_leaves_out_optional_sections():
    md, code = nbformat.v4.new_markdown_cell, nbformat.v4.new_code_cell
    cells = [
        md("# Lab\n" + "word " * 400),
        code("### BEGIN SOLUTION\nx = 1\n### END SOLUTION"),
        code("plot()"),
        md("## 9. Extra (optional)\n" + "word " * 2000),
        code("### BEGIN SOLUTION\n### END SOLUTION"),
        md("### 9.1 deeper"),
        md("## 10. Questions"),
    ]
    assert core_minutes(cells) == pytest.approx((1 + 400 + 2) / 200 + 10 + 1)  # "Lab", 400 words, "10 Questions"


# --- a lab notebook calls lab support, not the grader's checkpoints (issue 27 §3) ----------------------------------
def checkpoint_imports(cells) -> set[str]:
    """What a notebook's code imports from kfkit.checkpoints (modules or names), beyond ``check``."""
    found = set()
    for cell in cells:
        if cell.cell_type != "code":
            continue
        try:
            tree = ast.parse(re.sub(r"(?m)^\s*[%!].*$", "", cell.source))
        except SyntaxError:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("kfkit.checkpoints"):
                found |= {f"{node.module}.{a.name}" for a in node.names} - {"kfkit.checkpoints.check"}
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names if a.name.startswith("kfkit.checkpoints")}
    return found


@pytest.mark.parametrize("path", SOLUTIONS, ids=lambda p: p.stem)
def test_a_lab_imports_only_check_from_the_checkpoints(path):
    assert checkpoint_imports(nbformat.read(path, as_version=4).cells) == set(), (
        f"{path.name}: a lab's data preparation and truth helpers live in kfkit.labs, not kfkit.checkpoints"
    )
