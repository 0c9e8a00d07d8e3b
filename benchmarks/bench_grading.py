"""Grading time per submission and the speed-up of ``--jobs``, on copies of lab 01's solution.

    python benchmarks/bench_grading.py [--copies 20] [--jobs 1 2]

Each copy runs in its own sandboxed kernel (start, all cells, five checkpoint calls, judging),
watched by the memory/CPU-time limits.
Reports wall time, seconds per submission, the speed-up against the first ``--jobs`` value and
the 1-minute load average after each run (other work on the machine slows both); every copy must
score full marks (the table says so), or the figures mean nothing. Budget: under 60 s a submission.
"""

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

from kfkit.grading import core, resources, sandbox
from kfkit.paths import KIT_ROOT


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--copies", type=int, default=20)
    parser.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-grading-"))
    try:
        subs = work / "submissions"
        subs.mkdir()
        for k in range(args.copies):
            shutil.copy(KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb", subs / f"student{k:02d}.ipynb")
        box = sandbox.probe([str(work)])
        parent, why = resources.cgroup_v2_parent()
        print(
            f"{args.copies} copies of solutions/01_roll_kf_1d.ipynb; {os.cpu_count()} cores; "
            f"load average {os.getloadavg()[0]:.1f}; isolation: {box.describe(full=False)}; memory and CPU "
            f"limits: {resources.Cgroup.kind if parent else resources.ProcessTree.kind + ' (' + why + ')'}\n"
        )
        print(
            "| --jobs | wall (s) | s per submission | mean time in a worker (s) | speed-up | all full marks "
            "| load after |"
        )
        print("| --- | --- | --- | --- | --- | --- | --- |")
        first = None
        for jobs in args.jobs:
            t0 = time.perf_counter()
            grades, _ = core.grade([subs], "01", work / f"gradebook_{jobs}.csv", jobs=jobs, progress=False, sandbox=box)
            wall = time.perf_counter() - t0
            first = first or wall
            full = all(g.points == g.max_points for g in grades)
            mean = sum(g.seconds for g in grades) / len(grades)
            print(
                f"| {jobs} | {wall:.1f} | {wall / len(grades):.2f} | {mean:.2f} | {first / wall:.2f}× | {full} "
                f"| {os.getloadavg()[0]:.1f} |"
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
