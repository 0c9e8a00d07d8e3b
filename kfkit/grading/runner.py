"""One student notebook in one sandboxed kernel: run its cells, then call its functions.

:class:`KernelRun` drives nbclient cell by cell (errors do not stop the run: a later exercise
may still be right). Time is CPU time (user + system, all the kernel's processes, as the watchdog of
:mod:`kfkit.grading.resources` counts it), so a busy machine fails nobody: each cell and each grader's
call may use ``Limits.cell_timeout`` seconds of CPU, bounded by what is left of the submission's
``Limits.total_timeout``, of which ``reserve`` seconds are kept for the grader's calls (so a looping function
that every later cell calls still leaves time to grade the other functions; cells past that share are not
run). A cell over its CPU budget is interrupted ("timed out after 30 s"). Code that waits without computing
(``time.sleep`` in a loop, a deadlock) is stopped by a wall-clock backstop ``Limits.wall_factor`` times as long
as each budget, never the primary judge ("did not finish: used 0.1 s of CPU in 300 s"); the total has the same
backstop. If the kernel ignores the interrupt (it burns :data:`INTERRUPT_GRACE_CPU` more seconds of CPU, or does
not answer within :data:`PING_TIMEOUT` after the backstop's) or dies (``sys.exit`` in a thread, ``os._exit``, a
crash), the kernel is restarted and the notebook replayed without that cell.
Outputs of student cells are counted and dropped (only an error's name and message, cut short, are
kept), so a huge print costs nothing but its transfer; a cell that prints more than
``Limits.max_cell_output`` is stopped the same way (its kernel restarted, as a thread may go on printing), and no single
message above ``Limits.max_message`` is even received (ZeroMQ's MAXMSGSIZE on the grader's sockets): the kernel's
start and the client that hears it are in :mod:`kfkit.grading.kernel_client`.
Memory and CPU time are limited per submission, all its processes together
(:mod:`kfkit.grading.resources`): over either, the submission is stopped (:class:`StoppedByLimit`).

A loop is paid for once: when a cell times out inside a function of the notebook, that function is replaced by
a stub that raises ``TimedOutEarlier`` at once (:data:`KernelRun.stopped`), so the later cells that call it fail
at once instead of timing out each in turn; those cells, and the cells that then miss a name one of them
would have made (``NameError``), are noted as affected by that timeout (:data:`KernelRun.affected`), not as
faults. Before the grader's calls the functions are put back, so each is judged on the grader's own cases
(the interrupt may have caught a function that was merely called often); a grader's call that times out stops
its function for the rest of the grading the same way.
"""

from __future__ import annotations

import ast
import asyncio
import contextlib
import math
import os
import re
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import nbformat
from nbclient.exceptions import CellTimeoutError, DeadKernelError

from ..exercise_guard import assigned_names
from . import CELL_TIMEOUT, TOTAL_TIMEOUT, WALL_FACTOR, resources, wire
from . import sandbox as sb
from .kernel_client import PING_TIMEOUT, WARM_UP, WARM_UP_TIMEOUT, _Client, _die_with_grader, _SandboxKernelManager

MAX_RESTARTS = 3
SHORT_TMP = 48  # characters of temporary folder that leave room for box/ipc-N in an AF_UNIX path (≤ 107)
INTERRUPT_GRACE_CPU = (
    5.0  # s of CPU a cell interrupted for its CPU budget may still use: more, it ignored the interrupt
)
CPU_POLL = 0.1  # s between two looks at the watchdog's CPU count while a student's cell runs
GRADER_CELL_TIMEOUT = 60.0  # s for the grader's own short cells (stopping, restoring functions): a hang guard
IOPUB_TIMEOUT = 10  # s from a cell's reply to its last output; longer means the kernel's output has died


@dataclass
class Limits:
    cell_timeout: float = CELL_TIMEOUT  # s of CPU time per notebook cell and per checkpoint call
    total_timeout: float = TOTAL_TIMEOUT  # s of CPU time for the whole submission (cells and calls)
    wall_factor: float = WALL_FACTOR  # each of the two also stops after this many times as many s of wall time
    output_bytes: int = 1 << 20  # output of one student cell beyond which it is reported as huge
    max_cell_output: int = 64 << 20  # output of one cell beyond which it is stopped
    max_message: int = 256 << 20  # bytes of one message from the kernel beyond which it is not even read
    memory: int = 4 << 30  # bytes all the submission's processes may hold at once
    cpu_time: float = TOTAL_TIMEOUT  # s of CPU time after which the watchdog kills all the submission's processes


@dataclass
class Stopped:
    """A function of the notebook that timed out and was replaced by a stub (see the module doc)."""

    name: str
    cell: int  # where it timed out: a cell's index, or len(sources) for a grader's call
    why: str  # "timed out after 4 s" (of CPU) or "did not finish: used 0.1 s of CPU in 40 s" (the backstop)
    defined_in: int | None  # the cell defining it: after it runs again (a replay), it is stopped again
    checkpoint: str = ""  # the grader's call that timed out, when it was one


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


class KernelRun:
    """A kernel for one submission; use as a context manager (the kernel and its box go away)."""

    def __init__(self, sources: list[str], sandbox: sb.Sandbox, limits: Limits, reserve: float = 0.0):
        self.sources, self.sandbox, self.limits = sources, sandbox, limits
        self.reserve = reserve  # s of CPU of the total kept for the grader's calls after the notebook
        self.cpu_until = math.inf  # s of CPU (of the submission) at which the current phase ends
        self.deadline = self.until = math.inf  # the wall-clock backstops (monotonic): the total's, the current phase's
        self.skipped: set[int] = set()
        self.cell_notes: dict[int, str] = {}
        self.stopped: dict[str, Stopped] = {}  # function name → where it timed out
        self.affected: dict[int, tuple[str, str]] = {}  # cell → (the stopped function behind its error, why)
        self.unmade: dict[str, str] = {}  # a name a timed-out or affected cell did not make → the function behind
        self.restarts = 0
        self.current = 0  # index of the cell running (len(sources): the grader's calls)
        self.cpu_budget, self.wall_budget = limits.cell_timeout, 1  # of the cell running: s of CPU, s of wall time
        self.cell_start = (0.0, 0.0)  # the submission's CPU seconds and the monotonic clock when it started
        self.spent: dict[int, tuple[float, float]] = {}  # cell (len(sources): the last call) → (s of CPU, s of wall)
        self.last_why = ""  # how the last cell that timed out was stopped, e.g. "timed out after 30 s"
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
        self.deadline = self.until = time.monotonic() + self.limits.wall_factor * self.limits.total_timeout
        return self

    def __exit__(self, *exc):
        self._stop()
        shutil.rmtree(self.scratch, ignore_errors=True)

    @property
    def meter_kind(self) -> str:
        return resources.Cgroup.kind if self.cgroup_parent else resources.ProcessTree.kind

    def _start(self):
        self.box = sb.make_box(self.scratch, self.sandbox)
        km = _SandboxKernelManager(
            kernel_name="python3",
            transport="ipc",
            ip=str(self.box / "ipc"),
            connection_file=str(self.box / "kernel.json"),
        )
        cgroup = resources.Cgroup(self.cgroup_parent, self.limits.memory) if self.cgroup_parent else None
        km.wrap = lambda argv: self.sandbox.command(
            self.box, self.scratch, self.box / "home", km.connection_file, argv, cgroup=cgroup and cgroup.path
        )
        km.max_message = self.limits.max_message
        nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(s) for s in self.sources])
        self.client = _Client(
            nb,
            km,
            self.limits.max_cell_output,
            timeout=int(self.limits.cell_timeout),
            interrupt_on_timeout=True,
            error_on_timeout={"ename": "Timeout", "evalue": "timed out", "traceback": []},
            allow_errors=True,
            record_timing=False,
            shutdown_kernel="immediate",
            startup_timeout=60,
            iopub_timeout=IOPUB_TIMEOUT,
            raise_on_iopub_timeout=True,
        )
        self.client.timeout_func = self._cell_timeout
        self.log = open(self.box / "kernel.log", "wb")  # noqa: SIM115  (the kernel's stdout for its life; _stop closes it)
        cwd = self.box / "home" if self.sandbox.mode == "none" else Path("/")
        try:
            self.client.km = km
            self.client.start_new_kernel(
                env=sb.kernel_env(self.box), cwd=str(cwd), stdout=self.log, stderr=self.log, preexec_fn=_die_with_grader
            )
            self.client.start_new_kernel_client()
            if self.sandbox.uid():  # sockets exist now: the kernel may write only in its tmpfs home and /tmp
                os.chown(self.box, 0, 0)
                self.box.chmod(0o711)
            meter = cgroup or resources.ProcessTree(km.provisioner.pid)
            self._quiet(WARM_UP, max(WARM_UP_TIMEOUT, self.limits.cell_timeout))
            warm_up = meter.usage().cpu  # the grader's imports are not charged to the student
            self.watchdog = resources.Watchdog(
                meter, self.limits.memory, self.limits.cpu_time, cpu_before=self.cpu_used - warm_up
            )
        except Exception as exc:
            if cgroup is not None and self.watchdog is None:
                cgroup.close()
            self._stop()
            raise RuntimeError(
                f"the kernel did not start ({type(exc).__name__}: {exc}); kernel log: {self._log_tail()}"
            ) from None

    def _log_tail(self) -> str:
        try:
            return (self.box / "kernel.log").read_bytes()[-400:].decode(errors="replace").strip() or "(empty)"
        except OSError:
            return "(none)"

    def _stop(self):
        if self.client is not None and self.client.km is not None:
            with contextlib.suppress(Exception):  # already dead: nothing left to stop
                self.client._cleanup_kernel()
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

    def _cpu(self) -> float:
        """s of CPU the submission has used (all its kernels; the watchdog's last sample)."""
        return self.watchdog.cpu_used if self.watchdog is not None else self.cpu_used

    def _left(self) -> tuple[float, float]:
        """What the current phase (the notebook's share, or the whole) has left: (s of CPU, s of wall time)."""
        return (
            min(self.limits.total_timeout, self.cpu_until) - self._cpu(),
            min(self.deadline, self.until) - time.monotonic(),
        )

    def _cell_timeout(self, cell=None) -> int:
        """The wall-clock backstop of the cell running, in whole seconds (nbclient's unit)."""
        return self.wall_budget

    def _spent(self) -> tuple[float, float]:
        """(s of CPU, s of wall time) the cell running has used so far."""
        return self._cpu() - self.cell_start[0], time.monotonic() - self.cell_start[1]

    def _stopped_why(self) -> str:
        """How the cell just interrupted was stopped, by its CPU budget or by the wall-clock backstop; kept in
        :data:`last_why`."""
        if self.client.backstop:
            self.last_why = f"did not finish: used {self._spent()[0]:.1f} s of CPU in {self.wall_budget} s"
        else:
            self.last_why = f"timed out after {self.cpu_budget:g} s"
        return self.last_why

    def _check_time(self):
        if self._cpu() >= self.limits.total_timeout:
            raise OutOfTime(f"the submission used up its total time ({self.limits.total_timeout:g} s)")
        if self.deadline <= time.monotonic():
            raise OutOfTime(
                f"the submission did not finish: used {self._cpu():.1f} s of CPU in "
                f"{self.limits.wall_factor * self.limits.total_timeout:.0f} s (the wall-clock backstop)"
            )

    async def _judge_cpu(self):
        """Beside a student's cell: interrupt it when it has used its CPU budget (the watchdog's count, all its
        processes); if it goes on for :data:`INTERRUPT_GRACE_CPU` more, it ignored the interrupt: kill the kernel
        (nbclient then finds it dead)."""
        dog, limit, interrupted = self.watchdog, self.cpu_budget, False
        while True:
            await asyncio.sleep(CPU_POLL)
            if dog.cpu_used - self.cell_start[0] <= limit:
                continue
            if interrupted:
                dog.meter.kill()
                return
            self.client.timed_out = interrupted = True
            limit = dog.cpu_used - self.cell_start[0] + INTERRUPT_GRACE_CPU
            await self.client.km.interrupt_kernel()

    # execution
    def _execute(self, index: int, source: str, capture: list | None = None) -> tuple[str, dict | None]:
        """Run ``source`` with its CPU budget and wall-clock backstop (see the module doc); → (status, error) with
        status 'ok', 'error' or 'timeout' (how it was stopped: :data:`last_why`). Raises KernelLost."""
        self._check_limits()  # a fresh sample: the CPU count this cell starts from
        self._check_time()
        self.current = index
        client = self.client
        cells = client.nb.cells
        while len(cells) <= index:
            cells.append(nbformat.v4.new_code_cell(""))
        cell = nbformat.v4.new_code_cell(source)
        cpu_left, wall_left = self._left()
        per_cell = self.limits.cell_timeout  # or what is left of the share, rounded up, but not under 1 s
        self.cpu_budget = max(min(1.0, per_cell), math.ceil(10 * min(per_cell, cpu_left)) / 10)
        self.wall_budget = max(1, math.ceil(min(self.limits.wall_factor * self.cpu_budget, wall_left)))
        client.timed_out = client.flooded = client.backstop = False
        client.cell_bytes, client.capture, client.judge = 0, capture, self._judge_cpu
        client.iopub_timeout = IOPUB_TIMEOUT
        self.cell_start = (self._cpu(), time.monotonic())
        try:
            client.execute_cell(cell, index, store_history=False)
        except DeadKernelError:  # or killed by _judge_cpu when it ignored the interrupt
            self._check_limits()
            if client.timed_out:
                raise KernelLost(index, f"{self._stopped_why()} and ignored the interrupt", timed_out=True) from None
            raise KernelLost(
                index, "the kernel died (sys.exit in a thread, os._exit, a crash or too much memory)"
            ) from None
        except CellTimeoutError:  # the reply came, its output did not: the kernel's output thread is gone
            self._check_limits()
            if client.timed_out:
                raise KernelLost(index, f"{self._stopped_why()} and ignored the interrupt", timed_out=True) from None
            raise KernelLost(index, "the kernel stopped sending output (it printed more than it could send)") from None
        finally:
            client.capture = client.judge = None
            if self.watchdog is not None:
                self.watchdog.sample()
            self.spent[index] = self._spent()
        self._check_limits()
        if client.flooded:
            raise KernelLost(index, f"printed more than {self.limits.max_cell_output >> 20} MB of output (stopped)")
        if client.timed_out:
            why = self._stopped_why()
            if client.backstop and not self._ping():  # interrupted for its CPU budget, it answered: no need
                raise KernelLost(index, f"{why} and ignored the interrupt", timed_out=True)
            return "timeout", None
        errors = [o for o in cell.outputs if o.output_type == "error"]
        return ("error", errors[0]) if errors else ("ok", None)

    def _ping(self) -> bool:
        """Does the kernel answer again after an interrupt?"""
        return self._quiet("pass", PING_TIMEOUT)

    def _quiet(self, source: str, timeout: float, capture: list | None = None) -> bool:
        """Run the grader's ``source`` with its own timeout (its stdout into ``capture``); → True if it
        finished in time."""
        client, saved = self.client, self.client.timeout_func
        client.timeout_func = lambda cell: int(timeout)
        try:
            client.timed_out, client.flooded, client.cell_bytes, client.capture = False, False, 0, capture
            client.iopub_timeout = IOPUB_TIMEOUT
            client.execute_cell(nbformat.v4.new_code_cell(source), len(client.nb.cells) - 1, store_history=False)
            return not (client.timed_out or client.flooded)
        except (DeadKernelError, CellTimeoutError):
            return False
        finally:
            client.timeout_func, client.capture = saved, None

    # a loop paid for once (see the module doc)
    def _stop_functions(
        self, index: int, names: list[str] | None, checkpoint: str = "", why: str | None = None
    ) -> list[str]:
        """Stop ``names`` (None: the function the interrupt of cell ``index`` caught) in the kernel, stopped as
        ``why`` says (default: the last cell's :data:`last_why`); → those stopped."""
        why = self.last_why if why is None else why
        where = f"the grader's call for {checkpoint}" if checkpoint else "the notebook"
        message = f"{{name}} was stopped earlier in {where} ({why}): kfkit grade does not run it again"
        nonce, captured = wire.new_nonce(), []
        self._quiet(wire.stop_code(names, message, nonce, bool(checkpoint)), GRADER_CELL_TIMEOUT, captured)
        try:
            stopped = wire.extract("".join(captured), nonce).get("stopped")
        except wire.WireError:
            stopped = []
        stopped = [n for n in stopped if isinstance(n, str) and n.isidentifier()] if isinstance(stopped, list) else []
        if checkpoint:  # the grader's own call timed out: not called again, whatever the kernel answered
            stopped = list(dict.fromkeys(stopped + names))
        for name in stopped:
            if name not in self.stopped or checkpoint:  # a grader's call's timeout is the one that counts
                defining = re.compile(rf"^\s*def\s+{re.escape(name)}\s*\(", re.M)
                cells = [i for i, src in enumerate(self.sources[: index + 1]) if defining.search(src)]
                self.stopped[name] = Stopped(name, index, why, cells[-1] if cells else None, checkpoint)
        return stopped

    def _note_unmade(self, index: int, function: str):
        """The names cell ``index`` would have made, missing because ``function`` timed out."""
        try:
            made = assigned_names(ast.parse(self.sources[index]).body)
        except SyntaxError:
            return
        for name in made:
            self.unmade.setdefault(name, function)

    def _follow_on(self, index: int, error) -> str | None:
        """The stopped function behind cell ``index``'s error, if it is one's stub or a name one left unmade."""
        if error.ename == wire.TIMED_OUT_EARLIER:
            name = str(error.evalue).split(" ", 1)[0]
            if name in self.stopped:
                return name
        missing = re.match(r"name '(\w+)' is not defined", str(error.evalue)) if error.ename == "NameError" else None
        return self.unmade.get(missing.group(1)) if missing else None

    def _restore_functions(self):
        """Put back the functions the notebook's cells stopped (all the kernel holds, whatever this side heard of
        them), and stop again those the grader's calls stopped (a replay after a restart made them anew)."""
        if self.client is not None:
            self._quiet(wire.restore_code(), GRADER_CELL_TIMEOUT)
        for name, s in list(self.stopped.items()):
            if s.checkpoint:
                self._stop_functions(s.cell, [name], s.checkpoint, s.why)

    def run_notebook(self, reserve: float | None = None):
        """Run every student cell once (replaying after a restart), leaving ``reserve`` s of CPU of the total
        (default: the run's), and as many times the wall factor of its backstop, for the grader's calls; notes per
        cell in ``cell_notes``."""
        reserve = self.reserve if reserve is None else reserve
        self.cpu_until = self.limits.total_timeout - reserve
        self.until = self.deadline - self.limits.wall_factor * reserve
        try:
            self._run_cells()
        finally:
            self.cpu_until, self.until = math.inf, self.deadline
        self._restore_functions()

    def _outcome(self, i: int, status: str, error) -> list[str]:
        """The notes on cell ``i`` after it ran; a loop paid for once: a function it timed out in is stopped,
        an error that only follows from a stopped function is put in ``affected``, not in the notes."""
        notes, cause = [], None
        if status == "timeout":
            notes.append(f"{self.last_why} (interrupted)")
            cause = next(iter(self._stop_functions(i, None)), None)
            if cause is not None:
                notes[-1] += (
                    f" inside {cause}; later calls of {cause} in the notebook failed at once instead of running again"
                )
        elif status == "error":
            cause = self._follow_on(i, error)
            if cause is None:
                notes.append(f"{error.ename}: {error.evalue}" if error.evalue else error.ename)
            elif self.stopped[cause].cell != i:
                self.affected[i] = (
                    cause,
                    f"calls {cause}" if error.ename == wire.TIMED_OUT_EARLIER else f"{error.ename}: {error.evalue}",
                )
        if cause is not None:
            self._note_unmade(i, cause)
        for name, s in list(self.stopped.items()):  # a replay: stopped again before the cells calling it
            if s.defined_in == i < s.cell:
                self._stop_functions(s.cell, [name], s.checkpoint, s.why)
        return notes

    def _run_cells(self):
        while True:
            try:
                for i, source in enumerate(self.sources):
                    if i in self.skipped or not source.strip():
                        continue
                    if min(self._left()) <= 0:
                        left = sum(1 for k in range(i + 1, len(self.sources)) if k not in self.skipped)
                        self.cell_notes[i] = (
                            f"not run{f', nor the {left} cells after it' if left else ''}: the "
                            "notebook had used its share of the total time (the rest grades its "
                            "functions)"
                        )
                        return
                    status, error = self._execute(i, source)
                    printed = self.client.cell_bytes
                    notes = self._outcome(i, status, error)
                    if printed > self.limits.output_bytes:
                        notes.append(f"printed {printed / 1e6:.1f} MB of output (discarded)")
                    if notes:  # a replay after a restart says it again, once
                        self.cell_notes[i] = "; ".join(notes)
                return
            except KernelLost as lost:
                self.skipped.add(lost.index)
                self.cell_notes[lost.index] = lost.why + "; the kernel was restarted and this cell skipped"
                self._restart()

    def call(self, function: str, cases_args: list[dict], checkpoint: str = "") -> dict:
        """Call the student's ``function`` on each input in the kernel (for ``checkpoint``); → the report parsed from
        the kernel's line of JSON (:func:`wire.extract`; each output still encoded, for :func:`wire.decode`).

        Raises KernelLost (after restarting and replaying the notebook) or TimeoutError (and the function is stopped
        for the rest of the grading).
        """
        nonce, captured = wire.new_nonce(), []
        index = len(self.sources)
        try:
            status, error = self._execute(index, wire.call_code(function, cases_args, nonce), capture=captured)
        except KernelLost as lost:
            self._restart()
            cpu_left, wall_left = self._left()
            self.run_notebook(reserve=min(self.reserve, cpu_left / 2, wall_left / self.limits.wall_factor / 2))
            raise KernelLost(index, lost.why, lost.timed_out) from None
        if status == "timeout":
            self._stop_functions(index, [function], checkpoint)
            raise TimeoutError(self.last_why)
        if status == "error":
            raise wire.WireError(f"the grader's call failed in the kernel ({error.ename}: {error.evalue})")
        return wire.extract("".join(captured), nonce)
