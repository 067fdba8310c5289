"""``convert``: one call that turns any input slamcli reads into the file ``out`` names.

What is written depends on the input and on ``out``'s suffix, decided here in this order:

1. ``out`` ends in ``.tum``, ``.txt`` or ``.kitti``: the poses of a pose topic (``gt_topic``)
   or of a tf frame (``gt_frame``) of an MCAP log, as a trajectory file.
2. A run folder (it holds ``run.json``): a Foxglove result log of its trajectory, map, points
   and mesh (:func:`~slamcli.formats.mcap.write.write_result_log`).
3. A landmark folder (``odometry.csv`` and ``measurements.csv``): an MCAP landmark log for
   ``slamcli run ekf`` (:func:`~slamcli.formats.mcap.write.write_landmark_log`).
4. A folder of runs (as ``slamcli demo`` writes): refused, naming the runs it holds.
5. A KITTI or EuRoC stereo folder: an MCAP log of its images as recorded, their calibration, the
   IMU (EuRoC: from 1 s before the first pair to 1 s after the last) and the ground truth
   (:func:`~slamcli.formats.mcap.write.stereo.write_stereo_mcap`).
6. Any other source :func:`~slamcli.formats.open_source` recognises: an MCAP log of its RGB-D
   frames (:func:`~slamcli.formats.mcap.write.write_source_mcap`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from slamcli.errors import ConfigError, InputError

if TYPE_CHECKING:
    from slamcli.formats.mcap.write import McapWriteSummary
    from slamcli.types import ProgressFn

TRAJECTORY_SUFFIXES = {".tum": "tum", ".txt": "tum", ".kitti": "kitti"}
"""Output suffixes that ask for a trajectory, and the trajectory format each writes."""

KINDS = ("trajectory", "run", "landmarks", "stereo", "source")
"""What :func:`convert` found the input to be (:attr:`ConvertResult.kind`)."""

STEREO_FORMATS = ("kitti", "euroc")
"""The source formats written as stereo logs."""


@dataclass
class ConvertResult:
    """What :func:`convert` wrote.

    Attributes:
        kind: one of :data:`KINDS`.
        out: the file written.
        summary: topics and message counts of an MCAP output (None for a trajectory).
        poses: poses written to a trajectory output.
        poses_from: the topic (or ``"tf FRAME"``) the trajectory was read from.
        data_loss: damage the MCAP reader worked around while exporting a trajectory.
    """

    kind: str
    out: Path
    summary: McapWriteSummary | None = None
    poses: int = 0
    poses_from: str = ""
    data_loss: list[str] = field(default_factory=list)

    @property
    def skipped(self) -> int:
        """Frames the source skipped because an image was missing or unreadable."""
        return self.summary.skipped if self.summary is not None else 0


def convert(
    input: str | Path,
    out: str | Path,
    *,
    flavor: str | None = None,
    compress_images: str = "none",
    depth_encoding: str = "16UC1",
    jpeg_quality: int = 90,
    max_frames: int | None = None,
    force: bool = False,
    source_options: dict[str, Any] | None = None,
    progress: ProgressFn | None = None,
) -> ConvertResult:
    """Convert ``input`` into ``out``; what is written is chosen as the module docstring says.

    Args:
        input: a run folder, a landmark folder, or a source (TUM RGB-D folder, MCAP log, ...).
        out: the file to write; written to a temporary name and renamed into place when
            complete.
        flavor: ``"ros2"`` or ``"foxglove"`` for sources and landmark folders (default ros2);
            run folders are always written with Foxglove schemas.
        compress_images, depth_encoding, jpeg_quality, max_frames: for RGB-D sources only (see
            :func:`~slamcli.formats.mcap.write.write_source_mcap`).
        force: replace an existing ``out``.
        source_options: options for :func:`~slamcli.formats.open_source`; a trajectory export
            takes ``gt_topic``, ``gt_frame`` and ``strict`` from them; for a stereo folder,
            ``groundtruth`` names a trajectory file written instead of the folder's own.
        progress: called as ``progress(frames_done, frames_total)`` while converting a source
            (stereo pairs for a stereo folder).

    Raises:
        ConfigError: an option that does not apply to the input. InputError: an input that
            cannot be read, or a folder of runs. ExportError: ``out`` exists without ``force``
            or cannot be written.
    """
    from slamcli.formats import sniff
    from slamcli.formats.run_folder import is_run_dir, read_run, sub_runs

    src, dest = Path(input), Path(out)
    options = dict(source_options or {})
    if dest.suffix.lower() in TRAJECTORY_SUFFIXES:
        return _export_trajectory(src, dest, options, force)
    if options.get("gt_topic") or options.get("gt_frame"):
        raise ConfigError(
            "--gt-topic/--gt-frame export a trajectory: give OUT a .tum, .txt or .kitti name"
        )
    rgbd_only = [
        flag
        for flag, used in (
            ("--compress-images", compress_images != "none"),
            ("--depth-encoding", depth_encoding != "16UC1"),
            ("--max-frames", max_frames is not None),
        )
        if used
    ]
    if is_run_dir(src):
        from slamcli.formats.mcap.write import write_result_log

        given = (["--flavor ros2"] if flavor == "ros2" else []) + rgbd_only
        _refuse(src, given, "run folders", "a run folder is always written with Foxglove schemas")
        result = read_run(src).result()
        return ConvertResult("run", dest, write_result_log(dest, result, force=force))
    if sniff.landmark_world(src):
        from slamcli.formats.mcap.write import write_landmark_log

        _refuse(src, rgbd_only, "landmark folders", "a landmark folder has no images")
        summary = write_landmark_log(dest, src, flavor=flavor or "ros2", force=force)
        return ConvertResult("landmarks", dest, summary)
    if sub_runs(src):
        # Raises the error that names the runs the folder holds.
        read_run(src)
    stereo = _stereo_format(src)
    if stereo is not None:
        given = (["--flavor foxglove"] if flavor == "foxglove" else []) + rgbd_only
        _refuse(src, given, "stereo folders", "a stereo folder is written as ROS 2 messages")
        return _convert_stereo(src, dest, stereo, options, force, progress)
    from slamcli.formats import open_source
    from slamcli.formats.mcap.write import write_source_mcap

    with open_source(src, **options) as source:
        summary = write_source_mcap(
            source,
            dest,
            flavor=flavor or "ros2",
            compress_images=compress_images,
            depth_encoding=depth_encoding,
            jpeg_quality=jpeg_quality,
            max_frames=max_frames,
            force=force,
            progress=progress,
        )
    return ConvertResult("source", dest, summary)


def _refuse(input: Path, flags: list[str], what: str, why: str) -> None:
    """ConfigError when RGB-D-only options were given for an input that has no images."""
    if flags:
        verb = "is" if len(flags) == 1 else "are"
        raise ConfigError(
            f"{input}: {', '.join(flags)} {verb} for RGB-D inputs, not {what}",
            hint=f"{why}; drop those options",
        )


def _stereo_format(input: Path) -> str | None:
    """``"kitti"`` or ``"euroc"`` for a folder of that layout, else None."""
    from slamcli.formats import SNIFFERS

    return next((name for name in STEREO_FORMATS if SNIFFERS[name](input)), None)


def _convert_stereo(
    input: Path,
    out: Path,
    format: str,
    options: dict[str, Any],
    force: bool,
    progress: ProgressFn | None,
) -> ConvertResult:
    """A stereo folder as an MCAP log; ``options["groundtruth"]`` (a trajectory file) replaces
    the folder's ground truth."""
    from slamcli.formats import open_source
    from slamcli.formats.mcap.write.stereo import write_stereo_mcap
    from slamcli.formats.trajectory import read_trajectory

    given = options.pop("groundtruth", None)
    truth = None
    if given is not None:
        path = Path(str(given))
        if not path.is_file():
            raise InputError(
                f"--groundtruth {given}: no such file",
                hint="give a trajectory file (TUM, EuRoC or KITTI) of the body's poses",
            )
        truth = read_trajectory(path)
    with open_source(input, format, **options) as source:
        summary = write_stereo_mcap(source, out, groundtruth=truth, force=force, progress=progress)
    return ConvertResult("stereo", out, summary)


def _export_trajectory(
    input: Path, out: Path, options: dict[str, Any], force: bool
) -> ConvertResult:
    from slamcli.formats import SNIFFERS, source_class

    gt_topic, gt_frame = options.get("gt_topic"), options.get("gt_frame")
    kind = next((k for k in ("mcap", "rosbag1", "rosbag2") if SNIFFERS[k](input)), None)
    if kind is None:
        raise ConfigError(f"{input}: trajectories are exported from MCAP logs and ROS bags only")
    if out.exists() and not force:
        raise ConfigError(f"{out}: exists", hint="pass --force to overwrite it")
    if not (gt_topic or gt_frame):
        raise ConfigError(
            f"{out}: exporting a trajectory needs --gt-topic TOPIC or --gt-frame FRAME",
            hint=f"'slamcli info {input}' lists the topics",
        )
    from slamcli.formats.trajectory import write_trajectory

    strict = bool(options.get("strict", False))
    limit = {"max_chunk_mb": options["max_chunk_mb"]} if options.get("max_chunk_mb") else {}
    with source_class(kind).open(
        input, gt_topic=gt_topic, gt_frame=gt_frame, strict=strict, **limit
    ) as source:
        trajectory = source.groundtruth()
        lost = list(source.stats.data_loss)
    if trajectory is None:
        raise ConfigError(f"{input}: {gt_topic or gt_frame} holds no poses")
    write_trajectory(out, trajectory, TRAJECTORY_SUFFIXES[out.suffix.lower()])
    source_name = gt_topic or f"tf {gt_frame}"
    return ConvertResult("trajectory", out, None, len(trajectory), source_name, lost)


__all__ = ["KINDS", "STEREO_FORMATS", "TRAJECTORY_SUFFIXES", "ConvertResult", "convert"]
