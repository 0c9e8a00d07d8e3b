"""Memory and CPU time are limited per submission (all its processes together), and each cell, each grader's call
and the whole submission are timed by CPU time, not wall time, so a busy machine fails nobody; wall-clock limits
are only backstops, for code that waits without computing.

Oracles: what the test's own processes allocate, the kernel's own accounting of a reaped child's CPU time
(``resource.getrusage(RUSAGE_CHILDREN)``), and, for the busy machine, the same grading judged by the wall clock.
"""

import csv
import functools
import os
import re
import resource
import subprocess
import sys
import time

import nbformat
import psutil
import pytest
from lab01_notebooks import edit, minimal
from waiting import HANG_GUARD_S

from kfkit.grading import core, resources, runner, sandbox

#: lab 01's checkpoints, each a row of a lab 01 submission's grade
LAB01 = core.lab_checkpoints("01")

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

MB, GB = 1 << 20, 1 << 30
SAFETY = 120  # s of wall time before a test gives up (never reached when the limits work)

HOLDERS = """
import os, sys, time
for _ in range(3):
    if os.fork() == 0:
        block = bytearray(400 << 20)
        block[::4096] = b"x" * len(block[::4096])  # touch every page: really held
        time.sleep(600)
time.sleep(600)
"""
BUSY = "while True: pass"
REAPED = """
import os
while True:  # short-lived workers, each reaped: their time is in the parent's children_* fields
    pid = os.fork()
    if pid == 0:
        for _ in range(2_000_000):
            pass
        os._exit(0)
    os.waitpid(pid, 0)
"""


def watch(code, memory, cpu):
    proc = subprocess.Popen([sys.executable, "-c", code])
    tree = resources.ProcessTree(proc.pid)
    dog = resources.Watchdog(tree, memory, cpu, interval=0.1)
    seen = set()
    try:
        for _ in range(SAFETY * 10):
            seen |= {p.pid for p in tree.processes()}
            if dog.over or proc.poll() is not None:
                break
            time.sleep(0.1)
        proc.wait(timeout=30)
    finally:
        proc.kill()
        proc.wait()
        dog.stop()
    for _ in range(SAFETY * 10):  # killed children take a moment to die (freeing 400 MB on a busy machine)
        alive = [pid for pid in seen if _running(pid)]
        if not alive:
            break
        time.sleep(0.1)
    return dog, alive, len(seen)


def _running(pid) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def test_three_children_of_400_mb_go_over_1_gb_together():
    """Each process alone is far below the limit; together they are over: killed, memory named."""
    dog, alive, seen = watch(HOLDERS, GB, 1000)
    assert dog.over is not None and dog.over.what == "memory", dog.over
    assert GB < dog.over.used < 3 * 400 * MB + 200 * MB  # the three blocks and one small Python
    assert seen == 4 and alive == [] and "GB of memory at once (limit 1.00 GB)" in str(dog.over)


@pytest.mark.parametrize("code", [BUSY, REAPED], ids=["busy loop", "reaped workers"])
def test_cpu_time_is_counted_across_the_tree_and_stops_the_submission(code):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    dog, _, _ = watch(code, 100 * GB, 2.0)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    used = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)  # the kernel's own count
    assert dog.over is not None and dog.over.what == "CPU time", dog.over
    # it stopped at the limit, on no more than was really used: the kernel's count misses only the worker that was
    # running when the tree was killed (orphaned, init reaps it), which the watchdog saw: one worker's CPU, < 0.25 s
    assert 2.0 < dog.over.used <= used + (0.25 if code is REAPED else 0.05)
    assert used < 2.0 + 1.0  # and soon after (sampled every 0.1 s), whatever the machine's load
    assert "s of CPU time (limit 2 s)" in str(dog.over)


def test_cpu_time_of_earlier_kernels_counts():
    """A restarted kernel does not start again at zero: cpu_before is added."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
    try:
        dog = resources.Watchdog(resources.ProcessTree(proc.pid), 100 * GB, 5.0, cpu_before=5.5, interval=0.1)
        for _ in range(SAFETY * 10):
            if dog.over:
                break
            time.sleep(0.1)
        assert dog.over is not None and dog.over.what == "CPU time" and dog.over.used >= 5.5
        assert proc.wait(timeout=30) < 0  # killed
    finally:
        proc.kill()
        proc.wait()
        dog.stop()


def test_cgroup_v2_limits_where_delegated(tmp_path):
    parent, why = resources.cgroup_v2_parent()
    if parent is None:
        pytest.skip(f"no delegated cgroup v2 here, the process-tree watchdog is used: {why}")
    group = resources.Cgroup(parent, 256 * MB)
    try:
        proc = subprocess.Popen([sys.executable, "-c", HOLDERS])
        (group.path / "cgroup.procs").write_text(str(proc.pid))
        assert proc.wait(timeout=SAFETY) < 0  # the kernel's OOM killer took the whole group
        usage = group.usage()
        assert usage.memory > 256 * MB
    finally:
        group.close()


# ------------------------------------------------------------------ through the grader, in the sandbox
def grade_cells(tmp_path, cells, **limits):
    box = sandbox.probe([str(tmp_path)])
    if box.mode == "none":
        pytest.skip(f"no isolation possible here: {box.warning}")
    nb = nbformat.v4.new_notebook(
        cells=[nbformat.v4.new_markdown_cell("## 1. Roll from the accelerometer")]
        + [nbformat.v4.new_code_cell(c) for c in cells]
    )
    path = tmp_path / "student.ipynb"
    nbformat.write(nb, path)
    limits = core.Limits(cell_timeout=SAFETY, total_timeout=4 * SAFETY, **limits)
    return core.grade_submission(path, core.lab_checkpoints("01"), box, limits, seed=1)


ACCEL_ROLL = "import numpy as np\ndef accel_roll(ay, az):\n    return np.arctan2(-ay, -az)"


def test_a_submission_over_its_memory_is_stopped_and_told_which_limit(tmp_path):
    grade = grade_cells(tmp_path, [ACCEL_ROLL, "# hold memory in three processes" + HOLDERS], memory=GB)
    assert [r.status for r in grade.rows] == ["over limit"] * len(LAB01), grade.rows
    msg = grade.rows[0].message
    assert "GB of memory at once (limit 1.00 GB)" in msg and "the cell `import os, sys, time`" in msg, msg
    assert 'in section "1. Roll from the accelerometer"' in msg
    assert any("limit 1.00 GB" in n for n in grade.notes)


def test_a_submission_over_its_cpu_time_is_stopped_and_told_which_limit(tmp_path):
    t0 = time.process_time()
    grade = grade_cells(tmp_path, [ACCEL_ROLL, "while True:\n    pass"], cpu_time=3.0)
    assert time.process_time() - t0 < SAFETY
    assert {r.status for r in grade.rows} == {"over limit"}, grade.rows
    assert "s of CPU time (limit 3 s)" in grade.rows[0].message and "while True:" in grade.rows[0].message
    used = float(grade.rows[0].message.split("used ")[1].split(" s of CPU")[0])
    assert 3.0 <= used < 3.0 + 1.0  # shown to 0.1 s: a stop 0.02 s past the limit reads "3.0"


# ------------------------------------------------------------------ time is CPU time; the wall clock a backstop
SLEEPING = "import time\nwhile True:\n    time.sleep(0.1)"
IGNORING = "import signal\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nwhile True:\n    pass"


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    """The sandbox where there is one; these tests run only their own code, so without one too."""
    return sandbox.probe([str(tmp_path_factory.getbasetemp())])


def run_cells(box, cells, **limits) -> runner.KernelRun:
    """The cells run in one kernel with ``limits``; → the finished run (its notes, and what each cell spent)."""
    with runner.KernelRun(cells, box, core.Limits(**limits)) as run:
        run.run_notebook()
        return run


def test_a_busy_loop_is_stopped_by_its_cpu_time(box):
    """The watchdog's count of the cell's CPU time decides, not the wall clock (its backstop, 100 × 2 s, is far)."""
    run = run_cells(box, [BUSY, "after = 1"], cell_timeout=2, wall_factor=100)
    assert run.cell_notes == {0: "timed out after 2 s (interrupted)"}  # and the next cell ran
    cpu, _ = run.spent[0]
    assert 2 < cpu < 2 + 1, run.spent  # sampled every 0.25 s, looked at every 0.1 s


def test_a_sleeping_loop_is_stopped_by_the_wall_clock_backstop(box):
    """It uses no CPU: only the backstop, 5 × 1 s here, stops it, and the note says what it used in that time."""
    run = run_cells(box, [SLEEPING, "after = 1"], cell_timeout=1, wall_factor=5)
    note = run.cell_notes.pop(0)
    assert run.cell_notes == {}, run.cell_notes
    used = re.fullmatch(r"did not finish: used (\d+\.\d) s of CPU in 5 s \(interrupted\)", note)
    assert used and float(used[1]) < 1, note
    assert run.spent[0][0] < 1, run.spent


def test_a_busy_loop_ignoring_the_interrupt_loses_its_kernel(box):
    """Interrupted after its 1 s of CPU, it burns on: once it has used INTERRUPT_GRACE_CPU more, the kernel is killed,
    restarted, and the notebook replayed without it."""
    run = run_cells(box, [IGNORING, "after = 1"], cell_timeout=1, wall_factor=100)
    assert run.cell_notes == {
        0: "timed out after 1 s and ignored the interrupt; the kernel was restarted and this cell skipped"
    }
    assert run.restarts == 1 and 1 in run.spent  # the next cell ran, in the new kernel
    grace = 1 + runner.INTERRUPT_GRACE_CPU
    assert grace < run.spent[0][0] < grace + 1.5, run.spent


@pytest.mark.parametrize(
    "loop, factor, why",
    [
        (BUSY, 100, r"the submission used up its total time \(1 s\)"),
        (SLEEPING, 2, r"the submission did not finish: used \d+\.\d s of CPU in 2 s \(the wall-clock backstop\)"),
    ],
    ids=["busy: CPU time", "sleeping: the backstop"],
)
def test_the_total_is_cpu_time_with_a_wall_clock_backstop(box, loop, factor, why):
    """1 s of CPU in all, the backstop ``factor`` × that: the loop takes the lot, the next cell is not run, nor any
    call."""
    limits = core.Limits(cell_timeout=5, total_timeout=1, wall_factor=factor)
    with runner.KernelRun([loop, "after = 1"], box, limits) as run:
        run.run_notebook()
        assert run.cell_notes[1].startswith("not run: the notebook had used its share of the total time"), (
            run.cell_notes
        )
        with pytest.raises(runner.OutOfTime, match=why):
            run.call("accel_roll", [{"ay": 0.0, "az": -9.81}])


# ------------------------------------------------------------------ a busy machine
#: busy loops on the grader's core, each in its own session as other users' jobs are (with the scheduler's autogroups,
#: as on this machine, a session shares the CPU with the other sessions whatever the number of its processes)
BURNERS = 4
SLOW_BUT_RIGHT = """import time
    spent = time.process_time()
    while time.process_time() - spent < 0.04:  # 40 ms of CPU a call, however fast the machine: slow, but right
        pass
    return np.arctan2(-ay, -az)"""


def gradebook(path) -> dict:
    with open(path, newline="", encoding="utf-8") as f:
        return {row["checkpoint"]: row for row in csv.DictReader(f)}


@pytest.mark.slow  # about 2 minutes with one core fully taken
def test_a_busy_machine_fails_nobody_where_the_wall_clock_judge_did(tmp_path, box):
    """A right submission whose accel_roll takes 40 ms of CPU a call (0.5 s for the grader's 13 cases), graded with
    1 s of CPU per cell and call while four busy loops share its core (so it gets at most a fifth of it: 2.6 s of
    wall time for those 0.5 s): full marks. The control: the same grading judged by the wall clock, the old rule
    (--wall-factor 1), at the same time on the same core, times accel_roll out, and its message shows why (less
    than its 1 s of CPU used)."""
    subs = tmp_path / "submissions"
    subs.mkdir()
    nbformat.write(edit(minimal(), "return np.arctan2(-ay, -az)", SLOW_BUT_RIGHT), subs / "slow_but_right.ipynb")
    pin = functools.partial(os.sched_setaffinity, 0, {min(os.sched_getaffinity(0))})
    command = [
        sys.executable,
        "-m",
        "kfkit",
        "grade",
        "--lab",
        "01",
        "--jobs",
        "1",
        "--timeout",
        "1",
        *(["--no-sandbox"] if box.mode == "none" else []),
    ]
    burners = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=pin, start_new_session=True)
        for _ in range(BURNERS)
    ]
    graders = []
    try:
        for rule, extra in (("cpu", []), ("wall", ["--wall-factor", "1"])):
            with open(tmp_path / f"{rule}.log", "w") as log:  # the grader writes to its own copy of the file
                graders.append(
                    subprocess.Popen(
                        command + ["--out", str(tmp_path / f"{rule}.csv"), *extra, str(subs)],
                        preexec_fn=pin,
                        stdout=subprocess.DEVNULL,
                        stderr=log,
                    )
                )
        for grader in graders:
            grader.wait(timeout=HANG_GUARD_S)
    finally:
        for process in burners + graders:
            process.kill()
            process.wait()
    by_cpu, by_wall = gradebook(tmp_path / "cpu.csv"), gradebook(tmp_path / "wall.csv")
    assert {cp: row["status"] for cp, row in by_cpu.items()} == dict.fromkeys(by_cpu, "passed"), by_cpu
    assert len(by_cpu) == len(LAB01)
    control = by_wall["01.accel_roll"]
    assert control["status"] == "timed out", control
    used = re.fullmatch(
        r"accel_roll did not finish: used (\d+\.\d) s of CPU in 1 s on the grader's cases", control["message"]
    )
    assert used and float(used[1]) < 1, control
