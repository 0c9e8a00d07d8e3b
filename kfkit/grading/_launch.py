"""Sandbox launcher: run as ``unshare … -- python _launch.py SPEC_JSON -- COMMAND…`` (stdlib only).

It starts inside fresh mount, network, PID, IPC and UTS namespaces (made by ``unshare``, as real
root or as root of a user namespace), joins the submission's cgroup when the grader made one, then
builds the kernel's whole file system as a **whitelist** and moves into it:

1. a fresh tmpfs becomes the new root; into it, read-only and at their real paths, go only the
   system folders (``/usr``, ``/etc``, ``/bin`` … or their symbolic links) and the paths of
   ``spec["visible"]`` (the Python install, the venv, the kit's ``kfkit/`` and ``data/``: never the
   kit's repository root, so no ``.git``, ``solutions/`` or ``tests/``);
2. its own ``/tmp``, ``/run`` (``/var/run`` and ``/var/tmp`` link there) and ``/dev/shm`` (private,
   size-limited tmpfs), a minimal ``/dev`` (null, zero, full, random, urandom, tty, and a new
   devpts instance with its ptmx: lab 00's virtual board uses a pty), ``/proc`` of its PID namespace,
   and the submission's box folder (the grader's end of the kernel's sockets) with a private,
   size-limited tmpfs on its ``home/`` (the kernel's cwd and HOME);
3. ``pivot_root`` into it and detach the old root: nothing else of the machine is reachable any
   more (no other checkout of the kit, no pip cache, no socket file of the host);
4. remounts everything read-only except /tmp, /run, /dev/shm, the pty instance and the box; brings
   up the namespace's own loopback (lab 00 serves its virtual phone on 127.0.0.1; there is no other
   interface, so no network);
5. sets resource limits, drops privileges (another uid when real root; all capabilities when root
   of a user namespace) and sets no_new_privs, so the mounts cannot be undone, and asks for SIGKILL
   when ``unshare`` (killed with the grader) goes away; then execs COMMAND.

Any failure exits with status 70 and a one-line reason on stderr: the grader never runs a
kernel half-isolated in a mode it did not announce.
"""

import ctypes
import fcntl
import json
import os
import platform
import resource
import signal
import socket
import struct
import sys

MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC = 1, 2, 4, 8
MS_REMOUNT, MS_BIND, MS_REC, MS_PRIVATE = 32, 4096, 16384, 1 << 18
MS_NOATIME, MS_NODIRATIME, MS_RELATIME = 1024, 2048, 1 << 21
MNT_DETACH = 2
# statvfs f_flag bit → mount flag that a remount must keep (locked in a user namespace)
KEEP = {
    os.ST_NOSUID: MS_NOSUID,
    os.ST_NODEV: MS_NODEV,
    os.ST_NOEXEC: MS_NOEXEC,
    os.ST_NOATIME: MS_NOATIME,
    os.ST_NODIRATIME: MS_NODIRATIME,
    os.ST_RELATIME: MS_RELATIME,
}
PR_SET_PDEATHSIG, PR_CAPBSET_DROP, PR_SET_SECUREBITS, PR_SET_NO_NEW_PRIVS, PR_CAP_AMBIENT = 1, 24, 28, 38, 47
SECBITS_LOCKED_NOROOT = 0x2F  # NOROOT, NO_SETUID_FIXUP and KEEP_CAPS_LOCKED, each with its lock
SYS_PIVOT_ROOT = {"x86_64": 155, "aarch64": 41, "riscv64": 41, "ppc64le": 203, "s390x": 217}  # glibc has no wrapper
SYSTEM = ("/usr", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32", "/etc")
DEVICES = ("null", "zero", "full", "random", "urandom", "tty")
WRITABLE = ("/tmp", "/run", "/dev/shm", "/dev/pts")  # besides the box

libc = ctypes.CDLL(None, use_errno=True)


def fail(what):
    sys.stderr.write(f"kfkit sandbox: {what}\n")
    sys.exit(70)


def _check(result, what):
    if result != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"{what}: {os.strerror(err)}")


def mount(src, target, fstype, flags, data=None):
    def enc(s):
        return None if s is None else os.fsencode(s)

    _check(libc.mount(enc(src), enc(target), enc(fstype), ctypes.c_ulong(flags), enc(data)), f"mount {src} on {target}")


def prctl(option, arg):
    _check(libc.prctl(option, ctypes.c_ulong(arg), 0, 0, 0), f"prctl({option})")


def inside(path, folder):
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def mount_points():
    """Mount points of this namespace, deepest last (octal escapes of mountinfo decoded)."""
    points = []
    with open("/proc/self/mountinfo", "rb") as f:
        for line in f:
            field = line.split()[4].decode()
            points.append(field.encode().decode("unicode_escape").encode("latin-1").decode())
    return points


def _bind(source, target, root):
    """Bind ``source`` (a path or ``/proc/self/fd/N``) at ``root + target``, recursively."""
    dest = root + target
    if os.path.isdir(source):
        os.makedirs(dest, mode=0o755, exist_ok=True)
    else:
        os.makedirs(os.path.dirname(dest), mode=0o755, exist_ok=True)
        open(dest, "a").close()
    mount(source, dest, None, MS_BIND | MS_REC)


def build_root(spec, root):
    """Fill the tmpfs at ``root`` with the whitelist (see the module docstring, steps 1–2)."""
    box, cwd = spec["box"], spec["cwd"]
    box_handle = os.open(box, os.O_PATH | os.O_DIRECTORY)  # box lies under the folder the new root covers
    mount("tmpfs", root, "tmpfs", MS_NOSUID | MS_NODEV, "mode=755,size=16m")
    for path, options in (("/tmp", "mode=1777,size=256m"), ("/run", "mode=755,size=1m"), ("/dev", "mode=755,size=1m")):
        os.makedirs(root + path, mode=0o755, exist_ok=True)
        mount("tmpfs", root + path, "tmpfs", MS_NOSUID | (0 if path == "/dev" else MS_NODEV), options)
    for path in SYSTEM:
        if os.path.islink(path):  # merged /usr: /bin → usr/bin
            os.symlink(os.readlink(path), root + path)
        elif os.path.isdir(path):
            _bind(path, path, root)
    for path in spec["visible"]:  # after /tmp: a checkout under /tmp (CI) is bound inside it
        if not any(inside(path, s) for s in SYSTEM if os.path.isdir(s) and not os.path.islink(s)):
            _bind(path, path, root)
    os.makedirs(root + "/var", mode=0o755, exist_ok=True)
    os.symlink("../run", root + "/var/run")
    os.symlink("../tmp", root + "/var/tmp")
    for name in DEVICES:
        _bind(f"/dev/{name}", f"/dev/{name}", root)
    os.mkdir(root + "/dev/pts")
    mount("devpts", root + "/dev/pts", "devpts", MS_NOSUID | MS_NOEXEC, "newinstance,ptmxmode=0666,mode=0620")
    os.symlink("pts/ptmx", root + "/dev/ptmx")
    os.mkdir(root + "/dev/shm")
    mount("tmpfs", root + "/dev/shm", "tmpfs", MS_NOSUID | MS_NODEV, "mode=1777,size=256m")
    for name, target in (
        ("fd", "/proc/self/fd"),
        ("stdin", "/proc/self/fd/0"),
        ("stdout", "/proc/self/fd/1"),
        ("stderr", "/proc/self/fd/2"),
    ):
        os.symlink(target, f"{root}/dev/{name}")
    _bind("/proc", "/proc", root)  # unshare --mount-proc made it: this PID namespace's only
    _bind(f"/proc/self/fd/{box_handle}", box, root)
    os.close(box_handle)
    owner = f",uid={spec['uid']},gid={spec['gid']}" if spec.get("uid") is not None else ""
    mount("tmpfs", root + cwd, "tmpfs", MS_NOSUID | MS_NODEV, "mode=700,size=512m" + owner)  # private, bounded


def pivot(root):
    """Make ``root`` the file system's root and detach the old one (``pivot_root(".", ".")``)."""
    number = SYS_PIVOT_ROOT.get(platform.machine())
    if number is None:
        raise OSError(0, f"pivot_root: unknown system call number on {platform.machine()}")
    os.chdir(root)
    _check(libc.syscall(ctypes.c_long(number), b".", b"."), "pivot_root")
    _check(libc.umount2(b".", MNT_DETACH), "detaching the old root")
    os.chdir("/")


def make_read_only(box):
    """Remount every mount read-only except the writable ones, /proc and the box."""
    for point in mount_points():
        if point in WRITABLE or inside(point, "/proc") or inside(point, box):
            continue
        kept = sum(m for bit, m in KEEP.items() if os.statvfs(point).f_flag & bit)
        try:
            mount(None, point, None, MS_REMOUNT | MS_BIND | MS_RDONLY | kept)
        except OSError as exc:
            fail(f"cannot make {point} read-only ({exc.strerror})")


def isolate_files(spec):
    mount(None, "/", None, MS_REC | MS_PRIVATE)
    build_root(spec, spec["scratch"])
    pivot(spec["scratch"])
    make_read_only(spec["box"])


def join_cgroup(path):
    """Move this process (and so everything it starts) into the submission's cgroup v2."""
    with open(os.path.join(path, "cgroup.procs"), "w") as f:
        f.write("0")


def loopback_up():
    """Set IFF_UP on ``lo`` (SIOCGIFFLAGS / SIOCSIFFLAGS): a fresh network namespace starts with it down."""
    SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        flags = struct.unpack("16sH", fcntl.ioctl(s, SIOCGIFFLAGS, struct.pack("16sH", b"lo", 0)))[1]
        fcntl.ioctl(s, SIOCSIFFLAGS, struct.pack("16sH", b"lo", flags | IFF_UP))


def drop_privileges(spec):
    limits = {resource.RLIMIT_AS: spec["memory"], resource.RLIMIT_FSIZE: spec["file_size"], resource.RLIMIT_CORE: 0}
    if spec.get("uid") is not None:
        limits[resource.RLIMIT_NPROC] = spec["processes"]  # counted per uid: this kernel's own
    for what, value in limits.items():
        resource.setrlimit(what, (value, value))
    if spec.get("uid") is not None:
        uid, gid = spec["uid"], spec["gid"]
        os.chown(spec["connection_file"], uid, gid)
        os.setgroups([])
        os.setresgid(gid, gid, gid)
        os.setresuid(uid, uid, uid)  # leaving uid 0 clears every capability
        if os.getuid() != uid or os.geteuid() != uid:
            fail("could not change uid")
    else:  # root of a user namespace: keep uid 0 there, but without any capability
        prctl(PR_SET_SECUREBITS, SECBITS_LOCKED_NOROOT)
        with open("/proc/sys/kernel/cap_last_cap") as f:
            last = int(f.read())
        for cap in range(last + 1):
            prctl(PR_CAPBSET_DROP, cap)
        libc.prctl(PR_CAP_AMBIENT, 4, 0, 0, 0)  # PR_CAP_AMBIENT_CLEAR_ALL
        header = (ctypes.c_uint32 * 2)(0x20080522, 0)
        data = (ctypes.c_uint32 * 6)()
        if libc.capset(header, data) != 0:
            fail(f"capset: {os.strerror(ctypes.get_errno())}")
    prctl(PR_SET_NO_NEW_PRIVS, 1)
    prctl(PR_SET_PDEATHSIG, signal.SIGKILL)  # again: changing uid cleared the one unshare set


def main(argv):
    spec = json.loads(argv[1])
    if argv[2] != "--" or len(argv) < 4:
        fail("usage: _launch.py SPEC_JSON -- COMMAND…")
    try:
        if spec.get("cgroup"):
            join_cgroup(spec["cgroup"])
        isolate_files(spec)
        loopback_up()
        drop_privileges(spec)
        os.chdir(spec["cwd"])
    except OSError as exc:
        fail(str(exc))
    os.execv(argv[3], argv[3:])


if __name__ == "__main__":
    main(sys.argv)
