"""Every filter of the kit's labs, registered once, by name.

The contract test (tests/test_filter_contract.py) holds each to :class:`~kfkit.filters.contract.TunedFilter`;
:func:`~kfkit.filters.estimate_attitude`, :class:`~kfkit.widgets.attitude_view.LiveAttitude` and the benchmarks
take their methods from :func:`methods`. A new filter is one line here.
"""

from __future__ import annotations

from typing import NamedTuple

from .euler_ekf import EulerAttitudeEKF
from .euler_ekf_fast import FastEulerAttitudeEKF
from .mekf import MultiplicativeEKF
from .roll import RollKF
from .sideslip import SideslipKF
from .sideslip_ekf import SideslipEKF
from .tilt import TiltBiasKF


class Registered(NamedTuple):
    """A filter class and the front door it is a method of ("attitude": :func:`estimate_attitude`), if any."""

    cls: type
    estimates: str | None = None


FILTERS = {
    "roll-kf": Registered(RollKF),  # lab 01
    "euler-ekf": Registered(FastEulerAttitudeEKF, "attitude"),  # lab 04, what estimate_attitude runs by default
    "euler-ekf-steps": Registered(EulerAttitudeEKF),  # lab 04, the same filter as a loop over the lab's steps
    "mekf": Registered(MultiplicativeEKF, "attitude"),  # lab 04, quaternion error-state EKF with gyro bias
    "tilt-bias-kf": Registered(TiltBiasKF),  # lab 05
    "sideslip-kf": Registered(SideslipKF),  # lab 06, linear bicycle model
    "sideslip-ekf": Registered(SideslipEKF),  # lab 06, saturating tyres (estimate_sideslip's default)
}


def methods(estimates: str) -> dict:
    """{name: filter class} of the registered filters that are methods of the front door for ``estimates``."""
    return {name: entry.cls for name, entry in FILTERS.items() if entry.estimates == estimates}
