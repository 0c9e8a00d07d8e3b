"""How student kernels are isolated: pick the strongest mode this machine allows, and prove it.

Modes, strongest first (``probe`` tries them in order and keeps the first that passes):

``root``       running as root: new mount/net/PID/IPC/UTS namespaces, everything read-only except
               the submission's box and a private /tmp, then another uid (one per grading
               process) with no capabilities and no_new_privs.
``userns``     not root, user namespaces enabled: the same namespaces inside a user namespace;
               the kernel stays uid 0 *there* but with every capability dropped.
``none``       neither works: ``kfkit grade`` refuses to run student code unless told
               ``--no-sandbox``; then kernels run as the grader with only a temporary working
               folder, and the summary says so loudly.

In both isolated modes the instructor's home and current folder, the kit's ``solutions/``, the
submissions and the gradebook's folder are hidden (an empty read-only tmpfs over each, with only
what the kernel must import bound back inside), and the network is an empty namespace.

``probe`` runs a tiny program through exactly the launch path the kernels use and checks that it
cannot write into the kit, the venv or the instructor's folders, cannot list the hidden ones, and
whether it can reach the network; a mode is used only if that check passes.
"""
from __future__ import annotations

import functools
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
SYSTEM = ("/bin", "/dev", "/etc", "/lib", "/lib64", "/opt", "/proc", "/run", "/sbin", "/sys", "/usr", "/var")  # never hidden


@dataclass
class Sandbox:
    mode: str  # "root", "userns" or "none"
    network_blocked: bool = False
    protected: list = field(default_factory=list)  # folders the probe found not writable
    hidden: list = field(default_factory=list)  # folders the probe found empty from inside
    warning: str = ""

    def describe(self, full: bool = True) -> str:
        """How kernels are isolated; ``full`` adds the folders (for the instructor, not the students)."""
        if self.mode == "none":
            return f"NOT ISOLATED: {self.warning}"
        how = {"root": "namespaces + read-only mounts + unprivileged uid",
               "userns": "user namespace + read-only mounts + no capabilities"}[self.mode]
        net = "network blocked" if self.network_blocked else "network NOT blocked"
        if not full:
            return f"{how}; {net}"
        return f"{how}; {net}; read-only: {', '.join(self.protected)}; hidden: {', '.join(self.hidden)}"

    def uid(self) -> tuple[int, int] | None:
        """The unprivileged uid/gid this grading process gives its kernels (mode 'root')."""
        if self.mode != "root":
            return None
        uid = SANDBOX_UID_BASE + os.getpid()
        while _uid_taken(uid):
            uid += 1 << 22
        return uid, uid

    def command(self, box: Path, scratch: Path, cwd: Path, connection_file: str, argv: list[str]) -> list[str]:
        """The argv that runs ``argv`` in this sandbox (``argv`` unchanged in mode 'none')."""
        if self.mode == "none":
            return argv
        ids = self.uid()
        spec = {"box": str(box), "scratch": str(scratch), "cwd": str(cwd), "connection_file": connection_file,
                "uid": ids and ids[0], "gid": ids and ids[1], "needed": needed_paths(), "protect": self.protected,
                "hide": self.hidden, "memory": MEMORY_LIMIT, "file_size": FILE_SIZE_LIMIT, "processes": PROCESS_LIMIT}
        unshare = ["unshare"] + (["--user", "--map-root-user"] if self.mode == "userns" else [])
        unshare += ["--mount", "--net", "--pid", "--ipc", "--uts", "--fork", "--kill-child", "--mount-proc", "--"]
        return unshare + [sys.executable, "-I", str(LAUNCHER), json.dumps(spec), "--"] + argv


def _uid_taken(uid: int) -> bool:
    try:
        pwd.getpwuid(uid)
        return True
    except KeyError:
        return False


@functools.lru_cache(maxsize=1)
def needed_paths() -> list[str]:
    """Folders the kernel must read: the Python install, the venv, the kit and its import paths.

    The import paths are those of a fresh ``python -I`` (what the kernel gets: no PYTHONPATH, no
    current folder), not this process's ``sys.path``, which may hold the instructor's folders.
    """
    isolated = subprocess.run([sys.executable, "-I", "-c", "import json, sys; print(json.dumps(sys.path))"],
                              capture_output=True, text=True, check=True, env={"PATH": os.defpath})
    paths = {os.path.realpath(p) for p in (sys.base_prefix, sys.prefix, KIT_ROOT)}
    paths.add(os.path.dirname(os.path.realpath(sys.executable)))
    paths |= {os.path.realpath(p) for p in [*json.loads(isolated.stdout), *sysconfig.get_paths().values()] if p}
    paths = sorted(p for p in paths if os.path.isdir(p))
    return [p for p in paths if not any(p.startswith(q.rstrip("/") + "/") for q in paths)]


def protected_paths(extra=()) -> list[str]:
    """Folders a submission must not write: the kit, the venv, and the instructor's folders."""
    return _existing_dirs([KIT_ROOT, Path(sys.prefix), Path(__file__).resolve().parents[1], Path.cwd(), Path.home(),
                           *extra])


def hidden_paths(extra=()) -> list[str]:
    """Folders a submission must not even read: the instructor's home and current folder, the kit's
    solutions, the submissions and the gradebook's folder (``extra``). What the kernel needs inside
    them (a venv in the home folder, the kit in the current one) stays visible, read-only."""
    needed = needed_paths()
    return [p for p in _existing_dirs([Path.home(), Path.cwd(), KIT_ROOT / "solutions", *extra])
            if p not in needed and not any(s == p or s.startswith(p.rstrip("/") + "/") for s in SYSTEM)]


def _existing_dirs(paths) -> list[str]:
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
name, rest = sys.argv[1], sys.argv[2:]
protect, hide = rest[:rest.index("--hide")], rest[rest.index("--hide") + 1:]
report = {"network": False, "uid": os.getuid(), "hidden": {}}
for folder in protect:
    try:  # left behind on purpose: the grader looks for it outside the sandbox
        with open(os.path.join(folder, name), "w") as f:
            f.write("x")
    except OSError:
        pass
for folder in hide:
    try:
        report["hidden"][folder] = sorted(os.listdir(folder))
    except OSError:
        report["hidden"][folder] = []
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


def leaked_listings(seen: dict, needed: list[str]) -> list[str]:
    """Hidden folders whose listing from inside shows more than the way to what the kernel needs."""
    leaked = []
    for folder, names in seen.items():
        allowed = {Path(p).relative_to(folder).parts[0] for p in needed if p.startswith(folder.rstrip("/") + "/")}
        if set(names) - allowed:
            leaked.append(folder)
    return leaked


def run_in_sandbox(sandbox: Sandbox, argv: list[str], timeout=60.0) -> subprocess.CompletedProcess:
    """Run ``argv`` (a short program, not a kernel) the way kernels run; used by the probe and tests."""
    scratch = Path(tempfile.mkdtemp(prefix="kfkit-grade-"))
    try:
        scratch.chmod(0o711)
        box = make_box(scratch, sandbox)
        conn = box / "none.json"
        conn.write_text("{}")
        cmd = sandbox.command(box, scratch, box / "home", str(conn), argv)
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=kernel_env(box),
                              cwd=box / "home" if sandbox.mode == "none" else "/")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def probe(extra=(), modes=None) -> Sandbox:
    """The strongest sandbox that works here, checked from inside: it must not write into the
    protected folders (the kit, the venv, ``extra`` …) nor see into the hidden ones.

    ``extra``: the instructor's folders of this grading run (submissions, gradebook), both
    protected and hidden.
    """
    protect, hide = protected_paths(extra), hidden_paths(extra)
    if modes is None:
        modes = ["root"] if os.geteuid() == 0 else ["userns"]
    reasons = []
    for mode in modes:
        if shutil.which("unshare") is None:
            reasons.append("the 'unshare' command (util-linux) is not installed")
            break
        sb, name = Sandbox(mode, protected=protect, hidden=hide), f".kfkit-sandbox-probe-{os.getpid()}"
        try:
            done = run_in_sandbox(sb, [sys.executable, "-c", PROBE, name, *protect, "--hide", *hide])
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
        seen = leaked_listings(report["hidden"], needed_paths())
        if seen:
            reasons.append(f"{mode}: still visible: {', '.join(seen)}")
            continue
        sb.network_blocked = not report["network"] and not report["ifaces"]
        return sb
    return Sandbox("none", warning="student code would run with the grader's own permissions and could read and "
                                   "change the kit and your files (" +
                                   ("; ".join(reasons) or "no isolation mode was tried") + ")")
