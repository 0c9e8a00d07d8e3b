"""The grading pipeline behind ``kfkit grade`` (see the package docstring)."""

from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import importlib
import multiprocessing
import re
import secrets
import sys
import time
from pathlib import Path

import nbformat
import numpy as np

from .. import __version__
from .. import checkpoints as cps
from ..checkpoints import Status
from . import sandbox as sb
from . import wire
from .gradebook import (  # noqa: F401 (public)
    COLUMNS,
    Row,
    SubmissionGrade,
    default_feedback_dir,
    feedback_names,
    merge_grades,
    read_gradebook,
    write_gradebook,
)
from .quoting import clip, md_code, visible_controls
from .runner import KernelLost, KernelRun, Limits, OutOfTime, StoppedByLimit
from .submissions import Refused, Submission, TooLarge, find_submissions, read_submission

MAX_NOTEBOOK_BYTES = 50 << 20
MAX_MESSAGE = 600  # characters of one gradebook message (a student's output can make it long)


class NotANotebook(ValueError):
    """Not a notebook the grader can run (``status``: not graded, or refused when it was not even opened)."""

    def __init__(self, why: str, status: Status = Status.NOT_GRADED):
        super().__init__(why)
        self.status = status


class NoSandbox(RuntimeError):
    """No isolation works on this machine, and the instructor did not accept grading without it."""


def lab_checkpoints(lab: str) -> list[cps.Checkpoint]:
    """The checkpoints lab ``lab`` ('1', '01') registers, in registration order."""
    nn = f"{int(lab):02d}" if str(lab).isdigit() else str(lab)
    if f"lab{nn}" not in cps.LABS:
        raise ValueError(f"no checkpoints for lab {nn}: kfkit/checkpoints has {', '.join(cps.LABS) or 'none'}")
    importlib.import_module(f"kfkit.checkpoints.lab{nn}")
    found = [cp for name, cp in cps.REGISTRY.items() if name.startswith(f"{nn}.")]
    if not found:
        raise ValueError(f"kfkit/checkpoints/lab{nn}.py registers no checkpoint named '{nn}.…'")
    return found


def read_code_cells(path: Path | Submission) -> list[str]:
    """The code cells' sources of a notebook file; NotANotebook with the reason if it is not one."""
    return read_notebook(path)[0]


def _as_submission(path: Path | Submission) -> Submission:
    """A file named by its path: its folder is the root it may not leave (see :mod:`.submissions`)."""
    if isinstance(path, Submission):
        return path
    path = Path(path)
    return Submission(path.parent, Path(path.name), str(path))


def read_notebook(path: Path | Submission) -> tuple[list[str], list[str]]:
    """The code cells' sources and, for each, how a student finds it (:func:`cell_label`);
    NotANotebook with the reason if the file is not a notebook (status refused when it is a link or not
    a regular file: it is then not even opened, see :func:`.submissions.read_submission`).

    Only the sources are kept: tags (``skip-execution``, ``raises-exception``, …), the kernelspec
    and every other metadata field are dropped, so they cannot change how the grader runs it.
    """
    sub = _as_submission(path)
    try:
        text = read_submission(sub.root, sub.relative, MAX_NOTEBOOK_BYTES).decode("utf-8")
    except Refused as exc:
        raise NotANotebook(exc.why, Status.REFUSED) from None
    except TooLarge:
        raise NotANotebook(f"the file is larger than {MAX_NOTEBOOK_BYTES >> 20} MB") from None
    except UnicodeDecodeError:
        raise NotANotebook("the file is not text (not a .ipynb notebook)") from None
    except OSError as exc:
        raise NotANotebook(f"cannot read it ({exc.strerror})") from None
    try:
        nb = nbformat.reads(text, as_version=4)
        sources, labels, heading = [], [], None
        for c in nb.cells:
            source = c.source if isinstance(c.source, str) else "".join(c.source)
            if c.get("cell_type") == "markdown" and isinstance(source, str):
                heading = _last_heading(source) or heading
            elif c.get("cell_type") == "code":
                sources.append(source)
                labels.append(cell_label(source, heading) if isinstance(source, str) else "")
    except nbformat.reader.NotJSONError:
        raise NotANotebook("the file is not valid JSON (a damaged or renamed file?)") from None
    except Exception as exc:  # any other shape problem: not a notebook we can run
        raise NotANotebook(f"not a Jupyter notebook ({type(exc).__name__}: {str(exc)[:200]})") from None
    if not all(isinstance(s, str) for s in sources):
        raise NotANotebook("a code cell's source is not text")
    return sources, labels


def _last_heading(markdown: str) -> str | None:
    headings = [ln.lstrip("#").strip() for ln in markdown.splitlines() if re.match(r"#{1,6}\s", ln)]
    return headings[-1] if headings else None


def cell_label(source: str, heading: str | None) -> str:
    """How a student finds a code cell: its first line, the functions it defines, its section.

    e.g. ``the cell `def kf_update(x, P, z, r):` in section "3. The update"``.
    """
    defined = re.findall(r"^def\s+(\w+)\s*\(", source, re.M)
    first = _first_line(source)
    label = f"the cell `{first}`"
    if len(defined) > 1 or (defined and not first.startswith(f"def {defined[0]}")):
        label += f" (defining {', '.join(defined)})"
    return label + (f' in section "{clip(heading, 60)}"' if heading else " before the first heading")


def _short(message: str, name: str) -> str:
    """A checkpoint line without its leading emoji and name (the gradebook has a column for that)."""
    return clip(re.sub(rf"^\S+ {re.escape(name)}: ", "", message), MAX_MESSAGE)


def _student_exception(type_name: str, message: str) -> Exception:
    if type_name == "NotImplementedError":
        return NotImplementedError(message)
    if type_name == "StaleDefinition":  # the exercise guard set the function aside: its new cell was skipped
        stale = NotImplementedError(message)
        stale.stale_definition = True
        return stale
    name = type_name if type_name.isidentifier() else "Exception"
    return type(name, (Exception,), {})(message)


class OutputTooLarge(Exception):
    pass


def judge(cp: cps.Checkpoint, cases: list, report: dict, defining_note: str | None) -> Row:
    """Grade one checkpoint from the kernel's report, entirely in this process."""
    where = f" ({defining_note})" if defining_note else ""
    if report.get("missing"):
        return Row(
            cp.name,
            0,
            cp.points,
            Status.MISSING,
            f"no function named {cp.function} after running the notebook{where}: keep the exercise's "
            f"function name and signature, the grader calls {cp.function}(…) itself",
        )
    if "not_callable" in report:
        return Row(
            cp.name,
            0,
            cp.points,
            Status.MISSING,
            f"{cp.function} is a {report['not_callable']} at the end of the notebook, not a function",
        )
    if "kfkit_function" in report:
        return Row(
            cp.name,
            0,
            cp.points,
            Status.FAILED,
            f"{cp.function} is kfkit's own {report['kfkit_function']}, not a function written in the notebook",
        )
    results = report.get("results")
    if not isinstance(results, list) or not all(isinstance(r, dict) for r in results):
        return Row(cp.name, 0, cp.points, Status.ERROR, "the kernel's result was malformed")
    outcomes = iter(results)

    def replay(**_args):
        r = next(outcomes, None)
        if r is None:
            raise OutputTooLarge("no output came back for this case")
        if "raised" in r:
            raise _student_exception(str(r["raised"])[:80], str(r.get("message", ""))[:500])
        if "too_large" in r:
            raise OutputTooLarge(f"the output holds more than {r['too_large']} numbers")
        return wire.decode(r.get("out"))

    try:
        result = cps.run_checkpoint(dataclasses.replace(cp, cases=lambda _rng: cases), replay)
    except wire.WireError as exc:
        return Row(cp.name, 0, cp.points, Status.ERROR, f"the output could not be read: {exc}")
    except Exception as exc:  # a judge tripping over a strange output: zero, with the reason
        return Row(
            cp.name,
            0,
            cp.points,
            Status.ERROR,
            f"the grader could not judge the output ({type(exc).__name__}: {str(exc)[:200]})",
        )
    if result.status == Status.NOT_ATTEMPTED:
        stale = " — ".join(result.message.split(": stale: ", 1)[1:])
        return Row(
            cp.name,
            0,
            cp.points,
            Status.NOT_ATTEMPTED,
            f"not attempted (stale: {clip(stale, MAX_MESSAGE)})"
            if stale
            else f"not attempted ({cp.function} still raises NotImplementedError)",
        )
    return Row(cp.name, result.points, cp.points, result.status, _short(result.message, cp.name))


def _defining_note(run: KernelRun, sources: list[str], function: str) -> str | None:
    """What went wrong in the cell that defines ``function``, if anything."""
    pattern = re.compile(rf"^\s*def\s+{re.escape(function)}\s*\(", re.M)
    for i, src in enumerate(sources):
        if pattern.search(src):
            return f"the cell defining it failed: {run.cell_notes[i]}" if i in run.cell_notes else None
    return "no cell defines it"


def _first_line(source: str) -> str:
    """The first line of a cell that is not a comment, to recognise the cell by."""
    lines = [ln.strip() for ln in source.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    line = (lines or ["(comments only)"])[0].replace("`", "'")
    return line if len(line) <= 60 else line[:59] + "…"


def grade_checkpoints(run: KernelRun, sources: list[str], checkpoints: list, seed: int):
    """Draw each checkpoint's cases here (seeded by ``seed``), call the student's function in the
    kernel of ``run``, and judge its outputs here; yields one row per checkpoint (OutOfTime passes)."""
    for i, cp in enumerate(checkpoints):
        earlier = run.stopped.get(cp.function)
        if earlier is not None and earlier.checkpoint:  # a loop is paid for once (see runner.py)
            yield Row(
                cp.name,
                0,
                cp.points,
                Status.TIMED_OUT,
                f"not called again: {cp.function} {earlier.why} on the grader's cases for {earlier.checkpoint}",
            )
            continue
        try:
            cases = cp.cases(np.random.default_rng([i, seed]))
            report = run.call(cp.function, [c.args for c in cases], cp.name)
            row = _timed_out_inside(cp, report, run.stopped) or judge(
                cp, cases, report, _defining_note(run, sources, cp.function)
            )
        except TimeoutError as exc:
            row = Row(cp.name, 0, cp.points, Status.TIMED_OUT, f"{cp.function} {exc} on the grader's cases")
        except KernelLost as exc:
            row = Row(
                cp.name,
                0,
                cp.points,
                Status.TIMED_OUT if exc.timed_out else Status.ERROR,
                f"calling {cp.function} on the grader's cases: {exc.why}",
            )
        except wire.WireError as exc:
            row = Row(cp.name, 0, cp.points, Status.ERROR, f"calling {cp.function}: {exc}")
        except OutOfTime:
            raise
        except Exception as exc:  # the checkpoint's own code failed here: not the student's fault
            row = Row(
                cp.name,
                0,
                cp.points,
                Status.NOT_GRADED,
                f"GRADER ERROR, regrade this submission: {type(exc).__name__}: {str(exc)[:200]}",
            )
        yield row


def _timed_out_inside(cp: cps.Checkpoint, report: dict, stopped: dict) -> Row | None:
    """The row of a call that failed because the function called one the grader's calls stopped (it raised
    TimedOutEarlier naming a function the grader stopped: the kernel's word alone is not taken)."""
    results = report.get("results")
    raised = (
        next((r for r in results if isinstance(r, dict) and "raised" in r), None) if isinstance(results, list) else None
    )
    if raised is None or raised.get("raised") != wire.TIMED_OUT_EARLIER:
        return None
    inner = stopped.get(str(raised.get("message", "")).split(" ", 1)[0])
    if inner is None or not inner.checkpoint:
        return None
    return Row(
        cp.name,
        0,
        cp.points,
        Status.TIMED_OUT,
        f"{cp.function} calls {inner.name}, which {inner.why} on the grader's cases for {inner.checkpoint}: "
        "not run again",
    )


def _fill(grade: SubmissionGrade, checkpoints: list, status: Status, message: str):
    """Rows for the checkpoints ``grade`` has none for yet: 0 points, ``status``, ``message``."""
    for cp in checkpoints[len(grade.rows) :]:
        grade.rows.append(Row(cp.name, 0, cp.points, status, message))


def refused_grade(sub: Submission, checkpoints: list) -> SubmissionGrade:
    """The rows of a submission that is not opened (a link, not a regular file): refused, with the reason."""
    grade = SubmissionGrade(sub.name, 0)
    _fill(grade, checkpoints, Status.REFUSED, f"not graded, {sub.refused}")
    grade.notes.append(sub.refused)
    return grade


def grade_submission(
    path: Path | Submission,
    checkpoints: list,
    sandbox: sb.Sandbox,
    limits: Limits,
    seed: int | None = None,
    name: str | None = None,
) -> SubmissionGrade:
    """Run and grade one notebook file in a fresh kernel; never raises for anything the file contains.

    Over its memory or CPU-time limit the submission is stopped: the checkpoints not graded yet
    score 0 with the limit and the measured value (status "over limit")."""
    start = time.monotonic()
    seed = secrets.randbits(63) if seed is None else int(seed)
    grade = SubmissionGrade(name or str(path), seed)

    def fill(status, message):
        _fill(grade, checkpoints, status, message)

    try:
        sources, labels = read_notebook(path)
    except NotANotebook as exc:
        fill(exc.status, f"not graded{',' if exc.status == Status.REFUSED else ':'} {exc}")
        grade.notes.append(str(exc))
        return grade
    try:
        reserve = min(len(checkpoints) * limits.cell_timeout, limits.total_timeout / 2)  # for the grader's calls
        with KernelRun(sources, sandbox, limits, reserve) as run:
            try:
                run.run_notebook()
                grade.rows.extend(grade_checkpoints(run, sources, checkpoints, seed))
            except StoppedByLimit as exc:
                where = (
                    labels[run.current]
                    if run.current < len(sources)
                    else f"the grader's call of {checkpoints[len(grade.rows)].function}"
                )
                text = f"stopped: the submission {exc} while running {where} ({run.meter_kind})"
                fill(Status.OVER_LIMIT, f"not graded, {text}")
                grade.notes.append(text)
            except OutOfTime as exc:
                fill(Status.TIMED_OUT, f"timed out: not graded, {exc}")
            finally:
                grade.notes += _cell_notes(run, labels)
    except RuntimeError as exc:  # the kernel could not start: a grader-side problem, said plainly
        fill(Status.NOT_GRADED, f"GRADER ERROR, regrade this submission: {exc}")
    grade.seconds = time.monotonic() - start
    return grade


def _cell_notes(run: KernelRun, labels: list[str]) -> list[str]:
    """The feedback's notes on the notebook's cells: each cell that failed, looped, exited or printed too much;
    the cells whose error only followed from a function that timed out (its stub, or a name a cell calling it
    did not make) grouped under that function, not listed as faults."""
    notes = [f"{labels[i]}: {note}" for i, note in sorted(run.cell_notes.items())]
    affected: dict[str, list[str]] = {}
    for i, (function, error) in sorted(run.affected.items()):
        affected.setdefault(function, []).append(f"{labels[i]} ({clip(error, 120)})")
    return notes + [
        f"affected by {function} timing out, not faults of their own: {'; '.join(cells)}"
        for function, cells in affected.items()
    ]


# ---------------------------------------------------------------------------- outputs
def feedback_markdown(g: SubmissionGrade, lab: str, sandbox: sb.Sandbox) -> str:
    """The student's feedback file (Markdown). What the student's work produced (the submission's name, the
    messages, the notes on cells) is quoted with :func:`.quoting.md_code`: any Markdown or HTML renderer
    shows it as text, so the only score line is the grader's."""
    icon = {Status.PASSED: "✅", Status.NOT_ATTEMPTED: "⏳"}
    lines = [
        f"# Lab {lab} feedback: {md_code(g.submission)}",
        "",
        f"**Score: {g.points:g} / {g.max_points:g}**",
        "",
        f"Graded {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} with kfkit {__version__}; "
        f"random cases drawn with seed {g.seed} (regrade the same cases with `--seed {g.seed}`); "
        f"{g.seconds:.1f} s.",
        "",
        "## Checkpoints",
        "",
    ]
    lines += [
        f"- {icon.get(r.status, '❌')} {r.checkpoint}, {r.points:g} / {r.max_points:g} points: {md_code(r.message)}"
        for r in g.rows
    ]
    if g.notes:
        lines += ["", "## While running your notebook", ""] + [f"- {md_code(n)}" for n in g.notes]
    lines += ["", f"_Isolation: {sandbox.describe(full=False)}_", ""]
    return "\n".join(lines)


def summary(
    grades: list[SubmissionGrade],
    checkpoints: list,
    sandbox: sb.Sandbox,
    warnings=(),
    whole_class: list[SubmissionGrade] | None = None,
) -> str:
    """What the instructor reads at the end: isolation, pass rates per checkpoint and totals over
    ``whole_class`` (the whole gradebook after ``--update``; default: ``grades``, this run's)."""
    lines = []
    if sandbox.mode == "none":
        lines += ["!" * 78, f"WARNING: {sandbox.describe()}", "!" * 78]
    lines += [f"warning: {visible_controls(w)}" for w in warnings]
    refused = [g.submission for g in grades if any(r.status == Status.REFUSED for r in g.rows)]
    graded = [g for g in grades if g.submission not in refused]
    seconds = np.mean([g.seconds for g in graded]) if graded else 0.0
    lines.append(f"{len(graded)} submission(s) graded, {seconds:.1f} s per submission; isolation: {sandbox.describe()}")
    if refused:
        lines.append(
            f"REFUSED {len(refused)} (links or not regular files: not opened, each a gradebook row with "
            f"status refused): {', '.join(map(visible_controls, refused))}"
        )
    grades = grades if whole_class is None else whole_class
    n = len(grades)
    if whole_class is not None:
        lines.append(f"the whole gradebook ({n} submissions):")
    if n:
        width = max(len(cp.name) for cp in checkpoints)
        lines.append(f"{'checkpoint':{width}s}  passed  rate   mean points")
        for cp in checkpoints:
            rows = [r for g in grades for r in g.rows if r.checkpoint == cp.name]
            passed = sum(r.status == Status.PASSED for r in rows)
            mean = sum(r.points for r in rows) / max(len(rows), 1)
            lines.append(
                f"{cp.name:{width}s}  {passed:3d}/{len(rows):<3d} {100 * passed / max(len(rows), 1):4.0f} %"
                f"  {mean:.2f} / {cp.points}"
            )
        totals = [g.points for g in grades]
        lines.append(f"total: mean {np.mean(totals):.2f} / {grades[0].max_points:g}, median {np.median(totals):g}")
        errors = [visible_controls(g.submission) for g in grades if any("GRADER ERROR" in r.message for r in g.rows)]
        if errors:
            lines.append(f"GRADER ERROR for {len(errors)} submission(s), regrade them: {', '.join(errors)}")
    return "\n".join(lines)


class _Progress:
    def __init__(self, total, stream=sys.stderr):
        self.total, self.done, self.stream, self.start = total, 0, stream, time.monotonic()

    def step(self, label):
        self.done += 1
        width = 30
        fill = int(width * self.done / max(self.total, 1))
        line = (
            f"[{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
            f"{time.monotonic() - self.start:5.0f} s  {visible_controls(label[-40:])}"
        )
        if self.stream.isatty():
            self.stream.write("\r" + line.ljust(100) + ("\n" if self.done == self.total else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def _grade_one(args):
    path, name, lab, sandbox, limits, seed = args
    return grade_submission(path, lab_checkpoints(lab), sandbox, limits, seed, name)


def grade(
    paths,
    lab,
    out: Path,
    jobs: int = 1,
    limits: Limits | None = None,
    feedback_dir: Path | None = None,
    seed: int | None = None,
    update: bool = False,
    progress: bool = True,
    sandbox: sb.Sandbox | None = None,
    unsandboxed: bool = False,
):
    """Grade notebooks (files or folders) for lab ``lab``; → (grades, summary text).

    Writes the gradebook ``out`` and ``feedback_dir/<submission>.md`` (default: next to the
    gradebook, ``<stem>_feedback/``). ``seed`` fixes the cases (to reproduce one grade).
    Raises :class:`NoSandbox` when no isolation works here, unless ``unsandboxed``.
    """
    checkpoints = lab_checkpoints(lab)
    limits = limits or Limits()
    out = Path(out)
    earlier = read_gradebook(out) if update and out.exists() else None  # a damaged one: said before grading
    feedback_dir = Path(feedback_dir) if feedback_dir else default_feedback_dir(out)
    found, warnings = find_submissions(paths)
    instructor = {Path(p).resolve().parent if Path(p).is_file() else Path(p).resolve() for p in paths}
    instructor |= {out.resolve().parent, feedback_dir.resolve().parent}
    sandbox = sandbox or sb.probe(sorted(map(str, instructor)))
    if sandbox.mode == "none" and not unsandboxed:
        raise NoSandbox(sandbox.warning)
    grades = [refused_grade(sub, checkpoints) if sub.refused else None for sub in found]  # refused: never opened
    tasks = {k: (sub, sub.name, lab, sandbox, limits, seed) for k, sub in enumerate(found) if not sub.refused}
    bar = _Progress(len(tasks)) if progress else None
    if jobs <= 1 or len(tasks) <= 1:
        for k, task in tasks.items():
            grades[k] = _grade_one(task)
            bar and bar.step(task[1])
    else:
        # fork: workers inherit the imported kit at once; this process has no kernel or thread yet
        ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        with cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
            futures = {pool.submit(_grade_one, t): k for k, t in tasks.items()}
            for fut in cf.as_completed(futures):
                k = futures[fut]
                try:
                    grades[k] = fut.result()
                except Exception as exc:  # a worker crashed: say so in the gradebook, keep going
                    g = SubmissionGrade(found[k].name, seed or 0)
                    g.rows = [
                        Row(
                            cp.name,
                            0,
                            cp.points,
                            Status.NOT_GRADED,
                            f"GRADER ERROR, regrade this submission: {type(exc).__name__}: {exc}",
                        )
                        for cp in checkpoints
                    ]
                    grades[k] = g
                bar and bar.step(found[k].name)
    whole_class = merge_grades(earlier, grades) if earlier is not None else None
    write_gradebook(out, whole_class or grades)
    lab_nn = checkpoints[0].name.split(".")[0]
    for g, fname in zip(grades, feedback_names([g.submission for g in grades])):
        (feedback_dir / fname).parent.mkdir(parents=True, exist_ok=True)
        (feedback_dir / fname).write_text(feedback_markdown(g, lab_nn, sandbox), encoding="utf-8")
    return grades, summary(grades, checkpoints, sandbox, warnings, whole_class)


def cli(args) -> int:
    """``kfkit grade``: see :func:`grade`; exit 0 when every submission was graded, 1 otherwise (a grader
    error to regrade, or a refused file)."""
    try:
        lab_checkpoints(args.lab)
    except ValueError as exc:
        print(f"kfkit grade: {exc}", file=sys.stderr)
        return 2
    files, warnings = find_submissions(args.submissions)
    if not files:
        for w in warnings:
            print(f"kfkit grade: {w}", file=sys.stderr)
        print("kfkit grade: no notebooks to grade", file=sys.stderr)
        return 1
    limits = Limits(
        cell_timeout=args.timeout,
        total_timeout=args.total_timeout,
        wall_factor=args.wall_factor,
        memory=int(args.max_memory * (1 << 30)),
        cpu_time=args.max_cpu if args.max_cpu is not None else args.total_timeout,
    )
    try:
        grades, text = grade(
            args.submissions,
            args.lab,
            args.out,
            jobs=args.jobs,
            limits=limits,
            feedback_dir=args.feedback,
            seed=args.seed,
            update=args.update,
            unsandboxed=args.no_sandbox,
        )
    except NoSandbox as exc:
        print(
            f"kfkit grade: cannot isolate the students' code on this machine, so nothing was graded: {exc}.\n"
            "Grade on Linux with util-linux's 'unshare' (as root, or with user namespaces enabled), e.g. in a "
            "Linux VM or container, or accept the risk with --no-sandbox.",
            file=sys.stderr,
        )
        return 2
    except ValueError as exc:  # the gradebook to --update is not one
        print(f"kfkit grade: {exc}", file=sys.stderr)
        return 2
    print(text)
    print(f"gradebook: {args.out}; feedback: {args.feedback or default_feedback_dir(args.out)}")
    return 1 if any("GRADER ERROR" in r.message or r.status == Status.REFUSED for g in grades for r in g.rows) else 0
