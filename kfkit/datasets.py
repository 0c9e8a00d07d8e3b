"""The bundled recordings under ``data/``: how each is made, loading by name, regeneration.

Every file is a seeded simulation, so ``kfkit data regenerate`` rebuilds them all and
``kfkit data regenerate --check`` fails when a shipped file differs from what the code makes.
The data folder is ``data/`` beside the ``kfkit`` package; ``KFKIT_DATA`` overrides it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from . import sim
from .io import Recording, load_recording, recording_text

KIT_ROOT = Path(__file__).resolve().parents[1]


def data_dir() -> Path:
    """Folder holding the bundled recordings."""
    return Path(os.environ.get("KFKIT_DATA") or KIT_ROOT / "data")


def _roll_sine() -> Recording:
    """Lab 01: a Nucleo + X-NUCLEO-IKS02A1 rolled by hand, ±30° at 0.1 Hz, 104 Hz, 60 s."""
    motion = sim.sine_roll(duration=60.0, rate_hz=104.0, amplitude=np.radians(30.0), freq_hz=0.1,
                           still=5.0, shakes=(22.0, 42.0), vibration_rms=0.3, seed=101)
    return sim.simulate_imu(motion, board="nucleo-iks02a1", seed=102)


@dataclass(frozen=True)
class Bundled:
    """How one bundled file is made, written and read (IMU recordings by default)."""

    build: Callable[[], Any]
    text: Callable[[Any], str] = recording_text
    read: Callable[[Path], Any] = load_recording


#: name → how to make it; the file is ``data/<name>.csv``
BUNDLED = {
    "01_roll_sine": Bundled(_roll_sine),
}


def _entry(name: str) -> Bundled:
    try:
        return BUNDLED[name]
    except KeyError:
        raise ValueError(f"no bundled recording {name!r}; available: {', '.join(BUNDLED)}") from None


def build(name: str):
    """Build the bundled recording ``name`` from its seeded simulation."""
    return _entry(name).build()


def load(name: str):
    """Load the bundled recording ``name`` (e.g. '01_roll_sine') from the data folder."""
    entry = _entry(name)
    path = data_dir() / f"{name}.csv"
    if not path.exists():
        raise FileNotFoundError(f"bundled recording missing: {path}. Rebuild it with: python -m kfkit data regenerate")
    return entry.read(path)


def regenerate(check: bool = False, directory=None) -> list[str]:
    """Rebuild every bundled recording; with ``check``, write nothing and list the files that differ."""
    folder = Path(directory) if directory is not None else data_dir()
    report = []
    for name, entry in BUNDLED.items():
        path = folder / f"{name}.csv"
        text = entry.text(entry.build())
        if check:
            if not path.exists():
                report.append(f"{path} is missing")
            elif path.read_text(encoding="utf-8") != text:
                report.append(f"{path} differs from what its simulation makes now: {_first_difference(path.read_text(encoding='utf-8'), text)}")
        else:
            folder.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8", newline="\n")
            report.append(str(path))
    return report


def _first_difference(old: str, new: str) -> str:
    for i, (a, b) in enumerate(zip(old.splitlines(), new.splitlines()), start=1):
        if a != b:
            col = next((j for j, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
            lo = max(0, col - 30)
            return f"first at line {i}, column {col + 1}: shipped …{a[lo:col + 30]!r}…, regenerated …{b[lo:col + 30]!r}…"
    return f"line counts differ ({len(old.splitlines())} shipped, {len(new.splitlines())} regenerated)"
