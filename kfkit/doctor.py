"""``kfkit doctor``: check that this Python environment can run the labs.

Every line of the report starts with ✅ (fine), ❌ (must be fixed) or ⚠️
(advice only). The check never needs the optional pieces it reports on, so it
still runs in a half-installed environment.
"""

from __future__ import annotations

import os
import re
import sys
from importlib import metadata
from pathlib import Path

from .paths import KIT_ROOT, data_dir

OK, FAIL, WARN = "✅", "❌", "⚠️"
INSTALL_HINT = "run: python -m pip install -r environment.txt"
# the packages to check are the pins of the kit's environment.txt (the kit is installed editable, -e .)
ENVIRONMENT = KIT_ROOT / "environment.txt"
PIN = re.compile(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([A-Za-z0-9][A-Za-z0-9.+!_-]*)")
# JupyterLab front-end extension folder -> Python package that ships it
LABEXTENSIONS = {
    "@jupyter-widgets/jupyterlab-manager": "ipywidgets",
    "jupyter-matplotlib": "ipympl",
}
MIN_PYTHON = (3, 10)


def python_line() -> str:
    version = ".".join(map(str, sys.version_info[:3]))
    if sys.version_info[:2] < MIN_PYTHON:
        needed = ".".join(map(str, MIN_PYTHON))
        return f"{FAIL} Python {version} is too old: kfkit needs Python {needed} or newer"
    return f"{OK} Python {version} ({sys.executable})"


def read_pins(path: Path) -> dict[str, str]:
    """The exact pins ``name==version`` of pip requirements file ``path``, in file order.

    Blank lines, comments (``#`` at the start or after a space) and ``-e`` lines are skipped; any other
    line raises ValueError naming the file, the line and what was expected.
    """
    pins = {}
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        text = re.sub(r"(^|\s)#.*", "", line).strip()
        if not text or text.startswith(("-e ", "--editable ")):
            continue
        match = PIN.fullmatch(text)
        if not match:
            raise ValueError(f"{path}, line {number}: expected an exact pin 'name==version' or '-e .', got {line!r}")
        pins[match[1]] = match[2]
    return pins


def package_lines() -> list[str]:
    """One line per pin of environment.txt: ✅ as pinned, ⚠️ another version, ❌ missing."""
    try:
        pins = read_pins(ENVIRONMENT)
    except FileNotFoundError:
        return [
            f"{WARN} {ENVIRONMENT} not found (kfkit installed without the kit's folder): package versions not checked"
        ]
    except ValueError as e:
        return [f"{FAIL} cannot read the package list: {e}"]
    lines = []
    for name, pinned in pins.items():
        try:
            installed = metadata.version(name)
        except metadata.PackageNotFoundError:
            lines.append(f"{FAIL} {name} is not installed; {INSTALL_HINT}")
            continue
        if installed == pinned:
            lines.append(f"{OK} {name} {installed}")
        else:
            lines.append(
                f"{WARN} {name} {installed} is installed, the labs are tested with {pinned} "
                f"(environment.txt); if something misbehaves, {INSTALL_HINT}"
            )
    return lines


def labextension_search_path() -> list[Path]:
    """The folders where JupyterLab looks for prebuilt front-end extensions."""
    from jupyter_core.paths import jupyter_path

    return [Path(folder) for folder in jupyter_path("labextensions")]


def find_labextension(name: str, search_path: list[Path]) -> Path | None:
    """Return the folder of labextension ``name`` (e.g. ``jupyter-matplotlib``), or None."""
    for base in search_path:
        if (base / name / "package.json").is_file():
            return base / name
    return None


def labextension_lines() -> list[str]:
    try:
        search_path = labextension_search_path()
    except ImportError:
        return [f"{FAIL} cannot look for JupyterLab extensions: jupyter_core is not installed; {INSTALL_HINT}"]
    lines = []
    for name, package in LABEXTENSIONS.items():
        folder = find_labextension(name, search_path)
        if folder:
            lines.append(f"{OK} JupyterLab extension {name} ({package}) in {folder}")
        else:
            lines.append(
                f"{FAIL} JupyterLab extension {name} not found, so {package} plots/widgets will not show: "
                f"reinstall {package} in the same environment that runs `jupyter lab` "
                f"(python -m pip install --force-reinstall --no-deps {_pinned(package)}), then restart JupyterLab"
            )
    return lines


def _pinned(package: str) -> str:
    try:
        return f"{package}=={metadata.version(package)}"
    except metadata.PackageNotFoundError:
        return package


def describe_port(port) -> str:
    """``device: description [VID:PID]`` for a pyserial ListPortInfo (or look-alike)."""
    text = f"{port.device}: {port.description}"
    if port.vid is not None and port.pid is not None:
        text += f" [{port.vid:04X}:{port.pid:04X}]"
    return text


def serial_lines() -> list[str]:
    try:
        from .capture.ports import find_boards  # USB serial ports only: built-in UARTs (/dev/ttyS0) are no boards

        ports = find_boards()
    except ImportError as e:
        return [f"{WARN} cannot list serial ports: {e.name} is not installed"]
    if not ports:
        lines = [f"{WARN} no serial ports found (that is fine: the labs run on bundled data)"]
    else:
        lines = [f"{OK} serial port {port.port}: {port.description} [{port.vid_pid}]" for port in ports]
    if needs_dialout():
        lines.append(
            f"{WARN} you are not in the 'dialout' group, so you cannot open serial ports: "
            "run `sudo usermod -aG dialout $USER`, then log out and in again"
        )
    return lines


def needs_dialout() -> bool:
    """True on Linux when a non-root user lacks the ``dialout`` group that owns serial ports."""
    if not sys.platform.startswith("linux") or os.geteuid() == 0:
        return False
    import grp

    try:
        dialout = grp.getgrnam("dialout").gr_gid
    except KeyError:  # distribution without a dialout group (e.g. Arch uses uucp)
        return False
    return dialout not in os.getgroups()


def data_line() -> str:
    folder = data_dir()
    if not folder.is_dir():
        return f"{FAIL} bundled data not found at {folder} (set KFKIT_DATA, or use a complete copy of the kit)"
    count = len(list(folder.rglob("*.csv")))
    if count == 0:
        return f"{WARN} bundled data folder {folder} holds no *.csv files"
    return f"{OK} bundled data: {count} CSV files in {folder}"


def doctor_report() -> tuple[str, bool]:
    """Return the report text and whether nothing needs fixing (no ❌ line)."""
    lines = [python_line(), *package_lines(), *labextension_lines(), *serial_lines(), data_line()]
    ok = not any(line.startswith(FAIL) for line in lines)
    return "\n".join(lines), ok
