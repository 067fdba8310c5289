"""``slamcli info``: what an input log holds and what is wrong with it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.cli.source_options import SourceOptions, source_options
from slamcli.errors import DataLossError, UnknownFormatError

if TYPE_CHECKING:
    from slamcli.formats.base import SourceInfo
    from slamcli.types import PinholeCamera

HELP = """Show what an input holds: streams, paired RGB-D frames, camera, ground truth, problems.

For a landmark log (an MRCLAM folder with --robot N, a Victoria Park file, a 'slamcli synth \
landmarks' folder): odometry and observation counts, dropped robot sightings, skipped unknown \
barcodes, odometry gaps, landmark and robot ground truth and the start pose.

For an MCAP log: every topic with its type, encoding, count and rate; the log's health \
(summary, truncation, CRCs, overlapping chunks); the colour and depth topics and how many \
frames pair (by log time; --deep decodes every frame and pairs by header stamps, which also \
checks every chunk's CRC).

Maps (a map_server .yaml, an .npz map, a run folder's map.yaml), trajectory files (TUM, KITTI, \
EuRoC) and g2o pose graphs are described too: size and cell counts; poses, time span, rate and \
path length; vertices and edges.

Exit codes: 0 ok; 1 bad input, or an ambiguous or missing topic choice (the candidates are \
listed) (with --strict, also an unreadable image or a damaged log); 2 usage; 3 some listed \
images are missing or (with --deep) cannot be decoded, or the log is damaged, so reading would \
lose data.

Examples:

[bold]slamcli info sample_data/rgbd_room[/]

[bold]slamcli info sample_data/landmarks --json[/]

[bold]slamcli info ../shared/data/mcap/nav2_turtlebot.mcap[/]

[bold]slamcli info ../shared/data/maps/turtlebot3_world.yaml[/]

[bold]slamcli info ../shared/data/trajectories/freiburg1_xyz-groundtruth.txt[/]

[bold]slamcli info ../shared/data/pose_graphs/intel.g2o --json[/]
"""


def register(app: typer.Typer) -> None:
    app.command("info", help=HELP, rich_help_panel="Inspect")(info)


@boundary
@source_options()
def info(
    input: Annotated[
        Path,
        typer.Argument(
            help="A TUM RGB-D folder, an MCAP file, an MRCLAM folder, a Victoria Park file, a "
            "'slamcli synth landmarks' folder; or a map (.yaml, .npz, a run folder with "
            "map.yaml), a trajectory file (TUM, KITTI, EuRoC) or a .g2o pose graph.",
            show_default=False,
        ),
    ],
    deep: Annotated[
        bool, typer.Option("--deep", help="Decode every image (slow) to find unreadable ones.")
    ] = False,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print one JSON object on stdout instead of tables.")
    ] = False,
    *,
    source: SourceOptions,
) -> None:
    from slamcli.formats import open_source

    kind = _other_kind(input)
    if kind is not None:
        facts = _describe_other(kind, input)
        if json_out:
            render.print_json({"kind": kind, "path": str(input), **facts})
        else:
            render.key_values(f"{kind}: {input}", _other_items(kind, facts))
        return
    try:
        opened = open_source(input, **source.open_kwargs())
    except UnknownFormatError as exc:
        exc.hint = (
            f"{exc.hint}; info also describes maps (.yaml, .npz, a folder with map.yaml), "
            f"trajectory files ({', '.join(_TRAJECTORY_SUFFIXES)}) and g2o pose graphs (.g2o)"
        )
        raise
    with opened as src:
        if deep:
            with render.progress("decoding images") as progress:
                result = src.info(deep=True, progress=progress)
        else:
            result = src.info()
    if json_out:
        render.print_json(result.to_dict())
    else:
        _show(result)
    unreadable = result.details.get("unreadable") or []
    if unreadable:
        raise DataLossError(
            f"{input}: {len(unreadable)} listed image(s) missing or unreadable",
            hint="reading skips those frames; --strict stops at the first one instead",
        )
    if result.details.get("data_loss"):
        raise DataLossError(
            f"{input}: the log is damaged; reading uses what is left",
            hint="--strict stops instead; 'mcap recover' can rebuild a damaged MCAP file",
        )


_TRAJECTORY_SUFFIXES = (".txt", ".tum", ".csv", ".kitti")


def _other_kind(path: Path) -> str | None:
    """``map``, ``trajectory`` or ``pose graph`` for inputs that are not logs, else None."""
    from slamcli.formats import SNIFFERS

    if any(looks_like(path) for looks_like in SNIFFERS.values()):
        return None
    suffix = path.suffix.lower()
    if suffix == ".g2o":
        return "pose graph"
    if suffix in (".yaml", ".yml", ".npz") or (path.is_dir() and (path / "map.yaml").is_file()):
        return "map"
    if path.is_file() and suffix in _TRAJECTORY_SUFFIXES:
        return "trajectory"
    return None


def _describe_other(kind: str, path: Path) -> dict[str, Any]:
    """JSON-able facts about a map, a trajectory file or a pose graph."""
    if kind == "map":
        from slamcli.cli.map_cmd import describe_map

        return describe_map(path)
    if kind == "pose graph":
        from slamcli.formats.g2o import read_g2o

        return read_g2o(path).summary()
    import numpy as np

    from slamcli.formats.trajectory import read_poses

    table = read_poses(path)
    facts: dict[str, Any] = {"format": table.format, "poses": len(table)}
    if table.timed and len(table) > 1:
        span = float(table.stamps_ns[-1] - table.stamps_ns[0]) * 1e-9
        facts["span_s"] = span
        facts["rate_hz"] = (len(table) - 1) / span if span > 0 else None
    steps = np.linalg.norm(np.diff(table.positions, axis=0), axis=1)
    facts["path_length_m"] = float(steps.sum())
    return facts


def _other_items(kind: str, d: dict[str, Any]) -> dict[str, Any]:
    if kind == "map":
        from slamcli.cli.map_cmd import map_items

        return map_items(d)
    if kind == "pose graph":
        ids = f", {d['pose_ids']} pose ids" if d["pose_ids"] != d["vertices"] else ""
        return {
            "graph": f"{d['dimension']}, {d['vertices']} vertices{ids}",
            "edges": f"{d['edges']}: {d['odometry_edges']} between consecutive ids, "
            f"{d['loop_closure_edges']} loop closures",
            "fixed": ", ".join(map(str, d["fixed"])) or "none",
        }
    items: dict[str, Any] = {"format": d["format"], "poses": d["poses"]}
    if "span_s" in d:
        items["span"] = f"{d['span_s']:.2f} s"
        if d["rate_hz"]:
            items["rate"] = f"{d['rate_hz']:.1f} Hz"
    else:
        items["times"] = "none (KITTI poses are numbered, not timed)"
    items["path length"] = f"{d['path_length_m']:.2f} m"
    return items


def _show(info: SourceInfo) -> None:
    rows = [
        [
            s.name,
            s.count,
            f"{s.rate_hz:.1f}" if s.rate_hz else "-",
            _span(s.start_s, s.end_s),
            s.detail,
        ]
        for s in info.streams
    ]
    render.table(
        f"{info.format}: {info.path}",
        ["stream", "count", "rate Hz", "span s", "from"],
        rows,
        right_align=["count", "rate Hz", "span s"],
    )
    d = info.details
    items: dict[str, Any]
    if "landmark_observations" in d:
        items = _landmark_items(info)
    elif d.get("landmark_topic"):
        # An MCAP landmark log: odometry and observations, no images to pair.
        items = {
            "landmark observations": f"{d.get('landmark_messages', 0)} messages on "
            f"{d['landmark_topic']}",
        }
        if d.get("odometry_topic"):
            items["odometry"] = str(d["odometry_topic"])
        if info.frames:
            items["frames"] = f"{info.frames} paired RGB-D frames"
    elif any(s.kind == "scan" for s in info.streams):
        items = _scan_items(info)
    elif any(s.kind == "stereo" for s in info.streams):
        items = _stereo_items(info)
    elif not d.get("depth_topic") and not any(s.kind == "depth" for s in info.streams):
        items = {"frames": f"{info.frames} images (no depth: monocular)"}
    else:
        items = {"frames": f"{info.frames} paired RGB-D frames"}
    if d.get("imu_check"):
        items["imu"] = _imu_summary(d["imu_check"])
    if d.get("rgb_topic"):
        items["topics"] = f"colour {d['rgb_topic']}, depth {d['depth_topic']}"
    health = d.get("health")
    if health:
        items["health"] = ", ".join(
            [
                "summary present" if health["summary_present"] else "no summary",
                "truncated" if health["truncated"] else "complete",
                "CRCs checked" if health["crc_checked"] else "CRCs not checked",
                f"{health['bad_chunks']} bad chunk(s)",
                "chunks overlap" if health["chunk_overlap"] else "no chunk overlap",
            ]
        )
    if "unmatched_rgb" in d:
        items["unmatched"] = (
            f"colour {d['unmatched_rgb']}, depth {d['unmatched_depth']} "
            f"(max dt {d['max_dt_s']:g} s, offset {d['dt_offset_s']:g} s)"
        )
    if "pair_dt_ms" in d:
        items["pair dt"] = (
            f"median {d['pair_dt_ms']['median']:.1f} ms, max {d['pair_dt_ms']['max']:.1f} ms"
        )
    if info.camera is not None:
        items["camera"] = _camera(info.camera)
        items["camera from"] = info.camera_source
    if "depth_factor" in d:
        items["depth factor"] = f"{d['depth_factor']:g} per metre ({d['depth_factor_source']})"
    check = d.get("depth_check") or {}
    if "median_m" in check:
        items["depth"] = (
            f"median {check['median_m']:.2f} m "
            f"(5-95 %: {check['p5_m']:.2f}-{check['p95_m']:.2f} m), "
            f"{check['valid_fraction']:.0%} valid, from {check['samples']} sampled images"
        )
    items["ground truth"] = _groundtruth(info)
    render.key_values(None, items)
    if info.problems:
        for p in info.problems:
            render.out.print(f"[yellow]problem:[/] {escape(p)}")
    else:
        render.out.print("[green]no problems found[/]")


def _landmark_items(info: SourceInfo) -> dict[str, Any]:
    """The key facts of a landmark log (MRCLAM, Victoria Park, synth landmarks)."""
    d = info.details
    items: dict[str, Any] = {}
    if "robot" in d:
        items["robot"] = f"{d['robot']} (robots here: {', '.join(map(str, d['robots']))})"
    items["frames"] = (
        f"{info.frames}: {d['odometry']} odometry ({d['odometry_kind']}), "
        f"{d['landmark_frames']} with landmark observations"
    )
    odometry = []
    if "odometry_max_gap_s" in d:
        odometry.append(f"largest gap {d['odometry_max_gap_s']:.3f} s")
        odometry.append(f"{d['odometry_repeated_stamps']} repeated stamp(s)")
    if d.get("stamps"):
        odometry.append(d["stamps"])
    if odometry:
        items["odometry"] = ", ".join(odometry)
    ids = "ids ignored" if d["ignore_ids"] else f"{d['landmark_ids_seen']} distinct ids"
    items["observations"] = f"{d['landmark_observations']} landmark observations, {ids}"
    if "robot_sightings" in d:
        items["robot sightings"] = f"{d['robot_sightings']} (dropped)"
    unknown = d.get("unknown_barcodes")
    if unknown is not None:
        items["unknown barcodes"] = (
            ", ".join(f"{b} ({n}x)" for b, n in unknown.items()) + " (skipped)"
            if unknown
            else "none"
        )
    items["landmarks"] = f"{d['landmarks']} surveyed" if d.get("landmarks") else "none"
    if "dead_reckoning_length_m" in d:
        items["dead reckoning"] = f"{d['dead_reckoning_length_m']:.1f} m travelled"
    start = d.get("start_pose")
    if start is not None:
        items["start pose"] = f"x {start[0]:.3f} m, y {start[1]:.3f} m, yaw {start[2]:.3f} rad"
    return items


def _span(start: float | None, end: float | None) -> str:
    return f"{end - start:.2f}" if start is not None and end is not None else "-"


def _camera(cam: PinholeCamera) -> str:
    text = f"{cam.width}x{cam.height} fx {cam.fx:g} fy {cam.fy:g} cx {cam.cx:g} cy {cam.cy:g}"
    if cam.is_distorted:
        text += ", distortion " + " ".join(f"{c:g}" for c in cam.distortion)
    return text


def _groundtruth(info: SourceInfo) -> str:
    if not info.groundtruth:
        return "none"
    text = f"{info.groundtruth} poses"
    if info.details.get("groundtruth_from"):
        text += f" from {info.details['groundtruth_from']}"
    coverage = info.details.get("groundtruth_coverage")
    if coverage is not None:
        text += (
            f"; {info.details['groundtruth_covered']} of {info.frames} frames ({coverage:.0%}) "
            "have a pose within 0.02 s"
        )
    return text


def _scan_items(info: Any) -> dict[str, Any]:
    """What a laser log holds: its scans (count, beams), their mounting, where odometry is."""
    d = info.details
    scans = [s for s in info.streams if s.kind == "scan"]
    items: dict[str, Any] = {
        "scans": ", ".join(
            f"{s.count} on {s.name}" + (f" ({s.detail})" if s.detail else "") for s in scans
        ),
    }
    if d.get("scan_mounting"):
        items["mounting"] = d["scan_mounting"]
    odometry = d.get("scan_odometry")
    if odometry is None:
        odometry = next(
            (
                f"{s.count} poses on {s.name}" + (f" ({s.detail})" if s.detail else "")
                for s in info.streams
                if s.kind == "odometry" and s.count
            ),
            None,
        )
    items["odometry"] = odometry or "none (scans alone: run lidar matches them without a guess)"
    return items


def _stereo_items(info: SourceInfo) -> dict[str, Any]:
    """What a stereo sequence holds: its pairs, their size, the baseline, where times come from."""
    d = info.details
    items: dict[str, Any] = {
        "pairs": ", ".join(
            f"{s.count}" + (f" ({s.detail})" if s.detail else "")
            for s in info.streams
            if s.kind == "stereo"
        ),
    }
    size = d.get("image_size")
    if size:
        colour = d.get("colour")
        shade = "" if colour is None else (", colour" if colour else ", grey")
        items["image size"] = f"{size[0]}x{size[1]}{shade}"
    if d.get("baseline_m") is not None:
        items["baseline"] = f"{d['baseline_m']:.4f} m"
    if d.get("times_source"):
        items["times"] = d["times_source"]
    return items


def _imu_summary(check: dict[str, Any]) -> str:
    """One line on an IMU stream's checks: its rate, gaps and stamp problems, and how its time
    lines up with the camera's."""
    rate = check.get("rate_hz")
    parts = [f"{rate:.1f} Hz" if rate else "no rate", f"{check['samples']} samples"]
    gaps = check.get("gaps", 0)
    parts.append(
        f"{gaps} gap(s), the longest {check['largest_gap_s']:.3f} s" if gaps else "no gaps"
    )
    bad = [
        f"{check[k]} {label}"
        for k, label in (("duplicates", "duplicate stamp(s)"), ("backwards", "backwards"))
        if check.get(k)
    ]
    parts.append(", ".join(bad) if bad else "stamps increase")
    before, after = check.get("imu_before_first_image_s"), check.get("imu_after_last_image_s")
    if before is not None and after is not None:
        parts.append(f"{before:.2f} s before the first image, {after:.2f} s after the last")
    return "; ".join(parts)
