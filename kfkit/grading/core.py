"""The grading pipeline behind ``kfkit grade`` (see the package docstring)."""
from __future__ import annotations

import concurrent.futures as cf
import csv
import dataclasses
import importlib
import multiprocessing
import re
import secrets
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import nbformat
import numpy as np

from .. import __version__
from .. import checkpoints as cps
from . import sandbox as sb
from . import wire
from .runner import KernelLost, KernelRun, Limits, OutOfTime, StoppedByLimit  # noqa: F401 (Limits is public)

COLUMNS = ["submission", "checkpoint", "points", "max_points", "message"]
MAX_NOTEBOOK_BYTES = 50 << 20
MAX_MESSAGE = 600  # characters of one gradebook message (a student's output can make it long)


@dataclass
class Row:
    checkpoint: str
    points: float
    max_points: float
    status: str  # passed, failed, error, not attempted, timed out, missing, not graded
    message: str


@dataclass
class SubmissionGrade:
    submission: str
    seed: int
    rows: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    seconds: float = 0.0

    @property
    def points(self) -> float:
        return sum(r.points for r in self.rows)

    @property
    def max_points(self) -> float:
        return sum(r.max_points for r in self.rows)


class NotANotebook(ValueError):
    pass


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


def find_submissions(paths) -> tuple[list[tuple[Path, str]], list[str]]:
    """Notebooks named or held (recursively) by ``paths``; → ([(path, display name)], warnings).

    The display name (the gradebook's ``submission``) is the path relative to the current folder
    when inside it, else ``folder/…`` from the folder named, or ``parent/file`` for a file.
    """
    found, warnings = {}, []
    for p in map(Path, paths):
        if p.is_dir():
            nbs = sorted(q for q in p.rglob("*.ipynb") if ".ipynb_checkpoints" not in q.parts)
            if not nbs:
                warnings.append(f"{p}: folder holds no .ipynb file")
            for q in nbs:
                found.setdefault(q.resolve(), _display_name(q, Path(p.resolve().name) / q.relative_to(p)))
        elif p.is_file():
            found.setdefault(p.resolve(), _display_name(p, Path(p.resolve().parent.name) / p.name))
        else:
            warnings.append(f"{p}: no such file or folder")
    names = list(found.values())  # two files shown alike (same folder name elsewhere): full paths instead
    return [(f, str(f) if names.count(n) > 1 else n) for f, n in found.items()], warnings


def _display_name(path: Path, fallback: Path) -> str:
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(fallback)


def read_code_cells(path: Path) -> list[str]:
    """The code cells' sources of a notebook file; NotANotebook with the reason if it is not one."""
    return read_notebook(path)[0]


def read_notebook(path: Path) -> tuple[list[str], list[str]]:
    """The code cells' sources and, for each, how a student finds it (:func:`cell_label`);
    NotANotebook with the reason if the file is not a notebook.

    Only the sources are kept: tags (``skip-execution``, ``raises-exception``, …), the kernelspec
    and every other metadata field are dropped, so they cannot change how the grader runs it.
    """
    try:
        if path.stat().st_size > MAX_NOTEBOOK_BYTES:
            raise NotANotebook(f"the file is larger than {MAX_NOTEBOOK_BYTES >> 20} MB")
        text = path.read_text(encoding="utf-8")
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
    return label + (f' in section "{_clip(heading, 60)}"' if heading else " before the first heading")


def _short(message: str, name: str) -> str:
    """A checkpoint line without its leading emoji and name (the gradebook has a column for that)."""
    return _clip(re.sub(rf"^\S+ {re.escape(name)}: ", "", message))


def _clip(text: str, limit: int = MAX_MESSAGE) -> str:
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _student_exception(type_name: str, message: str) -> Exception:
    if type_name == "NotImplementedError":
        return NotImplementedError(message)
    name = type_name if type_name.isidentifier() else "Exception"
    return type(name, (Exception,), {})(message)


class OutputTooLarge(Exception):
    pass


def judge(cp: cps.Checkpoint, cases: list, report: dict, defining_note: str | None) -> Row:
    """Grade one checkpoint from the kernel's report, entirely in this process."""
    where = f" ({defining_note})" if defining_note else ""
    if report.get("missing"):
        return Row(cp.name, 0, cp.points, "missing",
                   f"no function named {cp.function} after running the notebook{where}: keep the exercise's "
                   f"function name and signature, the grader calls {cp.function}(…) itself")
    if "not_callable" in report:
        return Row(cp.name, 0, cp.points, "missing",
                   f"{cp.function} is a {report['not_callable']} at the end of the notebook, not a function")
    if "kfkit_function" in report:
        return Row(cp.name, 0, cp.points, "failed",
                   f"{cp.function} is kfkit's own {report['kfkit_function']}, not a function written in the notebook")
    results = report.get("results")
    if not isinstance(results, list) or not all(isinstance(r, dict) for r in results):
        return Row(cp.name, 0, cp.points, "error", "the kernel's result was malformed")
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
        return Row(cp.name, 0, cp.points, "error", f"the output could not be read: {exc}")
    except Exception as exc:  # a judge tripping over a strange output: zero, with the reason
        return Row(cp.name, 0, cp.points, "error",
                   f"the grader could not judge the output ({type(exc).__name__}: {str(exc)[:200]})")
    if result.status == "not attempted":
        return Row(cp.name, 0, cp.points, "not attempted",
                   f"not attempted ({cp.function} still raises NotImplementedError)")
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
        try:
            cases = cp.cases(np.random.default_rng([i, seed]))
            report = run.call(cp.function, [c.args for c in cases])
            row = judge(cp, cases, report, _defining_note(run, sources, cp.function))
        except TimeoutError as exc:
            row = Row(cp.name, 0, cp.points, "timed out", f"{cp.function} {exc} on the grader's cases")
        except KernelLost as exc:
            row = Row(cp.name, 0, cp.points, "timed out" if exc.timed_out else "error",
                      f"calling {cp.function} on the grader's cases: {exc.why}")
        except wire.WireError as exc:
            row = Row(cp.name, 0, cp.points, "error", f"calling {cp.function}: {exc}")
        except OutOfTime:
            raise
        except Exception as exc:  # the checkpoint's own code failed here: not the student's fault
            row = Row(cp.name, 0, cp.points, "not graded",
                      f"GRADER ERROR, regrade this submission: {type(exc).__name__}: {str(exc)[:200]}")
        yield row


def grade_submission(path: Path, checkpoints: list, sandbox: sb.Sandbox, limits: Limits,
                     seed: int | None = None, name: str | None = None) -> SubmissionGrade:
    """Run and grade one notebook file in a fresh kernel; never raises for anything the file contains.

    Over its memory or CPU-time limit the submission is stopped: the checkpoints not graded yet
    score 0 with the limit and the measured value (status "over limit")."""
    start = time.monotonic()
    seed = secrets.randbits(63) if seed is None else int(seed)
    grade = SubmissionGrade(name or str(path), seed)

    def fill(status, message):
        for cp in checkpoints[len(grade.rows):]:
            grade.rows.append(Row(cp.name, 0, cp.points, status, message))

    try:
        sources, labels = read_notebook(Path(path))
    except NotANotebook as exc:
        fill("not graded", f"not graded: {exc}")
        grade.notes.append(str(exc))
        return grade
    try:
        reserve = min(len(checkpoints) * limits.cell_timeout, limits.total_timeout / 2)  # for the grader's calls
        with KernelRun(sources, sandbox, limits, reserve) as run:
            try:
                run.run_notebook()
                grade.rows.extend(grade_checkpoints(run, sources, checkpoints, seed))
            except StoppedByLimit as exc:
                where = (labels[run.current] if run.current < len(sources) else
                         f"the grader's call of {checkpoints[len(grade.rows)].function}")
                text = f"stopped: the submission {exc} while running {where} ({run.meter_kind})"
                fill("over limit", f"not graded, {text}")
                grade.notes.append(text)
            except OutOfTime as exc:
                fill("timed out", f"timed out: not graded, {exc}")
            finally:
                grade.notes += [f"{labels[i]}: {note}" for i, note in sorted(run.cell_notes.items())]
    except RuntimeError as exc:  # the kernel could not start: a grader-side problem, said plainly
        fill("not graded", f"GRADER ERROR, regrade this submission: {exc}")
    grade.seconds = time.monotonic() - start
    return grade


# ---------------------------------------------------------------------------- outputs
FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "'")  # a spreadsheet reads a cell starting so as a formula


def _csv_safe(text: str) -> str:
    """Keep spreadsheet programs from reading a cell as a formula: a leading ``'`` (also before a
    leading ``'``, so that :func:`_csv_unsafe` undoes it exactly)."""
    return "'" + text if text.startswith(FORMULA_START) else text


def _csv_unsafe(text: str) -> str:
    """The value :func:`_csv_safe` was given."""
    return text[1:] if text.startswith("'") else text


def read_gradebook(path: Path) -> list[SubmissionGrade]:
    """The submissions of a gradebook, in its order, with their rows (status: passed when full points).

    Raises ValueError naming the file and line when it is not a kfkit gradebook."""
    grades: dict[str, SubmissionGrade] = {}
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        try:
            if reader.fieldnames != COLUMNS:
                raise ValueError(f"{path}: line 1 should be the header {','.join(COLUMNS)}, not {reader.fieldnames}")
            for r in reader:
                try:
                    points, max_points = float(r["points"]), float(r["max_points"])
                except (TypeError, ValueError):
                    raise ValueError(f"{path}, line {reader.line_num}: points and max_points should be numbers, "
                                     f"not {r['points']!r} and {r['max_points']!r}") from None
                name = _csv_unsafe(r["submission"])
                status = "passed" if points == max_points > 0 else "failed"
                grades.setdefault(name, SubmissionGrade(name, 0)).rows.append(
                    Row(r["checkpoint"], points, max_points, status, _csv_unsafe(r["message"] or "")))
        except (UnicodeDecodeError, csv.Error) as exc:
            raise ValueError(f"{path}, line {reader.line_num + 1}: not a CSV gradebook ({exc})") from None
    return list(grades.values())


def merge_grades(old: list[SubmissionGrade], new: list[SubmissionGrade]) -> list[SubmissionGrade]:
    """``old`` with each regraded submission replaced where it was; new submissions at the end."""
    fresh = {g.submission: g for g in new}
    merged = [fresh.pop(g.submission, g) for g in old]
    return merged + [g for g in new if g.submission in fresh]


def write_gradebook(path: Path, grades: list[SubmissionGrade]):
    rows = []
    for g in grades:
        rows += [{"submission": _csv_safe(g.submission), "checkpoint": r.checkpoint, "points": f"{r.points:g}",
                  "max_points": f"{r.max_points:g}", "message": _csv_safe(r.message)} for r in g.rows]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def feedback_markdown(g: SubmissionGrade, lab: str, sandbox: sb.Sandbox) -> str:
    icon = {"passed": "✅", "not attempted": "⏳"}
    lines = [f"# Lab {lab} feedback: {g.submission}", "",
             f"**Score: {g.points:g} / {g.max_points:g}**", "",
             f"Graded {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} with kfkit {__version__}; "
             f"random cases drawn with seed {g.seed} (regrade the same cases with `--seed {g.seed}`); "
             f"{g.seconds:.1f} s.", "",
             "| checkpoint | points | result |", "| --- | --- | --- |"]
    for r in g.rows:
        msg = r.message.replace("|", "\\|").replace("\n", " ")
        lines.append(f"| {r.checkpoint} | {r.points:g} / {r.max_points:g} | {icon.get(r.status, '❌')} {msg} |")
    if g.notes:
        lines += ["", "## While running your notebook", ""] + [f"- {n}".replace("\n", " ") for n in g.notes]
    lines += ["", f"_Isolation: {sandbox.describe(full=False)}_", ""]
    return "\n".join(lines)


def feedback_names(names: list[str]) -> list[str]:
    """The feedback file of each submission: its gradebook name with ``.md`` for ``.ipynb``, as a
    path under the feedback folder (``submissions/alice.ipynb`` → ``submissions/alice.md``;
    nbgrader's ``submitted/alice/lab01/x.ipynb`` → ``submitted/alice/lab01/x.md``), unique."""
    out, used = [], set()
    for n in names:
        parts = [p for p in Path(n.removesuffix(".ipynb")).parts if p not in ("/", ".", "..")] or ["submission"]
        base = str(Path(*parts))
        cand, k = base, 1
        while cand in used:
            k += 1
            cand = f"{base}_{k}"
        used.add(cand)
        out.append(cand + ".md")
    return out


def summary(grades: list[SubmissionGrade], checkpoints: list, sandbox: sb.Sandbox, warnings=(),
            whole_class: list[SubmissionGrade] | None = None) -> str:
    """What the instructor reads at the end: isolation, pass rates per checkpoint and totals over
    ``whole_class`` (the whole gradebook after ``--update``; default: ``grades``, this run's)."""
    lines = []
    if sandbox.mode == "none":
        lines += ["!" * 78, f"WARNING: {sandbox.describe()}", "!" * 78]
    lines += [f"warning: {w}" for w in warnings]
    seconds = np.mean([g.seconds for g in grades]) if grades else 0.0
    lines.append(f"{len(grades)} submission(s) graded, {seconds:.1f} s per submission; isolation: {sandbox.describe()}")
    grades = grades if whole_class is None else whole_class
    n = len(grades)
    if whole_class is not None:
        lines.append(f"the whole gradebook ({n} submissions):")
    if n:
        width = max(len(cp.name) for cp in checkpoints)
        lines.append(f"{'checkpoint':{width}s}  passed  rate   mean points")
        for cp in checkpoints:
            rows = [r for g in grades for r in g.rows if r.checkpoint == cp.name]
            passed = sum(r.status == "passed" for r in rows)
            mean = sum(r.points for r in rows) / max(len(rows), 1)
            lines.append(f"{cp.name:{width}s}  {passed:3d}/{len(rows):<3d} {100 * passed / max(len(rows), 1):4.0f} %"
                         f"  {mean:.2f} / {cp.points}")
        totals = [g.points for g in grades]
        lines.append(f"total: mean {np.mean(totals):.2f} / {grades[0].max_points:g}, median {np.median(totals):g}")
        errors = [g.submission for g in grades if any("GRADER ERROR" in r.message for r in g.rows)]
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
        line = (f"[{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
                f"{time.monotonic() - self.start:5.0f} s  {label[-40:]}")
        if self.stream.isatty():
            self.stream.write("\r" + line.ljust(100) + ("\n" if self.done == self.total else ""))
        else:
            self.stream.write(line + "\n")
        self.stream.flush()


def _grade_one(args):
    path, name, lab, sandbox, limits, seed = args
    return grade_submission(path, lab_checkpoints(lab), sandbox, limits, seed, name)


def default_feedback_dir(gradebook: Path) -> Path:
    """Where the per-submission feedback goes unless told: ``<gradebook stem>_feedback/`` beside the gradebook."""
    gradebook = Path(gradebook)
    return gradebook.with_name(gradebook.stem + "_feedback")


def grade(paths, lab, out: Path, jobs: int = 1, limits: Limits | None = None, feedback_dir: Path | None = None,
          seed: int | None = None, update: bool = False, progress: bool = True, sandbox: sb.Sandbox | None = None,
          unsandboxed: bool = False):
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
    names = [n for _, n in found]
    tasks = [(f, n, lab, sandbox, limits, seed) for f, n in found]
    bar = _Progress(len(tasks)) if progress else None
    grades = [None] * len(tasks)
    if jobs <= 1 or len(tasks) <= 1:
        for k, task in enumerate(tasks):
            grades[k] = _grade_one(task)
            bar and bar.step(task[1])
    else:
        # fork: workers inherit the imported kit at once; this process has no kernel or thread yet
        ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
        with cf.ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
            futures = {pool.submit(_grade_one, t): k for k, t in enumerate(tasks)}
            for fut in cf.as_completed(futures):
                k = futures[fut]
                try:
                    grades[k] = fut.result()
                except Exception as exc:  # a worker crashed: say so in the gradebook, keep going
                    g = SubmissionGrade(names[k], seed or 0)
                    g.rows = [Row(cp.name, 0, cp.points, "not graded",
                                  f"GRADER ERROR, regrade this submission: {type(exc).__name__}: {exc}")
                              for cp in checkpoints]
                    grades[k] = g
                bar and bar.step(names[k])
    whole_class = merge_grades(earlier, grades) if earlier is not None else None
    write_gradebook(out, whole_class or grades)
    lab_nn = checkpoints[0].name.split(".")[0]
    for g, fname in zip(grades, feedback_names([g.submission for g in grades])):
        (feedback_dir / fname).parent.mkdir(parents=True, exist_ok=True)
        (feedback_dir / fname).write_text(feedback_markdown(g, lab_nn, sandbox), encoding="utf-8")
    return grades, summary(grades, checkpoints, sandbox, warnings, whole_class)


def cli(args) -> int:
    """``kfkit grade``: see :func:`grade`; exit 0 when every submission was graded, 1 otherwise."""
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
    limits = Limits(cell_timeout=args.timeout, total_timeout=args.total_timeout, memory=int(args.max_memory * (1 << 30)),
                    cpu_time=args.max_cpu if args.max_cpu is not None else args.total_timeout)
    try:
        grades, text = grade(args.submissions, args.lab, args.out, jobs=args.jobs, limits=limits,
                             feedback_dir=args.feedback, seed=args.seed, update=args.update,
                             unsandboxed=args.no_sandbox)
    except NoSandbox as exc:
        print(f"kfkit grade: cannot isolate the students' code on this machine, so nothing was graded: {exc}.\n"
              "Grade on Linux with util-linux's 'unshare' (as root, or with user namespaces enabled), e.g. in a "
              "Linux VM or container, or accept the risk with --no-sandbox.", file=sys.stderr)
        return 2
    except ValueError as exc:  # the gradebook to --update is not one
        print(f"kfkit grade: {exc}", file=sys.stderr)
        return 2
    print(text)
    print(f"gradebook: {args.out}; feedback: {args.feedback or default_feedback_dir(args.out)}")
    return 1 if any("GRADER ERROR" in r.message for g in grades for r in g.rows) else 0
