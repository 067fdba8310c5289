"""Batch rigid-body maths on ``(..., 4, 4)`` and ``(..., 3, 3)`` stacks, planar (x, y, yaw)
poses and the unicycle motion model, and the χ² quantiles of Gaussian gates."""

from slamcli.geometry.align import umeyama
from slamcli.geometry.chi2 import chi2_quantile
from slamcli.geometry.planar import (
    compose_planar,
    integrate_unicycle,
    interpolate_planar,
    planar_to_se3,
    se3_to_planar,
    sin_ratio,
    unicycle_step,
    wrap_angle,
)
from slamcli.geometry.se3 import (
    blend_poses,
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
    "blend_poses",
    "chi2_quantile",
    "compose",
    "compose_planar",
    "integrate_unicycle",
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
    "sin_ratio",
    "slerp",
    "so3_exp",
    "so3_log",
    "umeyama",
    "unicycle_step",
    "wrap_angle",
]
