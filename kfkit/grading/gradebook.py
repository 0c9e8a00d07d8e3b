"""The gradebook file ``kfkit grade`` writes and ``kfkit report`` and ``--update`` read, and its feedback folder.

``submission,checkpoint,points,max_points,status,message``: one row per submission and checkpoint, ``status``
one of :class:`kfkit.checkpoints.Status` (what happened: passed, failed, timed out, over a limit, refused, …;
the message says it in words, and nothing reads the words back). A gradebook may have been edited by hand, so
reading one checks every row (ValueError naming the file and line): points finite and within
``0 ≤ points ≤ max_points ≤ MAX_POINTS``, a known status.

Gradebooks written before the ``status`` column (``submission,checkpoint,points,max_points,message``) still
load: :func:`legacy_status` gives each row its status, the one place where that is guessed.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

from ..checkpoints import Status

COLUMNS = ["submission", "checkpoint", "points", "max_points", "status", "message"]
LEGACY_COLUMNS = [c for c in COLUMNS if c != "status"]
MAX_POINTS = 1000  # points one checkpoint may be worth (kfkit's are worth 1 to 3): a typo of 1e6 is refused
FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "'")  # a spreadsheet reads a cell starting so as a formula


@dataclass
class Row:
    checkpoint: str
    points: float
    max_points: float
    status: Status
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


def legacy_status(points: float, max_points: float) -> Status:
    """The status of a row from a gradebook without the column: passed with all its points (> 0), else
    unknown (its message says what happened; regrade to have it recorded)."""
    return Status.PASSED if points == max_points > 0 else Status.UNKNOWN


def _csv_safe(text: str) -> str:
    """Keep spreadsheet programs from reading a cell as a formula: a leading ``'`` (also before a
    leading ``'``, so that :func:`_csv_unsafe` undoes it exactly)."""
    return "'" + text if text.startswith(FORMULA_START) else text


def _csv_unsafe(text: str) -> str:
    """The value :func:`_csv_safe` was given."""
    return text[1:] if text.startswith("'") else text


def read_gradebook(path: Path) -> list[SubmissionGrade]:
    """The submissions of a gradebook, in its order, with their rows.

    Raises ValueError naming the file and line when it is not a kfkit gradebook or a row is out of bounds."""
    grades: dict[str, SubmissionGrade] = {}
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        try:
            if reader.fieldnames not in (COLUMNS, LEGACY_COLUMNS):
                raise ValueError(f"{path}: line 1 should be the header {','.join(COLUMNS)}, not {reader.fieldnames}")
            for r in reader:
                where = f"{path}, line {reader.line_num}"
                points, max_points = _points(r, where)
                if "status" in r:
                    try:
                        status = Status(r["status"])
                    except ValueError:
                        raise ValueError(
                            f"{where}: status {r['status']!r} is not one of {', '.join(s.value for s in Status)}"
                        ) from None
                else:
                    status = legacy_status(points, max_points)
                name = _csv_unsafe(r["submission"] or "")
                grades.setdefault(name, SubmissionGrade(name, 0)).rows.append(
                    Row(r["checkpoint"] or "", points, max_points, status, _csv_unsafe(r["message"] or ""))
                )
        except (UnicodeDecodeError, csv.Error) as exc:
            raise ValueError(f"{path}, line {reader.line_num + 1}: not a CSV gradebook ({exc})") from None
    return list(grades.values())


def _points(r: dict, where: str) -> tuple[float, float]:
    """(points, max_points) of a row, checked: finite numbers, 0 ≤ points ≤ max_points ≤ MAX_POINTS."""
    try:
        points, max_points = float(r["points"]), float(r["max_points"])
    except (TypeError, ValueError):
        raise ValueError(
            f"{where}: points and max_points should be numbers, not {r['points']!r} and {r['max_points']!r}"
        ) from None
    if not (math.isfinite(points) and math.isfinite(max_points)):
        raise ValueError(
            f"{where}: points and max_points should be finite, not {r['points']!r} and {r['max_points']!r}"
        )
    if not 0 <= max_points <= MAX_POINTS:
        raise ValueError(
            f"{where}: max_points {max_points:g} is outside 0 … {MAX_POINTS} (a checkpoint of kfkit is "
            "worth a few points)"
        )
    if not 0 <= points <= max_points:
        raise ValueError(f"{where}: points {points:g} is outside 0 … max_points ({max_points:g})")
    return points, max_points


def merge_grades(old: list[SubmissionGrade], new: list[SubmissionGrade]) -> list[SubmissionGrade]:
    """``old`` with each regraded submission replaced where it was; new submissions at the end."""
    fresh = {g.submission: g for g in new}
    merged = [fresh.pop(g.submission, g) for g in old]
    return merged + [g for g in new if g.submission in fresh]


def write_gradebook(path: Path, grades: list[SubmissionGrade]):
    rows = []
    for g in grades:
        rows += [
            {
                "submission": _csv_safe(g.submission),
                "checkpoint": r.checkpoint,
                "points": f"{r.points:g}",
                "max_points": f"{r.max_points:g}",
                "status": Status(r.status).value,
                "message": _csv_safe(r.message),
            }
            for r in g.rows
        ]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def default_feedback_dir(gradebook: Path) -> Path:
    """Where the per-submission feedback goes unless told: ``<gradebook stem>_feedback/`` beside the gradebook."""
    gradebook = Path(gradebook)
    return gradebook.with_name(gradebook.stem + "_feedback")


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
