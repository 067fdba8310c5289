"""The real excerpts of the accuracy tests, each perturbed three ways (``variants.py``: one
step of seeded sensor noise, the first frame left out, every tenth frame left out), each run
as its main test runs it and held to the main test's threshold (imported from it)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import shared_path
from test_dense import TUM_ATE_M as DENSE_TUM_ATE_M
from test_ekf import MRCLAM_MAX_ATE_M, MRCLAM_MEAN_ATE_M, MRCLAM_MEAN_LANDMARK_M
from test_graph_slam import (
    JOINT_MAX_ATE_M,
    JOINT_MEAN_ATE_M,
    ROBOT1_ATE_M,
    ROBOT4_BATCH_ATE_M,
)
from test_lidar import LOG_ATE_M, LOG_RPE_1S_M, LOGS
from test_visual import TUM_RGBD_ATE_M
from test_visual_stereo import (
    EUROC_STATIC_M,
    KITTI_ATE_M,
    KITTI_DRIFT_PER_PATH,
    KITTI_SCALE_ERROR,
    KITTI_SIM3_ATE_M,
)

from slamcli.evaluation import align, associate
from slamcli.evaluation import ate as position_errors
from slamcli.run import RunOutcome, run_pipeline

from .conftest import Figures
from .variants import (
    VARIANTS,
    carmen_variant,
    euroc_variant,
    kitti_variant,
    mrclam_variant,
    tum_variant,
)

TUM = ("tum", "rgbd_dataset_freiburg1_rpy_excerpt")
KITTI = ("stereo", "kitti_excerpt_1")
EUROC = ("stereo", "euroc_V1_01_micro")
MRCLAM = ("landmarks", "MRCLAM_Dataset6")

DENSE_TUM_ROBUST_ATE_M = 0.02
"""The dense run's ATE on fr1/rpy, widened from the main test's 0.016 m for every variant: that
was set for the unperturbed run (0.0151 m), and the colour images' last bits move the visual
front end's keypoints and with them the error. One grey level of noise gave 0.0176, 0.0175,
0.0181 and 0.0167 m (noise seeds 0-3), every tenth frame left out 0.0170 m, the first 0.0155 m,
each with all 150 frames placed and nothing lost; 0.02 m holds that spread with 10 % to spare."""

LASER_ROBUST_ATE_M = {("csail", "drop-every-10th"): 0.18}
"""Laser-log ATE widened from the main test's 0.15 m where a variant makes the task harder. The
CSAIL log's scans are sparse (about 1 m and 20 degrees apart, up to 78 degrees): across two of
its dropped scans the laser turned 81 and 46 degrees (1.7 and 2.1 m), too little of the new scan
overlaps the submap to be matched, and those two poses follow the drifting odometry. The ATE
rises from 0.103 m (all scans) to 0.154 m (largest error 0.52 m); 0.18 m leaves 15 % over that."""


ROBOT4_BATCH_ROBUST_ATE_M = {"drop-every-10th": 0.17}
"""Robot 4's ATE with the batch solver, widened from the main test's 0.16 m where every tenth
record is left out: 0.1618 m. The batch solver gates observations against an estimate solved
again only every few updates, and rejects far more of them than iSAM2 (238 unperturbed, 126
here; iSAM2 46 and 59, and 0.122 m on the same data), so which ones it keeps moves with the
input. The run is not lost; 0.17 m leaves 5 % over it."""


def _ate(outcome: RunOutcome) -> float:
    return float(outcome.metrics["evaluation"]["ate"]["rmse"])


def _copy(shared_artefact: Any, name: str, make: Any, src: Path, variant: str) -> Path:
    """The variant of ``src`` made by ``make``, once per session (several tests read it)."""
    folder = shared_artefact(f"robust-{name}-{variant}", lambda f: make(src, f, variant))
    return Path(folder) / src.name


# -- TUM RGB-D fr1/rpy --------------------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS)
def test_tum_visual_rgbd(
    variant: str, shared_artefact: Any, tmp_path: Path, figures: Figures
) -> None:
    folder = _copy(shared_artefact, "tum", tum_variant, shared_path(*TUM), variant)
    outcome = run_pipeline(folder, "visual", tmp_path / "run")
    figures.expect("ATE (m)", _ate(outcome), "<=", TUM_RGBD_ATE_M)
    figures.verify()


@pytest.mark.parametrize("variant", VARIANTS)
def test_tum_dense(variant: str, shared_artefact: Any, tmp_path: Path, figures: Figures) -> None:
    folder = _copy(shared_artefact, "tum", tum_variant, shared_path(*TUM), variant)
    outcome = run_pipeline(folder, "dense", tmp_path / "run")
    widened = f"widened from {DENSE_TUM_ATE_M}"
    figures.expect("ATE (m)", _ate(outcome), "<=", DENSE_TUM_ROBUST_ATE_M, widened)
    figures.verify()


# -- stereo: KITTI and EuRoC --------------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS)
def test_kitti_stereo(variant: str, tmp_path: Path, figures: Figures) -> None:
    from slamcli.formats.kitti import KittiSource

    folder = kitti_variant(shared_path(*KITTI), tmp_path / "in", variant)
    outcome = run_pipeline(folder, "visual", tmp_path / "run")
    gt = KittiSource(folder).groundtruth()
    assert gt is not None and outcome.result.trajectory is not None
    # The ground truth at the pairs that were run: all of them but the dropped ones.
    matched = associate(gt, outcome.result.trajectory)
    ref, est = matched.gt, matched.est
    path = float(np.linalg.norm(np.diff(ref[:, :3, 3], axis=0), axis=1).sum())
    run_path = float(np.linalg.norm(np.diff(est[:, :3, 3], axis=0), axis=1).sum())
    # Endpoint drift: the end's offset from the start, in each one's own first frame.
    offset_est = est[0, :3, :3].T @ (est[-1, :3, 3] - est[0, :3, 3])
    offset_ref = ref[0, :3, :3].T @ (ref[-1, :3, 3] - ref[0, :3, 3])
    aligned, _, _, scale = align(ref, est, "sim3")
    sim3 = float(np.sqrt(np.mean(position_errors(ref, aligned) ** 2)))
    figures.expect("ATE (m)", _ate(outcome), "<", KITTI_ATE_M)
    drift = float(np.linalg.norm(offset_est - offset_ref)) / path
    figures.expect("endpoint drift / path", drift, "<", KITTI_DRIFT_PER_PATH)
    figures.expect("Sim(3) ATE (m)", sim3, "<", KITTI_SIM3_ATE_M)
    figures.expect("|Sim(3) scale - 1|", abs(scale - 1.0), "<", KITTI_SCALE_ERROR)
    figures.expect("|path length ratio - 1|", abs(run_path / path - 1.0), "<", KITTI_SCALE_ERROR)
    figures.verify()


@pytest.mark.parametrize("variant", VARIANTS)
def test_euroc_static_start(variant: str, tmp_path: Path, figures: Figures) -> None:
    folder = euroc_variant(shared_path(*EUROC), tmp_path / "in", variant)
    outcome = run_pipeline(
        folder,
        "visual",
        tmp_path / "run",
        source_options={"groundtruth": str(folder / "groundtruth_body.txt")},
    )
    assert outcome.result.trajectory is not None
    pos = outcome.result.trajectory.world_from_body[:, :3, 3]
    figures.expect("ATE (m)", _ate(outcome), "<", EUROC_STATIC_M)
    figures.expect("end - start (m)", float(np.linalg.norm(pos[-1] - pos[0])), "<", EUROC_STATIC_M)
    excursion = float(np.max(np.linalg.norm(pos - pos[0], axis=1)))
    figures.expect("largest excursion (m)", excursion, "<", EUROC_STATIC_M)
    figures.verify()


# -- laser logs: the Radish CARMEN logs with drifting odometry ----------------------------------


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("log", LOGS)
def test_laser_log(log: str, variant: str, tmp_path: Path, figures: Figures) -> None:
    figures.case = f"laser_log {log}"
    figures.variant = variant
    corrected = shared_path("lidar", "carmen", f"{log}-corrected.log.gz")
    drifted, reference = carmen_variant(corrected, tmp_path / "in", variant)
    outcome = run_pipeline(
        drifted, "lidar", tmp_path / "run", source_options={"groundtruth": str(reference)}
    )
    rpe = outcome.metrics["evaluation"]["rpe"]["1s"]["trans"]["mean"]
    widened = LASER_ROBUST_ATE_M.get((log, variant))
    if widened is None:
        figures.expect("ATE (m)", _ate(outcome), "<=", LOG_ATE_M)
    else:
        figures.expect("ATE (m)", _ate(outcome), "<=", widened, f"widened from {LOG_ATE_M}")
    figures.expect("RPE over 1 s, mean (m)", rpe, "<", LOG_RPE_1S_M)
    figures.verify()


# -- MRCLAM Dataset 6: landmark SLAM ------------------------------------------------------------


def _mrclam(shared_artefact: Any, variant: str) -> Path:
    return _copy(shared_artefact, "mrclam", mrclam_variant, shared_path(*MRCLAM), variant)


@pytest.mark.parametrize("variant", VARIANTS)
def test_mrclam_ekf_robots_1_to_5(
    variant: str, shared_artefact: Any, tmp_path: Path, figures: Figures
) -> None:
    folder = _mrclam(shared_artefact, variant)
    ate, landmarks = [], []
    for robot in range(1, 6):
        outcome = run_pipeline(
            folder, "ekf", tmp_path / f"r{robot}", source_options={"robot": robot}
        )
        ate.append(_ate(outcome))
        landmarks.append(float(outcome.metrics["evaluation"]["landmarks"]["rmse_m"]))
    figures.expect("largest ATE (m)", max(ate), "<=", MRCLAM_MAX_ATE_M)
    figures.expect("mean ATE (m)", float(np.mean(ate)), "<=", MRCLAM_MEAN_ATE_M)
    figures.expect(
        "mean landmark error (m)", float(np.mean(landmarks)), "<=", MRCLAM_MEAN_LANDMARK_M
    )
    figures.verify()


@pytest.mark.parametrize("variant", VARIANTS)
def test_mrclam_graph_robot_1(
    variant: str, shared_artefact: Any, tmp_path: Path, figures: Figures
) -> None:
    folder = _mrclam(shared_artefact, variant)
    outcome = run_pipeline(folder, "graph", tmp_path / "run", source_options={"robot": 1})
    figures.expect("ATE (m)", _ate(outcome), "<", ROBOT1_ATE_M)
    figures.verify()


@pytest.mark.parametrize("variant", VARIANTS)
def test_mrclam_graph_robot_4_batch(
    variant: str, shared_artefact: Any, tmp_path: Path, figures: Figures
) -> None:
    from slamcli.pipelines.graph import GraphConfig

    folder = _mrclam(shared_artefact, variant)
    outcome = run_pipeline(
        folder,
        "graph",
        tmp_path / "run",
        config=GraphConfig(solver="batch"),
        source_options={"robot": 4},
    )
    widened = ROBOT4_BATCH_ROBUST_ATE_M.get(variant)
    if widened is None:
        figures.expect("ATE (m)", _ate(outcome), "<", ROBOT4_BATCH_ATE_M)
    else:
        note = f"widened from {ROBOT4_BATCH_ATE_M}"
        figures.expect("ATE (m)", _ate(outcome), "<", widened, note)
    figures.verify()


@pytest.mark.parametrize("variant", VARIANTS)
def test_mrclam_graph_joint(
    variant: str, shared_artefact: Any, tmp_path: Path, figures: Figures
) -> None:
    folder = _mrclam(shared_artefact, variant)
    outcome = run_pipeline(folder, "graph", tmp_path / "run", source_options={"robot": "all"})
    per_robot = outcome.metrics["robots"]["per_robot"]
    common = [float(per_robot[str(r)]["ate_common"]["rmse"]) for r in range(1, 6)]
    figures.expect("largest common-frame ATE (m)", max(common), "<=", JOINT_MAX_ATE_M)
    figures.expect("mean common-frame ATE (m)", float(np.mean(common)), "<=", JOINT_MEAN_ATE_M)
    figures.verify()
