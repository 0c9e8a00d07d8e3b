import nbformat
import pytest
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook, new_output

from kfkit.authoring import AuthoringError, make_labs, strip_solutions

FUNCTION_SOLUTION = """\
import math

def predict(x, dt):
    \"\"\"Constant-velocity prediction.\"\"\"
    ### BEGIN SOLUTION
    pos, vel = x
    return (pos + vel * dt, vel)
    ### END SOLUTION

def rms(values):
    values = list(values)
    ### BEGIN SOLUTION
    if values:
        return math.sqrt(sum(v * v for v in values) / len(values))
    return 0.0
    ### END SOLUTION
"""


def solution_notebook():
    nb = new_notebook(
        metadata={
            "kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"},
            "language_info": {"name": "python", "version": "3.11.7"},
            "widgets": {"application/vnd.jupyter.widget-state+json": {"state": {}}},
        }
    )
    code = new_code_cell(
        "import numpy as np\n### BEGIN SOLUTION\nK = 0.5\n### END SOLUTION\nprint(K)",
        execution_count=3,
        outputs=[new_output("stream", name="stdout", text="0.5\n")],
        metadata={
            "tags": ["kalman-gain"],
            "scrolled": True,
            "collapsed": False,
            "execution": {"iopub.status.idle": "2024-01-01T00:00:00Z"},
        },
    )
    functions = new_code_cell(FUNCTION_SOLUTION, execution_count=4)
    answer = new_markdown_cell(
        "**Question:** why does P shrink?\n\n### BEGIN SOLUTION\nEach update adds information.\n### END SOLUTION"
    )
    instructor = new_code_cell("assert K == 0.5", metadata={"tags": ["solution-only"]})
    nb.cells = [code, functions, answer, instructor]
    return nb


def write_nb(path, nb):
    path.parent.mkdir(parents=True, exist_ok=True)
    nbformat.write(nb, str(path))


def test_single_block_replaced_and_outputs_cleared():
    lab = strip_solutions(solution_notebook())
    cell = lab.cells[0]
    assert cell.source == "import numpy as np\n# YOUR CODE HERE\nraise NotImplementedError()\nprint(K)"
    assert cell.outputs == []
    assert cell.execution_count is None
    assert cell.metadata == {"tags": ["kalman-gain"]}
    assert lab.cells[1].execution_count is None


def test_nbval_markers_stay_in_the_solution_and_leave_the_lab():
    nb = solution_notebook()
    nb.cells[0].source = "# NBVAL_CHECK_OUTPUT\n" + nb.cells[0].source
    nb.cells[1].source = "  # NBVAL_IGNORE_OUTPUT\n" + nb.cells[1].source + "\n# the NBVAL_ word in a comment stays"
    lab = strip_solutions(nb)
    assert nb.cells[0].source.startswith("# NBVAL_CHECK_OUTPUT")
    assert lab.cells[0].source == "import numpy as np\n# YOUR CODE HERE\nraise NotImplementedError()\nprint(K)"
    assert lab.cells[1].source.startswith("import math") and "# NBVAL_IGNORE_OUTPUT" not in lab.cells[1].source
    assert lab.cells[1].source.endswith("# the NBVAL_ word in a comment stays")


def test_solution_notebook_is_not_modified():
    nb = solution_notebook()
    strip_solutions(nb)
    assert "K = 0.5" in nb.cells[0].source
    assert nb.cells[0].outputs
    assert "widgets" in nb.metadata


def test_indented_blocks_compile_and_raise():
    source = strip_solutions(solution_notebook()).cells[1].source
    assert "    # YOUR CODE HERE\n    raise NotImplementedError()\n" in source
    assert "    values = list(values)\n    # YOUR CODE HERE\n    raise NotImplementedError()" in source
    assert "sqrt" not in source and "pos + vel" not in source
    namespace = {}
    exec(compile(source, "lab-cell", "exec"), namespace)
    with pytest.raises(NotImplementedError):
        namespace["predict"]((0.0, 1.0), 0.1)
    for values in ([1.0], []):
        with pytest.raises(NotImplementedError):
            namespace["rms"](values)


@pytest.mark.parametrize(
    "function, line",
    [
        (
            "def rms(values):\n    if values:\n        ### BEGIN SOLUTION\n        return 1.0\n"
            "        ### END SOLUTION\n    return 0.0",
            4,
        ),
        (
            "def rms(values):\n    try:\n        ### BEGIN SOLUTION\n        return 1.0\n        ### END SOLUTION\n"
            "    except ValueError:\n        return 0.0",
            4,
        ),
        (
            "def rms(values):\n    if not values:\n        return 0.0\n    ### BEGIN SOLUTION\n    return 1.0\n"
            "    ### END SOLUTION",
            5,
        ),
        ("for k in range(3):\n    ### BEGIN SOLUTION\n    print(k)\n    ### END SOLUTION", 3),
    ],
)
def test_a_block_the_exercise_guard_would_not_take_for_a_stub_is_refused(function, line):
    """Inside an if or a try, or after a return, the stub left in the lab raises only for some input: the guard
    (which must never skip a finished function that raises NotImplementedError for some input) would let the
    cells that call it run, and Run All would stop there."""
    nb = new_notebook(cells=[new_markdown_cell("intro"), new_code_cell("%matplotlib inline\n" + function)])
    with pytest.raises(AuthoringError, match=rf"solutions/01_x\.ipynb: cell index 1, line {line + 1}: .*guard"):
        strip_solutions(nb, name="solutions/01_x.ipynb")


def test_markdown_answer_replaced():
    source = strip_solutions(solution_notebook()).cells[2].source
    assert source == "**Question:** why does P shrink?\n\nYOUR ANSWER HERE"


def test_solution_only_cells_dropped_and_ids_kept():
    nb = solution_notebook()
    lab = strip_solutions(nb)
    assert [cell.id for cell in lab.cells] == [cell.id for cell in nb.cells[:3]]
    assert all("solution-only" not in cell.metadata.get("tags", []) for cell in lab.cells)


def test_notebook_metadata_keeps_only_kernel_and_language():
    lab = strip_solutions(solution_notebook())
    assert set(lab.metadata) == {"kernelspec", "language_info"}


@pytest.mark.parametrize(
    "source, line, words",
    [
        ("x = 1\n### BEGIN SOLUTION\nx = 2", 2, "without"),
        ("x = 1\ny = 2\n### END SOLUTION", 3, "without"),
        ("### BEGIN SOLUTION\nx = 1\n    ### BEGIN SOLUTION\nx = 2\n### END SOLUTION", 3, "nested"),
    ],
)
def test_malformed_markers_name_cell_and_line(source, line, words):
    nb = new_notebook(cells=[new_markdown_cell("intro"), new_code_cell(source)])
    with pytest.raises(AuthoringError, match=rf"solutions/01_x\.ipynb: cell index 1, line {line}: .*{words}"):
        strip_solutions(nb, name="solutions/01_x.ipynb")


def test_malformed_markdown_markers_raise():
    nb = new_notebook(cells=[new_markdown_cell("### BEGIN SOLUTION\nanswer")])
    with pytest.raises(AuthoringError, match="cell index 0, line 1"):
        strip_solutions(nb)


def test_leftover_marker_is_refused():
    nb = new_notebook(cells=[new_code_cell("# BEGIN SOLUTION\nx = 1\n# END SOLUTION")])
    with pytest.raises(AuthoringError, match="BEGIN SOLUTION"):
        strip_solutions(nb)


def test_make_labs_writes_then_check_is_clean(tmp_path):
    write_nb(tmp_path / "solutions" / "01_gain.ipynb", solution_notebook())
    (tmp_path / "solutions" / ".ipynb_checkpoints").mkdir()
    write_nb(tmp_path / "solutions" / ".ipynb_checkpoints" / "01_gain-checkpoint.ipynb", solution_notebook())

    written = make_labs(tmp_path / "solutions", tmp_path / "labs")

    assert written == ["labs/01_gain.ipynb"]
    assert sorted(p.name for p in (tmp_path / "labs").iterdir()) == ["01_gain.ipynb"]
    text = (tmp_path / "labs" / "01_gain.ipynb").read_text(encoding="utf-8")
    assert "K = 0.5" not in text and "SOLUTION" not in text and '"outputs": []' in text
    assert text.endswith("}\n")
    assert make_labs(tmp_path / "solutions", tmp_path / "labs", check=True) == []
    assert make_labs(tmp_path / "solutions", tmp_path / "labs") == []


def test_edited_solution_makes_lab_stale(tmp_path):
    solution = tmp_path / "solutions" / "01_gain.ipynb"
    nb = solution_notebook()
    write_nb(solution, nb)
    make_labs(tmp_path / "solutions", tmp_path / "labs")
    nb.cells[0].source = nb.cells[0].source.replace("print(K)", "print(K * 2)")
    write_nb(solution, nb)
    before = (tmp_path / "labs" / "01_gain.ipynb").read_bytes()

    problems = make_labs(tmp_path / "solutions", tmp_path / "labs", check=True)

    assert problems == ["labs/01_gain.ipynb is stale: regenerate with 'kfkit make-labs'"]
    assert (tmp_path / "labs" / "01_gain.ipynb").read_bytes() == before
    assert make_labs(tmp_path / "solutions", tmp_path / "labs") == ["labs/01_gain.ipynb"]
    assert "print(K * 2)" in (tmp_path / "labs" / "01_gain.ipynb").read_text(encoding="utf-8")


def test_missing_and_orphan_labs(tmp_path):
    write_nb(tmp_path / "solutions" / "01_gain.ipynb", solution_notebook())
    write_nb(tmp_path / "labs" / "99_old.ipynb", new_notebook())
    (tmp_path / "labs" / "README.md").write_text("keep me")

    problems = make_labs(tmp_path / "solutions", tmp_path / "labs", check=True)

    assert problems == [
        "labs/01_gain.ipynb is missing",
        "labs/99_old.ipynb has no solution in solutions/",
    ]
    assert not (tmp_path / "labs" / "01_gain.ipynb").exists()
    assert make_labs(tmp_path / "solutions", tmp_path / "labs") == ["labs/01_gain.ipynb", "labs/99_old.ipynb"]
    assert sorted(p.name for p in (tmp_path / "labs").iterdir()) == ["01_gain.ipynb", "README.md"]


def test_output_is_byte_deterministic(tmp_path):
    write_nb(tmp_path / "solutions" / "01_gain.ipynb", solution_notebook())
    write_nb(tmp_path / "solutions" / "02_more.ipynb", solution_notebook())
    make_labs(tmp_path / "solutions", tmp_path / "a")
    make_labs(tmp_path / "solutions", tmp_path / "b")
    for name in ("01_gain.ipynb", "02_more.ipynb"):
        first = (tmp_path / "a" / name).read_bytes()
        assert first == (tmp_path / "b" / name).read_bytes()
        assert b"YOUR CODE HERE" in first


def predicting_notebook(reveal_text="The RMSE falls to <!-- run: the RMSE printed above -->0.33°<!-- /run -->."):
    nb = new_notebook()
    nb.cells = [
        new_markdown_cell("**Predict before you run.** Will the RMSE fall?", metadata={"tags": ["predict"]}),
        new_code_cell("print(0.33)", execution_count=1, outputs=[new_output("stream", name="stdout", text="0.33\n")]),
        new_markdown_cell(reveal_text, metadata={"tags": ["reveal"]}),
        new_markdown_cell("## Next"),
    ]
    return nb


def test_a_prediction_gets_an_answer_cell_and_its_explanation_is_folded_in_the_lab_only():
    nb = predicting_notebook()
    lab = strip_solutions(nb)
    assert [c.cell_type for c in lab.cells] == ["markdown", "markdown", "code", "markdown", "markdown"]
    mine = lab.cells[1]
    assert mine.source.startswith("**My prediction:**") and mine.metadata["tags"] == ["my-prediction"]
    assert mine.id == f"{nb.cells[0].id}-mine"
    reveal = lab.cells[3]
    assert reveal.metadata["jupyter"]["source_hidden"] is True
    lead, text = reveal.source.split("\n\n")
    assert lead.startswith("**Explanation**")  # what the fold bar previews: not the answer
    assert text == "The RMSE falls to the RMSE printed above."  # the run's number stays in the solution
    assert "jupyter" not in nb.cells[2].metadata and "0.33°" in nb.cells[2].source  # the solution keeps all open
    nbformat.validate(lab)  # the new cell's id is a valid nbformat 4.5 id
    assert strip_solutions(nb).cells[1].id == mine.id  # deterministic


@pytest.mark.parametrize("text", ["falls to <!-- run: the RMSE -->0.33°.", "falls to 0.33°<!-- /run -->."])
def test_an_unclosed_run_number_is_refused(text):
    with pytest.raises(AuthoringError, match="run"):
        strip_solutions(predicting_notebook(text))
