"""One student notebook in one sandboxed kernel: run its cells, then call its functions.

:class:`KernelRun` drives nbclient cell by cell (errors do not stop the run: a later exercise
may still be right), with a per-cell timeout bounded by the submission's total deadline, of
which ``reserve`` seconds are kept for the grader's calls (so a looping function that every later
cell calls still leaves time to grade the other functions; cells past that share are not run). A cell
that times out is interrupted; if the kernel stays busy or dies (``sys.exit`` in a thread,
``os._exit``, a crash), the kernel is restarted and the notebook replayed without that cell.
Outputs of student cells are counted and dropped (only an error's name and message, cut short, are
kept), so a huge print costs nothing but its transfer; a cell that prints more than
``Limits.max_cell_output`` is stopped the same way (its kernel restarted, as a thread may go on printing), and no single
message above ``Limits.max_message`` is even received (ZeroMQ's MAXMSGSIZE on the grader's sockets).
Memory and CPU time are limited per submission, all its processes together
(:mod:`kfkit.grading.resources`): over either, the submission is stopped (:class:`StoppedByLimit`).
"""
from __future__ import annotations

import asyncio
import ctypes
import json
import logging
import math
import os
import shutil
import signal
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import nbformat
import zmq
import zmq.asyncio
from jupyter_client.manager import AsyncKernelManager
from nbclient import NotebookClient
from nbclient.exceptions import CellTimeoutError, DeadKernelError

from . import CELL_TIMEOUT, TOTAL_TIMEOUT
from . import resources
from . import sandbox as sb
from . import wire

MAX_RESTARTS = 3
WARM_UP_TIMEOUT = 120.0  # s for the kernel's first imports, not charged to the student's first cell
WARM_UP_MODULES = ("numpy", "scipy.linalg", "matplotlib.pyplot", "ipywidgets", "kfkit.datasets", "kfkit.filters",
                   "kfkit.frames", "kfkit.metrics", "kfkit.plots", "kfkit.widgets", "kfkit.checkpoints")
_WARM_UP_CODE = f"""
import importlib
for name in {WARM_UP_MODULES!r}:
    try:
        importlib.import_module(name)
    except Exception:  # a missing optional module: the student's own import will say so
        pass
"""
WARM_UP = f"exec({_WARM_UP_CODE!r}, {{}})"  # the labs' heavy imports, outside the student's namespace
SHORT_TMP = 48  # characters of temporary folder that leave room for box/ipc-N in an AF_UNIX path (≤ 107)
PING_TIMEOUT = 5.0  # s a kernel gets to answer after an interrupted cell before it is restarted
IOPUB_TIMEOUT = 10  # s from a cell's reply to its last output; longer means the kernel's output has died
_LOG = logging.getLogger("kfkit.grading.nbclient")
_LOG.setLevel(logging.CRITICAL)


@dataclass
class Limits:
    cell_timeout: float = CELL_TIMEOUT  # s per notebook cell and per checkpoint call
    total_timeout: float = TOTAL_TIMEOUT  # s for the whole submission
    output_bytes: int = 1 << 20  # output of one student cell beyond which it is reported as huge
    max_cell_output: int = 64 << 20  # output of one cell beyond which it is stopped
    max_message: int = 256 << 20  # bytes of one message from the kernel beyond which it is not even read
    memory: int = 4 << 30  # bytes all the submission's processes may hold at once
    cpu_time: float = TOTAL_TIMEOUT  # s of CPU time (all processes, user + system; the warm-up not counted)


def _die_with_grader():
    """In the kernel's launcher, before exec: SIGKILL it if this grading process dies first."""
    ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


class KernelLost(Exception):
    """The kernel hung past an interrupt, flooded its output or died: restart and replay without
    cell ``index``; ``timed_out`` when it was a timeout the kernel ignored."""

    def __init__(self, index, why, timed_out=False):
        super().__init__(why)
        self.index, self.why, self.timed_out = index, why, timed_out


class OutOfTime(Exception):
    pass


class StoppedByLimit(OutOfTime):
    """The submission went over its memory or CPU-time limit and was killed (``over`` says which)."""

    def __init__(self, over: resources.OverLimit):
        super().__init__(str(over))
        self.over = over


class _SandboxKernelManager(AsyncKernelManager):
    """Starts ``python -m ipykernel_launcher`` through the sandbox, whatever the notebook asks for."""

    wrap = None  # callable(argv) → argv, set by KernelRun
    max_message = None  # bytes: a bigger message from the kernel drops its connection, unread

    def format_kernel_cmd(self, extra_arguments=None):
        argv = [sys.executable, "-m", "ipykernel_launcher", "-f", self.connection_file,
                "--HistoryManager.enabled=False", "--IPKernelApp.log_level=CRITICAL"]
        return self.wrap(argv)

    def client(self, **kwargs):
        context = zmq.asyncio.Context()
        context.setsockopt(zmq.MAXMSGSIZE, self.max_message)  # the default of every socket it makes
        kc = super().client(context=context, **kwargs)
        kc._created_context = True  # the client destroys it when it goes
        return kc


def _output_size(kind: str, content: dict) -> int:
    """Characters of one output message (stream text, error value, or display data)."""
    if kind == "stream":
        return len(content.get("text", ""))
    if kind == "error":
        return len(str(content.get("evalue", "")))
    data = content.get("data", {})
    return sum(len(v) if isinstance(v, str) else len(json.dumps(v)) for v in data.values()) if isinstance(data, dict) else 0


class _Client(NotebookClient):
    """nbclient with outputs counted and dropped, errors kept short, and no widget state."""

    def __init__(self, nb, km, max_output, **kw):
        super().__init__(nb, km=km, log=_LOG, **kw)
        self.comm_open_handlers = {}
        self.timed_out = self.flooded = False
        self.cell_bytes = 0
        self.max_output = max_output
        self.capture = None  # a list collecting stdout text for the grader's own cells

    async def _async_handle_timeout(self, timeout, cell=None):
        self.timed_out = True
        self.iopub_timeout = int(PING_TIMEOUT)  # an interrupted cell's last output comes at once, or never
        return await super()._async_handle_timeout(timeout, cell)

    def handle_comm_msg(self, outs, msg, cell_index):
        return None

    def output(self, outs, msg, display_id, cell_index):
        kind, content = msg["msg_type"], msg["content"]
        size = _output_size(kind, content)
        if kind == "stream" and self.capture is not None and content.get("name") == "stdout":
            if sum(map(len, self.capture)) + size <= wire.MAX_PAYLOAD + 200:
                self.capture.append(content["text"])
        elif kind == "error":
            outs.append(nbformat.NotebookNode(output_type="error", ename=str(content.get("ename", ""))[:100],
                                              evalue=str(content.get("evalue", ""))[:600], traceback=[]))
        self.cell_bytes += size
        if self.cell_bytes > self.max_output and not self.flooded:
            self.flooded = True  # stop the cell now rather than read on until it times out
            asyncio.ensure_future(self.km.interrupt_kernel())
        return None


class KernelRun:
    """A kernel for one submission; use as a context manager (the kernel and its box go away)."""

    def __init__(self, sources: list[str], sandbox: sb.Sandbox, limits: Limits, reserve: float = 0.0):
        self.sources, self.sandbox, self.limits = sources, sandbox, limits
        self.reserve = reserve  # s of the total kept for the grader's calls after the notebook
        self.deadline = self.until = math.inf  # total deadline (from the first kernel's start); current phase's
        self.skipped: set[int] = set()
        self.cell_notes: dict[int, str] = {}
        self.restarts = 0
        self.current = 0  # index of the cell running (len(sources): the grader's calls)
        self.last_timeout = limits.cell_timeout
        self.scratch = self.box = self.client = self.log = self.watchdog = None
        self.cpu_used, self.memory_peak, self.over = 0.0, 0, None  # over all the kernels of this submission
        self.cgroup_parent = None
        if sandbox.mode != "none":
            self.cgroup_parent, self.cgroup_missing = resources.cgroup_v2_parent()

    # kernel lifecycle
    def __enter__(self):
        base = tempfile.gettempdir()
        if len(base) > SHORT_TMP and os.path.isdir("/tmp"):  # the kernel's sockets need a path < 108 bytes
            base = "/tmp"
        self.scratch = Path(tempfile.mkdtemp(prefix="kfkit-grade-", dir=base))
        self.scratch.chmod(0o711)
        self._start()
        self.deadline = self.until = time.monotonic() + self.limits.total_timeout
        return self

    def __exit__(self, *exc):
        self._stop()
        shutil.rmtree(self.scratch, ignore_errors=True)

    @property
    def meter_kind(self) -> str:
        return resources.Cgroup.kind if self.cgroup_parent else resources.ProcessTree.kind

    def _start(self):
        self.box = sb.make_box(self.scratch, self.sandbox)
        km = _SandboxKernelManager(kernel_name="python3", transport="ipc", ip=str(self.box / "ipc"),
                                   connection_file=str(self.box / "kernel.json"))
        cgroup = resources.Cgroup(self.cgroup_parent, self.limits.memory) if self.cgroup_parent else None
        km.wrap = lambda argv: self.sandbox.command(self.box, self.scratch, self.box / "home", km.connection_file,
                                                    argv, cgroup=cgroup and cgroup.path)
        km.max_message = self.limits.max_message
        nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(s) for s in self.sources])
        self.client = _Client(nb, km, self.limits.max_cell_output, timeout=int(self.limits.cell_timeout),
                              interrupt_on_timeout=True,
                              error_on_timeout={"ename": "Timeout", "evalue": "timed out", "traceback": []},
                              allow_errors=True, record_timing=False, shutdown_kernel="immediate",
                              startup_timeout=60, iopub_timeout=IOPUB_TIMEOUT, raise_on_iopub_timeout=True)
        self.client.timeout_func = self._cell_timeout
        self.log = open(self.box / "kernel.log", "wb")
        cwd = self.box / "home" if self.sandbox.mode == "none" else Path("/")
        try:
            self.client.km = km
            self.client.start_new_kernel(env=sb.kernel_env(self.box), cwd=str(cwd), stdout=self.log, stderr=self.log,
                                         preexec_fn=_die_with_grader)
            self.client.start_new_kernel_client()
            if self.sandbox.uid():  # sockets exist now: the kernel may write only in its tmpfs home and /tmp
                os.chown(self.box, 0, 0)
                self.box.chmod(0o711)
            meter = cgroup or resources.ProcessTree(km.provisioner.pid)
            self._quiet(WARM_UP, max(WARM_UP_TIMEOUT, self.limits.cell_timeout))
            warm_up = meter.usage().cpu  # the grader's imports are not charged to the student
            self.watchdog = resources.Watchdog(meter, self.limits.memory, self.limits.cpu_time,
                                               cpu_before=self.cpu_used - warm_up)
        except Exception as exc:
            if cgroup is not None and self.watchdog is None:
                cgroup.close()
            self._stop()
            raise RuntimeError(f"the kernel did not start ({type(exc).__name__}: {exc}); "
                               f"kernel log: {self._log_tail()}") from None

    def _log_tail(self) -> str:
        try:
            return (self.box / "kernel.log").read_bytes()[-400:].decode(errors="replace").strip() or "(empty)"
        except OSError:
            return "(none)"

    def _stop(self):
        if self.client is not None and self.client.km is not None:
            try:
                self.client._cleanup_kernel()
            except Exception:  # already dead: nothing left to stop
                pass
        self.client = None
        if self.watchdog is not None:
            self.watchdog.stop()
            self.cpu_used, self.over = self.watchdog.cpu_used, self.over or self.watchdog.over
            self.memory_peak = max(self.memory_peak, self.watchdog.peak.memory)
            self.watchdog = None
        if self.log is not None:
            self.log.close()
            self.log = None

    def _check_limits(self):
        """Raise StoppedByLimit when the watchdog killed this submission, or the kernel's OOM killer did
        in its cgroup (a fresh sample sees that); the kernel is stopped first."""
        if self.watchdog is not None and self.watchdog.sample() is not None:
            self._stop()
        if self.over is not None:
            raise StoppedByLimit(self.over)

    def _restart(self):
        self.restarts += 1
        self._stop()
        self._check_limits()
        if self.restarts > MAX_RESTARTS:
            raise OutOfTime(f"the kernel had to be restarted more than {MAX_RESTARTS} times")
        self._check_time()
        self._start()

    def _remaining(self) -> float:
        return min(self.deadline, self.until) - time.monotonic()

    def _cell_timeout(self, cell=None) -> int:
        """Whole seconds the next cell may take (nbclient's unit): the per-cell limit or what is left."""
        self.last_timeout = max(1, int(min(self.limits.cell_timeout, self._remaining()) + 0.999))
        return self.last_timeout

    def _check_time(self):
        if self.deadline <= time.monotonic():
            raise OutOfTime(f"the submission used up its total time ({self.limits.total_timeout:g} s)")

    # execution
    def _execute(self, index: int, source: str, capture: list | None = None) -> tuple[str, dict | None]:
        """Run ``source``; → (status, error) with status 'ok', 'error' or 'timeout'. Raises KernelLost."""
        self._check_time()
        self.current = index
        client = self.client
        cells = client.nb.cells
        while len(cells) <= index:
            cells.append(nbformat.v4.new_code_cell(""))
        cell = nbformat.v4.new_code_cell(source)
        client.timed_out, client.flooded, client.cell_bytes, client.capture = False, False, 0, capture
        client.iopub_timeout = IOPUB_TIMEOUT
        try:
            client.execute_cell(cell, index, store_history=False)
        except DeadKernelError:
            self._check_limits()
            raise KernelLost(index, "the kernel died (sys.exit in a thread, os._exit, a crash or too much memory)") from None
        except CellTimeoutError:  # the reply came, its output did not: the kernel's output thread is gone
            self._check_limits()
            if client.timed_out:
                raise KernelLost(index, f"timed out after {self.last_timeout:g} s and ignored the interrupt",
                                 timed_out=True) from None
            raise KernelLost(index, "the kernel stopped sending output (it printed more than it could send)") from None
        finally:
            client.capture = None
        self._check_limits()
        if client.flooded:
            raise KernelLost(index, f"printed more than {self.limits.max_cell_output >> 20} MB of output (stopped)")
        if client.timed_out:
            if not self._ping():
                raise KernelLost(index, f"timed out after {self.last_timeout:g} s and ignored the interrupt",
                                 timed_out=True)
            return "timeout", None
        errors = [o for o in cell.outputs if o.output_type == "error"]
        return ("error", errors[0]) if errors else ("ok", None)

    def _ping(self) -> bool:
        """Does the kernel answer again after an interrupt?"""
        return self._quiet("pass", PING_TIMEOUT)

    def _quiet(self, source: str, timeout: float) -> bool:
        """Run the grader's ``source`` with its own timeout; → True if it finished in time."""
        client, saved = self.client, self.client.timeout_func
        client.timeout_func = lambda cell: int(timeout)
        try:
            client.timed_out, client.flooded, client.cell_bytes = False, False, 0
            client.iopub_timeout = IOPUB_TIMEOUT
            client.execute_cell(nbformat.v4.new_code_cell(source), len(client.nb.cells) - 1, store_history=False)
            return not (client.timed_out or client.flooded)
        except (DeadKernelError, CellTimeoutError):
            return False
        finally:
            client.timeout_func = saved

    def run_notebook(self, reserve: float | None = None):
        """Run every student cell once (replaying after a restart), leaving ``reserve`` s of the total
        (default: the run's) for the grader's calls; notes per cell in ``cell_notes``."""
        self.until = self.deadline - (self.reserve if reserve is None else reserve)
        try:
            self._run_cells()
        finally:
            self.until = self.deadline

    def _run_cells(self):
        while True:
            try:
                for i, source in enumerate(self.sources):
                    if i in self.skipped or not source.strip():
                        continue
                    if time.monotonic() >= self.until:
                        left = sum(1 for k in range(i + 1, len(self.sources)) if k not in self.skipped)
                        self.cell_notes[i] = (f"not run{f', nor the {left} cells after it' if left else ''}: the "
                                              "notebook had used its share of the total time (the rest grades its "
                                              "functions)")
                        return
                    status, error = self._execute(i, source)
                    notes = []
                    if status == "timeout":
                        notes.append(f"timed out after {self.last_timeout:g} s (interrupted)")
                    elif status == "error":
                        notes.append(f"{error.ename}: {error.evalue}" if error.evalue else error.ename)
                    if self.client.cell_bytes > self.limits.output_bytes:
                        notes.append(f"printed {self.client.cell_bytes / 1e6:.1f} MB of output (discarded)")
                    if notes:  # a replay after a restart says it again, once
                        self.cell_notes[i] = "; ".join(notes)
                return
            except KernelLost as lost:
                self.skipped.add(lost.index)
                self.cell_notes[lost.index] = lost.why + "; the kernel was restarted and this cell skipped"
                self._restart()

    def call(self, function: str, cases_args: list[dict]) -> dict:
        """Call the student's ``function`` on each input in the kernel; → the report parsed from the kernel's line
        of JSON (:func:`wire.extract`; each output still encoded, for :func:`wire.decode`).

        Raises KernelLost (after restarting and replaying the notebook) or TimeoutError.
        """
        nonce, captured = wire.new_nonce(), []
        index = len(self.sources)
        try:
            status, error = self._execute(index, wire.call_code(function, cases_args, nonce), capture=captured)
        except KernelLost as lost:
            self._restart()
            self.run_notebook(reserve=min(self.reserve, (self.deadline - time.monotonic()) / 2))
            raise KernelLost(index, lost.why, lost.timed_out) from None
        if status == "timeout":
            raise TimeoutError(f"timed out after {self.last_timeout:g} s")
        if status == "error":
            raise wire.WireError(f"the grader's call failed in the kernel ({error.ename}: {error.evalue})")
        return wire.extract("".join(captured), nonce)
