"""Sandbox launcher: run as ``unshare … -- python _launch.py SPEC_JSON -- COMMAND…`` (stdlib only).

It starts inside fresh mount, network, PID, IPC and UTS namespaces (made by ``unshare``, as real
root or as root of a user namespace), then:

1. covers ``/tmp``, ``/var/tmp``, ``/dev/shm`` and the grader's scratch folder with private tmpfs
   (other submissions' folders disappear), and every top-most folder the sandbox user cannot
   traverse (e.g. ``/root`` holding a pyenv Python) or that the spec hides (the instructor's
   home, the submissions, the gradebook's folder, the kit's ``solutions/``) with an empty tmpfs,
   binding back only the paths the kernel needs (the Python install, the venv, the kit), wherever
   they are (a checkout under ``/tmp`` included);
2. binds the submission's own box folder back (the grader's end of the kernel's sockets), and
   mounts a private, size-limited tmpfs on its ``home/`` (the kernel's cwd and HOME);
3. remounts every other mount read-only (the kit, the instructor's folders, the venv, /);
   brings up the namespace's own loopback (a lab may serve itself on 127.0.0.1, as lab 00's
   virtual phone does; the namespace has no other interface, so still no network);
4. sets resource limits, drops privileges (another uid when real root; all capabilities when
   root of a user namespace) and sets no_new_privs, so the read-only mounts cannot be undone,
   and asks for SIGKILL when ``unshare`` (killed with the grader) goes away;
5. execs COMMAND (the kernel, or the isolation probe).

Any failure exits with status 70 and a one-line reason on stderr: the grader never runs a
kernel half-isolated in a mode it did not announce.
"""
import ctypes
import fcntl
import json
import os
import resource
import signal
import socket
import struct
import sys

MS_RDONLY, MS_NOSUID, MS_NODEV, MS_NOEXEC = 1, 2, 4, 8
MS_REMOUNT, MS_BIND, MS_MOVE, MS_REC, MS_PRIVATE = 32, 4096, 8192, 16384, 1 << 18
MS_NOATIME, MS_NODIRATIME, MS_RELATIME = 1024, 2048, 1 << 21
# statvfs f_flag bit → mount flag that a remount must keep (locked in a user namespace)
KEEP = {os.ST_NOSUID: MS_NOSUID, os.ST_NODEV: MS_NODEV, os.ST_NOEXEC: MS_NOEXEC,
        os.ST_NOATIME: MS_NOATIME, os.ST_NODIRATIME: MS_NODIRATIME, os.ST_RELATIME: MS_RELATIME}
PR_SET_PDEATHSIG, PR_CAPBSET_DROP, PR_SET_SECUREBITS, PR_SET_NO_NEW_PRIVS, PR_CAP_AMBIENT = 1, 24, 28, 38, 47
SECBITS_LOCKED_NOROOT = 0x2F  # NOROOT, NO_SETUID_FIXUP and KEEP_CAPS_LOCKED, each with its lock

libc = ctypes.CDLL(None, use_errno=True)


def fail(what):
    sys.stderr.write(f"kfkit sandbox: {what}\n")
    sys.exit(70)


def mount(src, target, fstype, flags, data=None):
    enc = lambda s: None if s is None else os.fsencode(s)  # noqa: E731
    if libc.mount(enc(src), enc(target), enc(fstype), ctypes.c_ulong(flags), enc(data)) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"mount {src} on {target}: {os.strerror(err)}")


def prctl(option, arg):
    if libc.prctl(option, ctypes.c_ulong(arg), 0, 0, 0) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"prctl({option}): {os.strerror(err)}")


def inside(path, folder):
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def traversable(path, uid, gid):
    st = os.stat(path)
    if st.st_uid == uid:
        return bool(st.st_mode & 0o100)
    if st.st_gid == gid:
        return bool(st.st_mode & 0o010)
    return bool(st.st_mode & 0o001)


def blocked_ancestor(path, uid, gid):
    """The top-most folder on the way to ``path`` that ``uid`` cannot enter, or None."""
    parts = path.strip("/").split("/")
    for i in range(1, len(parts) + 1):
        folder = "/" + "/".join(parts[:i])
        if not traversable(folder, uid, gid):
            return folder
    return None


def mount_points():
    """Mount points of this namespace, deepest last (octal escapes of mountinfo decoded)."""
    points = []
    with open("/proc/self/mountinfo", "rb") as f:
        for line in f:
            field = line.split()[4].decode()
            points.append(field.encode().decode("unicode_escape").encode("latin-1").decode())
    return points


def isolate_files(spec):
    uid, gid = spec.get("uid"), spec.get("gid")
    box, needed = spec["box"], [p for p in spec["needed"] if os.path.exists(p)]
    hidden = [p for p in spec.get("hide", []) if os.path.isdir(p)]
    mount(None, "/", None, MS_REC | MS_PRIVATE)
    private = [p for p in ("/tmp", "/var/tmp", "/dev/shm", spec["scratch"]) if os.path.isdir(p)]
    covers = {p: "mode=1777,size=256m" for p in private}
    if uid is not None:  # real root dropping to another uid: make the kernel's files reachable
        for path in needed:
            top = blocked_ancestor(path, uid, gid)
            if top is not None:
                covers.setdefault(top, "mode=755,size=1m")
    for path in hidden:  # a hidden folder holding what the kernel needs: covered, that part bound back
        if any(inside(p, path) for p in needed + [box]):
            covers.setdefault(path, "mode=755,size=1m")
    tops = sorted(covers, key=len)
    tops = [t for i, t in enumerate(tops) if not any(inside(t, o) for o in tops[:i])]
    # O_PATH handles keep covered folders reachable through /proc/self/fd after they are covered
    rebind = [p for p in needed if any(inside(p, t) for t in tops)]
    handles = {p: os.open(p, os.O_PATH) for p in rebind + [box]}
    for top in tops:
        mount("tmpfs", top, "tmpfs", MS_NOSUID | MS_NODEV, covers[top])
    for path in rebind + [box]:
        os.makedirs(path, exist_ok=True)
        mount(f"/proc/self/fd/{handles[path]}", path, None, MS_BIND | MS_REC)
        os.close(handles[path])
    emptied = []
    for path in sorted(hidden, key=len):  # the other hidden folders (e.g. solutions/ in the kit): an empty tmpfs
        gone = any(inside(path, t) for t in tops) and not any(inside(path, p) for p in rebind)
        if path not in covers and not gone and not any(inside(path, e) for e in emptied):
            mount("tmpfs", path, "tmpfs", MS_NOSUID | MS_NODEV, "mode=755,size=1m")
            emptied.append(path)
    owner = f",uid={uid},gid={gid}" if uid is not None else ""
    mount("tmpfs", spec["cwd"], "tmpfs", MS_NOSUID | MS_NODEV, "mode=700,size=512m" + owner)  # private, bounded
    writable = set(private) | {box}
    for point in mount_points():
        if point in writable or inside(point, "/proc") or inside(point, box):
            continue
        try:
            kept = sum(m for bit, m in KEEP.items() if os.statvfs(point).f_flag & bit)
            mount(None, point, None, MS_REMOUNT | MS_BIND | MS_RDONLY | kept)
        except OSError as exc:
            if any(inside(p, point) or inside(point, p) for p in spec["protect"]) or point == "/":
                fail(f"cannot make {point} read-only ({exc.strerror})")


def loopback_up():
    """Set IFF_UP on ``lo`` (SIOCGIFFLAGS / SIOCSIFFLAGS): a fresh network namespace starts with it down."""
    SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        flags = struct.unpack("16sH", fcntl.ioctl(s, SIOCGIFFLAGS, struct.pack("16sH", b"lo", 0)))[1]
        fcntl.ioctl(s, SIOCSIFFLAGS, struct.pack("16sH", b"lo", flags | IFF_UP))


def drop_privileges(spec):
    limits = {resource.RLIMIT_AS: spec["memory"], resource.RLIMIT_FSIZE: spec["file_size"],
              resource.RLIMIT_CORE: 0}
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
        last = int(open("/proc/sys/kernel/cap_last_cap").read())
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
        isolate_files(spec)
        loopback_up()
        drop_privileges(spec)
        os.chdir(spec["cwd"])
    except OSError as exc:
        fail(str(exc))
    os.execv(argv[3], argv[3:])


if __name__ == "__main__":
    main(sys.argv)
