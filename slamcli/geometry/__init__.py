"""Batch rigid-body maths on ``(..., 4, 4)`` and ``(..., 3, 3)`` stacks."""

from slamcli.geometry.align import umeyama
from slamcli.geometry.se3 import (
    compose,
    interpolate_poses,
    inverse,
    make_pose,
    matrix_to_quat_wxyz,
    matrix_to_quat_xyzw,
    quat_wxyz_to_matrix,
    quat_xyzw_to_matrix,
    rotation_angle,
    se3_exp,
    se3_log,
    slerp,
    so3_exp,
    so3_log,
)

__all__ = [
    "compose",
    "interpolate_poses",
    "inverse",
    "make_pose",
    "matrix_to_quat_wxyz",
    "matrix_to_quat_xyzw",
    "quat_wxyz_to_matrix",
    "quat_xyzw_to_matrix",
    "rotation_angle",
    "se3_exp",
    "se3_log",
    "slerp",
    "so3_exp",
    "so3_log",
    "umeyama",
]
