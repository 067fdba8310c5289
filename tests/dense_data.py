"""The synthetic closed loop the dense SLAM tests share (rendered once per test session)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

SYNTH_FRAMES = 90
SYNTH_SIZE = (320, 240)


def render_synth_loop(out: Path) -> None:
    """A 3 s closed loop (the camera ends one step before its start) with Kinect-like noise."""
    from slamcli.synth.rgbd import render_rgbd_sequence

    render_rgbd_sequence(out, frames=SYNTH_FRAMES, size=SYNTH_SIZE, seed=3, noise=True)


def cli_run(source: Path, out: Path, padding: int, *options: str) -> bytes:
    """``slamcli run dense`` in a fresh process: its trajectory.tum's bytes.

    A different environment size moves every later heap allocation, so ``padding`` gives the
    run its images at other addresses than another run's, as on a busy machine."""
    env = {**os.environ, "SLAMCLI_TEST_HEAP_PADDING": "x" * padding}
    argv = [sys.executable, "-m", "slamcli", "run", "dense", str(source), "--out", str(out)]
    proc = subprocess.run([*argv, *options], capture_output=True, text=True, env=env, check=False)
    assert proc.returncode == 0, proc.stderr
    trajectory = (out / "trajectory.tum").read_bytes()
    assert trajectory, "empty trajectory"
    return trajectory
