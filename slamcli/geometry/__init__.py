"""Batch rigid-body maths on ``(..., 4, 4)`` and ``(..., 3, 3)`` stacks."""

from slamcli.geometry.align import umeyama
from slamcli.geometry.planar import (
    compose_planar,
    interpolate_planar,
    planar_to_se3,
    se3_to_planar,
    wrap_angle,
)
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
    "compose_planar",
    "interpolate_planar",
    "interpolate_poses",
    "inverse",
    "make_pose",
    "matrix_to_quat_wxyz",
    "matrix_to_quat_xyzw",
    "planar_to_se3",
    "quat_wxyz_to_matrix",
    "quat_xyzw_to_matrix",
    "rotation_angle",
    "se3_exp",
    "se3_log",
    "se3_to_planar",
    "slerp",
    "so3_exp",
    "so3_log",
    "umeyama",
    "wrap_angle",
]
