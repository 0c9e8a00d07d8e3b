"""Generate the student notebooks in ``labs/`` from the instructor notebooks in ``solutions/``.

Workflow: edit and run only ``solutions/NN_name.ipynb`` (complete code, with
outputs), then run ``kfkit make-labs`` to regenerate ``labs/NN_name.ipynb``.
Never edit ``labs/`` by hand; ``kfkit make-labs --check`` (CI) fails when a
lab is stale, missing, or has no solution.

Markers (the ones nbgrader uses), each on a line of its own:

* code cells: the lines from ``### BEGIN SOLUTION`` to ``### END SOLUTION``
  (inclusive) become ``# YOUR CODE HERE`` and ``raise NotImplementedError()``,
  indented like the BEGIN line. A cell may hold several blocks. Each block must
  be a statement of its function's body, or of the cell (not inside an if, a
  loop, a try or a with), with no ``return`` before it: that is how the exercise
  guard tells a stub from a finished function (:func:`is_stub`), and a block it
  would not recognise is refused.
* markdown cells: the same markers around a model answer; the block becomes
  ``YOUR ANSWER HERE``.
* cells tagged ``solution-only`` (instructor notes, checks of the model
  answer) are left out of the lab entirely.
* nbval's cell markers (``# NBVAL_CHECK_OUTPUT``, ``# NBVAL_IGNORE_OUTPUT``, …) are removed: nbval
  validates the solutions, and a student has no use for them.

Predict, run, then read. A markdown cell tagged ``predict`` asks the student to predict what the cells after it
will show; the lab gets a markdown cell for the student's answer right after it ("My prediction: …", tag
``my-prediction``, ungraded). Markdown cells tagged ``reveal`` explain the answer: in the lab they are folded
(``jupyter.source_hidden``, which JupyterLab shows as a bar to click) until the student opens them, and start with a
line that names them (the bar previews a cell's first line, which would otherwise give the answer away). A reveal may
quote the bundled run's numbers for the instructor as ``<!-- run: the RMSE printed above -->0.33°<!-- /run -->``:
the solution shows 0.33° (the comment is invisible), the lab reads "the RMSE printed above", so a hand-out never
gives a number the student has not produced yet.

The labs carry no outputs and no run state, so they are byte-identical
whoever regenerates them.
"""

from __future__ import annotations

import ast
import copy
import re
from pathlib import Path

import nbformat

BEGIN = "### BEGIN SOLUTION"
END = "### END SOLUTION"
CODE_STUB = ["# YOUR CODE HERE", "raise NotImplementedError()"]
_STUB_STATEMENT = ast.dump(ast.parse(CODE_STUB[-1]).body[0])  # the statement, whatever its indentation
ANSWER_STUB = ["YOUR ANSWER HERE"]
SOLUTION_ONLY_TAG = "solution-only"
RUN_STATE_KEYS = ("execution", "collapsed", "scrolled")
NOTEBOOK_METADATA_KEPT = ("kernelspec", "language_info")
NBVAL_MARKER = "# NBVAL_"
PREDICT_TAG, REVEAL_TAG, MY_PREDICTION_TAG = "predict", "reveal", "my-prediction"
MY_PREDICTION = (
    "**My prediction:** *(write it here before you run the cells below; the explanation after them is "
    "folded: click its bar to open it once you have compared)*"
)
#: the first line of a folded explanation: JupyterLab's fold bar previews a cell's first line, which must not be the
#: answer
REVEAL_LEAD = "**Explanation** *(folded: open it after you have run the cells above and compared with your prediction)*"
RUN_NUMBER = re.compile(r"<!--\s*run:\s*(.*?)\s*-->(.*?)<!--\s*/run\s*-->", re.S)


class AuthoringError(ValueError):
    """A solution notebook cannot be turned into a lab (bad solution markers)."""


def strip_solutions(nb: nbformat.NotebookNode, name: str | None = None) -> nbformat.NotebookNode:
    """Return the student version of solution notebook ``nb`` (``nb`` is not modified).

    ``name`` (e.g. the notebook path) is only used in error messages.
    """
    where = f"{name}: " if name else ""
    lab = copy.deepcopy(nb)
    lab.metadata = nbformat.NotebookNode(
        {key: lab.metadata[key] for key in NOTEBOOK_METADATA_KEPT if key in lab.metadata}
    )
    cells = []
    for index, cell in enumerate(lab.cells):
        tags = cell.metadata.get("tags", [])
        if SOLUTION_ONLY_TAG in tags:
            continue
        if REVEAL_TAG in tags:
            cell.source = f"{REVEAL_LEAD}\n\n{_lab_wording(cell.source, f'{where}cell index {index}')}"
            cell.metadata.setdefault("jupyter", {})["source_hidden"] = True
        stub = {"code": CODE_STUB, "markdown": ANSWER_STUB}.get(cell.cell_type)
        if stub:
            cell.source, stubs = _replace_blocks(cell.source, stub, f"{where}cell index {index}")
            if cell.cell_type == "code":
                _check_stubs_recognised(cell.source, stubs, f"{where}cell index {index}")
        if cell.cell_type == "code":
            cell.source = _without_test_markers(cell.source)
            cell.outputs = []
            cell.execution_count = None
        for key in RUN_STATE_KEYS:
            cell.metadata.pop(key, None)
        cells.append(cell)
        if PREDICT_TAG in tags:
            cells.append(
                nbformat.v4.new_markdown_cell(
                    MY_PREDICTION, id=f"{cell.id}-mine"[:64], metadata={"tags": [MY_PREDICTION_TAG]}
                )
            )
    lab.cells = cells
    _check_clean(lab, where)
    return lab


def is_stub(body: list[ast.stmt]) -> bool:
    """True when ``body``, a function's statements or a cell's, is an exercise make-labs left to the student: the
    statement it writes, ``raise NotImplementedError()``, is one of ``body``'s own statements (not inside an if, a
    loop, a try or a with) and nothing before it can return or yield. Calling such a function raises it whatever the
    input. A finished function never is one: one that raises NotImplementedError for some input, catches it, or keeps
    the stub after its ``return`` can return."""
    for statement in body:
        if ast.dump(statement) == _STUB_STATEMENT:
            return True
        if any(isinstance(n, (ast.Return, ast.Yield, ast.YieldFrom)) for n in _same_scope(statement)):
            return False
    return False


def _same_scope(node: ast.AST):
    """``node`` and what it holds, not the bodies of the functions, lambdas and classes it defines."""
    stack = [node]
    while stack:
        n = stack.pop()
        yield n
        stack.extend(
            c
            for c in ast.iter_child_nodes(n)
            if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef))
        )


def _check_stubs_recognised(source: str, stub_lines: list[int], where: str) -> None:
    """Refuse a stub (its ``raise`` on one of ``stub_lines``, 1-based) that :func:`is_stub` would not recognise in
    the lab's cell ``source``: the exercise guard would let the cells that need it run, and Run All would stop."""
    python = "\n".join("" if line.lstrip().startswith(("%", "!")) else line for line in source.split("\n"))
    try:
        tree = ast.parse(python)
    except SyntaxError:  # not Python (a %%bash cell …): no function in it for the guard to judge
        return
    bodies = [tree.body] + [n.body for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
    recognised = {statement.lineno for body in bodies if is_stub(body) for statement in body}
    for line in stub_lines:
        if line not in recognised:
            raise AuthoringError(
                f"{where}, line {line}: the exercise guard would not take this for a stub: put the "
                f"'{BEGIN}' block straight in the function's body (or the cell's), not inside an if, a loop, a try "
                "or a with, and with no return before it"
            )


def _replace_blocks(source: str, stub: list[str], where: str) -> tuple[str, list[int]]:
    """Replace every BEGIN..END block in ``source`` by ``stub`` at the BEGIN line's indentation; → (the new source,
    the line numbers (1-based) of each stub's last line)."""
    out: list[str] = []
    stub_lines: list[int] = []
    begin_line = None  # 1-based line number of the open BEGIN marker
    for number, line in enumerate(source.split("\n"), start=1):
        if BEGIN in line:
            if begin_line is not None:
                raise AuthoringError(
                    f"{where}, line {number}: nested '{BEGIN}' (the block opened on line {begin_line} is not closed)"
                )
            begin_line = number
            indent = line[: len(line) - len(line.lstrip())]
            out.extend(indent + stub_line for stub_line in stub)
            stub_lines.append(len(out))
        elif END in line:
            if begin_line is None:
                raise AuthoringError(f"{where}, line {number}: '{END}' without '{BEGIN}'")
            begin_line = None
        elif begin_line is None:
            out.append(line)
    if begin_line is not None:
        raise AuthoringError(f"{where}, line {begin_line}: '{BEGIN}' without '{END}'")
    return "\n".join(out), stub_lines


def _lab_wording(source: str, where: str) -> str:
    """A reveal cell's text for the lab: each ``<!-- run: words -->number<!-- /run -->`` becomes ``words``."""
    lab = RUN_NUMBER.sub(lambda m: m.group(1), source)
    if re.search(r"<!--\s*/?run\b", lab):
        raise AuthoringError(f"{where}: a '<!-- run: … -->' needs its '<!-- /run -->' (and the other way round)")
    return lab


def _without_test_markers(source: str) -> str:
    """``source`` without the lines that are only an nbval marker (``# NBVAL_CHECK_OUTPUT`` …)."""
    return "\n".join(line for line in source.split("\n") if not line.strip().startswith(NBVAL_MARKER))


def _check_clean(lab: nbformat.NotebookNode, where: str) -> None:
    """Refuse a lab that would leak a solution marker or an output to students."""
    text = nbformat.writes(lab, version=4)
    for marker in ("BEGIN SOLUTION", "END SOLUTION"):
        if marker in text:
            raise AuthoringError(
                f"{where}the lab would still contain '{marker}' (markers must be "
                f"'{BEGIN}' / '{END}' lines in code or markdown cells)"
            )
    if any(cell.get("outputs") for cell in lab.cells):
        raise AuthoringError(f"{where}the lab would still contain outputs")


def _render_lab(solution_path: str | Path) -> str:
    """Return the lab file contents for one solution notebook (deterministic text)."""
    nb = nbformat.read(solution_path, as_version=4)
    return nbformat.writes(strip_solutions(nb, name=str(solution_path)), version=4) + "\n"


def make_labs(solutions_dir: str | Path, labs_dir: str | Path, check: bool = False) -> list[str]:
    """Regenerate ``labs_dir`` from ``solutions_dir``.

    With ``check=False``, write the labs that changed, delete lab notebooks that
    have no solution, and return the paths written or removed. With
    ``check=True``, write nothing and return the problems found (empty: up to
    date). Paths are shown as ``<labs dir name>/<file>``, e.g. ``labs/01_x.ipynb``.
    """
    solutions_dir, labs_dir = Path(solutions_dir), Path(labs_dir)
    solutions = sorted(solutions_dir.glob("*.ipynb"))
    wanted = {path.name for path in solutions}
    changes: list[str] = []
    problems: list[str] = []

    for solution in solutions:
        lab = labs_dir / solution.name
        shown = f"{labs_dir.name}/{lab.name}"
        text = _render_lab(solution)
        if not lab.exists():
            problems.append(f"{shown} is missing")
        elif lab.read_bytes() == text.encode("utf-8"):
            continue
        else:
            problems.append(f"{shown} is stale: regenerate with 'kfkit make-labs'")
        if not check:
            labs_dir.mkdir(parents=True, exist_ok=True)
            lab.write_bytes(text.encode("utf-8"))
            changes.append(shown)

    for orphan in sorted(labs_dir.glob("*.ipynb")):
        if orphan.name in wanted:
            continue
        shown = f"{labs_dir.name}/{orphan.name}"
        problems.append(f"{shown} has no solution in {solutions_dir.name}/")
        if not check:
            orphan.unlink()
            changes.append(shown)

    return problems if check else changes
