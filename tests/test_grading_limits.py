"""Memory and CPU time are limited per submission (all its processes together), by CPU time not
wall time, so these pass on a busy machine; wall-clock timeouts are only safety nets.

Oracles: what the test's own processes allocate, and the kernel's own accounting of a reaped
child's CPU time (``resource.getrusage(RUSAGE_CHILDREN)``).
"""
import resource
import subprocess
import sys
import time

import nbformat
import psutil
import pytest

from kfkit.grading import core, resources, sandbox

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
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_markdown_cell("## 1. Roll from the accelerometer")] +
                                  [nbformat.v4.new_code_cell(c) for c in cells])
    path = tmp_path / "student.ipynb"
    nbformat.write(nb, path)
    limits = core.Limits(cell_timeout=SAFETY, total_timeout=4 * SAFETY, **limits)
    return core.grade_submission(path, core.lab_checkpoints("01"), box, limits, seed=1)


ACCEL_ROLL = "import numpy as np\ndef accel_roll(ay, az):\n    return np.arctan2(-ay, -az)"


def test_a_submission_over_its_memory_is_stopped_and_told_which_limit(tmp_path):
    grade = grade_cells(tmp_path, [ACCEL_ROLL, "# hold memory in three processes" + HOLDERS], memory=GB)
    assert [r.status for r in grade.rows] == ["over limit"] * 5, grade.rows
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
