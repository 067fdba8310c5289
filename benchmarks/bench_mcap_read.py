"""Read speed and peak memory of McapLog.messages() against a bare mcap pass over the same log.

Usage: python benchmarks/bench_mcap_read.py [LOG.mcap] [--size-mb N] [--repeats N]

Without a log, one is generated in a temporary folder: ROS 2 ``sensor_msgs/msg/Image`` colour
(640x480 rgb8) and depth (16UC1) at 30 Hz plus ``CameraInfo``, zstd chunks of 768 KiB as
``ros2 bag record`` writes them, until the file reaches ``--size-mb`` (500 by default).

Each measurement runs in its own Python process, so its peak RSS is its own: the kernel's
peak counter (``VmHWM``) is reset after the imports, and the table shows the peak during the
read and its growth over the RSS just before it (``ru_maxrss`` where /proc is missing).
Measurements are interleaved ``--repeats`` times; the fastest run counts, and the largest
peak. The reference is ``mcap``'s ``make_reader(f).iter_messages()`` with its default
``log_time_order=True``, i.e. how a user reads a log with ``mcap`` alone; a second row turns
on its CRC checks, which McapLog always makes.

Goals: raw reading at least as fast as the reference (speed ratio >= 1.00) and peak RSS
growth under 300 MB on a 500 MB log. More measurements (for example decoded RGB-D frames)
register in ``MEASUREMENTS``; the speed ratio is the reference's seconds over theirs, so it
compares passes over the same file whatever they count.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

REFERENCE = "mcap-bare"
RAW_SPEED_GOAL = 1.0
RGBD_SPEED_GOAL = 0.70
"""Decoding and pairing are extra work; the RGB-D pass keeps at least this share of the speed."""
RSS_GROWTH_GOAL_MB = 300.0
WIDTH, HEIGHT, FPS = 640, 480, 30


@dataclass(frozen=True)
class Measurement:
    """One way of reading the whole log; ``run`` returns (items read, payload bytes)."""

    label: str
    unit: str
    run: Callable[[Path], tuple[int, int]]


def _mcap_bare(path: Path, validate_crcs: bool = False) -> tuple[int, int]:
    from mcap.reader import make_reader

    n = nbytes = 0
    with path.open("rb") as fh:
        for _, _, message in make_reader(fh, validate_crcs=validate_crcs).iter_messages():
            n += 1
            nbytes += len(message.data)
    return n, nbytes


def _mcap_log(path: Path) -> tuple[int, int]:
    from slamcli.formats.mcap.reader import McapLog

    n = nbytes = 0
    with McapLog(path) as log:
        for message in log.messages():
            n += 1
            nbytes += len(message.data)
    return n, nbytes


def _rgbd_frames(path: Path) -> tuple[int, int]:
    from slamcli.formats.mcap.source import McapSource

    n = nbytes = 0
    with McapSource(path) as source:
        for frame in source.frames(("rgbd",)):
            n += 1
            nbytes += frame.rgb.nbytes + frame.depth_m.nbytes  # type: ignore[union-attr]
    return n, nbytes


MEASUREMENTS: dict[str, Measurement] = {
    REFERENCE: Measurement("mcap iter_messages() (bare)", "messages", _mcap_bare),
    "mcap-crc": Measurement(
        "mcap iter_messages(), CRCs on", "messages", lambda p: _mcap_bare(p, validate_crcs=True)
    ),
    "mcap-log": Measurement("McapLog.messages()", "messages", _mcap_log),
    "rgbd": Measurement("McapSource RGB-D frames", "frames", _rgbd_frames),
}


def _rss_mb(field: str) -> float | None:
    """``VmRSS`` or ``VmHWM`` (peak) of this process in MB, where /proc has them."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def _reset_peak() -> bool:
    """Restart the kernel's peak-RSS counter at the current RSS (Linux >= 4.0)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return True


def measure_here(name: str, path: Path) -> dict[str, float]:
    """Run one measurement in this process; called in the child."""
    import mcap.reader  # noqa: F401  (imports count towards the baseline, not the growth)

    import slamcli.formats.mcap.reader  # noqa: F401

    # Imports may have peaked higher than reading will; restart the peak counter so it
    # covers the read alone, and fall back to ru_maxrss (KiB on Linux) where that fails.
    before = _rss_mb("VmRSS")
    if before is None or not _reset_peak():
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    items, nbytes = MEASUREMENTS[name].run(path)
    seconds = time.perf_counter() - t0
    peak = _rss_mb("VmHWM")
    if peak is None:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return {
        "items": items,
        "bytes": nbytes,
        "seconds": seconds,
        "peak_mb": peak,
        "growth_mb": peak - before,
    }


def measure_in_child(name: str, path: Path) -> dict[str, float]:
    out = subprocess.run(
        [sys.executable, __file__, "--measure", name, str(path)],
        capture_output=True,
        text=True,
        check=True,
    )
    result: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def generate(path: Path, size_mb: float) -> int:
    """Write a ROS 2 RGB-D log of about ``size_mb`` MB; returns the number of frames."""
    import numpy as np
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    image_t = store.types["sensor_msgs/msg/Image"]
    info_t = store.types["sensor_msgs/msg/CameraInfo"]
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    roi_t = store.types["sensor_msgs/msg/RegionOfInterest"]

    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH]
    base_rgb = np.stack([xx * 255 // WIDTH, yy * 255 // HEIGHT, (xx + yy) % 256], -1)
    base_depth = 800 + 3 * yy + xx
    # A few fixed noise fields keep the images about as compressible as camera images.
    noise = [rng.integers(0, 24, (HEIGHT, WIDTH, 3)) for _ in range(4)]
    k = np.array([525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1])
    p = np.array([525.0, 0, 319.5, 0, 0, 525.0, 239.5, 0, 0, 0, 1, 0])

    target = int(size_mb * 1e6)
    frames = 0
    t0 = 1_700_000_000 * 10**9
    with path.open("wb") as fh:
        writer = Writer(fh, chunk_size=768 * 1024, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="slamcli benchmarks")
        ids = {}
        for topic, typename in (
            ("/camera/color/image_raw", "sensor_msgs/msg/Image"),
            ("/camera/depth/image_raw", "sensor_msgs/msg/Image"),
            ("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo"),
        ):
            schema = writer.register_schema(
                typename, "ros2msg", store.generate_msgdef(typename, ros_version=2)[0].encode()
            )
            ids[topic] = writer.register_channel(topic, "cdr", schema)
        while fh.tell() < target:
            t = t0 + frames * 10**9 // FPS
            stamp = time_t(sec=t // 10**9, nanosec=t % 10**9)
            rgb = ((base_rgb + 2 * frames) % 256 + noise[frames % 4]).clip(0, 255)
            depth = base_depth + 5 * (frames % 60)
            messages = (
                (
                    "/camera/color/image_raw",
                    image_t(
                        header_t(stamp, "camera_color_optical_frame"),
                        HEIGHT,
                        WIDTH,
                        "rgb8",
                        0,
                        WIDTH * 3,
                        rgb.astype(np.uint8).reshape(-1),
                    ),
                ),
                (
                    "/camera/depth/image_raw",
                    image_t(
                        header_t(stamp, "camera_color_optical_frame"),
                        HEIGHT,
                        WIDTH,
                        "16UC1",
                        0,
                        WIDTH * 2,
                        depth.astype("<u2").view(np.uint8).reshape(-1),
                    ),
                ),
                (
                    "/camera/color/camera_info",
                    info_t(
                        header_t(stamp, "camera_color_optical_frame"),
                        HEIGHT,
                        WIDTH,
                        "plumb_bob",
                        np.zeros(5),
                        k,
                        np.eye(3).reshape(-1),
                        p,
                        0,
                        0,
                        roi_t(0, 0, 0, 0, False),
                    ),
                ),
            )
            for topic, msg in messages:
                data = store.serialize_cdr(msg, msg.__msgtype__)
                writer.add_message(ids[topic], log_time=t, data=bytes(data), publish_time=t)
            frames += 1
        writer.finish()
    return frames


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("log", nargs="?", type=Path, help="an MCAP log (default: generate one)")
    parser.add_argument("--size-mb", type=float, default=500.0)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--measure", nargs=2, metavar=("NAME", "LOG"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        name, log = args.measure
        print(json.dumps(measure_here(name, Path(log))))
        return

    with tempfile.TemporaryDirectory(prefix="bench_mcap_") as tmp:
        path = args.log
        if path is None:
            path = Path(tmp) / "rgbd.mcap"
            t0 = time.perf_counter()
            frames = generate(path, args.size_mb)
            print(
                f"generated {path.name}: {frames} RGB-D frames in {time.perf_counter() - t0:.1f} s"
            )
        size_mb = path.stat().st_size / 1e6
        # Warm the page cache so the first measurement does not pay for the disk alone.
        with path.open("rb") as fh:
            while fh.read(1 << 24):
                pass
        results: dict[str, list[dict[str, float]]] = {name: [] for name in MEASUREMENTS}
        for _ in range(args.repeats):
            for name in MEASUREMENTS:
                results[name].append(measure_in_child(name, path))
        report(path, size_mb, results, args.repeats)


def report(
    path: Path, size_mb: float, results: dict[str, list[dict[str, float]]], repeats: int
) -> None:
    print(f"log: {path}  {size_mb:.0f} MB on disk  best of {repeats}, each run in its own process")
    print(
        f"{'variant':<30}{'items':>8}{'items/s':>11}{'MB/s':>9}{'speed':>8}"
        f"{'peak RSS':>11}{'growth':>9}"
    )
    ref_seconds = min(r["seconds"] for r in results[REFERENCE])
    for name, runs in results.items():
        best = min(runs, key=lambda r: r["seconds"])
        peak = max(r["peak_mb"] for r in runs)
        growth = max(r["growth_mb"] for r in runs)
        m = MEASUREMENTS[name]
        print(
            f"{m.label:<30}{int(best['items']):>8}{best['items'] / best['seconds']:>11.0f}"
            f"{best['bytes'] / 1e6 / best['seconds']:>9.0f}{ref_seconds / best['seconds']:>7.2f}x"
            f"{peak:>8.0f} MB{growth:>6.0f} MB"
        )
    print(
        "items are messages (or frames) per pass; MB/s counts message payload bytes; speed is "
        "the bare pass's time over this one's; peak RSS is the process's peak during the read "
        "(VmHWM, reset just before it), growth is that peak minus the RSS just before reading "
        "(after imports). McapLog always checks chunk CRCs; the plain bare pass does not."
    )
    ours = min(results["mcap-log"], key=lambda r: r["seconds"])
    speed = ref_seconds / ours["seconds"]
    growth = max(r["growth_mb"] for r in results["mcap-log"])
    verdict = "meets" if speed >= RAW_SPEED_GOAL and growth < RSS_GROWTH_GOAL_MB else "MISSES"
    print(
        f"McapLog.messages(): {speed:.2f}x the bare pass, {growth:.0f} MB RSS growth "
        f"({verdict} the goals >= {RAW_SPEED_GOAL:.2f}x and < {RSS_GROWTH_GOAL_MB:.0f} MB)"
    )
    frames = min(results["rgbd"], key=lambda r: r["seconds"])
    speed = ref_seconds / frames["seconds"]
    growth = max(r["growth_mb"] for r in results["rgbd"])
    verdict = "meets" if speed >= RGBD_SPEED_GOAL and growth < RSS_GROWTH_GOAL_MB else "MISSES"
    print(
        f"McapSource RGB-D frames (decoded, paired): {frames['items'] / frames['seconds']:.0f} "
        f"frames/s, {speed:.2f}x the bare pass's speed over the same file, {growth:.0f} MB RSS "
        f"growth ({verdict} the goals >= {RGBD_SPEED_GOAL:.2f}x and < {RSS_GROWTH_GOAL_MB:.0f} MB)"
    )


if __name__ == "__main__":
    main()
