"""``slamcli convert``: RGB-D, stereo or landmark folders to MCAP logs, run folders to
``result.mcap``."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.cli.source_options import SourceOptions, source_options
from slamcli.errors import DataLossError

if TYPE_CHECKING:
    from slamcli.formats.mcap.write import McapWriteSummary

HELP = """Convert a TUM RGB-D folder, a KITTI or EuRoC stereo folder or a landmark folder to an \
MCAP log, a run folder to a Foxglove result log, or a pose topic of an MCAP log to a trajectory \
file.

[bold]RGB-D folder[/] -> MCAP: colour, depth, camera info, ground truth and (ros2 only) the \
accelerometer on /camera/color/image_raw, /camera/depth/image_raw, /camera/color/camera_info, \
/groundtruth and /imu. --flavor ros2 writes sensor_msgs and geometry_msgs messages as CDR with \
full ros2msg schemas, as `ros2 bag record` does; --flavor foxglove writes foxglove.RawImage, \
CompressedImage, CameraCalibration, PoseInFrame and FrameTransform (/tf) as JSON with the \
official Foxglove JSON schemas. Depth 16UC1 is millimetres (rounded: TUM's 0.2 mm steps are \
lost); 32FC1 is metres, exactly the source's values. --compress-images jpeg|png compresses \
colour, and in the ros2 flavour 16UC1 depth as lossless "16UC1; compressedDepth png".

[bold]Stereo folder[/] (KITTI odometry, EuRoC / ASL) -> MCAP as ROS 2 messages (CDR): the \
images as recorded (KITTI's rectified, EuRoC's raw) as sensor_msgs/Image (mono8, rgb8 for \
colour) on /cam0/image_raw and /cam1/image_raw, a CameraInfo per image on /cam0/camera_info and \
/cam1/camera_info (the raw K and D, the rectification R, the rectified P; the right P[0,3] = \
-fx * baseline), the cameras (and IMU) on the body as base_link -> cam0, cam1, imu0 on \
/tf_static, and the ground truth of base_link (--groundtruth FILE, else the folder's) as \
PoseStamped in world on /groundtruth. EuRoC's IMU goes on /imu0, only the samples from 1 s \
before the first stereo pair to 1 s after the last. Only pairs whose two images exist are written.

[bold]Landmark folder[/] (odometry.csv and measurements.csv, as `slamcli synth landmarks` \
writes) -> MCAP for `slamcli run ekf`: odometry as nav_msgs/msg/Odometry on /odom (twist = the \
control, pose = dead reckoning), observations as slamcli.LandmarkObservations JSON on \
/landmarks, groundtruth.tum as PoseStamped (--flavor foxglove: foxglove.PoseInFrame and /tf) \
on /ground_truth.

[bold]Run folder[/] (it has run.json) -> a log Foxglove opens: the trajectory \
(foxglove.PoseInFrame on /slamcli/pose, world->camera on /tf), map.yaml as foxglove.Grid, \
points.ply as foxglove.PointCloud and mesh.ply as a GLB model in a foxglove.SceneUpdate.

[bold]MCAP log[/] -> OUT.tum / OUT.txt (TUM) or OUT.kitti: the poses of --gt-topic (PoseStamped, \
PoseWithCovarianceStamped, Odometry, foxglove.PoseInFrame) at their header stamps, or of \
--gt-frame from tf (the frame's pose in the root of its tree).

OUT is written to a temporary name and renamed into place when complete.

Exit codes: 0 ok; 1 bad input or options, or OUT exists without --force; 2 usage; 3 written, \
but some images were missing or unreadable and their frames were skipped.

Examples:

[bold]slamcli convert sample_data/rgbd_room room.mcap --flavor ros2[/]

[bold]slamcli convert sample_data/rgbd_room room_fg.mcap --flavor foxglove --compress-images jpeg[/]

[bold]slamcli convert sample_data/landmarks landmarks.mcap[/]

[bold]slamcli convert ../shared/data/stereo/kitti_excerpt_1 kitti.mcap[/]

[bold]slamcli convert runs/demo/dense runs/demo/dense/result.mcap[/]

[bold]slamcli convert ../shared/data/mcap/nav2_turtlebot.mcap amcl.tum --gt-topic /amcl_pose[/]
"""


class Flavor(str, Enum):
    ros2 = "ros2"
    foxglove = "foxglove"


class Compression(str, Enum):
    none = "none"
    jpeg = "jpeg"
    png = "png"


class DepthEncoding(str, Enum):
    millimetres = "16UC1"
    metres = "32FC1"


_NOT_FOR_CONVERT = (
    "robot",
    "ignore_ids",
    "rgb_topic",
    "depth_topic",
    "camera_info_topic",
    "odom_topic",
    "landmark_topic",
    "left_topic",
    "right_topic",
    "calib",
)
"""Source options convert has no use for: it reads RGB-D and landmark folders whole, and from an
MCAP log only the poses of --gt-topic or --gt-frame."""


def register(app: typer.Typer) -> None:
    app.command("convert", help=HELP, rich_help_panel="Export")(convert)


@boundary
@source_options(without=_NOT_FOR_CONVERT)
def convert(
    input: Annotated[
        Path,
        typer.Argument(
            help="A TUM RGB-D folder, a KITTI or EuRoC folder, a landmark folder, a run folder, "
            "or an MCAP log.",
            show_default=False,
        ),
    ],
    out: Annotated[
        Path,
        typer.Argument(
            help="The .mcap file to write (or a .tum/.txt/.kitti trajectory for an MCAP log).",
            show_default=False,
        ),
    ],
    flavor: Annotated[
        Flavor | None,
        typer.Option(
            "--flavor",
            help="Message types for an RGB-D or landmark input: ros2 (CDR) or foxglove (JSON). "
            "Default: ros2; run folders are always written with Foxglove schemas.",
            show_default=False,
        ),
    ] = None,
    compress_images: Annotated[
        Compression,
        typer.Option("--compress-images", help="Compress colour images (and ros2 16UC1 depth)."),
    ] = Compression.none,
    depth_encoding: Annotated[
        DepthEncoding,
        typer.Option(
            "--depth-encoding", help="Depth as 16UC1 millimetres or 32FC1 metres (exact)."
        ),
    ] = DepthEncoding.millimetres,
    jpeg_quality: Annotated[
        int, typer.Option("--jpeg-quality", min=1, max=100, help="JPEG quality (1-100).")
    ] = 90,
    max_frames: Annotated[
        int | None,
        typer.Option(
            "--max-frames",
            min=1,
            help="Convert only the first N RGB-D frames (and the data up to the last one).",
            show_default=False,
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite OUT if it exists.")] = False,
    *,
    source: SourceOptions,
) -> None:
    from slamcli.atomic import check_writable_file
    from slamcli.convert import convert as convert_input

    check_writable_file(out)
    options = source.open_kwargs()
    with render.progress("converting frames") as progress:
        result = convert_input(
            input,
            out,
            flavor=flavor.value if flavor is not None else None,
            compress_images=compress_images.value,
            depth_encoding=depth_encoding.value,
            jpeg_quality=jpeg_quality,
            max_frames=max_frames,
            force=force,
            source_options=options,
            progress=progress,
        )
    if result.summary is None:
        render.key_values(None, {"poses": result.poses, "from": result.poses_from})
        render.written([result.out])
        if result.data_loss:
            raise DataLossError(f"{input}: the log is damaged; {out} holds what could be read")
        return
    _show(result.summary)
    if result.skipped:
        raise DataLossError(
            f"{input}: {result.skipped} frame(s) skipped because an image was missing or "
            f"unreadable; {out} holds the other {result.summary.frames}",
            hint=f"'slamcli info {input} --deep' names every unreadable image",
        )


def _show(summary: McapWriteSummary) -> None:
    rows = [[topic, schema, count] for topic, (schema, count) in summary.topics.items()]
    render.table(str(summary.path), ["topic", "type", "messages"], rows, right_align=["messages"])
    render.written([summary.path])
