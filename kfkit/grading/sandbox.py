"""How student kernels are isolated: pick the strongest mode this machine allows, and prove it.

Modes, strongest first (``probe`` tries them in order and keeps the first that passes):

``root``       running as root: new mount/net/PID/IPC/UTS namespaces, everything read-only except
               the submission's box and a private /tmp, then another uid (one per grading
               process) with no capabilities and no_new_privs.
``userns``     not root, user namespaces enabled: the same namespaces inside a user namespace;
               the kernel stays uid 0 *there* but with every capability dropped.
``none``       neither works: kernels run as the grader with only a temporary working folder.
               The gradebook summary says so loudly.

``probe`` runs a tiny program through exactly the launch path the kernels use and checks that it
cannot write into the kit, the venv or the instructor's folders, and whether it can reach the
network; a mode is used only if that check passes.
"""
from __future__ import annotations

import json
import os
import pwd
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from ..datasets import KIT_ROOT

LAUNCHER = Path(__file__).with_name("_launch.py")
MEMORY_LIMIT = 4 << 30  # bytes of address space per kernel (RLIMIT_AS)
FILE_SIZE_LIMIT = 256 << 20  # bytes per file the kernel writes
PROCESS_LIMIT = 256  # processes and threads of one sandbox uid
SANDBOX_UID_BASE = 1_000_000  # + grading process id: one uid per concurrent grader, none in /etc/passwd


@dataclass
class Sandbox:
    mode: str  # "root", "userns" or "none"
    network_blocked: bool = False
    protected: list = field(default_factory=list)  # folders the probe found not writable
    warning: str = ""

    def describe(self) -> str:
        if self.mode == "none":
            return f"NOT ISOLATED: {self.warning}"
        how = {"root": "namespaces + read-only mounts + unprivileged uid",
               "userns": "user namespace + read-only mounts + no capabilities"}[self.mode]
        net = "network blocked" if self.network_blocked else "network NOT blocked"
        return f"{how}; {net}; protected from writes: {', '.join(self.protected)}"

    def uid(self) -> tuple[int, int] | None:
        """The unprivileged uid/gid this grading process gives its kernels (mode 'root')."""
        if self.mode != "root":
            return None
        uid = SANDBOX_UID_BASE + os.getpid()
        while _uid_taken(uid):
            uid += 1 << 22
        return uid, uid

    def command(self, box: Path, scratch: Path, cwd: Path, connection_file: str, argv: list[str],
                protect: list[str]) -> list[str]:
        """The argv that runs ``argv`` in this sandbox (``argv`` unchanged in mode 'none')."""
        if self.mode == "none":
            return argv
        ids = self.uid()
        spec = {"box": str(box), "scratch": str(scratch), "cwd": str(cwd), "connection_file": connection_file,
                "uid": ids and ids[0], "gid": ids and ids[1], "needed": needed_paths(), "protect": protect,
                "memory": MEMORY_LIMIT, "file_size": FILE_SIZE_LIMIT, "processes": PROCESS_LIMIT}
        unshare = ["unshare"] + (["--user", "--map-root-user"] if self.mode == "userns" else [])
        unshare += ["--mount", "--net", "--pid", "--ipc", "--uts", "--fork", "--kill-child", "--mount-proc", "--"]
        return unshare + [sys.executable, "-I", str(LAUNCHER), json.dumps(spec), "--"] + argv


def _uid_taken(uid: int) -> bool:
    try:
        pwd.getpwuid(uid)
        return True
    except KeyError:
        return False


def needed_paths() -> list[str]:
    """Folders the kernel must read: the Python install, the venv, the kit and its import paths."""
    paths = {os.path.realpath(p) for p in (sys.base_prefix, sys.prefix, KIT_ROOT)}
    paths.add(os.path.dirname(os.path.realpath(sys.executable)))
    paths |= {os.path.realpath(p) for p in [*sys.path, *sysconfig.get_paths().values()] if p}
    paths = sorted(p for p in paths if os.path.isdir(p))
    return [p for p in paths if not any(p.startswith(q.rstrip("/") + "/") for q in paths)]


def protected_paths(extra=()) -> list[str]:
    """Folders a submission must not write: the kit, the venv, and the instructor's folders."""
    paths = [KIT_ROOT, Path(sys.prefix), Path(__file__).resolve().parents[1], Path.cwd(), Path.home(), *extra]
    seen = []
    for p in paths:
        p = os.path.realpath(p)
        if os.path.isdir(p) and p not in seen:
            seen.append(p)
    return seen


def make_box(scratch: Path, sandbox: Sandbox) -> Path:
    """A fresh folder for one kernel: ``home/`` is its cwd and HOME; owned by the sandbox uid."""
    box = Path(tempfile.mkdtemp(prefix="box-", dir=scratch))
    (box / "home").mkdir()
    ids = sandbox.uid()
    if ids:
        for p in (box, box / "home"):
            os.chown(p, *ids)
    return box


def kernel_env(box: Path) -> dict:
    """A clean environment: none of the grader's variables (tokens, paths) reach student code."""
    home = box / "home"
    return {"PATH": f"{Path(sys.executable).parent}:/usr/local/bin:/usr/bin:/bin", "HOME": str(home),
            "TMPDIR": "/tmp", "LANG": "C.UTF-8", "MPLCONFIGDIR": str(home / ".matplotlib"),
            "IPYTHONDIR": str(home / ".ipython"), "JUPYTER_CONFIG_DIR": str(home / ".jupyter"),
            "JUPYTER_DATA_DIR": str(home / ".jupyter-data"), "JUPYTER_RUNTIME_DIR": str(box),
            "PYTHONNOUSERSITE": "1", "PYTHONDONTWRITEBYTECODE": "1", "PYDEVD_DISABLE_FILE_VALIDATION": "1",
            "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


PROBE = r"""
import json, os, socket, sys
report = {"network": False, "uid": os.getuid()}
for folder in sys.argv[2:]:
    try:  # left behind on purpose: the grader looks for it outside the sandbox
        with open(os.path.join(folder, sys.argv[1]), "w") as f:
            f.write("x")
    except OSError:
        pass
try:
    socket.create_connection(("1.1.1.1", 53), timeout=2).close()
    report["network"] = True
except OSError:
    pass
report["ifaces"] = [name for _, name in socket.if_nameindex() if name != "lo"]
import numpy, kfkit.checkpoints  # the kernel's imports must work in the sandbox
print(json.dumps(report))
"""


def leaked_writes(name: str, folders: list[str]) -> list[str]:
    """Folders where a file ``name`` written inside the sandbox really appeared (then removed)."""
    leaked = []
    for folder in folders:
        target = Path(folder, name)
        if target.exists():
            leaked.append(folder)
            target.unlink()
    return leaked


def run_in_sandbox(sandbox: Sandbox, argv: list[str], protect: list[str], timeout=60.0) -> subprocess.CompletedProcess:
    """Run ``argv`` (a short program, not a kernel) the way kernels run; used by the probe and tests."""
    scratch = Path(tempfile.mkdtemp(prefix="kfkit-grade-"))
    try:
        scratch.chmod(0o711)
        box = make_box(scratch, sandbox)
        conn = box / "none.json"
        conn.write_text("{}")
        cmd = sandbox.command(box, scratch, box / "home", str(conn), argv, protect)
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=kernel_env(box),
                              cwd=box / "home" if sandbox.mode == "none" else "/")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def probe(extra_protect=(), modes=None) -> Sandbox:
    """The strongest sandbox that works here, checked by trying to write into protected folders."""
    protect = protected_paths(extra_protect)
    if modes is None:
        modes = ["root"] if os.geteuid() == 0 else ["userns"]
    reasons = []
    for mode in modes:
        if shutil.which("unshare") is None:
            reasons.append("the 'unshare' command (util-linux) is not installed")
            break
        sb, name = Sandbox(mode), f".kfkit-sandbox-probe-{os.getpid()}"
        try:
            done = run_in_sandbox(sb, [sys.executable, "-c", PROBE, name, *protect], protect)
        except subprocess.TimeoutExpired:
            reasons.append(f"{mode}: the probe timed out")
            continue
        finally:
            leaked = leaked_writes(name, protect)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no message"])[-1]
            reasons.append(f"{mode}: {last}")
            continue
        report = json.loads(done.stdout.strip().splitlines()[-1])
        if leaked:
            reasons.append(f"{mode}: still writable: {', '.join(leaked)}")
            continue
        sb.network_blocked = not report["network"] and not report["ifaces"]
        sb.protected = protect
        return sb
    return Sandbox("none", warning="student code runs with the grader's own permissions and can change "
                                   "the kit and your files (" + ("; ".join(reasons) or "no isolation mode was tried") + ")")
