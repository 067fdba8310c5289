"""Inputs for the visual SLAM tests and benchmark: a rendered loop and deliberately bad folders.

The loop is the camera path of ``slamcli synth rgbd`` over 540 frames (one full turn around
the room, ending near its start), rendered at every ``every``-th frame only: 270 frames at 15 Hz
keep a test run short while the turn still closes. Everything is seeded: the same arguments
give the same bytes.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

LOOP_FRAMES = 540
LOOP_EVERY = 2
LOOP_SIZE = (320, 240)


def _write_list(path: Path, stamps_s: list[float], folder: str) -> list[str]:
    names = [f"{folder}/{s:.6f}.png" for s in stamps_s]
    path.write_text("".join(f"{s:.6f} {n}\n" for s, n in zip(stamps_s, names, strict=True)))
    return names


def render_loop(
    out: Path,
    frames: int = LOOP_FRAMES,
    every: int = LOOP_EVERY,
    size: tuple[int, int] = LOOP_SIZE,
    seed: int = 0,
    noise: bool = True,
) -> Path:
    """Render every ``every``-th frame of a ``frames``-frame synthetic RGB-D loop as a TUM
    folder (rgb/, depth/, rgb.txt, depth.txt, groundtruth.txt with every pose of the path,
    camera.yaml); returns ``out``."""
    import cv2

    from slamcli.formats.camera import save_camera_file
    from slamcli.formats.trajectory import tum_lines
    from slamcli.synth.rgbd import DEPTH_FACTOR, build_rgbd_world

    (out / "rgb").mkdir(parents=True, exist_ok=True)
    (out / "depth").mkdir(exist_ok=True)
    world = build_rgbd_world(frames, size, seed)
    rng = np.random.default_rng(seed) if noise else None
    traj = world.trajectory
    rgb_stamps, depth_stamps = [], []
    for i in range(0, frames, every):
        rgb, depth = world.render(traj.world_from_body[i], rng)
        s, ds = traj.stamps_ns[i] / 1e9, world.depth_stamps_ns[i] / 1e9
        cv2.imwrite(str(out / f"rgb/{s:.6f}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        raw = np.rint(depth.astype(np.float64) * DEPTH_FACTOR).astype(np.uint16)
        cv2.imwrite(str(out / f"depth/{ds:.6f}.png"), raw)
        rgb_stamps.append(s)
        depth_stamps.append(ds)
    _write_list(out / "rgb.txt", rgb_stamps, "rgb")
    _write_list(out / "depth.txt", depth_stamps, "depth")
    (out / "groundtruth.txt").write_text("\n".join(tum_lines(traj, stamp_decimals=6)) + "\n")
    save_camera_file(out / "camera.yaml", world.camera, depth_factor=DEPTH_FACTOR)
    return out


def colour_only_copy(folder: Path, out: Path) -> Path:
    """``folder`` without its depth: rgb/, rgb.txt, groundtruth.txt and camera.yaml only."""
    out.mkdir(parents=True)
    shutil.copytree(folder / "rgb", out / "rgb")
    for name in ("rgb.txt", "groundtruth.txt", "camera.yaml"):
        shutil.copy(folder / name, out / name)
    return out


def flat_folder(out: Path, frames: int = 10, size: tuple[int, int] = (320, 240)) -> Path:
    """A TUM folder of uniform grey images with a flat wall 2 m away: nothing to track."""
    import cv2

    from slamcli.formats.camera import save_camera_file
    from slamcli.synth.rgbd import DEPTH_FACTOR, camera_for_size

    w, h = size
    (out / "rgb").mkdir(parents=True)
    (out / "depth").mkdir()
    stamps = [1.0 + i / 30 for i in range(frames)]
    for s in stamps:
        cv2.imwrite(str(out / f"rgb/{s:.6f}.png"), np.full((h, w, 3), 128, np.uint8))
        cv2.imwrite(str(out / f"depth/{s:.6f}.png"), np.full((h, w), 2 * DEPTH_FACTOR, np.uint16))
    _write_list(out / "rgb.txt", stamps, "rgb")
    _write_list(out / "depth.txt", stamps, "depth")
    save_camera_file(out / "camera.yaml", camera_for_size(w, h), depth_factor=DEPTH_FACTOR)
    return out


def wrong_camera_copy(folder: Path, out: Path) -> Path:
    """``folder`` with a camera.yaml for images twice the size of its own."""
    from dataclasses import replace

    from slamcli.formats.camera import load_camera_file, save_camera_file

    shutil.copytree(folder, out)
    cam_file = load_camera_file(out / "camera.yaml")
    cam = cam_file.camera
    wrong = replace(cam, width=2 * cam.width, height=2 * cam.height)
    save_camera_file(out / "camera.yaml", wrong, depth_factor=cam_file.depth_factor)
    return out


def blanked_copy(folder: Path, out: Path, first: int, last: int) -> Path:
    """A copy of a TUM folder whose frames ``first``..``last - 1`` are flat grey with no depth
    (the camera blinded for a while), the others linked to the originals."""
    import cv2

    out.mkdir(parents=True)
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "camera.yaml"):
        shutil.copy(folder / name, out / name)
    for lst, sub in (("rgb.txt", "rgb"), ("depth.txt", "depth")):
        (out / sub).mkdir()
        rows = [ln.split() for ln in (folder / lst).read_text().splitlines() if ln[:1] not in "#"]
        for i, (_stamp, name) in enumerate(r for r in rows if r):
            if first <= i < last:
                like = cv2.imread(str(folder / name), cv2.IMREAD_UNCHANGED)
                blank = np.zeros_like(like) if sub == "depth" else np.full_like(like, 128)
                cv2.imwrite(str(out / name), blank)
            else:
                (out / name).symlink_to(folder / name)
    return out


SLOW_LOOP_KEY = "stereo-loop-10hz"
"""The ``shared_artefact`` key of :func:`render_slow_loop`'s folder."""


def render_slow_loop(folder: Path) -> None:
    """18 s of ``synth stereo`` at 10 Hz into ``folder / "rig"``: 180 pairs, 320x240, noise;
    one turn around the room at a steady pace, back to the start."""
    from slamcli.synth.stereo import render_stereo_sequence

    render_stereo_sequence(folder / "rig", frames=180, size=(320, 240), noise=True, seed=0, fps=10)
