"""How long a JupyterHub takes to serve N students their first lab, and what one student's server costs.

    python benchmarks/bench_hub.py [--students 1 5 20] [--full-lab]   # as root, with configurable-http-proxy (npm)

For each N, a fresh hub of tests/hub.py (real local users, LocalProcessSpawner, the kit without solutions/)
and N students who "click" at once: the hub starts their servers (REST), nbgitpuller clones the hand-outs
into each home, and a kernel runs lab 01's first three code cells (%matplotlib, the exercise guard, the
kit's imports; the data source; loading the bundled recording). Reported: seconds from the clicks until the first, the
median and the last student has that kernel idle (wall clock: the machine's 2 cores are shared by all N);
CPU seconds of everything the hub ran (hub, proxy, servers, kernels, git; measured when the hub has
exited); memory (PSS, shared pages split fairly) of each student's processes with that kernel alive:
the server alone and server + kernel, median over the students. ``--full-lab``: then one student's kernel
runs all of lab 01 as solved (solutions/01's code cells: every figure, the tuning panel, the q sweep), and
the memory of that student's processes is reported the same way.
"""

import argparse
import json
import os
import resource
import statistics
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from functools import partial
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import hub as hubkit  # tests/hub.py: the same hub the test runs

from kfkit.paths import KIT_ROOT


def first_cells() -> str:
    """Lab 01's first three code cells: the setup, the data source, loading the recording."""
    nb = json.loads((KIT_ROOT / "labs" / "01_roll_kf_1d.ipynb").read_text(encoding="utf-8"))
    code = ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]
    return "\n".join(code[:3])


def solved_lab() -> str:
    """All code cells of solutions/01 (what a student who finished lab 01 has run)."""
    nb = json.loads((KIT_ROOT / "solutions" / "01_roll_kf_1d.ipynb").read_text(encoding="utf-8"))
    return "\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code")


def serve(hub, name, start, code):
    hub.spawn(name)
    hub.wait_ready(name)
    token = hub.user_token(name)
    hub.pull(name, token)
    hub.run_code(name, token, code, keep=True, timeout=600)
    return time.monotonic() - start


def pss_mb(user) -> tuple[float, float]:
    """(server alone, server + kernels) PSS in MB of ``user``'s processes."""
    server = total = 0.0
    for p in psutil.process_iter(["username", "cmdline"]):
        if p.info["username"] != user:
            continue
        try:
            pss = p.memory_full_info().pss / 2**20
        except psutil.Error:
            continue
        total += pss
        if any("jupyterhub-singleuser" in a for a in p.info["cmdline"] or []):
            server += pss
    return server, total


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--students", type=int, nargs="+", default=[1, 5, 20])
    parser.add_argument("--full-lab", action="store_true", help="also: one student runs all of lab 01 (solved)")
    args = parser.parse_args()
    reason = hubkit.why_no_hub()
    if reason:
        sys.exit(f"bench_hub: {reason}")
    code = first_cells()
    print(
        f"{os.cpu_count()} cores, {psutil.virtual_memory().total / 2**30:.0f} GB; load average "
        f"{os.getloadavg()[0]:.1f} at the start\n"
    )
    print(
        "| N | first (s) | median (s) | last (s) | CPU, all processes (s) | CPU per student (s) "
        "| server PSS (MB) | server + kernel PSS (MB) | load after |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for n in args.students:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        with hubkit.Hub(students=n, prefix="kfb") as hub:
            start = time.monotonic()
            with ThreadPoolExecutor(n) as pool:
                waits = sorted(pool.map(partial(serve, hub, start=start, code=code), hub.students))
            memory = [pss_mb(s) for s in hub.students]
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
        print(
            f"| {n} | {waits[0]:.1f} | {statistics.median(waits):.1f} | {waits[-1]:.1f} | {cpu:.0f} | {cpu / n:.1f} "
            f"| {statistics.median(m[0] for m in memory):.0f} | {statistics.median(m[1] for m in memory):.0f} "
            f"| {os.getloadavg()[0]:.1f} |",
            flush=True,
        )
    if args.full_lab:
        with hubkit.Hub(students=1, prefix="kfb") as hub:
            start = time.monotonic()
            seconds = serve(hub, hub.students[0], start, solved_lab())
            server, total = pss_mb(hub.students[0])
        print(
            f"\nlab 01 solved, run whole in one student's kernel: {seconds:.0f} s from the click; "
            f"PSS server {server:.0f} MB, server + kernel {total:.0f} MB"
        )


if __name__ == "__main__":
    main()
