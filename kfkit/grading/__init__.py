"""Instructor grading: a folder of submitted notebooks → a gradebook you can trust.

    kfkit grade --lab 01 --out gradebook.csv submissions/

For each submission, in its own fresh, sandboxed kernel (see :mod:`kfkit.grading.sandbox`: a
file system holding only what the kernel needs, read-only, no network; no sandbox, no grading),
with memory and CPU time limited for all its processes together (:mod:`kfkit.grading.resources`):

1. run the student's code cells top to bottom (cell tags and metadata dropped, so nothing is
   skipped or excused; errors do not stop the run), with a per-cell and a total timeout counted in
   CPU seconds, each with a wall-clock backstop ``--wall-factor`` times as long, and an output cap
   (see :mod:`kfkit.grading.runner`);
2. for each checkpoint of the lab (``kfkit.checkpoints.labNN``), draw fresh cases in the
   grader's process (a new seed per submission, written in the feedback), send only their
   inputs to the kernel (pickled), call the student's function there, and receive only its outputs,
   or the class name and message of what it raised, as JSON (:mod:`kfkit.grading.wire`: nothing
   the kernel sends is unpickled);
3. judge those outputs here, with the checkpoint's own ``judge`` and ``points``, against
   expected values the kernel never sees. Nothing the notebook prints or patches in its kernel
   (``kfkit.checkpoints``, kfkit's reference functions) enters that judgement.

Writes ``gradebook.csv`` (``submission,checkpoint,points,max_points,status,message``: see
:mod:`kfkit.grading.gradebook`), one Markdown feedback file per submission (``<feedback>/<submission>.md``),
and returns a summary with per-checkpoint pass rates. A link or a non-regular file among the submissions is
refused, never followed or opened (:mod:`kfkit.grading.submissions`).
"""

from __future__ import annotations

import os
from pathlib import Path

CELL_TIMEOUT = 30.0  # s of CPU time per notebook cell and per checkpoint call
TOTAL_TIMEOUT = 300.0  # s of CPU time for one whole submission
WALL_FACTOR = 10.0  # each timeout's wall-clock backstop, as a multiple of it (for code that waits, computing nothing)
_PUBLIC = (
    "grade",
    "grade_submission",
    "grade_checkpoints",
    "lab_checkpoints",
    "find_submissions",
    "read_code_cells",
    "read_notebook",
    "read_gradebook",
    "summary",
    "Limits",
    "Row",
    "SubmissionGrade",
    "NotANotebook",
    "NoSandbox",
)


def __getattr__(name):
    """The pipeline (nbclient, numpy) loads only when used, so other ``kfkit`` commands stay fast."""
    if name in _PUBLIC:
        from . import core

        return getattr(core, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _cli(args) -> int:
    from .core import cli

    code = cli(args)
    if args.report and code != 2 and Path(args.out).is_file():
        from .report import write_report

        print(f"class report: {write_report(args.out, feedback_dir=args.feedback)}")
    return code


def add_parser(sub):
    """The ``grade`` subcommand of ``kfkit`` (see cli.py); its numbers are checked at the door
    (:mod:`kfkit.cli_options`)."""
    from ..cli_options import number

    p = sub.add_parser("grade", help="grade submitted notebooks in isolated kernels into a gradebook (instructors)")
    p.add_argument("submissions", nargs="+", metavar="SUBMISSION", help=".ipynb files or folders holding them")
    p.add_argument("--lab", required=True, help="lab number, e.g. 01")
    p.add_argument("--out", type=Path, default=Path("gradebook.csv"), help="gradebook CSV (default: %(default)s)")
    p.add_argument(
        "--jobs",
        type=number(int, 0),
        default=os.cpu_count() or 1,
        help="submissions graded in parallel (default: one per core, %(default)s)",
    )
    p.add_argument(
        "--timeout",
        type=number(float, 0.0, unit="s"),
        default=CELL_TIMEOUT,
        help="CPU seconds per notebook cell and per checkpoint call (user + system, all the kernel's "
        "processes; not wall time, so a busy machine fails nobody) (default: %(default)g)",
    )
    p.add_argument(
        "--total-timeout",
        type=number(float, 0.0, unit="s"),
        default=TOTAL_TIMEOUT,
        help="CPU seconds for one whole submission, cells and checkpoint calls; part is kept for the "
        "calls (default: %(default)g)",
    )
    p.add_argument(
        "--wall-factor",
        type=number(float, 1.0, include_low=True),
        default=WALL_FACTOR,
        metavar="K",
        help="wall-clock backstop for code that waits without computing (sleep in a loop, a deadlock): a "
        "cell or call is stopped after K times --timeout seconds of wall time, a submission after K "
        "times --total-timeout (default: %(default)g; 1 is the old rule, judging by wall time)",
    )
    p.add_argument(
        "--max-memory",
        type=number(float, 0.0, unit="GB"),
        default=4.0,
        metavar="GB",
        help="memory all of one submission's processes may hold at once (default: %(default)g GB)",
    )
    p.add_argument(
        "--max-cpu",
        type=number(float, 0.0, unit="s"),
        default=None,
        metavar="S",
        help="hard limit: CPU seconds after which all of one submission's processes are killed, "
        "even those an interrupt does not stop (default: --total-timeout)",
    )
    p.add_argument(
        "--feedback",
        type=Path,
        default=None,
        help="folder for the per-submission Markdown feedback (default: <out stem>_feedback/)",
    )
    p.add_argument(
        "--seed",
        type=number(int, 0, include_low=True),
        default=None,
        help="fix the random cases (to reproduce a grade)",
    )
    p.add_argument(
        "--update",
        action="store_true",
        help="replace only these submissions' rows in an existing gradebook (regrade one student)",
    )
    p.add_argument(
        "--report",
        action="store_true",
        help="also write the HTML class report of the whole gradebook (<out stem>_report.html; kfkit report)",
    )
    p.add_argument(
        "--no-sandbox",
        action="store_true",
        help="grade even where no isolation works (macOS, Windows): student code can then read and "
        "change your files; by default kfkit grade refuses",
    )
    p.set_defaults(run=_cli)
    return p


def _report_cli(args) -> int:
    from .report import cli

    return cli(args)


def add_report_parser(sub):
    """The ``report`` subcommand of ``kfkit``: a gradebook → one self-contained HTML page (see report.py)."""
    p = sub.add_parser("report", help="a gradebook → one self-contained HTML class report (instructors)")
    p.add_argument("gradebook", type=Path, help="the CSV kfkit grade wrote")
    p.add_argument("--out", type=Path, default=None, help="HTML file (default: <gradebook stem>_report.html beside it)")
    p.add_argument(
        "--feedback",
        type=Path,
        default=None,
        help="the feedback folder to link (default: <gradebook stem>_feedback/, as kfkit grade writes it)",
    )
    p.set_defaults(run=_report_cli)
    return p
