"""``slamcli synth``: make synthetic data with exact ground truth."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError

synth_app = typer.Typer(
    help="Make synthetic data with exact ground truth, for tests, demos and benchmarks.",
    no_args_is_help=True,
    rich_markup_mode="rich",
)

_SIZE = re.compile(r"^\s*(\d+)\s*[xX×]\s*(\d+)\s*$")


def register(app: typer.Typer) -> None:
    app.add_typer(synth_app, name="synth", rich_help_panel="Data")


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``; raises ConfigError naming ``--size`` otherwise."""
    m = _SIZE.match(text)
    width, height = (int(m.group(1)), int(m.group(2))) if m else (0, 0)
    if not m or not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise ConfigError(
            f"--size: expected WIDTHxHEIGHT with each side in [16, 4096] pixels, got {text!r}",
            hint="for example --size 640x480 or --size 320x240",
        )
    return width, height


@synth_app.command("rgbd")
@boundary
def rgbd(
    out: Annotated[
        Path,
        typer.Argument(help="Folder to write the TUM RGB-D sequence into.", show_default=False),
    ],
    frames: int = typer.Option(300, "--frames", "-n", min=2, help="Colour/depth pairs, at 30 Hz."),
    size: str = typer.Option("640x480", "--size", help="Image size WIDTHxHEIGHT in pixels."),
    seed: int = typer.Option(0, "--seed", help="Seeds textures and noise; same seed, same bytes."),
    noise: bool = typer.Option(
        False, "--noise/--no-noise", help="Kinect-like depth noise and holes, colour noise."
    ),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty OUT folder."),
) -> None:
    """Render a textured room as a TUM RGB-D folder with ground truth.

    Writes rgb/ and depth/ PNGs, rgb.txt, depth.txt, groundtruth.txt (world_from_camera),
    accelerometer.txt and camera.yaml. The camera flies a closed loop at handheld speeds
    (fx = fy = 0.8 x width); sequences of 18 s (540 frames) or more turn once around the room.

    Example: [bold]slamcli synth rgbd runs/synth_room --frames 4 --size 160x120 --noise[/]
    """
    from slamcli.synth.rgbd import render_rgbd_sequence

    width, height = parse_size(size)
    with render.progress("rendering", frames) as progress:
        summary = render_rgbd_sequence(
            out,
            frames=frames,
            size=(width, height),
            seed=seed,
            noise=noise,
            force=force,
            progress=progress,
        )
    cam = summary["camera"]
    render.key_values(
        "Sequence",
        {
            "frames": f"{summary['frames']} ({summary['duration_s']:.2f} s at 30 Hz)",
            "camera": f"{cam['width']}x{cam['height']}, fx=fy={cam['fx']:g}, "
            f"cx={cam['cx']:g}, cy={cam['cy']:g}",
            "path": f"{summary['path_length_m']:.2f} m, up to {summary['max_speed_mps']:.2f} m/s "
            f"and {summary['max_rotation_dps']:.1f} deg/s",
            "loop gap": f"{summary['closure_m'] * 100:.1f} cm, {summary['closure_deg']:.2f} deg",
            "noise": f"on, {summary['hole_fraction']:.1%} depth holes" if noise else "off",
            "seed": seed,
        },
    )
    render.written(summary["files"][:-2])
    render.note(f"images in {summary['files'][-2]} and {summary['files'][-1]}")


@synth_app.command("stereo")
@boundary
def stereo(
    out: Annotated[
        Path,
        typer.Option(
            "--out", "-o", help="Folder to write the EuRoC / ASL folder into.", show_default=False
        ),
    ],
    frames: int = typer.Option(300, "--frames", "-n", min=2, help="Stereo pairs, at --fps."),
    fps: float = typer.Option(
        20.0,
        "--fps",
        help="Stereo pairs per second: 20 as EuRoC's cameras, 10 as KITTI's; any rate that "
        "divides the IMU's 200 Hz.",
    ),
    size: str = typer.Option("640x480", "--size", help="Image size WIDTHxHEIGHT in pixels."),
    baseline: float = typer.Option(
        0.12, "--baseline", help="Distance between the cameras in metres, up to 0.5."
    ),
    seed: int = typer.Option(0, "--seed", help="Seeds textures and noise; same seed, same bytes."),
    noise: bool = typer.Option(
        False,
        "--noise/--no-noise",
        help="Grey-level noise per camera, a brighter right camera, IMU noise and biases.",
    ),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty --out folder."),
) -> None:
    """Render a textured room with a stereo rig and an IMU as a EuRoC / ASL folder.

    Two undistorted pinhole cameras (fx = fy = 0.8 x width), --baseline apart along the left
    camera's x axis, fly synth rgbd's closed loop at 20 Hz (or --fps); the images are rectified
    as rendered. A slower rate takes the same loop in the same time, with larger steps between
    pairs. The body is the IMU, with the left camera mounted on it as on EuRoC's rig.
    Writes mav0/cam0 and mav0/cam1 (data.csv, data/<ns>.png in 8-bit grey, sensor.yaml),
    mav0/imu0 (200 Hz gyroscope and accelerometer in the body frame, sensor.yaml) and
    mav0/state_groundtruth_estimate0/data.csv (world_from_body at every IMU sample).

    Example: [bold]slamcli synth stereo --out runs/synth_stereo --frames 8 --size 320x240
    --noise[/]

    Example: [bold]slamcli synth stereo --out runs/synth_stereo_10hz --frames 6 --fps 10 --size
    160x120[/]
    """
    from slamcli.synth.stereo import render_stereo_sequence

    width, height = parse_size(size)
    with render.progress("rendering", frames) as progress:
        summary = render_stereo_sequence(
            out,
            frames=frames,
            size=(width, height),
            baseline_m=baseline,
            seed=seed,
            noise=noise,
            force=force,
            progress=progress,
            fps=fps,
        )
    cam = summary["camera"]
    render.key_values(
        "Stereo sequence",
        {
            "pairs": f"{summary['frames']} ({summary['duration_s']:.2f} s at {fps:g} Hz)",
            "cameras": f"{cam['width']}x{cam['height']}, fx=fy={cam['fx']:g}, "
            f"baseline {summary['baseline_m']:g} m",
            "imu": f"{summary['imu_samples']} samples at 200 Hz",
            "path": f"{summary['path_length_m']:.2f} m, up to {summary['max_speed_mps']:.2f} m/s "
            f"and {summary['max_rotation_dps']:.1f} deg/s",
            "loop gap": f"{summary['closure_m'] * 100:.1f} cm, {summary['closure_deg']:.2f} deg",
            "noise": "on" if noise else "off",
            "seed": seed,
        },
    )
    render.written(summary["files"][:-2])
    render.note(f"images in {summary['files'][-2]} and {summary['files'][-1]}")


@synth_app.command("landmarks")
@boundary
def landmarks(
    out: Annotated[
        Path, typer.Argument(help="Folder to write the landmark world into.", show_default=False)
    ],
    seed: int = typer.Option(0, "--seed", help="Seeds landmark placement and all noise."),
    count: int = typer.Option(40, "--landmarks", min=1, help="Number of landmarks."),
    duration: float = typer.Option(
        120.0, "--duration", min=0.05, help="Driving time in seconds (one lap takes 52 s)."
    ),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty OUT folder."),
    robots: int = typer.Option(
        1,
        "--robots",
        min=1,
        max=16,
        help="Robots driving the field at once; 2-16 write an MRCLAM folder (RobotN_*.dat).",
    ),
) -> None:
    """Simulate robots driving laps among landmarks, for EKF-SLAM and map merging.

    One robot (the default) writes odometry.csv (t,v,omega), measurements.csv
    (t,id,range,bearing), groundtruth.tum, landmarks.csv (id,x,y) and world.json (noise, sensor
    limits, seed). Odometry has white noise and a constant scale error; observations are
    range-bearing within 6 m and a 180-degree field of view.

    With --robots N (2-16) the robots start spread around the loop, the even-numbered ones
    driving it clockwise, and the folder is MRCLAM-shaped: Barcodes.dat (landmarks numbered
    after the robots), Landmark_Groundtruth.dat and per robot RobotK_Odometry.dat,
    RobotK_Measurement.dat (landmarks and the other robots in view) and
    RobotK_Groundtruth.dat, plus world.json; run each robot with
    'slamcli run ekf OUT --robot K' and join the runs with 'slamcli merge'.

    Example: [bold]slamcli synth landmarks runs/world --landmarks 60 --duration 60 --seed 3[/]

    Example: [bold]slamcli synth landmarks runs/world3 --robots 3 --duration 30 --seed 1[/]
    """
    from slamcli.synth.landmarks import generate_landmark_world

    total = 5 if robots == 1 else 3 + 3 * robots
    with render.progress("writing", total) as progress:
        summary = generate_landmark_world(
            out,
            seed=seed,
            landmarks=count,
            duration_s=duration,
            force=force,
            progress=progress,
            robots=robots,
        )
    rows: dict[str, object] = {
        "landmarks": summary["landmarks"],
        "drive": f"{summary['duration_s']:.1f} s, {summary['path_length_m']:.1f} m, "
        f"{summary['laps']:.2f} laps",
        "odometry": f"{summary['odometry']} records",
        "observations": summary["measurements"],
        "seed": seed,
    }
    if robots > 1:
        rows["drive"] = f"{summary['duration_s']:.1f} s, {summary['laps']:.2f} laps each"
        rows["robots"] = robots
        rows["robot sightings"] = summary["sightings"]
    render.key_values("World", rows)
    render.written(summary["files"])
    if robots > 1:
        render.note(f"run a robot with: slamcli run ekf {out} --robot 1 --out runs/robot1")


@synth_app.command("lidar")
@boundary
def lidar(
    map: Annotated[
        Path,
        typer.Argument(
            help="A .yaml (map_server) or .npz map, or a run folder with map.yaml.",
            show_default=False,
        ),
    ],
    out: Annotated[
        Path,
        typer.Option("--out", "-o", help="Folder to write the log into.", show_default=False),
    ],
    seed: int = typer.Option(
        0, "--seed", help="Seeds the route and all noise; same seed, same bytes."
    ),
    scans: int = typer.Option(1200, "--scans", "-n", min=2, help="Number of sweeps."),
    beams: int = typer.Option(360, "--beams", min=1, help="Beams per sweep."),
    fov_deg: float = typer.Option(
        360.0, "--fov-deg", help="Field of view in degrees, centred ahead (360: all around)."
    ),
    max_range: float = typer.Option(20.0, "--max-range", help="Maximum range in metres."),
    rate: float = typer.Option(10.0, "--rate", help="Sweeps per second."),
    speed: float = typer.Option(0.5, "--speed", help="Driving speed on straights, m/s."),
    clearance: float = typer.Option(
        0.4, "--clearance", help="Least distance (m) of the route from obstacles and unknown."
    ),
    odometry: str = typer.Option(
        "drift",
        "--odometry",
        help="drift: wheel odometry 2 % long with 0.01 rad/m heading drift; none: no odometry.",
    ),
    noise: bool = typer.Option(
        True, "--noise/--no-noise", help="Range noise (1 cm), dropouts and odometry white noise."
    ),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty --out folder."),
) -> None:
    """Simulate a robot with a 2-D lidar driving a closed route through an occupancy map.

    The route joins seeded waypoints in free space (more than --clearance from obstacles and
    unknown cells) by exact grid paths, smoothed, and ends back at its start, so loop closure
    has something to find; it is timed so the --scans sweeps at --rate cover it at about
    --speed. Beams are cast exactly through the map's occupied cells (honouring the origin's
    yaw), with 1 cm range noise and a few NaN dropouts; a beam with nothing within --max-range
    is +inf. The scanner sits 0.1 m ahead of the body.

    Writes scans.log (CARMEN, poses = odometry), scans.mcap (ROS 2 LaserScan, Odometry,
    tf_static), groundtruth.tum (world_from_body at every sweep) and world.json (seed, map,
    sensor, route, revisits).

    Example: [bold]slamcli synth lidar ../shared/data/maps/building_31.yaml --out runs/lidar_b31
    --scans 200 --seed 1[/]
    """
    import math

    from slamcli.synth.lidar import (
        DEFAULT_ODOMETRY,
        ODOMETRY_CHOICES,
        LidarSensor,
        generate_lidar_world,
    )

    if odometry not in ODOMETRY_CHOICES:
        raise ConfigError(
            f"--odometry: expected one of {', '.join(ODOMETRY_CHOICES)}, got {odometry!r}",
            hint="--odometry drift (wheel odometry with errors) or --odometry none",
        )
    sensor = LidarSensor(beams=beams, fov=math.radians(fov_deg), max_range=max_range, rate_hz=rate)
    wheels = None if odometry == "none" else DEFAULT_ODOMETRY
    if not noise:
        sensor = sensor.noiseless()
        wheels = None if wheels is None else wheels.noiseless()
    with render.progress("simulating", scans + 4) as progress:
        summary = generate_lidar_world(
            map,
            out,
            seed=seed,
            scans=scans,
            sensor=sensor,
            odometry=wheels,
            speed_mps=speed,
            clearance_m=clearance,
            force=force,
            progress=progress,
        )
    render.key_values(
        "Lidar log",
        {
            "scans": f"{summary['scans']} x {summary['beams']} beams, "
            f"{summary['no_return_share']:.1%} with nothing in range",
            "route": f"{summary['path_length_m']:.1f} m in {summary['duration_s']:.1f} s at "
            f"{summary['speed_mps']:.2f} m/s, {summary['waypoints']} waypoints",
            "revisits": summary["revisits"],
            "odometry": f"{summary['odometry']} poses" if summary["odometry"] else "none",
            "seed": seed,
        },
    )
    render.written(summary["files"])
