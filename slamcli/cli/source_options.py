"""Options shared by every command that reads a source (``info``, ``run dense``, ``run ekf``, ...).

A command declares them once, with :func:`source_options`, and receives one
:class:`SourceOptions`::

    @source_options()
    def cmd(input: Path, source: SourceOptions) -> None:
        with open_source(input, **source.open_kwargs()) as src: ...
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Collection
from dataclasses import asdict, fields
from typing import Annotated, Any, TypeVar

import typer

from slamcli.source_options import DEFAULTS, SourceOptions

PANEL = "Input options"

MaxDt = Annotated[
    float,
    typer.Option(
        "--max-dt",
        help="Pair colour and depth images less than this many seconds apart (TUM associate.py).",
        rich_help_panel=PANEL,
    ),
]
DtOffset = Annotated[
    float,
    typer.Option(
        "--dt-offset",
        help="Seconds added to depth stamps before pairing (associate.py's --offset).",
        rich_help_panel=PANEL,
    ),
]
DepthFactor = Annotated[
    float | None,
    typer.Option(
        "--depth-factor",
        help="Raw depth units per metre (TUM 5000, millimetres 1000). "
        "Default: the camera file's, else 5000.",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]
CameraOpt = Annotated[
    str | None,
    typer.Option(
        "--camera",
        help="Camera preset (fr1, fr2, fr3, ros-default) or a camera file (.yaml/.json). "
        "Default: camera.yaml/.json next to the data, else the preset in the folder name, "
        "else ros-default.",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]


def _intrinsic(flag: str, what: str) -> Any:
    return typer.Option(
        flag,
        help=f"{what} in pixels; give all of --fx --fy --cx --cy to override the camera.",
        show_default=False,
        rich_help_panel=PANEL,
    )


Fx = Annotated[float | None, _intrinsic("--fx", "Focal length x")]
Fy = Annotated[float | None, _intrinsic("--fy", "Focal length y")]
Cx = Annotated[float | None, _intrinsic("--cx", "Principal point x")]
Cy = Annotated[float | None, _intrinsic("--cy", "Principal point y")]
Undistort = Annotated[
    bool,
    typer.Option(
        "--undistort",
        help="Remove lens distortion from colour (and registered depth) using the camera's "
        "distortion coefficients.",
        rich_help_panel=PANEL,
    ),
]
Strict = Annotated[
    bool,
    typer.Option(
        "--strict",
        help="Stop at the first missing or unreadable image (MRCLAM: unknown barcode) "
        "instead of skipping it.",
        rich_help_panel=PANEL,
    ),
]
MaxChunkMb = Annotated[
    int | None,
    typer.Option(
        "--max-chunk-mb",
        min=1,
        help="MCAP logs: largest chunk or message to read, in MB (2^20 bytes; default 256). "
        "A larger one is skipped as damage; raise this for a genuine log with huge chunks.",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]

Robot = Annotated[
    str | None,
    typer.Option(
        "--robot",
        help="MRCLAM folders: which robot's log (default 1), or several for 'run graph': "
        "1,2,3 or all.",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]
IgnoreIds = Annotated[
    bool,
    typer.Option(
        "--ignore-ids",
        help="Treat landmark ids as unknown: the filter associates observations itself.",
        rich_help_panel=PANEL,
    ),
]


Odometry = Annotated[
    str | None,
    typer.Option(
        "--odometry",
        help="'none' ignores the log's odometry: the scans alone place the robot (e.g. a "
        "corrected laser log, whose poses are a reference, not odometry).",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]
Groundtruth = Annotated[
    str | None,
    typer.Option(
        "--groundtruth",
        help="Score against this trajectory file (TUM, EuRoC or KITTI), or 'log': the poses a "
        "laser log carries (CARMEN logs corrected by a SLAM system).",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]
Calib = Annotated[
    list[str] | None,
    typer.Option(
        "--calib",
        help="Kalibr calibration files (EuRoC folders, MCAP logs, bags), given once each: "
        "camchain-imucam.yaml (the cameras, and the IMU on them: the body is then the IMU) and "
        "imu.yaml (the IMU's noise and rate). They replace the input's own calibration; a log "
        "without camera_info or tf, or a ROS 1 bag (whose IMU topic carries no noise model), "
        "needs them for a visual-inertial run.",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]
MaxRange = Annotated[
    float | None,
    typer.Option(
        "--max-range",
        help="CARMEN logs: ranges at or beyond this (m) are no return (default 50; FLASER "
        "lines do not say).",
        show_default=False,
        rich_help_panel=PANEL,
    ),
]


TOPICS = "MCAP topics"


def _topic(flag: str, what: str) -> Any:
    return typer.Option(
        flag,
        help=f"{what} (MCAP logs). Default: the one topic of the right type; with none or "
        "several, the command lists the candidates.",
        show_default=False,
        rich_help_panel=TOPICS,
    )


RgbTopic = Annotated[str | None, _topic("--rgb-topic", "Colour image topic")]
DepthTopic = Annotated[str | None, _topic("--depth-topic", "Depth image topic")]
CameraInfoTopic = Annotated[
    str | None, _topic("--camera-info-topic", "CameraInfo or CameraCalibration topic")
]
OdomTopic = Annotated[str | None, _topic("--odom-topic", "Odometry or Twist topic")]
GtTopic = Annotated[
    str | None, _topic("--gt-topic", "Ground-truth pose topic (PoseStamped, Odometry, ...)")
]
LandmarkTopic = Annotated[
    str | None, _topic("--landmark-topic", "Landmark observation topic (range-bearing)")
]
ScanTopic = Annotated[str | None, _topic("--scan-topic", "Laser scan topic (LaserScan)")]
LeftTopic = Annotated[
    str | None,
    typer.Option(
        "--left-topic",
        help="Left camera's image topic of a stereo pair (MCAP logs, bags). Default: the one "
        "pair of image topics named like left/right, cam0/cam1 or infra1/infra2; with one of "
        "the two options, the topic named like it; with none or several, the command lists "
        "the candidates.",
        show_default=False,
        rich_help_panel=TOPICS,
    ),
]
RightTopic = Annotated[
    str | None,
    typer.Option(
        "--right-topic",
        help="Right camera's image topic of a stereo pair (MCAP logs, bags); see --left-topic.",
        show_default=False,
        rich_help_panel=TOPICS,
    ),
]
GtFrame = Annotated[
    str | None,
    typer.Option(
        "--gt-frame",
        help="Take ground truth from tf: the pose of this frame in the root of its tf tree "
        "(MCAP logs).",
        show_default=False,
        rich_help_panel=TOPICS,
    ),
]


_OPTIONS: dict[str, Any] = {
    "max_dt": MaxDt,
    "dt_offset": DtOffset,
    "depth_factor": DepthFactor,
    "camera": CameraOpt,
    "fx": Fx,
    "fy": Fy,
    "cx": Cx,
    "cy": Cy,
    "undistort": Undistort,
    "strict": Strict,
    "max_chunk_mb": MaxChunkMb,
    "robot": Robot,
    "ignore_ids": IgnoreIds,
    "rgb_topic": RgbTopic,
    "depth_topic": DepthTopic,
    "camera_info_topic": CameraInfoTopic,
    "odom_topic": OdomTopic,
    "gt_topic": GtTopic,
    "gt_frame": GtFrame,
    "landmark_topic": LandmarkTopic,
    "scan_topic": ScanTopic,
    "left_topic": LeftTopic,
    "right_topic": RightTopic,
    "odometry": Odometry,
    "groundtruth": Groundtruth,
    "max_range": MaxRange,
    "calib": Calib,
}
"""The typer option of each :class:`SourceOptions` field."""

F = TypeVar("F", bound=Callable[..., Any])


def source_options(without: Collection[str] = ()) -> Callable[[F], F]:
    """Give a command the source options (all but the fields named in ``without``).

    The options are appended to the command's signature, which typer reads, and the command
    is called with them collected into its ``source: SourceOptions`` parameter.
    """
    names = [f.name for f in fields(SourceOptions) if f.name not in without]
    defaults = asdict(DEFAULTS)
    unknown = set(without) - {f.name for f in fields(SourceOptions)}
    if unknown:
        raise ValueError(f"not source options: {', '.join(sorted(unknown))}")

    def decorate(fn: F) -> F:
        signature = inspect.signature(fn, eval_str=True)
        own = [p for p in signature.parameters.values() if p.name != "source"]
        added = [
            inspect.Parameter(
                name,
                inspect.Parameter.KEYWORD_ONLY,
                annotation=_OPTIONS[name],
                default=defaults[name],
            )
            for name in names
        ]

        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            picked = {name: kwargs.pop(name) for name in names if name in kwargs}
            return fn(*args, source=SourceOptions(**picked), **kwargs)

        wrapper.__signature__ = signature.replace(parameters=[*own, *added])  # type: ignore[attr-defined]
        return wrapper  # type: ignore[return-value]

    return decorate
