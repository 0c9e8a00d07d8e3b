"""How student kernels are isolated: pick the strongest mode this machine allows, and prove it.

Modes, strongest first (``probe`` tries them in order and keeps the first that passes):

``root``       running as root: new mount/net/PID/IPC/UTS namespaces and a file system that holds
               only what the kernel needs (a whitelist, see ``_launch.py``), read-only except the
               submission's box and a private /tmp, then another uid (one per grading process)
               with no capabilities and no_new_privs.
``userns``     not root, user namespaces enabled: the same inside a user namespace; the kernel
               stays uid 0 *there* but with every capability dropped.
``none``       neither works: ``kfkit grade`` refuses to run student code unless told
               ``--no-sandbox``; then kernels run as the grader with only a temporary working
               folder, and the summary says so loudly.

In both isolated modes the kernel's root file system is a fresh tmpfs into which only the system
folders (:data:`SYSTEM`), the Python install, the venv and the kit's ``kfkit/`` and ``data/`` are
bound, read-only, at their real paths (:func:`visible_paths`): the kit's repository (``.git``,
``solutions/``, ``tests/``), the instructor's folders, other copies of the kit, pip's cache and the
host's socket files are not hidden, they are simply not there. The network is an empty namespace.

``probe`` runs a tiny program through exactly the launch path the kernels use and checks those
guarantees from inside (see :data:`PROBE`); a mode is used only if that check passes.
"""

from __future__ import annotations

import functools
import json
import os
import pwd
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from ..paths import KIT_ROOT

LAUNCHER = Path(__file__).with_name("_launch.py")
MEMORY_LIMIT = 4 << 30  # bytes of address space per kernel process (RLIMIT_AS; the submission's total: Limits)
FILE_SIZE_LIMIT = 256 << 20  # bytes per file the kernel writes
PROCESS_LIMIT = 256  # processes and threads of one sandbox uid
SANDBOX_UID_BASE = 1_000_000  # + grading process id: one uid per concurrent grader, none in /etc/passwd
SYSTEM = ("/usr", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32", "/etc")  # bound read-only (as _launch.py)
PRIVATE = ("/tmp", "/run", "/var", "/dev", "/proc")  # the sandbox's own (fresh tmpfs, minimal /dev, its /proc)


@dataclass
class Sandbox:
    mode: str  # "root", "userns" or "none"
    network_blocked: bool = False
    visible: list = field(default_factory=list)  # the only folders bound in, read-only (besides SYSTEM)
    warning: str = ""

    def describe(self, full: bool = True) -> str:
        """How kernels are isolated; ``full`` adds the folders (for the instructor, not the students)."""
        if self.mode == "none":
            return f"NOT ISOLATED: {self.warning}"
        how = {
            "root": "namespaces + whitelisted read-only file system + unprivileged uid",
            "userns": "user namespace + whitelisted read-only file system + no capabilities",
        }[self.mode]
        net = "network blocked" if self.network_blocked else "network NOT blocked"
        if not full:
            return f"{how}; {net}"
        system = [p for p in SYSTEM if os.path.isdir(p) and not os.path.islink(p)]
        return (
            f"{how}; {net}; the only folders visible, read-only: {', '.join(system + self.visible)}; "
            f"private: /tmp, /run, /dev/shm, its home"
        )

    def uid(self) -> tuple[int, int] | None:
        """The unprivileged uid/gid this grading process gives its kernels (mode 'root')."""
        if self.mode != "root":
            return None
        uid = SANDBOX_UID_BASE + os.getpid()
        while _uid_taken(uid):
            uid += 1 << 22
        return uid, uid

    def command(
        self, box: Path, scratch: Path, cwd: Path, connection_file: str, argv: list[str], cgroup: Path | None = None
    ) -> list[str]:
        """The argv that runs ``argv`` in this sandbox (``argv`` unchanged in mode 'none').

        ``scratch`` (the box's parent, private to this kernel) becomes the new root's mount point;
        ``cgroup``: the submission's cgroup v2 folder, joined before anything else.
        """
        if self.mode == "none":
            return argv
        ids = self.uid()
        spec = {
            "box": str(box),
            "scratch": str(scratch),
            "cwd": str(cwd),
            "connection_file": connection_file,
            "uid": ids and ids[0],
            "gid": ids and ids[1],
            "visible": self.visible or visible_paths(),
            "cgroup": str(cgroup) if cgroup else None,
            "memory": MEMORY_LIMIT,
            "file_size": FILE_SIZE_LIMIT,
            "processes": PROCESS_LIMIT,
        }
        unshare = ["unshare"] + (["--user", "--map-root-user"] if self.mode == "userns" else [])
        unshare += ["--mount", "--net", "--pid", "--ipc", "--uts", "--fork", "--kill-child", "--mount-proc", "--"]
        return unshare + [sys.executable, "-I", str(LAUNCHER), json.dumps(spec), "--"] + argv


def _uid_taken(uid: int) -> bool:
    try:
        pwd.getpwuid(uid)
        return True
    except KeyError:
        return False


def inside(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


@functools.lru_cache(maxsize=1)
def visible_paths() -> list[str]:
    """Folders bound into the kernel's file system besides :data:`SYSTEM`: what a fresh ``python -I``
    imports from (the Python install, the venv, their import paths, where ``kfkit`` is found:
    editable-install finders keep working because the kit is bound at its real path) and the
    bundled ``data/``. Any of them holding the kit's repository root is replaced by the kit's
    ``kfkit/`` and ``data/`` alone: never ``.git``, ``solutions/`` or ``tests/``.

    The import paths are those of a fresh ``python -I`` (what the kernel gets: no PYTHONPATH, no
    current folder), not this process's ``sys.path``, which may hold the instructor's folders.
    """
    code = (
        "import importlib.util, json, sys; spec = importlib.util.find_spec('kfkit'); "
        "print(json.dumps([sys.path, list(spec.submodule_search_locations or []) if spec else []]))"
    )
    fresh = subprocess.run(
        [sys.executable, "-I", "-c", code],
        capture_output=True,
        text=True,
        check=True,
        env={"PATH": os.defpath},
        cwd="/",
    )
    path, kfkit_dirs = json.loads(fresh.stdout)
    kit = os.path.realpath(KIT_ROOT)
    paths = {os.path.realpath(p) for p in (sys.base_prefix, sys.prefix, *path, *kfkit_dirs) if p}
    paths.add(os.path.dirname(os.path.realpath(sys.executable)))
    paths = {p for p in paths if not inside(kit, p)} | {os.path.join(kit, "kfkit"), os.path.join(kit, "data")}
    system = [os.path.realpath(s) for s in SYSTEM if os.path.isdir(s) and not os.path.islink(s)]
    paths = sorted(p for p in paths if os.path.isdir(p) and not any(inside(p, s) for s in system))
    return [p for p in paths if not any(p != q and inside(p, q) for q in paths)]


def instructor_paths(extra=()) -> list[str]:
    """Folders a submission must not even see: the instructor's home and current folder, the kit's
    repository (its ``.git``, ``solutions/``, ``tests/``), the submissions and the gradebook's
    folder (``extra``); what the kernel needs inside them (the kit's package, a venv in the home
    folder) is bound at its own path and nothing else of them is there."""
    return _existing_dirs([Path.home(), Path.cwd(), KIT_ROOT, KIT_ROOT / ".git", KIT_ROOT / "solutions", *extra])


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
    return {
        "PATH": f"{Path(sys.executable).parent}:/usr/local/bin:/usr/bin:/bin",
        "HOME": str(home),
        "TMPDIR": "/tmp",
        "LANG": "C.UTF-8",
        "MPLCONFIGDIR": str(home / ".matplotlib"),
        "IPYTHONDIR": str(home / ".ipython"),
        "JUPYTER_CONFIG_DIR": str(home / ".jupyter"),
        "JUPYTER_DATA_DIR": str(home / ".jupyter-data"),
        "JUPYTER_RUNTIME_DIR": str(box),
        "PYTHONNOUSERSITE": "1",
        "PYTHONDONTWRITEBYTECODE": "1",
        "PYDEVD_DISABLE_FILE_VALIDATION": "1",
        "OMP_NUM_THREADS": "1",
        "OPENBLAS_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
    }


PROBE = r"""
import json, os, socket, stat, sys
args = json.loads(sys.argv[1])
report = {"network": False, "uid": os.getuid(), "root": sorted(os.listdir("/")), "written": [], "seen": {},
          "sockets": []}
for folder in args["write"]:
    try:  # left behind on purpose if it works: the grader looks for it outside the sandbox too
        with open(os.path.join(folder, args["name"]), "w") as f:
            f.write("x")
        report["written"].append(folder)
    except OSError:
        pass
for folder in args["absent"]:
    try:
        report["seen"][folder] = sorted(os.listdir(folder))
    except OSError:
        pass
for top in ("/tmp", "/run", "/dev", "/var"):  # the private folders hold no socket file but the kernel's own
    for where, dirs, files in os.walk(top):
        for f in files:
            path = os.path.join(where, f)
            if not path.startswith(args["box"] + "/") and stat.S_ISSOCK(os.lstat(path).st_mode):
                report["sockets"].append(path)
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
    """Folders whose listing from inside shows more than the way to what the kernel needs."""
    leaked = []
    for folder, names in seen.items():
        allowed = {Path(p).relative_to(folder).parts[0] for p in needed if p.startswith(folder.rstrip("/") + "/")}
        if set(names) - allowed:
            leaked.append(folder)
    return leaked


def root_entries(visible: list[str], box: str) -> set[str]:
    """The names ``/`` may hold inside the sandbox: the top folder of everything bound or made there."""
    return {Path(p).parts[1] for p in [*SYSTEM, *PRIVATE, *visible, box] if os.path.lexists(p) or p in PRIVATE}


def check_report(report: dict, visible: list[str], box: str) -> list[str]:
    """What the probe's report shows broken (empty when every guarantee holds)."""
    broken = []
    extra = set(report["root"]) - root_entries(visible, box)
    if extra:
        broken.append(f"/ holds more than the whitelist: {', '.join(sorted(extra))}")
    if report["written"]:
        broken.append(f"still writable: {', '.join(report['written'])}")
    seen = leaked_listings(report["seen"], visible)
    if seen:
        broken.append(f"still visible: {', '.join(seen)}")
    if report["sockets"]:
        broken.append(f"socket files of the host: {', '.join(report['sockets'])}")
    return broken


def run_in_sandbox(
    sandbox: Sandbox, argv: list[str], timeout=60.0, args: dict | None = None, box_files: dict | None = None
) -> subprocess.CompletedProcess:
    """Run ``argv`` (a short program, not a kernel) the way kernels run; used by the probe and tests.

    ``args``: a dict passed as one more JSON argument, with ``"box"`` (the box's path) added to it;
    ``box_files``: {name: text} written into the box first.
    """
    scratch = Path(tempfile.mkdtemp(prefix="kfkit-grade-"))
    try:
        scratch.chmod(0o711)
        box = make_box(scratch, sandbox)
        conn = box / "none.json"
        conn.write_text("{}")
        for name, text in (box_files or {}).items():
            (box / name).write_text(text)
        if args is not None:
            args["box"] = str(box)
            argv = [*argv, json.dumps(args)]
        cmd = sandbox.command(box, scratch, box / "home", str(conn), argv)
        return subprocess.run(
            cmd,
            capture_output=True,
            text=True,
            timeout=timeout,
            env=kernel_env(box),
            cwd=box / "home" if sandbox.mode == "none" else "/",
        )
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def probe(extra=(), modes=None) -> Sandbox:
    """The strongest sandbox that works here, checked from inside: ``/`` holds only the whitelist,
    nothing in it is writable (the kit's package, the venv, ``/`` itself), the instructor's folders
    and the kit's repository (``.git``, ``solutions/``) show nothing but the way to the kit's package
    and the venv, no host socket file is there, and the kernel's imports work.

    ``extra``: the instructor's folders of this grading run (submissions, gradebook).
    """
    visible, absent = visible_paths(), instructor_paths(extra)
    write = ["/", *visible, *absent]
    if modes is None:
        modes = ["root"] if os.geteuid() == 0 else ["userns"]
    reasons = []
    for mode in modes:
        if shutil.which("unshare") is None:
            reasons.append("the 'unshare' command (util-linux) is not installed")
            break
        sb, name = Sandbox(mode, visible=visible), f".kfkit-sandbox-probe-{os.getpid()}"
        args = {"name": name, "write": write, "absent": absent}
        try:
            done = run_in_sandbox(sb, [sys.executable, "-c", PROBE], args=args)
        except subprocess.TimeoutExpired:
            reasons.append(f"{mode}: the probe timed out")
            continue
        finally:
            leaked = leaked_writes(name, write)
        if done.returncode != 0:
            last = (done.stderr.strip().splitlines() or ["no message"])[-1]
            reasons.append(f"{mode}: {last}")
            continue
        report = json.loads(done.stdout.strip().splitlines()[-1])
        broken = check_report(report, visible, args["box"]) + (
            [f"written outside: {', '.join(leaked)}"] if leaked else []
        )
        if broken:
            reasons.append(f"{mode}: {'; '.join(broken)}")
            continue
        sb.network_blocked = not report["network"] and not report["ifaces"]
        return sb
    return Sandbox(
        "none",
        warning="student code would run with the grader's own permissions and could read and "
        "change the kit and your files (" + ("; ".join(reasons) or "no isolation mode was tried") + ")",
    )
