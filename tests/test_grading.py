"""kfkit grade on real, sandboxed kernels.

One module fixture does the expensive work once, two things at the same time, and the tests read
what it left:

* ``graded``: an instructor runs ``python -m kfkit grade --lab 01 --jobs 2`` (a real subprocess,
  as a new user would) on a folder of honest and adversarial lab 01 submissions built from the
  solution notebook, kept in a folder *outside* /tmp so only the sandbox protects it;
* ``every_lab``: meanwhile, every other lab's solution notebook, run in a fresh sandboxed kernel
  and graded on a fresh seed (``tests/test_checkpoints_every.py`` holds every checkpoint's model answer on many
  seeds, outside the sandbox), then its hand-out's exercise stubs, graded once.

Expected grades come from what each submission does (which function it breaks, how), never from
the grader's own output.
"""

import ast
import base64
import concurrent.futures as cf
import csv
import errno
import json
import multiprocessing
import os
import pickle
import secrets
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from pathlib import Path

import nbformat
import numpy as np
import psutil
import pytest
import zmq
from lab01_notebooks import LAB, SOLUTION, add, append, edit, minimal, read

from kfkit.checkpoints import LABS
from kfkit.cli import main
from kfkit.grading import _kernel_side, core, kernel_client, runner, sandbox, wire
from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

# lab 01's points as the lab's author set them in kfkit/checkpoints/lab01.py
POINTS = {
    "01.accel_roll": 1,
    "01.fuse_gaussians": 2,
    "01.kf_predict": 1,
    "01.kf_update": 2,
    "01.run_kf": 2,
    "01.kf_beats_sensors": 2,
    "01.q_for_time_constant": 2,
}
TIMEOUT = 4  # s of CPU per cell / call in these tests (the grader's warm-up has loaded the heavy modules)
BACKSTOP = int(TIMEOUT * runner.WALL_FACTOR)  # s of wall time after which a cell that computes nothing is stopped
SEEDS_PER_SOLUTION = 1  # fresh seeds each solution is graded on, in one kernel (lab 01: one per CLI submission)
KIT_FILE = KIT_ROOT / "kfkit" / "checkpoints" / "lab01.py"
SITE = Path(sysconfig.get_paths()["purelib"])
# limits for honest notebooks far above what they need, as safety nets (lab 04's Monte Carlo cell is the longest)
GENEROUS = core.Limits(cell_timeout=300, total_timeout=1200)


#: the cells after a looping kf_update: its check (the one timeout), then a call of it, a use of what that call
#: would have made, and a call of run_kf, which calls it: affected by the timeout, not faults of their own
AFTER_THE_LOOP = [
    'check("01.kf_update", kf_update)',
    "update_now = kf_update(0.0, 1.0, 0.5, 0.1)",
    "print(update_now)",
    "state = run_kf(np.ones(3), np.ones(3), 0.1, 1, 1, 0, 1)",
]


class Canaries:
    """The instructor's files a vandal submission goes after; ``intact()`` says which survived."""

    def __init__(self, instructor: Path):
        self.instructor = instructor
        self.files = {
            "instructor file": instructor / "canary.txt",
            "earlier gradebook": instructor / "gradebook_lab00.csv",
            "home file": Path.home() / f".kfkit-grading-canary-{os.getpid()}",
            "kit file": KIT_ROOT / "kfkit" / f".grading-canary-{os.getpid()}",
        }
        for name, path in self.files.items():
            path.write_text(f"{name}, kept")
        # files other people edit meanwhile: the vandal appends a token, and only the token is looked for
        self.token = f"vandal-{secrets.token_hex(8)}"
        self.shared = {"kit module": KIT_FILE, "solution": SOLUTION}
        self.planted = [
            instructor / "planted.txt",
            instructor / "gradebook_feedback" / "planted.md",
            KIT_ROOT / "kfkit" / "planted.py",
            KIT_ROOT / "solutions" / "planted.ipynb",
            SITE / "kfkit_planted.pth",
            Path.home() / f".kfkit-planted-{os.getpid()}",
        ]

    def vandal_cell(self) -> str:
        """Student code trying to change each file and to read the hidden ones.

        accel_roll is redefined to return NaN when any hidden file could be read, so a leak shows
        in the gradebook as a failed 01.accel_roll (and the attempts' errors are in its message)."""
        f = {k: str(v) for k, v in self.files.items()}
        return f"""
import os, socket
attempts, leaked = {{}}, []
for name, act in {{
    "append instructor": lambda: open({f["instructor file"]!r}, "a").write("x"),
    "delete instructor": lambda: os.remove({f["instructor file"]!r}),
    "overwrite gradebook": lambda: open({f["earlier gradebook"]!r}, "w").write("alice,01.x,100,1,ok"),
    "append home": lambda: open({f["home file"]!r}, "a").write("x"),
    "delete home": lambda: os.remove({f["home file"]!r}),
    "append kit module": lambda: open({str(KIT_FILE)!r}, "a").write("\\n# {self.token}"),
    "delete kit file": lambda: os.remove({f["kit file"]!r}),
    "append solution": lambda: open({str(SOLUTION)!r}, "a").write(" {self.token}"),
    **{{"plant " + p: (lambda p=p: open(p, "w").write("import os")) for p in {[str(p) for p in self.planted]!r}}},
    "network": lambda: socket.create_connection(("1.1.1.1", 53), timeout=2),
}}.items():
    try:
        act()
        attempts[name] = "done"
    except Exception as exc:
        attempts[name] = type(exc).__name__
for path in ({f["instructor file"]!r}, {f["home file"]!r}, {str(SOLUTION)!r}):
    try:
        open(path).read()
        leaked.append(path)
    except OSError:
        pass
if leaked:
    def accel_roll(ay, az):
        return float("nan")
print(attempts, leaked)
"""

    def damage(self) -> list[str]:
        """What the vandal managed: changed or deleted files, planted files."""
        done = [name for name, path in self.files.items() if not path.exists() or path.read_text() != f"{name}, kept"]
        done += [name for name, path in self.shared.items() if self.token in path.read_text()]
        return done + [str(p) for p in self.planted if p.exists()]

    def remove(self):
        """Clean up, and take back only what a broken sandbox would have let the vandal append."""
        for path in [*self.files.values(), *self.planted]:
            path.unlink(missing_ok=True)
        for path in self.shared.values():
            text = path.read_text()
            for appended in (f"\n# {self.token}", f" {self.token}"):
                if text.endswith(appended):
                    path.write_text(text[: -len(appended)])


HUGE_PRINT = (
    "print('x' * 30_000_000)\nfor k in range(100):  # 0..99,999 a line each, in 100 messages\n"
    "    print('\\n'.join(map(str, range(1000 * k, 1000 * k + 1000))))"
)  # 30.6 MB in all
ENDLESS_PRINT = "while True:\n    print('y' * 1_000_000, flush=True)"


def build(folder: Path, vandal: str):
    subs = {
        "correct": read(SOLUTION),
        "correct_again": minimal(),
        "blank": read(LAB),
        "wrong": edit(minimal(), "np.arctan2(-ay, -az)", "np.arctan2(ay, -az)"),
        "loop": add(
            edit(minimal(), "return np.arctan2(-ay, -az)", "while True:\n        pass"),
            "import time\nwhile True:  # the student's own infinite loop, outside any exercise\n    time.sleep(0.1)",
            at=-1,
        ),
        "stubborn": edit(
            minimal(),
            "return np.arctan2(-ay, -az)",
            "import signal, time\n    signal.signal(signal.SIGINT, signal.SIG_IGN)  # ignore interrupts"
            "\n    while True:\n        time.sleep(0.1)",
        ),
        "exits": add(
            add(edit(minimal(), "    y = z - x\n", "    import sys\n    sys.exit(1)\n"), "import sys\nsys.exit('bye')"),
            "import os\nos._exit(3)",
        ),
        "huge_print": add(minimal(), HUGE_PRINT),
        "loop_update": append(
            edit(minimal(), "    y = z - x\n", "    while True:\n        pass\n    y = z - x\n"), *AFTER_THE_LOOP
        ),
        "busy": append(
            edit(
                minimal(),
                "return x + omega * dt, P + q",
                "sum(range(2_000))  # slow, but right\n    return x + omega * dt, P + q",
            ),
            "for _ in range(10**9):  # a cell that calls a right function too often\n"
            "    kf_predict(0.0, 1.0, 0.1, 0.01, 1e-4)",
            "after = kf_predict(0.0, 1.0, 0.1, 0.01, 1e-4)",
        ),
        "renamed": edit(
            edit(minimal(), "def accel_roll(", "def accel_roll_v2("), "def kf_update(", "def kf_update_old("
        ),
        "syntax": edit(minimal(), "return x + omega * dt, P + q", "return x + omega * dt, P + q)"),
        "tamper": add(
            read(LAB),
            """
import kfkit, kfkit.checkpoints as C, kfkit.filters as F, kfkit.filters.roll as R
C.run_checkpoint = lambda cp, answer, seed=None: C.CheckResult(cp.name, "passed", 1, 1, cp.points, cp.points, "ok")
C.compare = lambda *a, **k: None
for cp in C.REGISTRY.values():
    object.__setattr__(cp, "judge", lambda case, got: None)
    object.__setattr__(cp, "points", 100)
def kf_predict(x, P, omega, dt, q):
    return (0.0, 0.0)
F.roll_kf_predict = R.roll_kf_predict = kf_predict
from kfkit.filters import roll_kf_update as kf_update
print("✅ 01.kf_predict: 12/12 random cases")
""",
            at=-1,
        ),
        "vandal": add(minimal(), vandal, at=-1),
    }
    for c in subs["correct_again"].cells[1:]:  # tags that would skip cells or excuse errors, ignored
        c.metadata["tags"] = ["skip-execution", "raises-exception"]
    subs["correct_again"].metadata["kernelspec"] = {
        "name": "no-such-kernel",
        "display_name": "nope",
        "language": "cobol",
    }
    for name, nb in subs.items():
        nbformat.write(nb, folder / f"{name}.ipynb")
    (folder / "not_json.ipynb").write_text("this is not JSON {")
    (folder / "binary.ipynb").write_bytes(bytes(range(256)) * 10)
    (folder / "not_notebook.ipynb").write_text(json.dumps({"hello": "world"}))


def graded_rows(path):
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    out = {}
    for r in rows:
        out.setdefault(Path(r["submission"]).stem, {})[r["checkpoint"]] = r
    return rows, out


def grader_kernels(marker):
    found = []
    for p in psutil.process_iter(["cmdline"]):
        try:
            if any(marker in a for a in (p.info["cmdline"] or [])):
                found.append(p)
        except psutil.Error:
            pass
    return found


@pytest.fixture(scope="module")
def instructor():
    """The instructor's course folder: world-readable and outside /tmp (every kernel gets a
    private /tmp anyway), so that only the sandbox stands between it and the students' code."""
    (KIT_ROOT / "build").mkdir(exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix="grading-test-", dir=KIT_ROOT / "build"))
    folder.chmod(0o755)
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="module")
def grading_runs(instructor, tmp_path_factory):
    """The CLI grading of the lab 01 folder (a subprocess, 2 jobs) and, meanwhile, every other lab's
    solution and hand-out (2 more processes): the two overlap where kernels wait on timeouts."""
    subs, empty = instructor / "submissions", instructor / "empty"
    subs.mkdir()
    empty.mkdir()
    (instructor / "gradebook_feedback").mkdir()
    box = sandbox.probe([str(instructor)])
    isolated = box.mode != "none"
    canaries = Canaries(instructor)
    build(subs, canaries.vandal_cell())
    if not isolated:  # never run the vandal unprotected: it would really write into the kit
        (subs / "vandal.ipynb").unlink()
    scratch = Path(tempfile.mkdtemp(prefix="kg-", dir="/tmp"))  # the grader's temporary folders (short: sockets)
    out = instructor / "gradebook.csv"
    cmd = [
        sys.executable,
        "-m",
        "kfkit",
        "grade",
        "--lab",
        "01",
        "--out",
        str(out),
        "--jobs",
        "2",
        "--timeout",
        str(TIMEOUT),
        "--total-timeout",
        "120",
        "submissions",
        "empty",
    ]
    logs = tmp_path_factory.mktemp("cli")
    try:
        with open(logs / "stdout", "w") as stdout, open(logs / "stderr", "w") as stderr:  # the grader writes its copies
            cli = subprocess.Popen(
                cmd + ([] if isolated else ["--no-sandbox"]),
                cwd=instructor,
                stdout=stdout,
                stderr=stderr,
                text=True,
                env={**os.environ, "TMPDIR": str(scratch)},
            )
        others = _grade_every_other_lab(tmp_path_factory, box) if isolated else None
        cli.wait(timeout=900)
        damage = canaries.damage()
    finally:
        canaries.remove()
    stdout, stderr = ((logs / name).read_text() for name in ("stdout", "stderr"))
    rows, by_sub = graded_rows(out) if out.exists() else ([], {})
    yield (
        {
            "isolated": isolated,
            "damage": damage,
            "scratch": scratch,
            "code": cli.returncode,
            "stdout": stdout,
            "stderr": stderr,
            "rows": rows,
            "subs": by_sub,
            "dir": instructor,
            "out": out,
        },
        others,
    )
    shutil.rmtree(scratch, ignore_errors=True)


@pytest.fixture(scope="module")
def graded(grading_runs):
    return grading_runs[0]


@pytest.fixture(scope="module")
def every_lab(grading_runs):
    if grading_runs[1] is None:
        pytest.skip("no isolation possible here: every lab is graded only in a sandbox")
    return grading_runs[1]


def points(graded, sub):
    return {cp: float(r["points"]) for cp, r in graded["subs"][sub].items()}


def message(graded, sub, cp):
    return graded["subs"][sub][cp]["message"]


def feedback(graded, sub):
    return (graded["dir"] / "gradebook_feedback" / "submissions" / f"{sub}.md").read_text()


def test_gradebook_has_one_row_per_checkpoint_and_submission(graded):
    assert graded["code"] == 0, graded["stderr"][-3000:]
    assert list(graded["rows"][0]) == ["submission", "checkpoint", "points", "max_points", "status", "message"]
    assert len(graded["subs"]) == (17 if graded["isolated"] else 16)
    for sub, cps in graded["subs"].items():
        assert {cp: float(r["max_points"]) for cp, r in cps.items()} == POINTS, sub
    assert len(graded["rows"]) == len(graded["subs"]) * len(POINTS)


def test_new_user_grades_a_correct_a_wrong_a_looping_and_a_tampering_submission(graded):
    """The issue's "done when": the four gradebook lines an instructor checks by eye."""
    totals = {sub: sum(points(graded, sub).values()) for sub in ("correct", "wrong", "loop", "tamper")}
    full = sum(POINTS.values())  # a wrong accel_roll loses its 1 point; so does one that loops
    assert totals == {"correct": full, "wrong": full - 1, "loop": full - 1, "tamper": 0}
    assert "timed out" in message(graded, "loop", "01.accel_roll")
    assert "expected" in message(graded, "wrong", "01.accel_roll")
    out, err = graded["stdout"], graded["stderr"]
    assert "01.accel_roll" in out and "passed  rate" in out  # the summary: per-checkpoint pass rates
    assert ("17/17" if graded["isolated"] else "16/16") in err  # the progress bar reached the last submission
    assert "empty: folder holds no .ipynb file" in out  # the empty folder is named, grading went on


def test_cell_tags_and_kernelspec_cannot_change_execution(graded):
    """correct_again: every cell tagged skip-execution and raises-exception, a kernel that does not exist."""
    assert points(graded, "correct_again") == POINTS, graded["subs"]["correct_again"]


def test_wrong_answer_loses_only_its_points_with_expected_vs_got(graded):
    assert points(graded, "wrong") == {**POINTS, "01.accel_roll": 0}
    msg = message(graded, "wrong", "01.accel_roll")
    assert "expected 1.571, got -1.571" in msg or "sign is flipped" in msg


def test_infinite_loop_scores_zero_timed_out_and_the_rest_is_graded(graded):
    """accel_roll loops (busy: stopped after its CPU time), and a cell of the student's sleeps in a loop (stopped by
    the wall-clock backstop, using next to no CPU)."""
    assert points(graded, "loop") == {**POINTS, "01.accel_roll": 0}
    assert message(graded, "loop", "01.accel_roll") == f"accel_roll timed out after {TIMEOUT} s on the grader's cases"
    sleeper = next(line for line in feedback(graded, "loop").splitlines() if "the cell `import time`" in line)
    assert "did not finish: used " in sleeper and f" s of CPU in {BACKSTOP} s (interrupted)" in sleeper, sleeper
    assert float(sleeper.split("used ")[1].split(" s of CPU")[0]) < TIMEOUT


def test_a_loop_is_paid_for_once_and_what_follows_from_it_is_not_a_fault(graded):
    """kf_update loops. Its check cell times out (the only cell that does: before, each cell calling it did, 99.5 s
    for lab 01's four cells at 30 s each); the later cells calling it fail at once and, with the cell that missed
    what one of them would have made, are listed as affected by that loop, not as faults of their own. The grader
    calls kf_update once more on its own cases (one more timeout), then run_kf, which calls it, fails at once."""
    notes = feedback(graded, "loop_update").split("## While running your notebook")[1]
    assert notes.count(f"timed out after {TIMEOUT} s") == 1, notes
    assert f"timed out after {TIMEOUT} s (interrupted) inside kf_update" in notes
    affected = next(line for line in notes.splitlines() if "affected by kf_update timing out" in line)
    for cell in AFTER_THE_LOOP[1:]:
        assert f"the cell `{cell}`" in affected, (cell, affected)
    assert "NameError: name 'update_now' is not defined" in affected
    faults = [line for line in notes.splitlines() if line.startswith("- ") and "affected by" not in line]
    assert not [line for line in faults if "NameError" in line or "TimedOutEarlier" in line], faults
    assert points(graded, "loop_update") == {**POINTS, "01.kf_update": 0, "01.run_kf": 0, "01.kf_beats_sensors": 0}
    rows = graded["subs"]["loop_update"]
    assert {rows[cp]["status"] for cp in ("01.kf_update", "01.run_kf", "01.kf_beats_sensors")} == {"timed out"}
    assert rows["01.kf_update"]["message"] == f"kf_update timed out after {TIMEOUT} s on the grader's cases"
    for cp in ("01.run_kf", "01.kf_beats_sensors"):
        assert rows[cp]["message"] == (
            f"run_kf calls kf_update, which timed out after {TIMEOUT} s on the grader's "
            "cases for 01.kf_update: not run again"
        ), rows[cp]["message"]


def test_a_function_caught_by_a_cells_timeout_is_still_judged_on_the_graders_cases(graded):
    """A cell calls a right (if slow) kf_predict too often and times out, most likely inside kf_predict: the
    grader still calls kf_predict on its own cases, and it earns its point."""
    assert points(graded, "busy")["01.kf_predict"] == 1, graded["subs"]["busy"]["01.kf_predict"]
    assert f"timed out after {TIMEOUT} s (interrupted)" in feedback(graded, "busy")


def test_functions_stopped_in_the_notebook_are_put_back_even_unheard_of(every_lab):
    """The kernel's stubs, not the grader's notes of them, decide: a stop whose answer never reached the grader is
    undone before grading all the same; a grading stop stays."""
    predict, update = every_lab["restored"]
    assert predict == [{"out": {"__tuple__": [0.1, 1.5]}}]
    assert update == [{"raised": "TimedOutEarlier", "message": "kf_update stopped"}]


def test_loop_ignoring_interrupts_restarts_the_kernel_and_grading_goes_on(graded):
    """accel_roll ignores SIGINT and sleeps in a loop: the backstop stops it, the kernel is restarted."""
    assert points(graded, "stubborn") == {**POINTS, "01.accel_roll": 0}
    row = graded["subs"]["stubborn"]["01.accel_roll"]
    assert row["status"] == "timed out" and row["message"].startswith(
        "calling accel_roll on the grader's cases: did not finish: used "
    ), row
    assert row["message"].endswith(f" s of CPU in {BACKSTOP} s and ignored the interrupt"), row


def test_killed_kernel_and_sys_exit(graded):
    assert points(graded, "exits") == {**POINTS, "01.kf_update": 0, "01.run_kf": 0, "01.kf_beats_sensors": 0}
    assert "raised SystemExit" in message(graded, "exits", "01.kf_update")
    text = feedback(graded, "exits")
    assert "SystemExit: bye" in text  # sys.exit() in a cell: an error like any other
    assert "kernel died" in text and "restarted" in text  # os._exit(): restarted, replayed without that cell


def test_huge_print_is_dropped_and_an_endless_one_stopped(graded, every_lab):
    """By the CLI (4 s per cell) the huge print costs no points; with wall-clock limits as mere safety
    nets (so that a busy machine cannot turn the output cap into a timeout), the notes say what happened."""
    assert points(graded, "huge_print") == POINTS
    grade = every_lab["flood"]
    assert {r.checkpoint: r.points for r in grade.rows} == POINTS, grade.rows
    assert any(
        n.startswith("the cell `print('x' * 30_000_000)`") and "printed 30.6 MB of output (discarded)" in n
        for n in grade.notes
    ), grade.notes
    endless = next(n for n in grade.notes if n.startswith("the cell `while True:` before the first heading"))
    assert "printed more than 64 MB of output (stopped); the kernel was restarted and this cell skipped" in endless


def test_tampering_with_kfkit_in_the_kernel_gains_nothing(graded):
    assert set(points(graded, "tamper").values()) == {0}
    assert {float(r["max_points"]) for r in graded["subs"]["tamper"].values()} <= set(POINTS.values())
    assert "kfkit's own kfkit.filters.roll.roll_kf_update" in message(graded, "tamper", "01.kf_update")
    assert "expected" in message(graded, "tamper", "01.kf_predict")
    assert "not attempted" in message(graded, "tamper", "01.accel_roll")


def test_renamed_or_deleted_function_gets_a_clear_message(graded):
    assert points(graded, "renamed")["01.accel_roll"] == 0
    assert "no function named accel_roll" in message(graded, "renamed", "01.accel_roll")
    assert "no function named kf_update" in message(graded, "renamed", "01.kf_update")
    assert points(graded, "renamed")["01.kf_predict"] == 1


def test_syntax_error_names_the_failing_cell(graded):
    p = points(graded, "syntax")
    assert p["01.kf_predict"] == 0 and p["01.kf_update"] == 0 and p["01.accel_roll"] == 1
    assert "SyntaxError" in message(graded, "syntax", "01.kf_predict")


def test_files_that_are_not_notebooks(graded):
    for sub, why in (
        ("not_json", "not valid JSON"),
        ("binary", "not text"),
        ("not_notebook", "not a Jupyter notebook"),
    ):
        assert set(points(graded, sub).values()) == {0}
        assert why in message(graded, sub, "01.accel_roll"), sub


def test_student_code_cannot_change_or_read_instructor_files_or_the_kit(graded):
    if not graded["isolated"]:
        pytest.skip("no sandbox on this machine (see test_grading_refuses_without_isolation)")
    assert graded["damage"] == []
    assert points(graded, "vandal") == POINTS, message(graded, "vandal", "01.accel_roll")  # NaN: something leaked


def test_no_kernel_or_temporary_folder_outlives_grading(graded):
    assert grader_kernels(str(graded["scratch"])) == []
    assert list(graded["scratch"].iterdir()) == []


def test_update_regrades_one_student_and_keeps_the_others(graded, tmp_path, capsys, monkeypatch):
    out = tmp_path / "gradebook.csv"
    out.write_bytes(graded["out"].read_bytes())
    student = graded["dir"] / "submissions" / "renamed.ipynb"
    nbformat.write(minimal(), student)  # the student fixed the names
    monkeypatch.chdir(graded["dir"])  # the same folder as the first run: the same submission names
    assert main(["grade", "--lab", "1", "--out", str(out), "--update", "--seed", "7", "submissions/renamed.ipynb"]) == 0
    rows, subs = graded_rows(out)
    assert len(rows) == len(graded["rows"])
    assert {cp: float(r["points"]) for cp, r in subs["renamed"].items()} == POINTS
    assert subs["correct"] == graded["subs"]["correct"]
    assert "01.kf_update" in capsys.readouterr().out


# ------------------------------------------------------------------ every lab, solution and hand-out
def _grade_solution_then_handout(lab, seeds, box):
    """The solution run top to bottom in a fresh kernel and judged on each seed's fresh cases; then
    the hand-out's own cells where it differs from the solution (its exercise stubs: make-labs
    changes nothing else, and tests/test_notebooks.py runs the whole hand-out) and judged again."""
    solution, handout = (
        core.read_code_cells(next((KIT_ROOT / folder).glob(f"{lab}_*.ipynb"))) for folder in ("solutions", "labs")
    )
    checkpoints = core.lab_checkpoints(lab)
    with runner.KernelRun(solution, box, GENEROUS) as run:
        run.run_notebook()
        solved = {seed: list(core.grade_checkpoints(run, solution, checkpoints, seed)) for seed in seeds}
        notes = dict(run.cell_notes)
        run.sources = [cell for cell in handout if cell not in set(solution)]
        assert run.sources, f"labs/{lab}_* has no exercise stub"
        run.run_notebook()
        return solved, notes, list(core.grade_checkpoints(run, run.sources, checkpoints, seeds[0]))


def _grade_slow(path, box):
    return core.grade_submission(path, core.lab_checkpoints("01"), box, core.Limits(cell_timeout=3, total_timeout=12))


def _grade_generously(path, box):
    return core.grade_submission(path, core.lab_checkpoints("01"), box, GENEROUS)


def _grade_unsandboxed(path):
    return core.grade_submission(path, core.lab_checkpoints("01"), sandbox.Sandbox("none", warning="test"), GENEROUS)


def _restore_unheard_stops(box):
    """A kernel where the notebook's kf_predict was stopped without the grader hearing of it (its answer lost on
    a loaded machine), and kf_update stopped for the grading: → (kf_predict's report, kf_update's) after the
    functions are put back before the grader's calls."""
    sources = [c.source for c in minimal().cells]
    with runner.KernelRun(sources, box, GENEROUS) as run:
        run.run_notebook()
        run._quiet(wire.stop_code(["kf_predict"], "{name} stopped", "KFKITx", False), 60)
        run._quiet(wire.stop_code(["kf_update"], "{name} stopped", "KFKITx", True), 60)
        run._restore_functions()
        return [
            run.call(name, [args])["results"]
            for name, args in (
                ("kf_predict", {"x": 0.0, "P": 1.0, "omega": 1.0, "dt": 0.1, "q": 0.5}),
                ("kf_update", {"x": 0.0, "P": 1.0, "z": 1.0, "r": 1.0}),
            )
        ]


def _grade_every_other_lab(tmp_path_factory, box):
    """Lab 01 is the CLI run's; the others: each solution on a fresh seed, each hand-out once."""
    slow = tmp_path_factory.mktemp("slow") / "slow.ipynb"  # kf_predict loops, and so do three cells at the end
    nb = edit(minimal(), "return x + omega * dt, P + q", "while True:\n        pass")
    for _ in range(3):
        add(nb, "while True:  # a loop of the notebook's own\n    pass", at=len(nb.cells))
    nbformat.write(nb, slow)
    seeds = [secrets.randbits(63) for _ in range(SEEDS_PER_SOLUTION)]
    labs = sorted((name[3:] for name in LABS if name != "lab01"), key=lambda lab: lab != "04")  # longest first
    ctx = multiprocessing.get_context("fork")
    with cf.ProcessPoolExecutor(max_workers=2, mp_context=ctx) as pool:
        jobs = {lab: pool.submit(_grade_solution_then_handout, lab, seeds, box) for lab in labs}
        slow_job = pool.submit(_grade_slow, slow, box)
        plain = tmp_path_factory.mktemp("plain") / "plain.ipynb"
        nbformat.write(minimal(), plain)
        plain_job = pool.submit(_grade_unsandboxed, plain)
        flood = tmp_path_factory.mktemp("flood") / "flood.ipynb"
        nbformat.write(add(add(minimal(), HUGE_PRINT), ENDLESS_PRINT, at=-1), flood)
        flood_job = pool.submit(_grade_generously, flood, box)
        restore_job = pool.submit(_restore_unheard_stops, box)
        return {
            "labs": {lab: f.result() for lab, f in jobs.items()},
            "slow": slow_job.result(),
            "unsandboxed": plain_job.result(),
            "flood": flood_job.result(),
            "restored": restore_job.result(),
        }


OTHER_LABS = [name[3:] for name in LABS if name != "lab01"]


def test_blank_lab_01_scores_zero_not_attempted(graded):
    assert set(points(graded, "blank").values()) == {0}
    assert all(r["message"].startswith("not attempted (") for r in graded["subs"]["blank"].values())


def test_lab_01_full_marks_on_every_fresh_seed(graded):
    """Every submission holding the solution's functions drew its own seed; each scored full."""
    solved = ["correct", "correct_again", "huge_print"] + (["vandal"] if graded["isolated"] else [])
    seeds = {feedback(graded, s).split("seed ")[1].split(" ")[0] for s in solved}
    assert len(seeds) == len(solved)
    for sub in solved:
        assert points(graded, sub) == POINTS, (sub, graded["subs"][sub])


@pytest.mark.parametrize("lab", OTHER_LABS)
def test_every_solution_scores_full_points_on_fresh_seeds(every_lab, lab):
    by_seed, notes, _ = every_lab["labs"][lab]
    assert notes == {}, notes  # the solution ran without an error or a timeout in the sandbox
    for seed, rows in by_seed.items():
        assert [r.checkpoint for r in rows] == [cp.name for cp in core.lab_checkpoints(lab)]
        failed = [(r.checkpoint, r.message) for r in rows if r.points != r.max_points or r.status != "passed"]
        assert failed == [], f"lab {lab}, seed {seed}: {failed}"


@pytest.mark.parametrize("lab", OTHER_LABS)
def test_every_handed_out_lab_scores_zero_not_attempted(every_lab, lab):
    rows = every_lab["labs"][lab][2]
    assert [r.checkpoint for r in rows] == [cp.name for cp in core.lab_checkpoints(lab)]
    for r in rows:
        assert r.points == 0 and r.status == "not attempted", (r.checkpoint, r.message)
        assert r.message.startswith("not attempted (") and "NotImplementedError" in r.message


def test_hanging_cells_and_functions_leave_time_to_grade_the_others(every_lab):
    """3 s of CPU per cell, 12 s in all: the looping cells get the notebook's share (12 s less the 6 kept for the
    5 calls): the first is interrupted after 3 s, the second after what is left of the share, the third is not run;
    kf_predict's call times out, kf_update is graded all the same, and run_kf, which calls kf_predict, fails at
    once."""
    grade = every_lab["slow"]
    rows = {r.checkpoint: r for r in grade.rows}
    assert rows["01.accel_roll"].points == 1 and rows["01.kf_update"].points == 2, grade.rows
    assert rows["01.kf_predict"].status == "timed out"
    assert rows["01.kf_predict"].message == "kf_predict timed out after 3 s on the grader's cases"
    for name in ("01.run_kf", "01.kf_beats_sensors"):
        assert rows[name].points == 0 and rows[name].status == "timed out", rows[name]
        assert rows[name].message.startswith("run_kf calls kf_predict, which timed out after 3 s"), rows[name]
    loops = [note for note in grade.notes if note.startswith("the cell `while True:  # a loop of the notebook's own`")]
    assert len(loops) == 3, grade.notes
    assert loops[0].endswith(": timed out after 3 s (interrupted)"), loops
    share_left = float(loops[1].split("timed out after ")[1].split(" s (interrupted)")[0])
    assert 1 <= share_left < 3, loops  # 6 s less the first cell's 3 and the cells before it; never below 1 s
    assert ": not run: the notebook had used its share of the total time" in loops[2], loops


# ------------------------------------------------------------------ the sandbox itself (no kernel)
ATTACK = r"""
import ctypes, errno, json, os, socket, sys
kit, home, instructor, site = sys.argv[1:5]
res = {}
def attempt(name, act):
    try:
        act()
        res[name] = "done"
    except OSError as exc:
        res[name] = errno.errorcode.get(exc.errno, str(exc.errno))
attempt("append kit module",
        lambda: open(os.path.join(kit, "kfkit", "checkpoints", "lab01.py"), "a").write("#kfkit-attack"))
attempt("new kit file", lambda: open(os.path.join(kit, "kfkit", "planted.py"), "w"))
attempt("chmod kit module", lambda: os.chmod(os.path.join(kit, "kfkit", "checkpoints", "lab01.py"), 0o777))
attempt("rename kit module", lambda: os.rename(os.path.join(kit, "kfkit", "checkpoints", "lab01.py"),
                                               os.path.join(kit, "kfkit", "checkpoints", "lab01.bak")))
attempt("plant .pth in the venv", lambda: open(os.path.join(site, "planted.pth"), "w"))
attempt("new file in /", lambda: open("/planted", "w"))
attempt("append instructor file", lambda: open(os.path.join(instructor, "canary.txt"), "a"))
attempt("append home file", lambda: open(home, "a"))
attempt("read instructor file", lambda: open(os.path.join(instructor, "canary.txt")).read())
attempt("read home file", lambda: open(home).read())
attempt("read solutions", lambda: open(os.path.join(kit, "solutions", "01_roll_kf_1d.ipynb")).read())
attempt("become root", lambda: os.setuid(0) if os.getuid() != 0 else None)
libc = ctypes.CDLL(None, use_errno=True)
def remount():
    if libc.mount(None, kit.encode(), None, ctypes.c_ulong(32 | 4096), None) != 0:  # MS_REMOUNT | MS_BIND, rw
        raise OSError(ctypes.get_errno(), "mount")
attempt("remount the kit read-write", remount)
attempt("network", lambda: socket.create_connection(("1.1.1.1", 53), timeout=2))
def loopback():  # the namespace's own 127.0.0.1 works (lab 00 serves its virtual phone there)
    with socket.create_server(("127.0.0.1", 0)) as server:
        socket.create_connection(server.getsockname(), timeout=2).close()
attempt("loopback", loopback)
res["processes"] = len([p for p in os.listdir("/proc") if p.isdigit()])
res["read kit"] = len(open(os.path.join(kit, "kfkit", "checkpoints", "lab01.py")).read()) > 0
print(json.dumps(res))
"""


@pytest.mark.parametrize("mode", ["root", "userns"])
def test_sandbox_refuses_writes_hides_instructor_files_and_blocks_the_network(instructor, mode):
    if mode == "root" and os.geteuid() != 0:
        pytest.skip("mode 'root' needs root")
    folder = Path(tempfile.mkdtemp(prefix="attack-", dir=instructor))
    folder.chmod(0o755)
    home = Path.home() / f".kfkit-attack-canary-{os.getpid()}"
    try:
        (folder / "canary.txt").write_text("kept")
        home.write_text("kept")
        home.chmod(0o644)
        box = sandbox.probe([str(folder)], modes=[mode])
        if box.mode == "none":
            pytest.skip(f"mode {mode} does not work here: {box.warning}")
        done = sandbox.run_in_sandbox(
            box, [sys.executable, "-c", ATTACK, str(KIT_ROOT), str(home), str(folder), str(SITE)]
        )
        assert done.returncode == 0, done.stderr
        res = json.loads(done.stdout)
        denied = {"EROFS", "EACCES", "EPERM", "ENOENT"}  # read-only mount, permissions, no capability, hidden
        for name, outcome in res.items():
            if name.startswith(
                (
                    "append",
                    "new",
                    "chmod",
                    "rename",
                    "plant",
                    "read instructor",
                    "read home",
                    "read solutions",
                    "remount",
                )
            ):
                assert outcome in denied, (name, outcome)
        assert res["become root"] in denied | {"done"} and res["network"] == "ENETUNREACH"
        assert res["loopback"] == "done"
        assert res["processes"] == 1 and res["read kit"] is True  # its own PID namespace; the kit stays readable
        assert (folder / "canary.txt").read_text() == "kept" and home.read_text() == "kept"
        assert not (KIT_ROOT / "kfkit" / "planted.py").exists() and not (SITE / "planted.pth").exists()
        assert not Path("/planted").exists() and "kfkit-attack" not in KIT_FILE.read_text()
    finally:  # what a broken sandbox would have let through, taken back (only that)
        home.unlink(missing_ok=True)
        for planted in (KIT_ROOT / "kfkit" / "planted.py", SITE / "planted.pth", Path("/planted")):
            planted.unlink(missing_ok=True)
        if KIT_FILE.read_text().endswith("#kfkit-attack"):
            KIT_FILE.write_text(KIT_FILE.read_text()[: -len("#kfkit-attack")])


def test_a_kit_checked_out_under_tmp_is_visible_read_only(tmp_path):
    """CI may check out (and make its venv) under /tmp, which kernels get a private copy of."""
    box = sandbox.probe()
    if box.mode == "none":
        pytest.skip(f"no isolation possible here: {box.warning}")
    kit = tmp_path / "checkout"
    kit.mkdir()
    kit.chmod(0o755)
    tmp_path.chmod(0o755)
    (kit / "module.py").write_text("x = 1")
    box.visible = box.visible + [str(kit)]
    code = (
        f"import os\nprint(open({str(kit / 'module.py')!r}).read())\n"
        f"try:\n    open({str(kit / 'new.py')!r}, 'w')\nexcept OSError as e:\n    print(e.errno)"
    )
    done = sandbox.run_in_sandbox(box, [sys.executable, "-c", code])
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["x", "=", "1", str(errno.EROFS)]


def test_kernels_see_only_the_import_paths_of_a_fresh_python_not_the_graders(tmp_path, monkeypatch):
    """The grader's sys.path (its current folder: the instructor's) must not become visible."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    paths = sandbox.visible_paths.__wrapped__()
    assert not [p for p in paths if str(tmp_path).startswith(p)]
    for must in (KIT_ROOT / "kfkit", KIT_ROOT / "data", sys.prefix, sys.base_prefix, SITE):
        assert [p for p in paths if (os.path.realpath(must) + "/").startswith(p + "/")], must


def test_no_sandbox_mode_still_grades(every_lab):
    """--no-sandbox (macOS, Windows): the kernel runs as the grader, in its temporary folder."""
    assert {r.checkpoint: r.points for r in every_lab["unsandboxed"].rows} == POINTS


def test_no_isolation_is_announced_loudly(tmp_path):
    box = sandbox.probe([str(tmp_path)], modes=[])
    assert box.mode == "none"
    text = core.summary([], core.lab_checkpoints("01"), box)
    assert text.startswith("!!!") and "NOT ISOLATED" in text


def test_grading_refuses_without_isolation_unless_told(tmp_path):
    """Without 'unshare' (macOS, a minimal container) nothing is graded unless --no-sandbox."""
    shutil.copy(LAB, tmp_path / "alice.ipynb")
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "kfkit",
            "grade",
            "--lab",
            "01",
            "--out",
            str(tmp_path / "g.csv"),
            str(tmp_path / "alice.ipynb"),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "PATH": str(tmp_path)},
    )  # no unshare on this PATH
    assert done.returncode == 2
    assert "cannot isolate" in done.stderr and "--no-sandbox" in done.stderr and "unshare" in done.stderr
    assert not (tmp_path / "g.csv").exists()


# ------------------------------------------------------------------ command line
def test_empty_folder_alone_is_an_error(tmp_path, capsys):
    assert main(["grade", "--lab", "01", "--out", str(tmp_path / "g.csv"), str(tmp_path)]) == 1
    assert "holds no .ipynb" in capsys.readouterr().err
    assert not (tmp_path / "g.csv").exists()


def test_unknown_lab_is_named(tmp_path, capsys):
    assert main(["grade", "--lab", "99", "--out", str(tmp_path / "g.csv"), str(tmp_path)]) == 2
    assert "lab01" in capsys.readouterr().err


def test_python_dash_m_kfkit_grade_help():
    out = subprocess.run(
        [sys.executable, "-m", "kfkit", "grade", "--help"], capture_output=True, text=True, check=True
    ).stdout
    assert "--jobs" in out and "--timeout" in out and "--update" in out and "--no-sandbox" in out
    assert "--wall-factor" in out and "CPU seconds per notebook cell" in out


def test_summary_reports_pass_rates():
    grades = [
        core.SubmissionGrade(
            "a",
            1,
            [core.Row("01.accel_roll", 1, 1, "passed", "")]
            + [core.Row(n, 0, p, "failed", "") for n, p in POINTS.items() if n != "01.accel_roll"],
        ),
        core.SubmissionGrade("b", 2, [core.Row(n, 0, p, "failed", "") for n, p in POINTS.items()]),
    ]
    text = core.summary(grades, core.lab_checkpoints("01"), sandbox.Sandbox("root", True, ["/x"]))
    line = next(s for s in text.splitlines() if s.startswith("01.accel_roll"))
    assert "1/2" in line and "50 %" in line


def test_same_named_submissions_from_different_folders_stay_apart(tmp_path):
    for course in ("a", "b"):
        (tmp_path / course / "sub").mkdir(parents=True)
        shutil.copy(LAB, tmp_path / course / "sub" / "alice.ipynb")
    found, _ = core.find_submissions([tmp_path / "a" / "sub" / "alice.ipynb", tmp_path / "b" / "sub" / "alice.ipynb"])
    assert len({sub.name for sub in found}) == 2


# ------------------------------------------------------------------ the wire format (no kernel)
def roundtrip(value):
    text = json.dumps(_kernel_side.encode(value, [wire.MAX_NUMBERS]))
    return wire.decode(json.loads(text))


def test_wire_roundtrip_keeps_numbers_shapes_and_containers():
    a = np.arange(6.0).reshape(2, 3)
    got = roundtrip((a, np.int32(3), [1.5, float("nan")], {"k": np.array([True, False])}, "s", None))
    assert isinstance(got, tuple) and got[0].shape == (2, 3) and np.array_equal(got[0], a)
    assert got[1] == 3 and np.isnan(got[2][1]) and got[3]["k"].dtype == bool and got[4:] == ("s", None)
    assert repr(roundtrip(object())) == "<builtins.object object>"


def test_wire_limits_sizes_and_rejects_malformed_data():
    with pytest.raises(_kernel_side.TooLarge):
        _kernel_side.encode(np.zeros(100), [10])
    for bad in (
        {"__ndarray__": [1, 2], "dtype": "f", "shape": [3]},
        {"__ndarray__": ["a"], "dtype": "f", "shape": [1]},
        {"__ndarray__": [1], "dtype": "V", "shape": [1]},
        {"__object__": "X", "fields": {"not id": 1}},
        {"__object__": "X", "fields": {"__class__": 1}},
        {"__tuple__": 5},
        {"what": 1},
    ):
        with pytest.raises(wire.WireError):
            wire.decode(bad)
    with pytest.raises(wire.WireError):
        wire.extract("no result here", "KFKITabc")
    with pytest.raises(wire.WireError):
        wire.extract("KFKITabc[[[" + "KFKITabc", "KFKITabc")


def test_a_pickle_from_the_kernel_is_never_unpickled(tmp_path):
    """An object whose unpickling would run code comes back as its name, and a report forged as
    a pickle is not read: the grader parses JSON only."""

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {tmp_path / 'pwned'}",))

    assert isinstance(roundtrip(Evil()), wire.Unsupported)
    blob = base64.b64encode(pickle.dumps(Evil())).decode()
    with pytest.raises(wire.WireError):
        wire.extract(f"KFKITabc{blob}KFKITabc", "KFKITabc")
    assert not (tmp_path / "pwned").exists()


def test_grader_side_modules_never_load_pickles():
    """What the kernel sends is only ever parsed as JSON: no pickle/cloudpickle/marshal loads in the
    modules that run in the grader (the kernel side, which unpickles the grader's inputs, is apart)."""
    for module in (core, wire, runner, kernel_client, sandbox):
        tree = ast.parse(Path(module.__file__).read_text())
        calls = {
            f"{n.func.value.id}.{n.func.attr}"
            for n in ast.walk(tree)
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and isinstance(n.func.value, ast.Name)
        }
        assert not {c for c in calls if c.split(".")[1] in ("loads", "load") and c.split(".")[0] != "json"}, module


def test_maxmsgsize_is_set_on_the_graders_sockets():
    km = kernel_client._SandboxKernelManager(kernel_name="python3")
    km.max_message = 1234
    kc = km.client()
    assert kc.context.getsockopt(zmq.MAXMSGSIZE) == 1234
    kc.context.destroy(linger=0)


@pytest.mark.parametrize("lab", [name[3:] for name in LABS])
def test_every_labs_cases_serialise_for_the_kernel(lab):
    """Every checkpoint's inputs (lambdas included) pickle on the grader's side and arrive complete."""
    for i, cp in enumerate(core.lab_checkpoints(lab)):
        cases = cp.cases(np.random.default_rng([i, 1]))
        code = wire.call_code(cp.function, [c.args for c in cases], "KFKITx")
        blob = code.split(f"{cp.function!r}, '", 1)[1].split("'", 1)[0]
        sent = pickle.loads(base64.b64decode(blob))
        assert len(sent) == len(cases) and sent[0].keys() == cases[0].args.keys(), cp.name


def test_killing_the_grader_kills_its_kernels(tmp_path):
    """A grader that dies (SIGKILL, OOM) takes its kernels with it: none is left running."""
    scratch = Path(tempfile.mkdtemp(prefix="kg-", dir="/tmp"))
    nbformat.write(add(minimal(), "import time\nwhile True:\n    time.sleep(0.1)", at=-1), tmp_path / "loop.ipynb")
    with open(tmp_path / "grader.log", "w") as log:  # the grader writes to its own copy of the file
        grader = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "kfkit",
                "grade",
                "--lab",
                "01",
                "--jobs",
                "1",
                "--timeout",
                "60",
                "--out",
                str(tmp_path / "g.csv"),
                str(tmp_path / "loop.ipynb"),
            ],
            env={**os.environ, "TMPDIR": str(scratch)},
            stdout=subprocess.DEVNULL,
            stderr=log,
        )
    try:
        for _ in range(360):
            if any("ipykernel_launcher" in " ".join(p.cmdline()) for p in grader_kernels(str(scratch))):
                break
            time.sleep(0.5)
        else:
            pytest.fail("no kernel started: " + (tmp_path / "grader.log").read_text()[-2000:])
    finally:
        grader.kill()
        grader.wait()
    for _ in range(20):
        if not grader_kernels(str(scratch)):
            break
        time.sleep(0.5)
    assert grader_kernels(str(scratch)) == []
    shutil.rmtree(scratch, ignore_errors=True)
