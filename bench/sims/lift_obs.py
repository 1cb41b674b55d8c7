"""The robot-agnostic Lift observation both Lift simulators produce: robosuite's (`suites/lift.py`, every
held_out_robots arm) and MJX's (`bench.sims.mjx_lift`). 18 numbers, named and sized here once."""

from __future__ import annotations

LIFT_OBS_FIELDS: tuple[tuple[str, int], ...] = (
    ("eef_pos", 3),  # end-effector position, world frame
    ("eef_quat_rel", 4),  # end-effector orientation relative to the arm's home orientation
    ("gripper_opening", 1),
    ("object_pos", 3),
    ("object_quat", 4),
    ("gripper_to_object", 3),
)
