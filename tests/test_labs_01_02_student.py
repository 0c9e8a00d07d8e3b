"""Labs 01 and 02 as a student meets them (issue 18).

Run All on a hand-out with every exercise unfilled reaches the end with no error: each cell it skips names an
exercise of that lab, and the cells that need none (the data, the raw figures, lab 01's real IMU) run. The text
leaves room to think: one Questions section at the end whose questions name their section, every figure explained
in the very next cell, and a prompt to predict before the key figure (lab 01's consistency, lab 02's Allan curve).
"""
import ast
import re

import nbformat
import pytest
from nbclient import NotebookClient

from kfkit.exercise_guard import _loaded_names
from kfkit.paths import KIT_ROOT

LABS = {
    "01_roll_kf_1d": {"key_figure": "plots.consistency(", "ran": ["RMS rates while it turns", "columns: t, seq"]},
    "02_bias_and_noise": {"key_figure": "plots.allan(axes[0], taus, adev_g",
                          "ran": ["first sample, accel counts", "samples at rest, 12.5 Hz"]},
}


def read(folder, name):
    return nbformat.read(KIT_ROOT / folder / f"{name}.ipynb", as_version=4)


def code(cell):
    """A cell's Python, IPython's % and ! lines left out."""
    return "\n".join(line for line in cell.source.splitlines() if not line.lstrip().startswith(("%", "!")))


def exercises(lab):
    """The hand-out's stub functions: the names a skip note may give as 'not written yet'."""
    return {node.name for cell in lab.cells if cell.cell_type == "code"
            for node in ast.walk(ast.parse(code(cell))) if isinstance(node, ast.FunctionDef)
            and any(isinstance(n, ast.Name) and n.id == "NotImplementedError" for n in ast.walk(node))}


def printed(cell):
    return "".join(o.get("text", "") for o in cell.get("outputs", []) if o.output_type == "stream")


@pytest.mark.parametrize("name", LABS)
def test_the_solution_loads_the_exercise_guard_right_after_matplotlib(name):
    first = next(c for c in read("solutions", name).cells if c.cell_type == "code")
    lines = first.source.splitlines()
    assert lines[:2] == ["%matplotlib inline", "%load_ext kfkit.exercise_guard"]
    assert lines[2].startswith("#") and "skipped" in lines[2]         # says what it does, for the student


@pytest.mark.parametrize("name", LABS)
def test_no_cell_hides_a_call_that_reaches_an_exercise_from_the_guard(name):
    """The guard looks a cell's names up in the notebook before the cell runs, and does not look inside lambdas: a
    function made in the same cell is not there yet, and a lambda handed to a widget is called at once, so either
    would reach an exercise's NotImplementedError unseen when that exercise alone is unfilled."""
    lab = read("labs", name)
    reaches = set(exercises(lab))
    for index, cell in enumerate(lab.cells):
        if cell.cell_type != "code":
            continue
        tree = ast.parse(code(cell))
        defs = [n for n in tree.body if isinstance(n, ast.FunctionDef)]
        made_here = set()
        for d in defs:
            if {n.id for n in ast.walk(d) if isinstance(n, ast.Name)} & reaches:
                made_here.add(d.name)
        reaches |= made_here
        calls = {name for node in tree.body if not isinstance(node, ast.FunctionDef) for name in _loaded_names(node)}
        assert not calls & made_here, f"cell {index} defines and calls {calls & made_here}: split it in two"
        in_lambdas = {n.id for node in tree.body if not isinstance(node, ast.FunctionDef)
                      for lam in ast.walk(node) if isinstance(lam, ast.Lambda)
                      for n in ast.walk(lam.body) if isinstance(n, ast.Name)}
        assert not in_lambdas & reaches, f"cell {index} hides {in_lambdas & reaches} in a lambda: give it a name in a cell before"


@pytest.mark.parametrize("name", LABS)
def test_the_hand_out_runs_to_its_end_with_its_exercises_unfilled(name):
    lab = read("labs", name)
    NotebookClient(lab, timeout=300, allow_errors=False, kernel_name="python3",
                   resources={"metadata": {"path": str(KIT_ROOT / "labs")}}).execute()   # raises on any error
    stubs = exercises(lab)
    notes = [printed(c) for c in lab.cells if c.cell_type == "code" and "skipped" in printed(c)]
    assert len(notes) >= 10
    for note in notes:
        named = re.findall(r"(\w+) \(not written yet\)", note)
        assert named and set(named) <= stubs, note
        assert "Run this cell again when that is done" in note
    everything = "".join(printed(c) for c in lab.cells if c.cell_type == "code")
    for text in LABS[name]["ran"]:
        assert text in everything, f"a cell that needs no exercise did not run: {text!r} missing"
    for cell in lab.cells:
        for out in cell.get("outputs", []):
            assert not (out.output_type == "stream" and out.name == "stderr" and "Warning" in out.text), out.text


@pytest.mark.parametrize("name", LABS)
def test_the_questions_are_one_section_at_the_end_each_naming_its_section(name):
    cells = read("solutions", name).cells
    with_questions = [i for i, c in enumerate(cells) if c.cell_type == "markdown" and "Questions" in c.source]
    assert with_questions == [len(cells) - 1], "one Questions section, the lab's last cell"
    text = cells[-1].source
    assert re.match(r"## \d+\. Questions\n", text)
    asked, answers = text.split("### BEGIN SOLUTION")
    questions = re.findall(r"^\d+\. (.*)", asked, flags=re.M)
    assert len(questions) >= 4 and all(q.startswith("*Section") for q in questions), questions
    assert len(re.findall(r"^\d+\. ", answers, flags=re.M)) == len(questions), "one model answer per question"


@pytest.mark.parametrize("name", LABS)
def test_every_figure_is_explained_in_the_very_next_cell(name):
    cells = read("solutions", name).cells
    for i, cell in enumerate(cells):
        if any("image/png" in o.get("data", {}) for o in cell.get("outputs", [])):
            assert i + 1 < len(cells) and cells[i + 1].cell_type == "markdown", f"the figure of cell {i} stands unexplained"


@pytest.mark.parametrize("name", LABS)
def test_the_key_figure_comes_after_a_prompt_to_predict_it(name):
    cells = read("solutions", name).cells
    index = next(i for i, c in enumerate(cells) if c.cell_type == "code" and LABS[name]["key_figure"] in c.source)
    assert any("image/png" in o.get("data", {}) for o in cells[index].outputs)
    before = cells[index - 1]
    assert before.cell_type == "markdown" and before.source.startswith("**Predict before you run:**")
    assert "?" in before.source
