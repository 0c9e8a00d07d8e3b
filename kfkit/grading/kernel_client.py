"""The grader's end of a student's kernel: how it is started and how the grader hears it.

Started: ``python -m ipykernel_launcher`` through the sandbox whatever the notebook asks for
(:class:`_SandboxKernelManager`), SIGKILLed if the grading process dies first (:func:`_die_with_grader`), its sockets
refusing any message over ``Limits.max_message`` bytes (ZeroMQ's MAXMSGSIZE), then warmed up with the labs' heavy
imports (:data:`WARM_UP`, outside the student's namespace and not charged to the student's first cell). Heard:
nbclient with each cell's outputs counted and dropped, only an error's name and message kept (cut short), no widget
state, and an interrupt as soon as a cell has printed more than its cap (:class:`_Client`). :mod:`.runner` runs a
submission's cells on it with their CPU budgets.
"""

from __future__ import annotations

import asyncio
import ctypes
import json
import logging
import signal
import sys

import nbformat
import zmq
import zmq.asyncio
from jupyter_client.manager import AsyncKernelManager
from nbclient import NotebookClient

from . import wire

WARM_UP_TIMEOUT = 120.0  # s for the kernel's first imports, not charged to the student's first cell
WARM_UP_MODULES = (
    "numpy",
    "scipy.linalg",
    "matplotlib.pyplot",
    "ipywidgets",
    "kfkit.datasets",
    "kfkit.filters",
    "kfkit.frames",
    "kfkit.metrics",
    "kfkit.plots",
    "kfkit.widgets",
    "kfkit.checkpoints",
    "kfkit.exercise_guard",  # every lab's first cell loads it; it reads make-labs' stubs through nbformat (3 s of CPU)
)
_WARM_UP_CODE = f"""
import importlib, pkgutil
for name in {WARM_UP_MODULES!r}:
    try:
        importlib.import_module(name)
    except Exception:  # a missing optional module: the student's own import will say so
        pass
import kfkit.labs
for lab in pkgutil.iter_modules(kfkit.labs.__path__):  # each lab's support: a lab's first cell imports it
    try:
        importlib.import_module("kfkit.labs." + lab.name)
    except Exception:
        pass
"""
WARM_UP = f"exec({_WARM_UP_CODE!r}, {{}})"  # the labs' heavy imports, outside the student's namespace
PING_TIMEOUT = 5.0  # s a kernel gets to answer after the wall-clock backstop's interrupt before it is restarted
_LOG = logging.getLogger("kfkit.grading.nbclient")
_LOG.setLevel(logging.CRITICAL)


def _die_with_grader():
    """In the kernel's launcher, before exec: SIGKILL it if this grading process dies first."""
    ctypes.CDLL(None).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


class _SandboxKernelManager(AsyncKernelManager):
    """Starts ``python -m ipykernel_launcher`` through the sandbox, whatever the notebook asks for."""

    wrap = None  # callable(argv) → argv, set by KernelRun
    max_message = None  # bytes: a bigger message from the kernel drops its connection, unread

    def format_kernel_cmd(self, extra_arguments=None):
        argv = [
            sys.executable,
            "-m",
            "ipykernel_launcher",
            "-f",
            self.connection_file,
            "--HistoryManager.enabled=False",
            "--IPKernelApp.log_level=CRITICAL",
        ]
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
    return (
        sum(len(v) if isinstance(v, str) else len(json.dumps(v)) for v in data.values())
        if isinstance(data, dict)
        else 0
    )


class _Client(NotebookClient):
    """nbclient with outputs counted and dropped, errors kept short, and no widget state; its timeout (wall
    time) is the backstop, and ``judge``, when set, runs beside each cell until its reply (the CPU budget)."""

    def __init__(self, nb, km, max_output, **kw):
        super().__init__(nb, km=km, log=_LOG, **kw)
        self.comm_open_handlers = {}
        self.timed_out = self.flooded = self.backstop = False  # backstop: the wall-clock timeout stopped the cell
        self.cell_bytes = 0
        self.max_output = max_output
        self.capture = None  # a list collecting stdout text for the grader's own cells
        self.judge = None  # a coroutine function run while a student's cell runs (KernelRun._judge_cpu)

    async def _async_handle_timeout(self, timeout, cell=None):
        self.backstop = not self.timed_out  # not already interrupted for its CPU budget
        self.timed_out = True
        self.iopub_timeout = int(PING_TIMEOUT)  # an interrupted cell's last output comes at once, or never
        return await super()._async_handle_timeout(timeout, cell)

    async def _async_poll_for_reply(self, *args, **kwargs):
        judge = asyncio.ensure_future(self.judge()) if self.judge is not None else None
        try:
            return await super()._async_poll_for_reply(*args, **kwargs)
        finally:
            if judge is not None:
                judge.cancel()

    def handle_comm_msg(self, outs, msg, cell_index):
        return None

    def output(self, outs, msg, display_id, cell_index):
        kind, content = msg["msg_type"], msg["content"]
        size = _output_size(kind, content)
        if kind == "stream" and self.capture is not None and content.get("name") == "stdout":
            if sum(map(len, self.capture)) + size <= wire.MAX_PAYLOAD + 200:
                self.capture.append(content["text"])
        elif kind == "error":
            outs.append(
                nbformat.NotebookNode(
                    output_type="error",
                    ename=str(content.get("ename", ""))[:100],
                    evalue=str(content.get("evalue", ""))[:600],
                    traceback=[],
                )
            )
        self.cell_bytes += size
        if self.cell_bytes > self.max_output and not self.flooded:
            self.flooded = True  # stop the cell now rather than read on until it times out
            asyncio.ensure_future(self.km.interrupt_kernel())
        return None
