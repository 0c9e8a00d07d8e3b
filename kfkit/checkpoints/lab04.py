"""Checkpoints of lab 04 (attitude with an Euler-angle EKF): importing this module registers them all, in the lab's
order, from the two modules that hold them: :mod:`.ekf_attitude_core` (the core path, sections 2–7: Euler rates,
predict, measurement and Jacobian, numerical Jacobian, update, the whole filter on the bundled recording) and
:mod:`.ekf_attitude_optional` (beyond it: NIS per row, the questions' coasting yaw, the real recording).
:data:`kfkit.checkpoints.LABS` finds this module, and the grader imports it by the lab's number.
"""

from . import ekf_attitude_core, ekf_attitude_optional  # noqa: F401 (importing them registers the checkpoints)
