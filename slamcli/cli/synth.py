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
