"""Visual-inertial SLAM on `synth stereo` seeds 0-4 (200 pairs, 10 s, 640x480, image noise and
IMU noise at EuRoC's densities), stereo-inertial and monocular-inertial, each also with the
images of 4.0-5.0 s blanked, against the thresholds of ``tests/test_visual_inertial.py``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from test_visual_inertial import (
    BLANK_RATIO,
    GRAVITY_DEG,
    MONO_ATE_PER_PATH,
    MONO_SCALE_ERROR,
    STEREO_ATE_PER_PATH,
    blank_images,
    synth_scores,
)

from slamcli.pipelines.visual import VisualConfig
from slamcli.run import run_pipeline

from .conftest import Figures

SEEDS = range(5)


@pytest.mark.parametrize(
    "seed",
    [pytest.param(s, id=str(s), marks=pytest.mark.xdist_group(f"vi-{s}")) for s in SEEDS],
)
@pytest.mark.parametrize("mode", ["stereo", "mono"])
def test_visual_inertial_seed(
    seed: int, mode: str, shared_artefact: Any, tmp_path: Path, figures: Figures
) -> None:
    from slamcli.synth.stereo import render_stereo_sequence

    def render(folder: Path) -> None:
        render_stereo_sequence(folder / "rig", frames=200, size=(640, 480), noise=True, seed=seed)

    rig = shared_artefact(f"robust-vi-rig-{seed}", render) / "rig"
    blank = tmp_path / "blank"
    assert blank_images(rig, blank, 4.0, 5.0) == 20
    scores = {}
    for name, folder in (("", rig), ("-blank", blank)):
        run_pipeline(folder, "visual", tmp_path / f"run{name}", config=VisualConfig(mode=mode))
        scores[name] = got = synth_scores(folder, tmp_path / f"run{name}")
        figures.variant = f"{seed}-{mode}{name}"
        per_path = STEREO_ATE_PER_PATH if mode == "stereo" else MONO_ATE_PER_PATH
        figures.expect(
            "SE(3) ATE (m)", got["ate"], "<=", per_path * got["path"], f"{per_path} x path"
        )
        figures.expect("gravity (deg)", got["tilt_deg"], "<=", GRAVITY_DEG)
        if mode == "mono":
            figures.expect("|Sim(3) scale - 1|", abs(got["scale"] - 1.0), "<=", MONO_SCALE_ERROR)
        figures.expect("frames posed", got["frames"], ">=", 0.95 * 200)
    figures.variant = f"{seed}-{mode}-blank"
    figures.expect(
        "ATE blank / ATE",
        scores["-blank"]["ate"] / scores[""]["ate"],
        "<=",
        BLANK_RATIO,
    )
    figures.verify()
