"""The class report (``kfkit report``, ``kfkit grade --report``) on a gradebook of 32 graded lab-01 submissions.

Where the rows come from: each submission is a set of lab-01 functions (correct ones written here, classic
wrong ones, the hand-out's stubs raising NotImplementedError, none at all, one that loops), graded by the
grader's own ``core.grade_checkpoints`` (cases drawn per submission, the grader's call sent through
``wire.call_code`` and run by the kernel-side code in this process instead of a sandboxed kernel, the report
read back with ``wire.extract``, judged by ``core.judge``); ``core.grade`` then writes the gradebook and the
feedback files with its own writer and names (only its per-submission kernel run, ``_grade_one``, is replaced).
A looping function is the one thing simulated: its call raises the runner's ``TimeoutError`` (and, as the
runner does, the function is stopped for the rest of the grading).
The page is opened in headless Chromium (Debian's, as in tests/browser/): DOM, requests, a screenshot.
"""

from __future__ import annotations

import contextlib
import csv
import faulthandler
import functools
import io
import os
import re
import time
from pathlib import Path

import nbformat
import numpy as np
import pytest
from browser.conftest import ARTIFACTS, browser  # noqa: F401 (a fixture)
from waiting import HANG_GUARD_S

from kfkit.checkpoints import Status, lab01
from kfkit.cli import main
from kfkit.grading import core, gradebook, report, runner, sandbox, wire

CHECKPOINTS = core.lab_checkpoints("01")
BOX = sandbox.Sandbox("root", True, ["/x"])
XSS = "window.__kfkit_xss = 1"


# ------------------------------------------------------------------ lab 01 answers: right, classic mistakes, stubs
def accel_roll(ay, az):
    return np.arctan2(-ay, -az)  # f_y = −g sin φ, f_z = −g cos φ


def accel_roll_swapped(ay, az):
    return np.arctan2(-az, -ay)


def accel_roll_flipped(ay, az):
    return np.arctan2(ay, -az)


def kf_predict(x, P, omega, dt, q):
    return x + omega * dt, P + q


def kf_predict_no_q(x, P, omega, dt, q):
    return x + omega * dt, P


def kf_update(x, P, z, r):
    y, S = z - x, P + r
    K = P / S
    return x + K * y, (1 - K) * P, y, S


def kf_update_gain_over_r(x, P, z, r):
    y, S = z - x, P + r
    K = P / r
    with np.errstate(over="ignore", invalid="ignore"):  # K > 1 makes run_kf diverge: that is the mistake
        return x + K * y, (1 - K) * P, y, S


def kf_update_raises(x, P, z, r):
    raise ValueError(f'<img src=x onerror="{XSS}">')


def stub(**_):
    raise NotImplementedError()


def make_run_kf(predict, update):
    def run_kf(gyro_rate, roll_acc, dt, q, r, x0, P0):
        out = np.empty((4, len(gyro_rate)))
        x, P = x0, P0
        for k in range(len(gyro_rate)):
            x, P = predict(x, P, gyro_rate[k], dt, q)
            x, P, y, S = update(x, P, roll_acc[k], r)
            out[:, k] = x, P, y, S
        return tuple(out)

    return run_kf


def answers(roll=accel_roll, predict=kf_predict, update=kf_update):
    return {"accel_roll": roll, "kf_predict": predict, "kf_update": update, "run_kf": make_run_kf(predict, update)}


EMPTY = {"accel_roll": stub, "kf_predict": stub, "kf_update": stub, "run_kf": stub}
#: variant → (its functions, how many students, functions whose call times out)
VARIANTS = {
    "correct": (answers(), 10, ()),
    "swapped": (answers(roll=accel_roll_swapped), 6, ()),
    "flipped": (answers(roll=accel_roll_flipped), 3, ()),
    "gain_over_r": (answers(update=kf_update_gain_over_r), 4, ()),
    "no_q": (answers(predict=kf_predict_no_q), 3, ()),
    "empty": (EMPTY, 3, ()),
    "loops": (answers(), 1, ("run_kf",)),
    "raises": (answers(update=kf_update_raises), 1, ()),
    "nothing": ({}, 1, ()),
}
#: students whose names a browser must show as text (one of the correct ones each)
AWKWARD = ["<script>window.__kfkit_xss = 1", f'<img src=x onerror="{XSS}">', "=HYPERLINK(1)", 'a&amp;b "q"']
#: checkpoint → variants that pass it (the oracle: what each variant's functions do, not what the report counts)
PASSING = {
    "01.accel_roll": {"correct", "gain_over_r", "no_q", "loops", "raises"},
    "01.kf_predict": {"correct", "swapped", "flipped", "gain_over_r", "loops", "raises"},
    "01.kf_update": {"correct", "swapped", "flipped", "no_q", "loops"},
    "01.run_kf": {"correct", "swapped", "flipped"},
}


class InProcessRun:
    """A :class:`kfkit.grading.runner.KernelRun` stand-in whose "kernel" is this process: the grader's call
    cell (``wire.call_code``, the kernel-side code as the kernel runs it) executes over ``namespace``."""

    cell_notes: dict = {}

    def __init__(self, namespace, hangs=()):
        self.namespace, self.hangs, self.stopped = namespace, hangs, {}

    def call(self, function, cases_args, checkpoint=""):
        if function in self.hangs:  # what KernelRun.call does for a call past its timeout
            self.stopped[function] = runner.Stopped(function, 4, "timed out after 30 s", 0, checkpoint)
            raise TimeoutError("timed out after 30 s")
        nonce, out = wire.new_nonce(), io.StringIO()
        with contextlib.redirect_stdout(out):
            exec(wire.call_code(function, cases_args, nonce), dict(self.namespace))
        return wire.extract(out.getvalue(), nonce)


def students():
    """(file stem, variant) of each of the 32 submissions."""
    names, n = [], 0
    for variant, (_, count, _) in VARIANTS.items():
        for _ in range(count):
            stem = AWKWARD[n] if variant == "correct" and n < len(AWKWARD) else f"student_{n:02d}_{variant}"
            names.append((stem, variant))
            n += 1
    return names


@pytest.fixture(scope="module")
def graded(tmp_path_factory):
    """A gradebook of 32 submissions and its feedback files, written by core.grade: → (gradebook, {name: variant})."""
    root = tmp_path_factory.mktemp("class")
    subs = root / "submissions"
    subs.mkdir()
    variant_of = {}
    for stem, variant in students():
        nbformat.write(nbformat.v4.new_notebook(), subs / f"{stem}.ipynb")
        variant_of[stem] = variant

    def grade_one(task):
        path, name, _lab, _box, _limits, seed = task
        functions, _, hangs = VARIANTS[variant_of[Path(path).stem]]
        sources = [f"def {f}(*args):\n    pass" for f in functions]
        g = core.SubmissionGrade(name, seed or 7)
        g.rows = list(core.grade_checkpoints(InProcessRun(functions, hangs), sources, CHECKPOINTS, g.seed))
        return g

    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(root)
        mp.setattr(core, "_grade_one", grade_one)
        mp.setattr(core.sb, "probe", lambda _paths: BOX)
        mp.setattr(lab01, "bundled_inputs", functools.cache(lab01.bundled_inputs))  # read once, not 32 times
        assert main(["grade", "--lab", "01", "--out", "gradebook.csv", "--jobs", "1", "--report", "submissions"]) == 0
    by_name = {f"submissions/{stem}.ipynb": variant for stem, variant in variant_of.items()}
    return root / "gradebook.csv", by_name


def gradebook_rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_the_gradebook_holds_what_each_variant_deserves(graded):
    """The rows behind the report: 32 submissions, each checkpoint passed exactly by the variants that should."""
    path, variant_of = graded
    rows = gradebook_rows(path)
    assert len({gradebook._csv_unsafe(r["submission"]) for r in rows}) == 32
    for cp, passing in PASSING.items():
        passed = {
            gradebook._csv_unsafe(r["submission"])
            for r in rows
            if r["checkpoint"] == cp and float(r["points"]) == float(r["max_points"])
        }
        assert passed == {n for n, v in variant_of.items() if v in passing}, cp


def test_the_same_mistake_groups_and_different_ones_do_not():
    """Random cases give every student different numbers; the mistake must still be one group."""
    cp = next(c for c in CHECKPOINTS if c.name == "01.accel_roll")
    from kfkit import checkpoints as cps

    def groups(fn, seeds):
        return {report.mistake(core._short(cps.run_checkpoint(cp, fn, s).message, cp.name)) for s in seeds}

    swapped, flipped = groups(accel_roll_swapped, range(8)), groups(accel_roll_flipped, range(8))
    assert len(swapped) == 1 and len(flipped) == 1 and swapped != flipped
    assert "swapped" in swapped.pop() and "flipped" in flipped.pop()
    upd = next(c for c in CHECKPOINTS if c.name == "01.kf_update")
    texts = {
        report.mistake(core._short(cps.run_checkpoint(upd, kf_update_gain_over_r, s).message, upd.name))
        for s in range(8)
    }
    assert all(t.startswith("value 1 of 4: expected #, got #") for t in texts), texts
    assert (
        report.mistake("expected 4 values (-0.35, 2.6e-06, 1.1, 3.4e-05), got 1 value: 0.02")
        == "expected 4 values (…), got 1 value: #"
    )


@pytest.mark.slow
def test_report_page_in_a_browser(graded, browser_page):
    """The page in headless Chromium: every student a row linking their feedback, the charts' numbers equal the
    gradebook's, the classic mistakes grouped, awkward names shown as text, nothing fetched from anywhere."""
    path, variant_of = graded
    page_path = path.with_name("gradebook_report.html")
    assert page_path.is_file()  # written by kfkit grade --report
    assert main(["report", str(path), "--out", str(path.parent / "again" / "report.html")]) == 0
    requests = []
    browser_page.on("request", lambda r: requests.append(r.url))
    browser_page.goto(page_path.as_uri())
    browser_page.wait_for_selector("tr.student")
    assert requests == [page_path.as_uri()]  # no script, style, font or image from anywhere
    assert browser_page.evaluate("() => window.__kfkit_xss") is None
    assert browser_page.locator("script").count() == 0 and browser_page.locator("img").count() == 0

    rows = gradebook_rows(path)
    students = browser_page.locator("tr.student")
    assert students.count() == 32
    names = [students.nth(i).locator("td").first.inner_text() for i in range(32)]
    for awkward in AWKWARD:
        assert f"submissions/{awkward}.ipynb" in names
    feedback_dir = path.with_name("gradebook_feedback")
    for i in range(32):  # each link opens that student's feedback, embedded: the page can be mailed alone
        link = students.nth(i).locator("td a")
        name, href = link.inner_text(), link.get_attribute("href")
        assert href.startswith("#feedback-")
        embedded = browser_page.locator(f"section{href} pre").inner_text()
        file = feedback_dir / gradebook.feedback_names([name])[0]
        assert embedded.rstrip() == file.read_text(encoding="utf-8").rstrip() and f"feedback: `{name}`" in embedded

    # the stacked bars: per checkpoint the outcomes add up to the class, passed = the gradebook's full marks
    for cp in CHECKPOINTS:
        segs = browser_page.locator(f'rect.segment[data-checkpoint="{cp.name}"]')
        counts = {
            segs.nth(i).get_attribute("data-outcome"): int(segs.nth(i).get_attribute("data-count"))
            for i in range(segs.count())
        }
        full = sum(1 for r in rows if r["checkpoint"] == cp.name and float(r["points"]) == float(r["max_points"]))
        assert sum(counts.values()) == 32 and counts.get("passed", 0) == full, (cp.name, counts)
    accel = browser_page.locator('rect.segment[data-checkpoint="01.accel_roll"]')
    assert {accel.nth(i).get_attribute("data-outcome") for i in range(accel.count())} == {
        "passed",
        "failed",
        "not attempted",
        "missing",
    }
    run_kf = browser_page.locator('rect.segment[data-checkpoint="01.run_kf"][data-outcome="timed out"]')
    assert run_kf.get_attribute("data-count") == "1"

    # the histogram: one bar per point total, its counts those of the gradebook's totals
    totals = {}
    for r in rows:
        totals[r["submission"]] = totals.get(r["submission"], 0) + float(r["points"])
    bars = browser_page.locator("svg.histogram rect.bar")
    hist = {
        int(bars.nth(i).get_attribute("data-points")): int(bars.nth(i).get_attribute("data-count"))
        for i in range(bars.count())
    }
    most = int(sum(float(r["max_points"]) for r in rows if r["submission"] == rows[0]["submission"]))  # the lab's total
    assert hist == {k: sum(1 for t in totals.values() if int(t) == k) for k in range(most + 1)}

    mistakes = browser_page.locator("tr.mistake").all_inner_texts()
    swapped = next(m for m in mistakes if "swapped" in m)
    assert swapped.startswith("01.accel_roll\t6\t")  # the six students' random numbers differ; one group
    assert any(m.startswith("01.kf_update\t4\tvalue 1 of 4") for m in mistakes)
    assert any(f'raised ValueError: <img src=x onerror="{XSS}">' in m for m in mistakes)  # shown, not run
    follow = {li.get_attribute("data-group"): li.inner_text() for li in browser_page.locator("li.follow-up").all()}
    empty = sorted(n for n, v in variant_of.items() if v in ("empty", "nothing"))
    assert follow["attempted nothing"].endswith(", ".join(empty))
    assert follow["timed out or stopped by a limit"].endswith(next(n for n, v in variant_of.items() if v == "loops"))
    browser_page.screenshot(path=str(ARTIFACTS / "class_report.png"), full_page=True)


def test_bad_gradebooks_are_named(tmp_path, capsys):
    bad = tmp_path / "marks.csv"
    bad.write_text("name,score\nalice,3\n")
    assert main(["report", str(bad)]) == 2
    assert "marks.csv: line 1 should be the header submission,checkpoint" in capsys.readouterr().err
    bad.write_text(",".join(core.COLUMNS) + "\n")
    assert main(["report", str(bad)]) == 2
    assert "marks.csv: the gradebook holds no submission" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "none.csv")]) == 2
    assert "none.csv" in capsys.readouterr().err


def test_a_missing_feedback_file_is_said_not_linked(tmp_path):
    path = tmp_path / "g.csv"
    core.write_gradebook(
        path, [core.SubmissionGrade("subs/x.ipynb", 1, [core.Row("01.accel_roll", 1, 1, "passed", "ok")])]
    )
    page = report.write_report(path).read_text(encoding="utf-8")
    assert "subs/x.ipynb <small>(no feedback file)</small>" in page and "<a " not in page


# ------------------------------------------------------------------ a hand-edited gradebook, hostile text
def row_line(name, checkpoint, points, max_points, status, message):
    return ",".join([name, checkpoint, points, max_points, status, message]) + "\n"


@pytest.mark.parametrize(
    "points, max_points, status, why",
    [
        ("nan", "2", "failed", "should be finite, not 'nan'"),
        ("1", "inf", "failed", "should be finite"),
        ("0", "1e6", "failed", "max_points 1e+06 is outside 0 … 1000"),
        ("-1", "2", "failed", "points -1 is outside 0 … max_points (2)"),
        ("3", "2", "passed", "points 3 is outside 0 … max_points (2)"),
        ("2", "2", "great", "status 'great' is not one of passed, failed"),
    ],
)
def test_a_hand_edited_gradebook_is_refused_with_file_and_line(tmp_path, capsys, points, max_points, status, why):
    path = tmp_path / "marks.csv"
    path.write_text(
        ",".join(gradebook.COLUMNS)
        + "\n"
        + row_line("alice", "01.kf_update", "2", "2", "passed", "ok")
        + row_line("bob", "01.kf_update", points, max_points, status, "ok"),
        encoding="utf-8",
    )
    assert main(["report", str(path)]) == 2
    err = capsys.readouterr().err
    assert "marks.csv, line 3: " in err and why in err, err
    assert not path.with_name("marks_report.html").exists()


def test_the_report_reads_the_status_column_not_the_words():
    """Each row is counted by its status, whatever its message says (the words are for people)."""
    words = ["timed out: not graded", "not attempted (x)", "GRADER ERROR, regrade", "no function named x", "fine"]
    grades = [
        gradebook.SubmissionGrade(f"s{i}", 1, [gradebook.Row("01.x", 0, 1, status, words[i % len(words)])])
        for i, status in enumerate(Status)
    ]
    page = report.render(grades, "t", {})
    assert sorted(re.findall(r'data-outcome="([^"]+)" data-count="1"', page)) == sorted(s.value for s in Status)
    assert set(report.OUTCOMES) == set(Status)  # every status has its colour


def test_bidi_controls_long_tokens_and_huge_rows_stay_text_and_bounded(tmp_path):
    """A U+202E in a name, a 5,000-character token, 100,000-character messages and names, 1,000-point
    checkpoints and a huge feedback file: shown escaped, clipped, and the page within its stated bound."""
    n, m = 4, 6
    token = "A" * 5000
    names = [f"s{token}.ipynb", f"evil\u202e{'&' * 100_000}.ipynb", f"{'&' * 100}.ipynb", "plain.ipynb"]  # no file
    messages = [token, '"\u202e' * 50_000, "<" * 100_000, "x"]  # can have the first two names
    rows = [
        gradebook.SubmissionGrade(
            name, 1, [gradebook.Row(f"01.c{k}", 1000 * (k % 2), 1000, Status.FAILED, message) for k in range(m)]
        )
        for name, message in zip(names, messages)
    ]
    path = tmp_path / "g.csv"
    gradebook.write_gradebook(path, rows)
    for name in gradebook.feedback_names(names)[2:]:
        (tmp_path / "g_feedback" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "g_feedback" / name).write_text("\u202e<" * 500_000, encoding="utf-8")
    page = report.write_report(path).read_bytes()
    assert len(page) <= report.page_bound(n, m) <= 4_000_000, (len(page), report.page_bound(n, m))
    text = page.decode("utf-8")
    assert "\u202e" not in text and "[U+202E]" in text
    assert max(map(len, re.findall(r"A+", text))) <= report.MESSAGE_CHARS  # the token: clipped where shown
    assert "overflow-wrap:anywhere" in text  # and what is shown wraps


def test_title_names_the_lab_and_the_gradebooks_date(tmp_path):
    path = tmp_path / "g.csv"
    gradebook.write_gradebook(
        path, [gradebook.SubmissionGrade("a", 1, [gradebook.Row("01.x", 1, 1, Status.PASSED, "ok")])]
    )
    when = time.mktime((2024, 3, 5, 12, 0, 0, 0, 0, -1))
    os.utime(path, (when, when))
    page = report.write_report(path).read_text(encoding="utf-8")
    assert "<title>Lab 01 class report, 2024-03-05 (g.csv)</title>" in page


def accel_roll_half_turn(ay, az):
    return np.arctan2(ay, az)  # both signs wrong: the angle is off by π


def test_grouped_failures_keep_the_number_that_explains_the_mistake():
    cp = next(c for c in CHECKPOINTS if c.name == "01.accel_roll")
    from kfkit import checkpoints as cps

    texts = {
        report.mistake(core._short(cps.run_checkpoint(cp, accel_roll_half_turn, s).message, cp.name)) for s in range(6)
    }
    assert len(texts) == 1 and "exactly 180° off" in texts.pop()


OLD_NUMBER = re.compile(r"(?<![\w.])[-−]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(?![\w.])")  # the report's old pattern


def test_numbers_are_masked_as_the_old_pattern_did_but_in_one_pass():
    """An independent oracle where it is cheap: the regular expression the report used to mask with, on
    short random strings (backtracking costs nothing there). Then a 200,000-digit run followed by a letter,
    which that pattern takes hours on (quadratic backtracking: 24 s for 16,000 digits): the answer must
    come (a hang guard, not a timing: the assertion is on the result)."""
    rng = np.random.default_rng(5)
    alphabet = list("0123456789.eE-+−x_ ,()a٣")
    for _ in range(20_000):
        text = "".join(rng.choice(alphabet, size=rng.integers(0, 14)))
        assert report.mask_numbers(text) == OLD_NUMBER.sub("#", text), text
    faulthandler.dump_traceback_later(HANG_GUARD_S, exit=True)
    try:
        assert (
            report.mistake("expected " + "7" * 200_000 + "x, got 1. Hint: h")
            == "expected " + "7" * 200_000 + "x, got #"
        )
        assert report.mistake("got " + "1 " * 100_000) == "got" + " #" * 100_000
    finally:
        faulthandler.cancel_dump_traceback_later()


def test_long_tokens_wrap_in_a_browser(tmp_path, browser_page):
    """A 5,000-character token in a name, a message and a feedback file: the page stays as wide as the window."""
    token = "W" * 5000
    path = tmp_path / "g.csv"
    gradebook.write_gradebook(
        path,
        [
            gradebook.SubmissionGrade(
                f"{token[:200]}.ipynb",
                1,
                [gradebook.Row(f"01.c{k}", 0, 1, Status.FAILED, f"expected 1, got {token}") for k in range(5)],
            )
        ],
    )
    (tmp_path / "g_feedback").mkdir()
    (tmp_path / "g_feedback" / f"{token[:200]}.md").write_text(token)
    browser_page.goto(report.write_report(path).as_uri())
    browser_page.wait_for_selector("tr.student")
    widths = browser_page.evaluate("() => [document.documentElement.scrollWidth, window.innerWidth]")
    assert widths[0] <= widths[1], widths


# ------------------------------------------------------------------ the browser: tests/browser/'s (Debian's Chromium)
@pytest.fixture(scope="module")
def browser_page(browser):  # noqa: F811  (the browser fixture imported from tests/browser/conftest.py)
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    yield context.new_page()
    context.close()
