"""Lab 01 notebooks for the grading tests, built from the solution: whole, reduced to its exercise functions, or
edited (a loop put in, a cell added)."""

import nbformat

from kfkit.paths import KIT_ROOT

SOLUTION = KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb"
LAB = KIT_ROOT / "labs" / "01_roll_kf_1d.ipynb"


def read(path):
    return nbformat.read(path, as_version=4)


def minimal():
    """Lab 01 reduced to its imports and the cells defining its exercise functions (solved)."""
    cells = [c for c in read(SOLUTION).cells if c.cell_type == "code"]
    keep = [cells[0]] + [c for c in cells if "### BEGIN SOLUTION" in c.source and "def " in c.source]
    return nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c.source) for c in keep])


def edit(nb, old, new):
    hits = [c for c in nb.cells if old in c.source]
    assert hits, f"{old!r} not in the notebook"
    for c in hits:
        c.source = c.source.replace(old, new)
    return nb


def add(nb, source, at=1):
    nb.cells.insert(at, nbformat.v4.new_code_cell(source))
    return nb


def append(nb, *sources):
    nb.cells += [nbformat.v4.new_code_cell(source) for source in sources]
    return nb
