"""Which files are graded, and reading them without leaving the folder being graded.

A submissions folder holds what students handed in, and students choose what is in it. The grader runs
outside the sandbox with the instructor's permissions, so a symbolic link named ``alice.ipynb`` that points at
``solutions/01_roll_kf_1d.ipynb`` would have it read (and score) the solution under Alice's name; a named pipe
would pass a size check (its size is 0) and block the grader forever. So:

* what the instructor names on the command line is trusted (a folder named may itself be a link: it is
  resolved once and becomes the *root* being graded; for a file named, its folder is the root);
* below a root, nothing is followed: folders are walked with ``os.walk(followlinks=False)``, and every link
  (to a file or a folder) and every ``.ipynb`` that is not a regular file (a pipe, a socket, a device) is
  *refused*: it becomes a gradebook row with status ``refused`` and the reason, and a line of the summary,
  so that no submission silently disappears;
* a file is opened only through :func:`read_submission`: each folder below the root with ``O_NOFOLLOW`` from
  the one before (``openat``), the file itself with ``O_NOFOLLOW | O_NONBLOCK`` after an ``lstat`` said it is
  a regular file, and the opened descriptor is checked again with ``fstat`` (a file swapped for a link or a
  pipe in between is refused, not followed; a pipe is never read).
"""

from __future__ import annotations

import errno
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from .quoting import clip

NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)  # 0 on Windows: there the lstat/fstat comparison below stands alone
SAFE_OPEN = (
    os.O_RDONLY | NOFOLLOW | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)
)
DIR_OPEN = os.O_RDONLY | NOFOLLOW | getattr(os, "O_DIRECTORY", 0)
SKIPPED_FOLDERS = (".ipynb_checkpoints",)  # Jupyter's autosaves beside each notebook, never a submission


class Refused(OSError):
    """A path below the root that is not opened: a link, or not a regular file (``why`` says which)."""

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


class TooLarge(ValueError):
    """The file holds more bytes than the grader reads."""


@dataclass(frozen=True)
class Submission:
    """One notebook to grade: ``relative`` (no component a link) inside ``root`` (the folder being graded);
    ``name`` is its gradebook name; ``refused``, when not empty, why it is not opened at all."""

    root: Path
    relative: Path
    name: str
    refused: str = ""

    @property
    def path(self) -> Path:
        return self.root / self.relative

    def __fspath__(self) -> str:
        return str(self.path)


def kind(mode: int, target: str | None = None) -> str:
    """What a non-regular file is, for a reason a person reads (``target``: a link's text)."""
    if stat.S_ISLNK(mode):
        return f"a symbolic link (to {clip(target, 200)})" if target is not None else "a symbolic link"
    for test, what in (
        (stat.S_ISFIFO, "a named pipe (FIFO)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISDIR, "a folder"),
    ):
        if test(mode):
            return what
    return "not a regular file"


def _refusal(path: Path) -> str:
    """Why ``path`` (which ``lstat`` shows is not a regular file) is refused."""
    mode = os.lstat(path).st_mode
    target = os.readlink(path) if stat.S_ISLNK(mode) else None
    followed = "not followed" if stat.S_ISLNK(mode) else "not opened"
    return f"refused: it is {kind(mode, target)}, {followed}; submit the notebook file itself"


def find_submissions(paths) -> tuple[list[Submission], list[str]]:
    """The notebooks named or held (recursively) by ``paths``; → ([:class:`Submission`], warnings).

    Links and non-regular ``.ipynb`` files below a folder named (and a file named that is one) come back
    refused, never followed. The gradebook name is the path relative to the current folder when inside it,
    else ``folder/…`` from the folder named, or ``parent/file`` for a file.
    """
    found: dict[Path, Submission] = {}
    warnings = []
    for p in map(Path, paths):
        if p.is_dir():
            root = p.resolve()
            held = list(_walk(root, warnings))
            if not held:
                warnings.append(f"{p}: folder holds no .ipynb file")
            for sub in held:
                found.setdefault(sub.path, sub)
        elif os.path.lexists(p):
            root = p.parent.resolve()
            sub = _submission(root, Path(p.name), Path(root.name) / p.name)
            found.setdefault(sub.path, sub)
        else:
            warnings.append(f"{p}: no such file or folder")
    subs = list(found.values())
    names = [s.name for s in subs]  # two files shown alike (same folder name elsewhere): full paths instead
    subs = [Submission(s.root, s.relative, str(s.path), s.refused) if names.count(s.name) > 1 else s for s in subs]
    warnings += [f"{s.name}: {s.refused}" for s in subs if s.refused]
    return subs, warnings


def _walk(root: Path, warnings: list):
    """Every ``.ipynb`` below ``root`` and every link to a folder there, as submissions (links and non-files
    refused); a folder that cannot be read is named in ``warnings``. ``os.walk`` lists a link to a folder among
    the folders and, told so, does not enter it."""

    def unreadable(exc: OSError):
        warnings.append(f"{exc.filename}: folder cannot be read ({exc.strerror}): what it holds is not graded")

    for folder, dirs, files in os.walk(root, onerror=unreadable, followlinks=False):
        here = Path(folder)
        dirs[:] = [d for d in dirs if d not in SKIPPED_FOLDERS]
        links = [d for d in dirs if os.path.islink(here / d)]
        dirs[:] = sorted(d for d in dirs if d not in links)
        for name in sorted(links + [f for f in files if f.endswith(".ipynb")]):
            rel = (here / name).relative_to(root)
            yield _submission(root, rel, Path(root.name) / rel)


def _submission(root: Path, relative: Path, fallback: Path) -> Submission:
    path = root / relative
    try:
        name = str(path.relative_to(Path.cwd().resolve()))
    except ValueError:
        name = str(fallback)
    try:
        regular = stat.S_ISREG(os.lstat(path).st_mode)
        refused = "" if regular else _refusal(path)
    except OSError as exc:
        refused = f"refused: it cannot be examined ({exc.strerror})"
    return Submission(root, relative, name, refused)


def read_submission(root: Path, relative: Path, limit: int) -> bytes:
    """The bytes of ``root/relative``, opened without following any link below ``root`` and only if it is a
    regular file (:class:`Refused` otherwise); :class:`TooLarge` when it holds more than ``limit`` bytes."""
    parts = Path(relative).parts
    if not parts or any(p in ("", ".", "..") for p in parts) or Path(relative).is_absolute():
        raise Refused(f"refused: {relative} is not a path inside the folder graded")
    if os.open not in os.supports_dir_fd:  # Windows: no openat; check each step with lstat, then compare
        return _read_by_path(root, parts, limit)
    folder = os.open(root, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        for part in parts[:-1]:
            try:
                inner = os.open(part, DIR_OPEN, dir_fd=folder)
            except OSError as exc:
                raise _refused_step(exc, part, folder) from None
            os.close(folder)
            folder = inner
        st = os.stat(parts[-1], dir_fd=folder, follow_symlinks=False)
        if not stat.S_ISREG(st.st_mode):
            target = os.readlink(parts[-1], dir_fd=folder) if stat.S_ISLNK(st.st_mode) else None
            raise Refused(f"refused: it is {kind(st.st_mode, target)}, not opened")
        try:
            fd = os.open(parts[-1], SAFE_OPEN, dir_fd=folder)
        except OSError as exc:
            raise _refused_step(exc, parts[-1], folder) from None
    finally:
        os.close(folder)
    return _read_regular(fd, limit)


def _refused_step(exc: OSError, part: str, folder: int) -> OSError:
    """A link met on the way (ELOOP from O_NOFOLLOW, ENOTDIR for a link to a file) → Refused; else ``exc``."""
    try:
        st = os.stat(part, dir_fd=folder, follow_symlinks=False)
    except OSError:
        return exc
    if stat.S_ISLNK(st.st_mode) or exc.errno == errno.ELOOP:
        return Refused(f"refused: {part} is {kind(st.st_mode, os.readlink(part, dir_fd=folder))}, not followed")
    return exc


def _read_by_path(root: Path, parts: tuple, limit: int) -> bytes:
    """:func:`read_submission` where ``openat`` is missing: each step checked with ``lstat``, the file opened
    by its path and its ``fstat`` compared with the ``lstat`` (a swap in between is refused)."""
    path = Path(root)
    for i, part in enumerate(parts):
        path = path / part
        mode = os.lstat(path).st_mode
        if stat.S_ISLNK(mode) or (i == len(parts) - 1 and not stat.S_ISREG(mode)):
            raise Refused(f"refused: {part} is {kind(mode)}, not opened")
    before = os.lstat(path)
    fd = os.open(path, SAFE_OPEN)
    after = os.fstat(fd)
    if (after.st_dev, after.st_ino) != (before.st_dev, before.st_ino):
        os.close(fd)
        raise Refused("refused: the file changed while it was being opened")
    return _read_regular(fd, limit)


def _read_regular(fd: int, limit: int) -> bytes:
    """Read an opened descriptor (closed here) if ``fstat`` says it is a regular file of at most ``limit`` bytes."""
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise Refused(f"refused: it is {kind(st.st_mode)}, not read")
        if st.st_size > limit:
            raise TooLarge(st.st_size)
        data = f.read(limit + 1)
    if len(data) > limit:  # it grew since fstat
        raise TooLarge(len(data))
    return data
