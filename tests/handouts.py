"""What the tests of the hand-outs share: running a lab notebook as a student does, a hand-out with some of its
exercises written, and reading what its cells printed and which stubs its skip notes name."""

import ast
import re

import nbformat
from nbclient import NotebookClient
from waiting import HANG_GUARD_S

from kfkit.paths import KIT_ROOT

#: the exercise guard's note in a skipped cell, and the stubs it names
NOTE = re.compile(r"⏭  skipped: (.*)\. Run this cell again when that is done\.")
NEEDS = re.compile(r"(\w+) \(not written yet\)")


def code(cell) -> str:
    """A cell's Python, IPython's % and ! lines left out."""
    return "\n".join(line for line in cell.source.splitlines() if not line.lstrip().startswith(("%", "!")))


def stubs(nb) -> set[str]:
    """The functions a hand-out leaves to the student: those whose body raises NotImplementedError."""
    return {
        node.name
        for cell in nb.cells
        if cell.cell_type == "code"
        for node in ast.walk(ast.parse(code(cell)))
        if isinstance(node, ast.FunctionDef)
        and any(isinstance(n, ast.Name) and n.id == "NotImplementedError" for n in ast.walk(node))
    }


def printed(cell) -> str:
    """What a code cell printed (its streams, however the kernel chunked them)."""
    return "".join(o.get("text", "") for o in cell.get("outputs", []) if o.output_type == "stream")


def execute(nb, timeout=HANG_GUARD_S) -> nbformat.NotebookNode:
    """Run All on ``nb`` in a fresh kernel, from labs/ as a student's would; nbclient raises on the first error,
    naming the cell."""
    NotebookClient(
        nb,
        timeout=timeout,
        startup_timeout=HANG_GUARD_S,
        allow_errors=False,
        kernel_name="python3",
        resources={"metadata": {"path": str(KIT_ROOT / "labs")}},
    ).execute()
    return nb


def half_done(lab, written) -> nbformat.NotebookNode:
    """The hand-out ``lab`` (a path in labs/) of a student who wrote the exercise functions ``written`` (the
    solution's code, cell by cell) and nothing else."""
    nb = nbformat.read(lab, as_version=4)
    solution = {c.id: c.source for c in nbformat.read(KIT_ROOT / "solutions" / lab.name, as_version=4).cells}
    for cell in nb.cells:
        if cell.cell_type == "code" and "NotImplementedError" in cell.source:
            defined = {n.name for n in ast.parse(code(cell)).body if isinstance(n, ast.FunctionDef)}
            if defined and defined <= set(written):
                cell.source = solution[cell.id]
    return nb
