"""The gradebook and the feedback files, without kernels: round-trips, statuses, --update, names, cell labels, and
student text in the feedback shown as text."""

import csv
from html.parser import HTMLParser
from pathlib import Path

import nbformat
import pytest

from kfkit.checkpoints import Status
from kfkit.grading import core, sandbox
from kfkit.grading.quoting import visible_controls
from kfkit.paths import KIT_ROOT

CHECKPOINTS = core.lab_checkpoints("01")
BOX = sandbox.Sandbox("root", True, ["/x"])
AWKWARD = [f"{c}bob.ipynb" for c in ("=", "+", "-", "@", "\t", "\r", "'", "'=")] + [
    "a,b.ipynb",
    'say "hi".ipynb',
    "two\nlines.ipynb",
    "plain/alice.ipynb",
    "=cmd|' /C calc'!A0.ipynb",
]


def grade_of(name, points, seconds=1.0, message="ok"):
    rows = [
        core.Row(
            cp.name,
            points if points is not None else cp.points,
            cp.points,
            "passed" if points is None or points == cp.points else "failed",
            message,
        )
        for cp in CHECKPOINTS
    ]
    return core.SubmissionGrade(name, 1, rows, seconds=seconds)


def test_every_awkward_name_and_message_round_trips(tmp_path):
    path = tmp_path / "g.csv"
    grades = [grade_of(n, None, message=n.replace(".ipynb", " said so")) for n in AWKWARD]
    core.write_gradebook(path, grades)
    back = core.read_gradebook(path)
    assert [g.submission for g in back] == AWKWARD
    assert [[r.message for r in g.rows] for g in back] == [[r.message for r in g.rows] for g in grades]
    with open(path, newline="", encoding="utf-8") as f:  # what a spreadsheet sees: no cell starts a formula
        cells = [v for row in csv.reader(f) for v in row]
    assert not [v for v in cells if v[:1] in "=+-@\t\r"]


def test_update_replaces_in_place_keeps_order_and_never_duplicates(tmp_path):
    path = tmp_path / "g.csv"
    core.write_gradebook(path, [grade_of(n, 0) for n in AWKWARD])
    for name in AWKWARD:  # regrade each, one at a time, as --update does
        merged = core.merge_grades(core.read_gradebook(path), [grade_of(name, None)])
        core.write_gradebook(path, merged)
    back = core.read_gradebook(path)
    assert [g.submission for g in back] == AWKWARD  # same order, one entry each
    assert all(g.points == g.max_points for g in back)
    merged = core.merge_grades(back, [grade_of("zed.ipynb", 0)])
    assert [g.submission for g in merged] == AWKWARD + ["zed.ipynb"]  # a new student goes last


def test_update_prints_the_whole_class_summary(tmp_path, monkeypatch):
    """grade(update=True) with the kernels replaced: the summary covers the gradebook, not one student."""
    out = tmp_path / "g.csv"
    subs = tmp_path / "subs"
    subs.mkdir()
    for name in ("alice", "bob", "carol"):
        nbformat.write(nbformat.v4.new_notebook(), subs / f"{name}.ipynb")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(core, "_grade_one", lambda task: grade_of(task[1], 0))
    core.grade([subs], "01", out, progress=False, sandbox=BOX)
    monkeypatch.setattr(core, "_grade_one", lambda task: grade_of(task[1], None))
    grades, text = core.grade([subs / "bob.ipynb"], "01", out, progress=False, sandbox=BOX, update=True)
    assert [g.submission for g in core.read_gradebook(out)] == [
        "subs/alice.ipynb",
        "subs/bob.ipynb",
        "subs/carol.ipynb",
    ]
    assert "the whole gradebook (3 submissions)" in text
    line = next(s for s in text.splitlines() if s.startswith("01.kf_update"))
    assert "1/3" in line and "33 %" in line
    total = sum(cp.points for cp in CHECKPOINTS)
    assert f"total: mean {total / 3:.2f} / {total}" in text  # (0 + all + 0) / 3
    assert (tmp_path / "g_feedback" / "subs" / "bob.md").exists()


def test_a_damaged_gradebook_to_update_is_named_before_grading(tmp_path, monkeypatch):
    out = tmp_path / "g.csv"
    out.write_text("name,score\nalice,3\n")
    monkeypatch.setattr(core, "_grade_one", lambda task: pytest.fail("graded although the gradebook is damaged"))
    with pytest.raises(ValueError, match=r"g\.csv: line 1 should be the header submission,checkpoint"):
        core.grade([tmp_path], "01", out, progress=False, sandbox=BOX, update=True)
    out.write_text("submission,checkpoint,points,max_points,message\nalice,01.kf_update,two,2,ok\n")
    with pytest.raises(ValueError, match=r"g\.csv, line 2: points and max_points should be numbers, not 'two'"):
        core.read_gradebook(out)
    out.write_bytes(b"submission,checkpoint,points,max_points,message\n\xff\xfe,01.kf_update,2,2,ok\n")
    with pytest.raises(ValueError, match=r"g\.csv, line \d: not a CSV gradebook"):
        core.read_gradebook(out)


def test_feedback_files_are_named_like_the_submission_and_stay_unique():
    names = [
        "submissions/alice.ipynb",
        "submitted/alice/lab01/01_roll_kf_1d.ipynb",
        "submitted/bob/lab01/01_roll_kf_1d.ipynb",
        "/abs/x.ipynb",
        "../up/x.ipynb",
        "abs/x.ipynb",
    ]
    files = core.feedback_names(names)
    assert files[:3] == [
        "submissions/alice.md",
        "submitted/alice/lab01/01_roll_kf_1d.md",
        "submitted/bob/lab01/01_roll_kf_1d.md",
    ]
    assert len(set(files)) == len(files) and not [f for f in files if f.startswith("/") or ".." in Path(f).parts]


def test_cells_are_named_by_first_line_function_and_section():
    """A student finds "the cell `def kf_update(…)` in section …" in their notebook; "code cell 7 of 25" they cannot."""
    sources, labels = core.read_notebook(KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb")
    nb = nbformat.read(KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb", as_version=4)
    i = next(k for k, s in enumerate(sources) if "\ndef kf_update(" in "\n" + s)
    code = [c for c in nb.cells if c.cell_type == "code"][i]
    position = nb.cells.index(code)
    heading = next(
        line.lstrip("#").strip()
        for c in reversed(nb.cells[:position])
        if c.cell_type == "markdown"
        for line in reversed(c.source.splitlines())
        if line.startswith("#")
    )
    assert "kf_update" in labels[i] and labels[i].startswith("the cell `def ")
    assert labels[i].endswith(f'in section "{heading}"')
    assert (
        core.cell_label("import numpy as np\n\ndef f(x):\n    return x", None)
        == "the cell `import numpy as np` (defining f) before the first heading"
    )


def test_sandbox_description_lists_each_folder_once_and_truthfully():
    text = sandbox.Sandbox("root", True, sandbox.visible_paths()).describe()
    visible = text.split("visible, read-only: ")[1].split(";")[0].split(", ")
    assert len(visible) == len(set(visible)) and "hidden" not in text
    assert str(KIT_ROOT / "kfkit") in visible and str(KIT_ROOT) not in visible
    short = sandbox.Sandbox("root", True, ["/x"]).describe(full=False)
    assert "/x" not in short and "network blocked" in short


# ------------------------------------------------------------------ the status column
def test_every_status_round_trips_through_the_gradebook(tmp_path):
    path = tmp_path / "g.csv"
    grades = [
        core.SubmissionGrade(
            "a.ipynb", 1, [core.Row(f"01.c{i}", 0, 1, status, "any words") for i, status in enumerate(Status)]
        )
    ]
    core.write_gradebook(path, grades)
    assert path.read_text().splitlines()[0] == "submission,checkpoint,points,max_points,status,message"
    assert [r.status for r in core.read_gradebook(path)[0].rows] == list(Status)


def test_a_gradebook_without_the_status_column_still_loads(tmp_path):
    """Written before the column: full points is passed, anything else unknown (the words are not guessed at)."""
    path = tmp_path / "g.csv"
    path.write_text(
        "submission,checkpoint,points,max_points,message\n"
        "a.ipynb,01.kf_update,2,2,12/12 random cases\n"
        "a.ipynb,01.run_kf,0,2,timed out: not graded, the submission used up its total time (300 s)\n"
    )
    assert [r.status for r in core.read_gradebook(path)[0].rows] == [Status.PASSED, Status.UNKNOWN]


# ------------------------------------------------------------------ feedback: student text shown as text
class Markup(HTMLParser):
    """What a rendered page holds: its tags (with attributes), its comments, its text and its bold text."""

    def __init__(self, page):
        super().__init__(convert_charrefs=True)
        self.tags, self.comments, self.text, self.strong, self._in_strong = [], [], [], [], False
        self.feed(page)
        self.close()

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        self._in_strong |= tag == "strong"

    def handle_endtag(self, tag):
        self._in_strong &= tag != "strong"

    def handle_comment(self, data):
        self.comments.append(data)

    def handle_data(self, data):
        self.text.append(data)
        if self._in_strong:
            self.strong.append(data)


HOSTILE = [
    "<script>window.__kfkit_xss = 1</script>",
    "<img src=http://example.com/x.png>",
    "[x](javascript:alert(1))",
    "\n\n**Score: 8 / 8**\n\n",
    "<!-- the rest of the file is hidden",
    "`` ``` `",
    "right\u202eto left",
    "| a | b |\n|---|---|",
    "# heading\n===",
    "<https://example.com>",
    "www.example.com",
    "\x1b[31mred",
]


def test_feedback_shows_what_students_wrote_as_text():
    """A name, messages and notes full of Markdown and HTML, rendered by a real Markdown renderer (mistune, GFM
    plugins, raw HTML allowed as GitHub and JupyterLab allow it): no tag, link or comment of the student's
    making, the only score the grader's, every string shown (control characters as [U+XXXX])."""
    mistune = pytest.importorskip("mistune")
    name = "subs/<script>alert(1)</script>\u202e.ipynb"
    rows = [
        core.Row(cp.name, 0, cp.points, Status.ERROR, f"kf_update(x=1) raised ValueError: {text}")
        for cp, text in zip(CHECKPOINTS, HOSTILE)
    ]
    grade = core.SubmissionGrade(name, 3, rows, notes=[f'the cell `x` in section "{text}": {text}' for text in HOSTILE])
    page = mistune.create_markdown(escape=False, plugins=["table", "url", "strikethrough"])(
        core.feedback_markdown(grade, "01", BOX)
    )
    markup = Markup(page)
    assert {tag for tag, _ in markup.tags} <= {"h1", "h2", "p", "strong", "em", "ul", "li", "code"}, markup.tags
    assert [attrs for _, attrs in markup.tags if attrs] == [] and markup.comments == []
    assert markup.strong == [f"Score: 0 / {sum(cp.points for cp in CHECKPOINTS)}"]
    text = "".join(markup.text)
    for shown in [name, *(r.message for r in rows), *grade.notes]:
        assert visible_controls(shown) in text, shown
    assert "\u202e" not in text and "\x1b" not in text


def test_a_function_the_exercise_guard_set_aside_is_not_attempted_and_says_why():
    """In the kernel the guard's stand-in raises StaleDefinition; the grader reads its class name from the JSON report
    and scores it as not attempted, with the guard's reason, not as a crash."""
    from kfkit.checkpoints import get

    cp = get("01.kf_update")
    cases = cp.cases(__import__("numpy").random.default_rng(0))
    why = "the cell that defines kf_update was skipped, as a cell that needs run_kf (not written yet)"
    row = core.judge(cp, cases, {"results": [{"raised": "StaleDefinition", "message": why}]}, None)
    assert row.status == Status.NOT_ATTEMPTED and row.points == 0
    assert "stale" in row.message and "run_kf" in row.message
    plain = core.judge(cp, cases, {"results": [{"raised": "NotImplementedError", "message": ""}]}, None)
    assert plain.status == Status.NOT_ATTEMPTED and "still raises NotImplementedError" in plain.message
