"""Where the kit's files live: the kit's root, the bundled data, and calibration files.

- :data:`KIT_ROOT`: the folder holding the ``kfkit`` package (labs, solutions, data, firmware).
- :func:`data_dir`: the bundled recordings and default calibrations, ``data/`` beside the package;
  the environment variable ``KFKIT_DATA`` overrides it.
- :func:`calibration_dir`: where students' own calibrations are saved, ``$KFKIT_HOME`` or ``~/.kfkit``.

A leaf: it imports nothing from the kit (and no NumPy), so every layer may use it.
"""

from __future__ import annotations

import os
from pathlib import Path

KIT_ROOT = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    """Folder holding the bundled recordings: ``$KFKIT_DATA`` or ``KIT_ROOT/data``."""
    return Path(os.environ.get("KFKIT_DATA") or KIT_ROOT / "data")


def calibration_dir() -> Path:
    """Where students' calibrations are saved: ``$KFKIT_HOME`` or ``~/.kfkit``."""
    return Path(os.environ.get("KFKIT_HOME") or Path.home() / ".kfkit")


def user_calibration_path(board="nucleo-iks02a1") -> Path:
    """The student's own calibration file for ``board`` (written by labs 02 and 03)."""
    return calibration_dir() / f"calibration_{board}.json"


def bundled_calibration_path(board="nucleo-iks02a1") -> Path:
    """The kit's default calibration for ``board``, bundled in :func:`data_dir`."""
    return data_dir() / f"calibration_{board}.json"
