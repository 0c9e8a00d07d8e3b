"""Memory and CPU time per submission (every process of its kernel together), not per process.

Two ways to measure, one :class:`Watchdog` that stops the submission when over:

* **cgroup v2** (:class:`Cgroup`), where the grader's own cgroup delegates the ``memory`` and ``cpu``
  controllers to its children (its ``cgroup.subtree_control`` lists both: a container or a systemd
  unit with ``Delegate=yes`` whose processes sit in a leaf). Each kernel gets a child cgroup with
  ``memory.max`` (the kernel's OOM killer enforces it at once, the whole group goes:
  ``memory.oom.group``); usage is ``memory.peak`` and ``cpu.stat``'s ``usage_usec``.
* otherwise a **process-tree watchdog** (:class:`ProcessTree`): every ``interval`` seconds it sums,
  over the sandbox's ``unshare`` process and all its descendants, the proportional set size
  (PSS: shared pages split between the processes sharing them, so forked children are not counted
  twice; RSS where PSS cannot be read) and the CPU time (user + system, including reaped
  children's: every process of the PID namespace is reaped inside the tree, so nothing is lost).
  Between two samples a process can still grow, up to the kernel's per-process ``RLIMIT_AS``.

CPU time is seconds of CPU, not wall time, so a busy machine does not make anyone fail; the runner times each
cell and each grader's call by the same count (:attr:`Watchdog.cpu_used`, see :mod:`kfkit.grading.runner`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import uuid
from dataclasses import dataclass
from pathlib import Path

import psutil

GB = 1 << 30


@dataclass(frozen=True)
class Usage:
    memory: int  # bytes held at once by the submission's processes (the largest sample)
    cpu: float  # s of CPU time used (user + system, all processes)


@dataclass(frozen=True)
class OverLimit:
    """Which limit stopped a submission, with the measured value."""

    what: str  # "memory" or "CPU time"
    used: float
    limit: float

    def __str__(self):
        if self.what == "memory":
            return f"used {self.used / GB:.2f} GB of memory at once (limit {self.limit / GB:.2f} GB)"
        return f"used {self.used:.1f} s of CPU time (limit {self.limit:g} s)"


class ProcessTree:
    """Usage of a process and its descendants, from /proc (psutil)."""

    kind = "process-tree watchdog"

    def __init__(self, pid: int):
        self.root = psutil.Process(pid)

    def processes(self) -> list:
        try:
            return [self.root, *self.root.children(recursive=True)]
        except psutil.Error:  # the root is gone: so is its PID namespace
            return []

    def usage(self) -> Usage:
        memory, cpu = 0, 0.0
        for p in self.processes():
            try:
                with p.oneshot():
                    t = p.cpu_times()
                    cpu += t.user + t.system + t.children_user + t.children_system
                    try:
                        memory += p.memory_full_info().pss
                    except (psutil.AccessDenied, AttributeError):  # no smaps access: RSS, counting shared pages
                        memory += p.memory_info().rss
            except psutil.Error:  # exited meanwhile: its time is in its parent's children_* at the next sample
                pass
        return Usage(memory, cpu)

    def kill(self):
        for p in self.processes():
            with contextlib.suppress(psutil.Error):
                p.send_signal(signal.SIGKILL)

    def close(self):
        pass


def cgroup_v2_parent() -> tuple[Path | None, str]:
    """The grader's cgroup v2 folder if it delegates memory and cpu to children; else (None, why not)."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
        rel = next((ln[3:] for ln in lines if ln.startswith("0::")), None)
        mounts = [ln.split(" - ") for ln in Path("/proc/self/mountinfo").read_text().splitlines()]
        point = next((m[0].split()[4] for m in mounts if len(m) == 2 and m[1].split()[0] == "cgroup2"), None)
    except OSError as exc:
        return None, f"cannot read this process's cgroups ({exc.strerror})"
    if rel is None or point is None:
        return None, "no cgroup v2 hierarchy is mounted"
    folder = Path(point) / rel.lstrip("/")
    try:
        delegated = set((folder / "cgroup.subtree_control").read_text().split())
        available = (folder / "cgroup.controllers").read_text().split()
    except OSError as exc:
        return None, f"cannot read {folder} ({exc.strerror})"
    if not {"memory", "cpu"} <= delegated or not os.access(folder, os.W_OK):
        return None, (
            f"cgroup v2 at {folder} does not delegate the memory and cpu controllers (available: "
            f"{' '.join(available) or 'none'}; delegated: {' '.join(sorted(delegated)) or 'none'})"
        )
    return folder, ""


class Cgroup:
    """A child cgroup v2 for one kernel: memory enforced by the kernel, usage read from its files."""

    kind = "cgroup v2"

    def __init__(self, parent: Path, memory: int):
        self.path = parent / f"kfkit-grade-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.path.mkdir()
        (self.path / "memory.max").write_text(str(memory))
        for name, value in (("memory.swap.max", 0), ("memory.oom.group", 1)):  # absent without swap / before 4.19
            if (self.path / name).exists():
                (self.path / name).write_text(str(value))
        self.limit = memory

    def usage(self) -> Usage:
        cpu = next(
            int(ln.split()[1])
            for ln in (self.path / "cpu.stat").read_text().splitlines()
            if ln.startswith("usage_usec")
        )
        events = dict(ln.split() for ln in (self.path / "memory.events").read_text().splitlines())
        peak_file = self.path / "memory.peak"  # Linux 5.19+
        peak = int(peak_file.read_text()) if peak_file.exists() else int((self.path / "memory.current").read_text())
        if int(events.get("oom_kill", 0)):  # the kernel stopped it at the limit: report what it tried to exceed
            peak = max(peak, self.limit + 1)
        return Usage(peak, cpu / 1e6)

    def kill(self):
        (self.path / "cgroup.kill").write_text("1")

    def close(self):
        try:
            self.kill()
            self.path.rmdir()
        except OSError:  # processes still leaving: the folder stays (empty cgroups cost nothing)
            pass


class Watchdog:
    """Samples ``meter`` every ``interval`` s and, when memory or CPU time is over its limit, kills
    the submission's processes and keeps what stopped it in ``over``. ``cpu_before``: CPU seconds
    earlier kernels of the same submission used (a restarted kernel does not start again at 0)."""

    def __init__(self, meter, memory: int, cpu: float, cpu_before: float = 0.0, interval: float = 0.25):
        self.meter, self.memory, self.cpu, self.cpu_before = meter, memory, cpu, cpu_before
        self.interval, self.over, self.peak = interval, None, Usage(0, 0.0)
        self._stop, self._lock = threading.Event(), threading.Lock()  # sampled by its thread and by the grader
        self._thread = threading.Thread(target=self._run, name="kfkit-watchdog", daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.wait(self.interval):
            self.sample()

    def sample(self) -> OverLimit | None:
        with self._lock:
            return self._sample()

    def _sample(self) -> OverLimit | None:
        try:
            now = self.meter.usage()
        except (OSError, StopIteration, ValueError):  # the cgroup went away with the kernel
            return self.over
        self.peak = Usage(max(self.peak.memory, now.memory), max(self.peak.cpu, now.cpu))
        if self.over is None:
            if now.memory > self.memory:
                self.over = OverLimit("memory", now.memory, self.memory)
            elif self.cpu_before + now.cpu > self.cpu:
                self.over = OverLimit("CPU time", self.cpu_before + now.cpu, self.cpu)
            if self.over is not None:
                self.meter.kill()
        return self.over

    @property
    def cpu_used(self) -> float:
        return self.cpu_before + self.peak.cpu

    def stop(self):
        """Stop sampling (after a last sample) and release the cgroup."""
        self._stop.set()
        self._thread.join()
        self.sample()
        self.meter.close()
