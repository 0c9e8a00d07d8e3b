"""Lab 04's ablation: why the Euler EKF breaks on BROAD's fast rotations, one of the MEKF's features at a time.

    python benchmarks/bench_lab04_ablation.py

The lab's Euler EKF (midpoint rate, its tuning and 1 m/s² gate) on both bundled BROAD excerpts, whole (to the end of
their movement), then with 5 substeps per sample (the same gyro samples, interpolated: discretisation only), then with
the substeps and each of the MEKF's other features added alone (a gyro-bias state; the magnetometer as a gated heading;
the accelerometer low-passed in a gyro-turned frame), then with all three; kfkit's MEKF last, for the gap.
:func:`kfkit.labs.lab04.ablation` defines each variant; lab 04, section 14, prints this table.
"""

import numpy as np

from kfkit import filters
from kfkit.labs import lab04


def main():
    table = lab04.ablation()
    mekf = {}
    for name in lab04.REAL_TRIALS:
        rec, gyr, acc, mag, field_n, q_true, moving = lab04.to_movement_end(name)
        q = filters.estimate_attitude(gyr, acc, mag, rec.rate_hz, method="mekf").quat
        mekf[name] = {k: float(np.degrees(v)) for k, v in lab04.metrics.attitude_rmse(q, q_true, moving).items()}
    table["kfkit's MEKF"] = mekf
    print(f"{'total (heading / inclination) RMSE, °':50s}" + "".join(f"{n[3:]:>28s}" for n in lab04.REAL_TRIALS))
    for label, row in table.items():
        print(
            f"{label:50s}"
            + "".join(
                f"{row[n]['total']:10.2f} ({row[n]['heading']:5.2f} / {row[n]['inclination']:5.2f})"
                for n in lab04.REAL_TRIALS
            )
        )


if __name__ == "__main__":
    main()
