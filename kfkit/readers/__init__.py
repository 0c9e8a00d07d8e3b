"""Foreign file formats, one module each, named for what it reads; each gives a kit :class:`~kfkit.io.Recording`.

- :mod:`.phyphox_export`  a phone's phyphox CSV export (folder, .zip, ``Raw Data.csv``): :func:`load_phyphox`
- :mod:`.broad`           a BROAD benchmark trial (``.mat``): :func:`load_broad`
- :mod:`.vehicle_csv`     your own drive from a logger's CSV, by naming its columns: :func:`load_vehicle_csv`

:func:`load_any` opens a recording of your own whatever made it. The kit's own formats are
:mod:`kfkit.io` (IMU recordings) and :mod:`kfkit.vehicle` (vehicle recordings).
"""

from __future__ import annotations

from pathlib import Path

from ..io import BOM, VERSION_PREFIX, Recording, load_recording
from .broad import load_broad
from .phyphox_export import load_phyphox
from .vehicle_csv import load_vehicle_csv

__all__ = ["load_any", "load_broad", "load_phyphox", "load_vehicle_csv"]


def load_any(path, mount="flat", require=("acc", "gyr")) -> Recording:
    """A recording of your own, whatever made it: a file in the kit's format (a board's or a phone's
    capture, lab 00) with :func:`kfkit.io.load_recording`, else a phone's phyphox CSV export (a folder, a
    ``.zip`` or a ``Raw Data.csv``) with :func:`load_phyphox` in the phone's ``mount``, with the
    sensors ``require`` names."""
    path = Path(path)
    if path.is_file():
        with open(path, "rb") as f:
            if (
                f.read(len(BOM.encode()) + len(VERSION_PREFIX))
                .removeprefix(BOM.encode())
                .startswith(VERSION_PREFIX.encode())
            ):
                return load_recording(path)
    elif not path.exists():
        raise FileNotFoundError(f"no recording or phyphox export at {path}")
    return load_phyphox(path, mount=mount, require=require)
