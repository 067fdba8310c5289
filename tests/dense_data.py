"""The synthetic closed loop the dense SLAM tests share (rendered once per test session)."""

from __future__ import annotations

from pathlib import Path

SYNTH_FRAMES = 90
SYNTH_SIZE = (320, 240)


def render_synth_loop(out: Path) -> None:
    """A 3 s closed loop (the camera ends one step before its start) with Kinect-like noise."""
    from slamcli.synth.rgbd import render_rgbd_sequence

    render_rgbd_sequence(out, frames=SYNTH_FRAMES, size=SYNTH_SIZE, seed=3, noise=True)
