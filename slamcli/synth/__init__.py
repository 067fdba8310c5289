"""Synthetic data with exact ground truth: a rendered RGB-D room and a 2-D landmark world.

Open3D and OpenCV load only when a sequence is rendered, so importing this package is cheap.
"""

from slamcli.synth.landmarks import (
    LandmarkSensor,
    LandmarkWorld,
    generate_landmark_world,
    simulate_landmark_world,
)
from slamcli.synth.rgbd import RgbdWorld, build_rgbd_world, render_rgbd_sequence

__all__ = [
    "LandmarkSensor",
    "LandmarkWorld",
    "RgbdWorld",
    "build_rgbd_world",
    "generate_landmark_world",
    "render_rgbd_sequence",
    "simulate_landmark_world",
]
