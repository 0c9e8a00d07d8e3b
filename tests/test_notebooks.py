"""The notebooks as CI sees them: labs/ run with only exercise-stub errors; labs/ are current (data/: test_datasets).

nbval validates solutions/ separately (pytest collects solutions/*.ipynb with --nbval-lax).
"""
import ast

import nbformat
import pytest
from nbclient import NotebookClient

from kfkit.authoring import make_labs
from kfkit.paths import KIT_ROOT

LABS = sorted((KIT_ROOT / "labs").glob("*.ipynb"))


def assigned_names(source: str) -> set[str]:
    """Names a cell binds (assignments, defs, imports); IPython magics are ignored."""
    code = "\n".join(line for line in source.splitlines() if not line.lstrip().startswith(("%", "!")))
    names = set()
    for node in ast.walk(ast.parse(code)):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def unexpected_errors(nb) -> list[str]:
    """Errors other than NotImplementedError from a stub, or a NameError for a value such a cell never made."""
    missing, problems = set(), []
    for i, cell in enumerate(nb.cells):
        if cell.cell_type != "code":
            continue
        for out in cell.get("outputs", []):
            if out.output_type != "error":
                continue
            cascade = out.ename == "NameError" and any(f"'{n}'" in out.evalue for n in missing)
            if out.ename == "NotImplementedError" or cascade:
                missing |= assigned_names(cell.source)
            else:
                problems.append(f"cell {i}: {out.ename}: {out.evalue}")
        for out in cell.get("outputs", []):
            if out.output_type == "stream" and out.name == "stderr" and "Warning" in out.text:
                problems.append(f"cell {i} printed a warning: {out.text.strip()[:200]}")
    return problems


@pytest.mark.parametrize("path", LABS, ids=[p.stem for p in LABS])
def test_lab_runs_with_only_stub_errors(path):
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=120, allow_errors=True, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    assert unexpected_errors(nb) == []
    printed = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []))
    assert "not attempted yet" in printed, "checkpoint cells should say 'not attempted yet' on an unfilled lab"
    assert "✅" not in printed, "a checkpoint passed on a lab with no answers: a check that cannot fail"


def test_labs_are_generated_from_current_solutions():
    assert make_labs(KIT_ROOT / "solutions", KIT_ROOT / "labs", check=True) == []


def test_solution_notebooks_have_no_warnings_or_errors():
    for path in sorted((KIT_ROOT / "solutions").glob("*.ipynb")):
        nb = nbformat.read(path, as_version=4)
        for i, cell in enumerate(nb.cells):
            for out in cell.get("outputs", []):
                assert out.output_type != "error", f"{path.name} cell {i} stored an error"
                assert not (out.output_type == "stream" and out.name == "stderr"), f"{path.name} cell {i} wrote to stderr: {out.text[:200]}"
