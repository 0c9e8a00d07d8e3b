"""Lab 03's support (magnetometer alignment, calibration and heading): what its notebook calls beyond the library."""
from __future__ import annotations

import tempfile
from pathlib import Path

from .. import phone_sim, sim
from ..io import Recording
from ..readers import load_phyphox


def simulated_phone_tumbling(seed=31) -> Recording:
    """A simulated phone tumbled for a minute in London's field (``sim.mag_rotations`` at 200 Hz), exported as
    phyphox writes a simple experiment and read back with ``readers.load_phyphox``: what a student's phone gives."""
    samples = phone_sim.simulate_phone(sim.mag_rotations(rate_hz=200.0, seed=seed), seed=seed + 1)
    with tempfile.TemporaryDirectory() as folder:
        export = phone_sim.write_export(phone_sim.simple_experiment_files(samples), Path(folder) / "phone_tumbling")
        return load_phyphox(export, require=("acc", "gyr", "mag"))
