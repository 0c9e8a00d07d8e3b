"""The notebooks as CI sees them: every hand-out in labs/ runs to its end unfilled; labs/ are current (data/: test_datasets).

nbval validates solutions/ separately (pytest collects solutions/*.ipynb with --nbval-lax).
"""
import ast
import re

import nbformat
import pytest
from nbclient import NotebookClient

from kfkit.authoring import make_labs
from kfkit.paths import KIT_ROOT

LABS = sorted((KIT_ROOT / "labs").glob("*.ipynb"))


#: per hand-out, what cells that need no exercise print: with every exercise unfilled they must still run
MUST_RUN = {
    "00_setup_and_capture": ["recording from: ", "samples,   5.0 s, 0 bad, 0 dropped → 02_stationary.csv",
                             "files: Gyroscope.csv, Accelerometer.csv, Magnetometer.csv"],
    "01_roll_kf_1d": ["RMS rates while it turns", "columns: t, seq"],
    "02_bias_and_noise": ["first sample, accel counts", "samples at rest, 12.5 Hz"],
    "05_tilt_bias_kf": ["3600 samples at 100 Hz"],
    "06_sideslip_kf": ["units of the copied model: A[0,0] ok, A[0,1] WRONG, A[1,0] WRONG",
                       "low-speed guard active for 7% of the samples", "measured a_y ÷ the linear tyres' a_y"],
}
NOTE = re.compile(r"⏭  skipped: (.*)\. Run this cell again when that is done\.")
EXERCISE_CELL = ("this cell is an exercise", "an exercise cell not filled in yet")


def code(cell) -> str:
    """A cell's Python, IPython's % and ! lines left out."""
    return "\n".join(line for line in cell.source.splitlines() if not line.lstrip().startswith(("%", "!")))


def stubs(nb) -> set[str]:
    """The functions a hand-out leaves to the student: those whose body raises NotImplementedError."""
    return {node.name for cell in nb.cells if cell.cell_type == "code"
            for node in ast.walk(ast.parse(code(cell))) if isinstance(node, ast.FunctionDef)
            and any(isinstance(n, ast.Name) and n.id == "NotImplementedError" for n in ast.walk(node))}


def printed(cell) -> str:
    return "".join(o.get("text", "") for o in cell.get("outputs", []) if o.output_type == "stream")


@pytest.mark.parametrize("path", LABS, ids=[p.stem for p in LABS])
def test_handout_runs_to_its_end_with_its_exercises_unfilled(path):
    """Run All on a hand-out as handed out (issue 18): no error anywhere (nbclient raises on the first, naming the
    cell); each cell the exercise guard skips names one of the hand-out's own stubs (or is an exercise cell); the
    cells that need no exercise run; every check says 'not attempted yet' and none passes; no warning."""
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, allow_errors=False, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    left = stubs(nb)
    notes = [(i, m) for i, c in enumerate(nb.cells) if c.cell_type == "code" for m in NOTE.findall(printed(c))]
    assert notes, f"{path.name}: nothing was skipped in a hand-out with stubs: is the exercise guard loaded?"
    for i, why in notes:
        named = set(re.findall(r"(\w+) \(not written yet\)", why))
        assert (named and named <= left) or (not named and why.endswith(EXERCISE_CELL)), (
            f"cell {i}: the note names {sorted(named)}, not one of the stubs {sorted(left)}: {why}")
    everything = "".join(printed(c) for c in nb.cells if c.cell_type == "code")
    for text in MUST_RUN.get(path.stem, []):
        assert text in everything, f"{path.name}: a cell that needs no exercise did not run: {text!r} missing"
    assert "not attempted yet" in everything, "checkpoint cells should say 'not attempted yet' on an unfilled lab"
    assert "✅" not in everything, "a checkpoint passed on a lab with no answers: a check that cannot fail"
    warnings = [printed(c)[:200] for c in nb.cells if c.cell_type == "code"
                for o in c.get("outputs", []) if o.output_type == "stream" and o.name == "stderr" and "Warning" in o.text]
    assert warnings == []


def test_labs_are_generated_from_current_solutions():
    assert make_labs(KIT_ROOT / "solutions", KIT_ROOT / "labs", check=True) == []


def test_solution_notebooks_have_no_warnings_or_errors():
    for path in sorted((KIT_ROOT / "solutions").glob("*.ipynb")):
        nb = nbformat.read(path, as_version=4)
        for i, cell in enumerate(nb.cells):
            for out in cell.get("outputs", []):
                assert out.output_type != "error", f"{path.name} cell {i} stored an error"
                assert not (out.output_type == "stream" and out.name == "stderr"), f"{path.name} cell {i} wrote to stderr: {out.text[:200]}"
