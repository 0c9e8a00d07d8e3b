"""The grading sandbox seen from inside: nothing of the instructor's is there, nothing of the host
is reachable (no kernel needed: small programs run exactly the way kernels are launched).

The walk test reads the whole readable file system from inside (less what is compiled or compressed, told by
its first bytes: no plain source text to find there) and fails on any solution text, any git repository and any socket
file but the box's own; a control run of the same walker over a planted folder outside the sandbox proves it finds each
of those.
"""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kfkit.grading import sandbox
from kfkit.paths import KIT_ROOT

pytestmark = pytest.mark.slow  # the quick tier (-m 'not slow') leaves this module out: see pyproject.toml

MODES = ["root", "userns"]
BIG = 4 << 20  # bytes: larger binary files are counted, not searched (larger text files are searched)
# The only files that may name the marker: they describe it, and hold no solution
# (the kit's own make-labs code and the installed package's copy of the README).
MARKER_DOCS = {str(KIT_ROOT / "kfkit" / "authoring.py")}
MARKER_DOC_NAMES = ("METADATA",)  # kfkit-*.dist-info/METADATA (the README)

WALK = r"""
import json, os, stat, sys, time
args = json.loads(sys.argv[1])
top, box, big = args["top"], args.get("box", "\0"), args["big"]
skip = set(args.get("skip", []))
found = {"solutions": [], "repositories": [], "sockets": [], "big_text": [], "files": 0, "bytes": 0, "big": 0,
         "compiled": 0, "unreadable": 0}
# compiled or compressed, by their first bytes: ELF, static library, Python bytecode (its magic ends in \r\n),
# gettext catalogue, gzip, zip: no plain source text to find (a compressed marker is invisible to a text search)
COMPILED = (b"\x7fELF", b"!<ar", b"\xde\x12\x04\x95", b"\x95\x04\x12\xde", b"\x1f\x8b", b"PK\x03\x04")
t0, c0 = time.monotonic(), time.process_time()
stack = [top]
while stack:
    folder = stack.pop()
    try:
        entries = list(os.scandir(folder))
    except OSError:
        found["unreadable"] += 1
        continue
    names = {e.name for e in entries}
    if "HEAD" in names and "objects" in names:  # a bare repository or a .git folder, whatever its name
        found["repositories"].append(folder)
    for e in entries:
        path = e.path
        if path in skip or path.startswith(box + "/"):
            continue
        try:
            mode = e.stat(follow_symlinks=False).st_mode
        except OSError:
            continue
        if stat.S_ISDIR(mode):
            if e.name == ".git":
                found["repositories"].append(path)
            stack.append(path)
        elif stat.S_ISSOCK(mode):
            found["sockets"].append(path)
        elif stat.S_ISREG(mode):
            found["files"] += 1
            try:
                with open(path, "rb") as f:
                    size = os.fstat(f.fileno()).st_size
                    magic = f.read(4)
                    if magic.startswith(COMPILED) or (path.endswith(".pyc") and magic[2:4] == b"\r\n"):
                        found["compiled"] += 1
                        continue
                    f.seek(0)
                    if size > big:  # binary (a NUL in its first 64 kB): counted, not searched
                        found["big"] += 1
                        head = f.read(65536)
                        if b"\0" in head:
                            continue
                        found["big_text"].append(path)  # text: searched all the same, a chunk at a time
                        f.seek(0)
                    hit, tail = False, b""
                    for chunk in iter(lambda: f.read(1 << 22), b""):
                        found["bytes"] += len(chunk)
                        hit = hit or b"BEGIN SOLUTION" in tail + chunk
                        tail = chunk[-16:]
            except OSError:
                found["unreadable"] += 1
                continue
            if hit:
                found["solutions"].append(path)
found["wall"], found["cpu"] = time.monotonic() - t0, time.process_time() - c0
print(json.dumps(found))
"""


def sandbox_or_skip(mode, extra=()):
    if mode == "root" and os.geteuid() != 0:
        pytest.skip("mode 'root' needs root")
    box = sandbox.probe(list(extra), modes=[mode])
    if box.mode == "none":
        pytest.skip(f"mode {mode} does not work here: {box.warning}")
    return box


def run_inside(box, code, args=None, timeout=600):
    done = sandbox.run_in_sandbox(box, [sys.executable, "-c", code], timeout=timeout, args=args)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_walker_finds_planted_solutions_repositories_sockets_and_big_text(tmp_path):
    """Control: outside the sandbox, the same walker finds each kind of leak (else the next test proves nothing),
    also in a large text file past its first chunk."""
    (tmp_path / "copy").mkdir()
    (tmp_path / "copy" / "lab.ipynb").write_text('{"source": "### BEGIN SOLUTION\\n    return 1\\n"}')
    subprocess.run(["git", "init", "-q", "--bare", str(tmp_path / "renamed_bare")], check=True)
    (tmp_path / "checkout" / ".git").mkdir(parents=True)
    (tmp_path / "big.txt").write_text("x" * (BIG + 5) + "### BEGIN SOLUTION")
    (tmp_path / "big.bin").write_bytes(b"\0" * (BIG + 1))
    (tmp_path / "lib.so").write_bytes(b"\x7fELF" + b"\0" * 60 + b"### BEGIN SOLUTION")  # compiled: not searched
    (tmp_path / "mod.pyc").write_bytes(b"\xa7\r\r\n" + b"\0" * 12 + b"### BEGIN SOLUTION")
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(tmp_path / "listener.sock"))
        done = subprocess.run(
            [sys.executable, "-c", WALK, json.dumps({"top": str(tmp_path), "big": BIG})],
            capture_output=True,
            text=True,
            check=True,
        )
    found = json.loads(done.stdout)
    assert sorted(found["solutions"]) == [str(tmp_path / "big.txt"), str(tmp_path / "copy" / "lab.ipynb")]
    assert sorted(found["repositories"]) == [str(tmp_path / "checkout" / ".git"), str(tmp_path / "renamed_bare")]
    assert found["sockets"] == [str(tmp_path / "listener.sock")]
    assert found["big_text"] == [str(tmp_path / "big.txt")] and found["big"] == 2 and found["compiled"] == 2


def test_nothing_readable_inside_holds_a_solution_a_repository_or_a_host_socket(tmp_path):
    """The whole readable file system (less /proc, /sys, /dev), as the kernel's user sees it, in the
    mode ``kfkit grade`` picks here (both modes bind the same folders; the other tests run both)."""
    mode = "root" if os.geteuid() == 0 else "userns"
    box = sandbox_or_skip(mode, [str(tmp_path)])
    args = {"top": "/", "big": BIG, "skip": ["/proc", "/sys", "/dev"]}
    t0 = time.monotonic()
    found = run_inside(box, WALK, args)
    wall = time.monotonic() - t0
    print(
        f"\nwalk ({mode}): {found['files']} files ({found['compiled']} compiled or compressed), "
        f"{found['bytes'] / 1e6:.0f} MB read, {found['big']} binary "
        f"files over {BIG >> 20} MB skipped ({len(found['big_text'])} text ones searched), {found['unreadable']} "
        f"unreadable; {found['wall']:.1f} s wall, "
        f"{found['cpu']:.1f} s CPU inside; {wall:.1f} s with the sandbox's start"
    )
    leaks = [
        p
        for p in found["solutions"]
        if p not in MARKER_DOCS and not (Path(p).name in MARKER_DOC_NAMES and ".dist-info" in p)
    ]
    assert leaks == []
    assert found["repositories"] == [] and found["sockets"] == []
    assert found["files"] > 1000  # it really walked the Python install and the venv
    assert str(KIT_ROOT / "kfkit" / "authoring.py") in found["solutions"]  # and it really searched them


def test_visible_paths_never_hold_the_repository_root():
    """The whitelist binds the kit's kfkit/ and data/, never the folder holding .git and solutions/."""
    kit = os.path.realpath(KIT_ROOT)
    paths = sandbox.visible_paths()
    assert not [p for p in paths if sandbox.inside(kit, p)]
    assert os.path.join(kit, "kfkit") in paths and os.path.join(kit, "data") in paths
    assert os.path.realpath(sys.prefix) in paths or any(sandbox.inside(os.path.realpath(sys.prefix), p) for p in paths)


GIT_AND_COPIES = r"""
import json, os, subprocess, sys
args = json.loads(sys.argv[1])
kit = args["kit"]
git = subprocess.run(["git", "-c", "safe.directory=*", "-C", kit, "show", "HEAD:solutions/01_roll_kf_1d.ipynb"],
                     capture_output=True, text=True)
print(json.dumps({"git": git.returncode, "git_out": len(git.stdout), "kit": sorted(os.listdir(kit)),
                  "root": sorted(os.listdir("/")), "exists": {p: os.path.exists(p) for p in args["paths"]},
                  "pty": bool(os.openpty())}))
"""


@pytest.mark.parametrize("mode", MODES)
def test_git_and_other_copies_of_the_kit_and_pips_cache_are_not_there(mode, tmp_path):
    """The issue's route (git show HEAD:solutions/…), a second checkout elsewhere, pip's cache; a pty still works."""
    copy = tmp_path / "other_checkout"
    (copy / "solutions").mkdir(parents=True)
    (copy / "solutions" / "01.ipynb").write_text("### BEGIN SOLUTION")
    tmp_path.chmod(0o755)
    box = sandbox_or_skip(mode)
    paths = [
        str(KIT_ROOT / ".git"),
        str(KIT_ROOT / "solutions"),
        str(KIT_ROOT / "tests"),
        str(copy),
        str(Path.home() / ".cache" / "pip"),
        str(Path.home() / ".gitconfig"),
    ]
    res = run_inside(box, GIT_AND_COPIES, {"kit": str(KIT_ROOT), "paths": paths})
    assert res["git"] != 0 and res["git_out"] == 0
    kit_inside = {"kfkit", "data"} | {
        Path(p).relative_to(KIT_ROOT).parts[0] for p in sandbox.visible_paths() if sandbox.inside(p, str(KIT_ROOT))
    }
    assert set(res["kit"]) == kit_inside
    assert res["exists"] == dict.fromkeys(paths, False)
    assert set(res["root"]) <= sandbox.root_entries(sandbox.visible_paths(), "/tmp")
    assert res["pty"]


CONNECT = r"""
import json, socket, sys
args = json.loads(sys.argv[1])
out = {}
for name, address in args["targets"].items():
    address = address.replace("@", "\0", 1) if address.startswith("@") else address
    try:
        with socket.socket(socket.AF_UNIX) as s:
            s.settimeout(5)
            s.connect(address)
            s.sendall(b"hello from inside")
        out[name] = "connected"
    except OSError as exc:
        out[name] = type(exc).__name__
print(json.dumps(out))
"""


@pytest.mark.parametrize("mode", MODES)
def test_host_unix_sockets_are_unreachable(mode, tmp_path):
    """Listeners of the test's own: a 0777 socket file under /run and under /tmp, and an abstract one."""
    box = sandbox_or_skip(mode)
    tag = f"kfkit-test-{os.getpid()}-{mode}"
    files = {"run": Path("/run") / f"{tag}.sock", "tmp": Path("/tmp") / f"{tag}.sock"}
    listeners = []
    try:
        targets = {}
        for name, path in files.items():
            s = socket.socket(socket.AF_UNIX)
            s.bind(str(path))
            path.chmod(0o777)
            s.listen()
            listeners.append(s)
            targets[name] = str(path)
        abstract = socket.socket(socket.AF_UNIX)
        abstract.bind("\0" + tag)
        abstract.listen()
        listeners.append(abstract)
        targets["abstract"] = "@" + tag
        control = json.loads(
            subprocess.run(
                [sys.executable, "-c", CONNECT, json.dumps({"targets": targets})],
                capture_output=True,
                text=True,
                check=True,
            ).stdout
        )
        assert control == dict.fromkeys(targets, "connected")  # the listeners are real
        for s in listeners:  # take the control's connections
            s.settimeout(5)
            s.accept()[0].close()
            s.settimeout(0.5)
        inside = run_inside(box, CONNECT, {"targets": targets})
        assert set(inside.values()) <= {"FileNotFoundError", "ConnectionRefusedError"}, inside
        for s in listeners:  # nothing arrived
            with pytest.raises(OSError):
                s.accept()
    finally:
        for s in listeners:
            s.close()
        for path in files.values():
            path.unlink(missing_ok=True)


def test_probe_report_check_names_each_broken_guarantee():
    """The probe's verdict from a report: each guarantee, broken alone, is named."""
    visible = sandbox.visible_paths()
    good = {"root": ["bin", "dev", "etc", "proc", "tmp", "usr"], "written": [], "seen": {}, "sockets": []}
    assert sandbox.check_report(good, visible, "/tmp/box") == []
    cases = {
        "root": ["bin", "farm"],
        "written": [visible[0]],
        "seen": {str(KIT_ROOT): ["kfkit", "solutions"]},
        "sockets": ["/run/x.sock"],
    }
    words = {
        "root": "more than the whitelist: farm",
        "written": "still writable",
        "seen": "still visible",
        "sockets": "socket files of the host: /run/x.sock",
    }
    for key, bad in cases.items():
        broken = sandbox.check_report({**good, key: bad}, visible, "/tmp/box")
        assert len(broken) == 1 and words[key] in broken[0], (key, broken)
