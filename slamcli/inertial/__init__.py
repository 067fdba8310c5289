"""The inertial part of visual-inertial SLAM: IMU preintegration between keyframes on GTSAM's
factors (``preintegration.py``) and the inertial-only initialisation of a visual map's scale,
gravity, velocities and biases (``initialisation.py``), kept apart from the visual pipeline
as ORB-SLAM3 keeps its ``ImuTypes`` and inertial optimisers."""

from slamcli.inertial.initialisation import (
    InertialInit,
    gravity_angle_deg,
    initialise_inertial,
    levelling_rotation,
)
from slamcli.inertial.preintegration import ImuNoise, preintegrate

__all__ = [
    "ImuNoise",
    "InertialInit",
    "gravity_angle_deg",
    "initialise_inertial",
    "levelling_rotation",
    "preintegrate",
]
