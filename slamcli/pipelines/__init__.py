"""SLAM pipelines. Each consumes frames through ``process(frame)`` and returns a
:class:`~slamcli.types.SlamResult` from ``finish()``; none prints or touches files.

A pipeline is one module and one :data:`PIPELINES` entry. The entry is a light declaration
(help, example, products, evaluation) so that the CLI can list and document every pipeline
without importing the modules, which pull in numpy, OpenCV and Open3D.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from slamcli.formats.base import SourceInfo
    from slamcli.types import SlamResult

Evaluation = Literal["se2", "se3", "sim3"]


class Pipeline(Protocol):
    """What :func:`slamcli.run.run_pipeline` asks of a pipeline: every capability it may use.

    A pipeline takes its frames through :meth:`process` and gives its result from
    :meth:`finish`; it never prints or touches files. :class:`PipelineBase` gives the
    optional parts their defaults.

    Attributes:
        name: the pipeline's name (its :data:`PIPELINES` key).
        config: the frozen settings dataclass it runs with.
        read_ahead: how many frames a reader thread may decode ahead of it (0: none).
    """

    name: str
    config: Any
    read_ahead: int

    @property
    def evaluation(self) -> Evaluation:
        """How its trajectory is scored (see :class:`PipelineSpec`); may be settled by
        :meth:`frame_kinds` (the visual pipeline is ``sim3`` on colour-only input)."""
        ...

    def frame_kinds(self, info: SourceInfo) -> tuple[str, ...]:
        """The frame kinds to read from a source described by ``info``."""
        ...

    def set_start(self, pose: NDArray[np.float64] | None) -> None:
        """The log's ground-truth start pose (x, y, yaw), or None; planar pipelines start
        there."""
        ...

    def process(self, frame: Any) -> None:
        """Take the next frame."""
        ...

    def finish(self) -> SlamResult:
        """The result, once every frame is in; several robots' trajectories are in its
        ``robots``."""
        ...

    def seeds(self) -> dict[str, int]:
        """The seeds of its random choices, by generator, for run.json."""
        ...

    def close(self) -> None:
        """Release threads and processes after an error (:meth:`finish` releases them
        itself)."""
        ...


class PipelineBase:
    """Defaults of the optional parts of :class:`Pipeline`: the frames it ``consumes``,
    the evaluation its :data:`PIPELINES` entry declares, no read-ahead, no start pose, no
    seeds, nothing to close."""

    name: str = ""
    consumes: tuple[str, ...] = ()
    read_ahead: int = 0

    @property
    def evaluation(self) -> Evaluation:
        return PIPELINES[self.name].evaluation

    def frame_kinds(self, info: SourceInfo) -> tuple[str, ...]:
        return self.consumes

    def set_start(self, pose: NDArray[np.float64] | None) -> None:
        return None

    def seeds(self) -> dict[str, int]:
        return {}

    def close(self) -> None:
        return None


@dataclass(frozen=True)
class InputFormat:
    """An input format as the run commands' help names it.

    Attributes:
        noun: what the user has, with its article ("a TUM RGB-D folder").
        kinds: the frame kinds its source class gives (``slamcli.formats.SOURCES``).
        topics: a log of topics, which gives a kind only when it has a topic of it.
    """

    noun: str
    kinds: tuple[str, ...]
    topics: bool = False


_LOG_KINDS = ("rgbd", "image", "odometry", "landmarks", "imu", "scan", "stereo")

INPUT_FORMATS: dict[str, InputFormat] = {
    "tum": InputFormat("a TUM RGB-D folder", ("rgbd", "image", "imu")),
    "redwood": InputFormat("an Open3D / Redwood RGB-D folder", ("rgbd", "image")),
    "kitti": InputFormat("a KITTI odometry folder", ("stereo", "image")),
    "euroc": InputFormat("a EuRoC / ASL folder", ("stereo", "image", "imu")),
    "mrclam": InputFormat("an MRCLAM folder", ("odometry", "landmarks")),
    "victoria": InputFormat("a Victoria Park file", ("odometry", "landmarks")),
    "landmarks": InputFormat("a 'slamcli synth landmarks' folder", ("odometry", "landmarks")),
    "carmen": InputFormat("a CARMEN laser log", ("scan", "odometry")),
    "mcap": InputFormat("an MCAP log", _LOG_KINDS, topics=True),
    "rosbag1": InputFormat("a ROS 1 bag", _LOG_KINDS, topics=True),
    "rosbag2": InputFormat("a ROS 2 bag folder", _LOG_KINDS, topics=True),
}
"""Every format of ``slamcli.formats.SOURCES`` (same keys; the kinds are the ones its source
class gives, which the tests hold this table to), in the order the help names them. Kept here
because the command line builds its help at start-up, where importing the sources is too
slow."""

_KIND_NOUNS = {
    "rgbd": "colour and depth images",
    "image": "colour images",
    "stereo": "a left and a right image topic",
    "scan": "laser scans",
    "odometry": "odometry",
    "landmarks": "landmark observations",
}


@dataclass(frozen=True)
class PipelineSpec:
    """What is known about a pipeline before its module is imported.

    Attributes:
        target: the class, as ``module:Class``.
        help: the ``slamcli run NAME --help`` text (rich markup); its first line is the summary.
        example: one ``slamcli run NAME ...`` command line that works from the repository root.
        produces: the run folder files the pipeline's results are written to.
        evaluation: how the trajectory is scored against ground truth: ``se2`` (planar: ATE
            after SE(2) alignment, landmark RMSE, NEES; the pipeline has ``set_start(pose)``
            taking the source's start pose (x, y, yaw) or None), ``se3`` or ``sim3`` (ATE and
            RPE after that alignment, as ``slamcli eval --align``).
        reads: the frame kinds it can run on, one set per way of running: an input that
            gives every kind of one set will do.
    """

    target: str
    help: str
    example: str
    produces: tuple[str, ...]
    evaluation: Evaluation
    reads: tuple[tuple[str, ...], ...]

    @property
    def doc(self) -> str:
        """The help text with the example, as a command docstring."""
        return f"{self.help}\n\nExample: [bold]{self.example}[/]"

    @property
    def formats(self) -> tuple[str, ...]:
        """The :data:`INPUT_FORMATS` it reads: those giving every kind of one of its sets."""
        return tuple(
            name
            for name, fmt in INPUT_FORMATS.items()
            if any(set(kinds) <= set(fmt.kinds) for kinds in self.reads)
        )

    @property
    def input_help(self) -> str:
        """The help of ``slamcli run NAME INPUT``: the formats it reads, and what a log of
        topics must hold for it."""
        files = [INPUT_FORMATS[f].noun for f in self.formats if not INPUT_FORMATS[f].topics]
        logs = [INPUT_FORMATS[f].noun for f in self.formats if INPUT_FORMATS[f].topics]
        parts = [_series(files)] if files else []
        if logs:
            needs = [" and ".join(_KIND_NOUNS[k] for k in kinds) for kinds in self.reads]
            parts.append(f"{_series(logs)} with {_series(needs)}")
        text = "; or ".join(parts)
        return text[0].upper() + text[1:] + "."


def _series(items: list[str]) -> str:
    """``a``, ``a or b``, ``a, b or c``: one of the items."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " or " + items[-1]


PIPELINES: dict[str, PipelineSpec] = {
    "odometry": PipelineSpec(
        target="slamcli.pipelines.odometry:RgbdOdometry",
        help="""Frame-to-frame RGB-D odometry: the simplest tracker, the baseline for others.

Registers each frame to the previous one (Open3D's multi-scale photometric + geometric kernel, \
seeded by a constant-velocity prior). Writes trajectory.tum, report.png and run.json (with \
ATE/RPE after SE(3) alignment when the input has ground truth). Settings: 'slamcli config dump \
odometry'. Exits with 3 when frames had to be skipped.""",
        example="slamcli run odometry sample_data/rgbd_room --out runs/room_odometry "
        "--max-frames 10 --force",
        produces=("trajectory.tum", "report.png"),
        evaluation="se3",
        reads=(("rgbd",),),
    ),
    "dense": PipelineSpec(
        target="slamcli.pipelines.dense:DenseSlam",
        help="""Dense RGB-D SLAM: a coloured mesh and a trajectory from an RGB-D log.

Tracks each frame against a ray-cast of the fused TSDF volume (seeded by ORB features and PnP), \
fuses trusted frames, closes loops between keyframes and re-integrates with the optimised \
poses. Writes trajectory.tum, keyframes.tum, mesh.ply, points.ply, report.png and run.json \
(ATE/RPE after SE(3) alignment when the input has ground truth). Settings: 'slamcli config \
dump dense'. Exits with 3 when frames had to be skipped.""",
        example="slamcli run dense sample_data/rgbd_room --out runs/room_dense --max-frames 8 "
        "--set voxel_size_m=0.02 --force",
        produces=("trajectory.tum", "keyframes.tum", "mesh.ply", "points.ply", "report.png"),
        evaluation="se3",
        reads=(("rgbd",),),
    ),
    "visual": PipelineSpec(
        target="slamcli.pipelines.visual:VisualSlam",
        help="""Feature-based visual SLAM (ORB-SLAM-like): a trajectory and a coloured point \
map, from RGB-D, stereo or colour-only logs.

ORB features spread over the image, tracking by a motion model and the local map, keyframes \
with local bundle adjustment (pycolmap), loop closure by a bag-of-words vocabulary with \
essential-graph optimisation (GTSAM) and global bundle adjustment; relocalisation and new maps \
when tracking is lost. Stereo for a stereo pair (KITTI or EuRoC folders, logs with left and \
right image topics), RGB-D when the input has depth, monocular otherwise (or --set mode=mono: \
a map without metric scale, scored after Sim(3) alignment). Writes trajectory.tum, \
keyframes.tum, points.ply, graph.g2o, report.png and run.json (frames by tracking state, maps, \
loop closures with their scores; ATE/RPE when the input has ground truth). Settings: 'slamcli \
config dump visual'. Exits with 3 when frames had to be skipped, or when a --fail-if gate holds.""",
        example="slamcli run visual sample_data/rgbd_room --out runs/room_visual --force "
        "--fail-if 'ate.rmse > 0.01' --fail-if 'frames.lost > 0'",
        produces=("trajectory.tum", "keyframes.tum", "points.ply", "graph.g2o", "report.png"),
        evaluation="se3",
        reads=(("rgbd",), ("stereo",), ("image",)),
    ),
    "ekf": PipelineSpec(
        target="slamcli.pipelines.ekf:EkfSlam",
        help="""EKF landmark SLAM: a planar trajectory and a landmark map from odometry and \
range-bearing observations.

Reads an MRCLAM folder (--robot N), a Victoria Park file (GTSAM format), a 'slamcli synth \
landmarks' folder or an MCAP log with odometry and landmark observations. Known \
correspondences when the log has landmark ids, nearest neighbour with chi-square gating (or \
JCBB) otherwise (--ignore-ids). Writes trajectory.tum (the path smoothed against the final \
map), trajectory_filtered.tum (the filter's own path), landmarks.csv (with covariances), \
report.png and run.json (ATE after SE(2) alignment, landmark RMSE, NEES/NIS when the log has \
ground truth). --map adds an occupancy map. Settings: 'slamcli config dump ekf'.""",
        example="slamcli run ekf sample_data/landmarks --out runs/landmarks --map --force",
        produces=(
            "trajectory.tum",
            "trajectory_filtered.tum",
            "landmarks.csv",
            "report.png",
        ),
        evaluation="se2",
        reads=(("odometry", "landmarks"),),
    ),
    "graph": PipelineSpec(
        target="slamcli.pipelines.graph:GraphSlam",
        help="""Graph landmark SLAM (GTSAM factor graph, iSAM2): a planar trajectory and a \
landmark map from odometry and range-bearing observations, for one robot or several.

Keyposes with odometry factors grown from the EKF's motion model, range-bearing factors to the \
landmarks (known ids with the EKF's gating, or nearest neighbour / JCBB without ids), solved \
incrementally by iSAM2 (--set solver=batch: Levenberg-Marquardt). Same inputs and outputs as \
'run ekf' (trajectory.tum, landmarks.csv, report.png, run.json with the SE(2) ATE). On an \
MRCLAM folder, --robot 1,2,3 or --robot all builds one graph of several robots: the first \
anchors the frame, the others are placed by the landmarks they share and by robot-to-robot \
sightings; writes trajectory_robotN.tum per robot and the ATE per robot and under one common \
alignment. Settings: 'slamcli config dump graph'.""",
        example="slamcli run graph sample_data/landmarks --out runs/landmarks_graph --force",
        produces=("trajectory.tum", "landmarks.csv", "report.png"),
        evaluation="se2",
        reads=(("odometry", "landmarks"),),
    ),
    "lidar": PipelineSpec(
        target="slamcli.pipelines.lidar:LidarSlam",
        help="""2-D lidar SLAM: an occupancy map and a trajectory from laser scans, with or \
without odometry.

Reads CARMEN laser logs, MCAP logs and ROS 1/ROS 2 bags with sensor_msgs/LaserScan (and \
nav_msgs/Odometry when there is one: --scan-topic, --odom-topic). Each scan is matched to a \
local submap (branch-and-bound correlative search, then continuous refinement) from an \
odometry, constant-velocity or no-motion guess; loops are closed against finished submaps in \
a window that grows with the distance travelled, verified, and solved on a GTSAM pose graph \
with a robust kernel. Writes trajectory.tum (a pose for every scan), keyframes.tum, map.yaml + \
map.pgm (map_server, trinary), map.png, points.ply, graph.g2o, report.png and run.json (ATE \
after SE(2) alignment and the relative pose errors over 1 s and 10 s when the input has \
ground truth: --groundtruth FILE, or 'log' for a corrected laser log's own poses). Settings: \
'slamcli config dump lidar'. Exits with 3 when scans had to be skipped.""",
        example="slamcli run lidar ../shared/data/lidar/rosbag1/ccny_scan_matcher_demo.bag "
        "--out runs/ccny --force",
        produces=(
            "trajectory.tum",
            "keyframes.tum",
            "map.yaml",
            "map.pgm",
            "points.ply",
            "graph.g2o",
            "report.png",
        ),
        evaluation="se2",
        reads=(("scan",),),
    ),
}
"""Pipelines by name. Adding one is one entry here and one module."""


def get_spec(name: str) -> PipelineSpec:
    """The declaration of the pipeline ``name``; ConfigError names the known ones."""
    from slamcli.errors import ConfigError

    if name not in PIPELINES:
        raise ConfigError(
            f"unknown pipeline {name!r}", hint=f"choose one of {', '.join(PIPELINES)}"
        )
    return PIPELINES[name]


def get_pipeline(name: str) -> Any:
    """The pipeline class registered under ``name`` (its module is imported now); its
    instances satisfy :class:`Pipeline`."""
    import importlib

    module, _, cls = get_spec(name).target.partition(":")
    return getattr(importlib.import_module(module), cls)
