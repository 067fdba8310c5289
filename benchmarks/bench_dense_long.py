"""Memory and speed of dense SLAM over a long log that keeps revisiting one room.

A rendered RGB-D loop (``synth rgbd``'s room, 320x240, depth noise) is flown ``--laps`` times,
each lap with fresh noise, as one TUM folder of ``laps x lap_frames`` frames (2,000 by
default). The dense pipeline runs over it frame by frame in this process; after every block of
``--block`` frames the script prints the process's resident memory (VmRSS) and the block's
ms/frame. Once the room is mapped (after the first lap) memory should stay flat and ms/frame
should not rise with the frame count; the script prints the growth per 1,000 frames from the end
of the first lap on (target: under 50 MB) and the ATE of the whole run.

Usage: python benchmarks/bench_dense_long.py [--laps 4] [--lap-frames 500] [--block 500]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

TARGET_MB_PER_1000 = 50.0


def rss_mb() -> float:
    """The process's resident memory now (Linux /proc), MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def render_laps(out: Path, laps: int, lap_frames: int, size: tuple[int, int]) -> Path:
    """A TUM folder: ``laps`` flights of one ``lap_frames``-frame loop, fresh noise each lap,
    stamps running on."""
    import cv2

    from slamcli.formats.camera import save_camera_file
    from slamcli.formats.trajectory import tum_lines
    from slamcli.synth.rgbd import DEPTH_FACTOR, FPS, build_rgbd_world
    from slamcli.types import Trajectory

    (out / "rgb").mkdir(parents=True)
    (out / "depth").mkdir()
    world = build_rgbd_world(lap_frames, size, seed=0)
    lap = world.trajectory
    step_ns = round(1e9 / FPS)
    offset_ns = int(world.depth_stamps_ns[0] - lap.stamps_ns[0])
    rng = np.random.default_rng(0)
    rgb_rows, depth_rows, stamps, poses = [], [], [], []
    for k in range(laps * lap_frames):
        pose = lap.world_from_body[k % lap_frames]
        stamp = int(lap.stamps_ns[0]) + k * step_ns
        rgb, depth = world.render(pose, rng)
        s, ds = stamp / 1e9, (stamp + offset_ns) / 1e9
        cv2.imwrite(str(out / f"rgb/{s:.6f}.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
        raw = np.rint(depth.astype(np.float64) * DEPTH_FACTOR).astype(np.uint16)
        cv2.imwrite(str(out / f"depth/{ds:.6f}.png"), raw)
        rgb_rows.append(f"{s:.6f} rgb/{s:.6f}.png\n")
        depth_rows.append(f"{ds:.6f} depth/{ds:.6f}.png\n")
        stamps.append(stamp)
        poses.append(pose)
    (out / "rgb.txt").write_text("".join(rgb_rows))
    (out / "depth.txt").write_text("".join(depth_rows))
    truth = Trajectory(np.array(stamps, dtype=np.int64), np.stack(poses))
    (out / "groundtruth.txt").write_text("\n".join(tum_lines(truth, stamp_decimals=6)) + "\n")
    save_camera_file(out / "camera.yaml", world.camera, depth_factor=DEPTH_FACTOR)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--laps", type=int, default=4)
    parser.add_argument("--lap-frames", type=int, default=500)
    parser.add_argument("--block", type=int, default=500)
    args = parser.parse_args()

    from slamcli.evaluation import evaluate
    from slamcli.formats import open_source
    from slamcli.pipelines.dense import DenseSlam

    with tempfile.TemporaryDirectory(prefix="bench_dense_long_") as tmp:
        start = time.perf_counter()
        folder = render_laps(Path(tmp) / "laps", args.laps, args.lap_frames, (320, 240))
        seconds = time.perf_counter() - start
        print(f"rendered {args.laps} x {args.lap_frames} frames in {seconds:.0f} s")
        pipe = DenseSlam()
        rows = []
        with open_source(folder) as source:
            block_start = time.perf_counter()
            for done, frame in enumerate(source.frames(("rgbd",)), start=1):
                pipe.process(frame)
                if done % args.block == 0:
                    now = time.perf_counter()
                    rows.append((done, rss_mb(), (now - block_start) / args.block * 1e3))
                    block_start = now
            finish_start = time.perf_counter()
            result = pipe.finish()
            finish_s = time.perf_counter() - finish_start
            truth = source.groundtruth()
    print(f"{'frames':>8}{'RSS MB':>10}{'ms/frame (block)':>18}")
    for frames, mb, ms in rows:
        print(f"{frames:>8}{mb:>10.0f}{ms:>18.1f}")
    # Once the room is mapped: from the end of the first lap on.
    after_first = [r for r in rows if r[0] >= args.lap_frames]
    if len(after_first) >= 2:
        (f0, m0, _), (f1, m1, _) = after_first[0], after_first[-1]
        per_1000 = (m1 - m0) / (f1 - f0) * 1000
        verdict = "meets" if per_1000 < TARGET_MB_PER_1000 else "MISSES"
        print(
            f"\nRSS growth from frame {f0} (the room mapped) to {f1}: {per_1000:+.1f} MB per "
            f"1,000 frames "
            f"({verdict} the target < {TARGET_MB_PER_1000:.0f} MB)"
        )
        # A row's ms/frame is that of the block ending at its frame count.
        later = [r for r in rows if r[0] - args.block >= args.lap_frames]
        if len(later) >= 2:
            (a, _, first_ms), (b, _, last_ms) = later[0], later[-1]
            print(
                f"ms/frame, first block after the first lap (frames {a - args.block + 1}-{a}) "
                f"vs last ({b - args.block + 1}-{b}): {first_ms:.1f} -> {last_ms:.1f}"
            )
    assert result.trajectory is not None and truth is not None
    ate = evaluate(truth, result.trajectory, align="se3").ate.rmse
    counts = result.counts
    print(
        f"ATE {ate:.4f} m over {len(result.trajectory)} frames; keyframes {counts['keyframes']}, "
        f"loop closures {counts['loop_closures_accepted']} accepted, "
        f"finish (pose graph, rebuild, mesh) {finish_s:.1f} s"
    )


if __name__ == "__main__":
    main()
