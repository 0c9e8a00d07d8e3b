"""Classroom deployment files agree with the kit: Binder/repo2docker installs environment.txt."""

import re

from kfkit.paths import KIT_ROOT


def requirement_files(path):
    """``path`` and every file it pulls in with ``-r`` (relative to the including file)."""
    files = [path]
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith(("-r ", "--requirement ")):
            files += requirement_files((path.parent / line.split(maxsplit=1)[1]).resolve())
    return files


def test_binder_installs_the_pinned_environment_and_the_kit():
    files = requirement_files(KIT_ROOT / "binder" / "requirements.txt")
    assert (KIT_ROOT / "environment.txt").resolve() in files
    lines = [line.strip() for f in files for line in f.read_text(encoding="utf-8").splitlines()]
    assert "-e ." in lines  # the kit itself; repo2docker runs pip from the repository root


def test_binder_python_is_one_the_kit_supports():
    runtime = (KIT_ROOT / "binder" / "runtime.txt").read_text(encoding="utf-8").strip()
    major, minor = map(int, re.fullmatch(r"python-(\d+)\.(\d+)", runtime).groups())
    floor = re.search(r'requires-python = ">=(\d+)\.(\d+)"', (KIT_ROOT / "pyproject.toml").read_text()).groups()
    assert (major, minor) >= tuple(map(int, floor))
