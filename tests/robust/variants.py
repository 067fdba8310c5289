"""Perturbed copies of the shared real excerpts, one folder per variant.

Three variants, each small enough that a method whose accuracy rests on sound decisions keeps
it, yet enough to move every later floating-point result:

- ``noise``: the sensor's smallest step of seeded noise. Every 8-bit image pixel gets
  -1, 0 or +1 grey level (clipped), depth images are kept; a laser reading moves by one
  range step of its log (1 cm in the Radish logs); an MRCLAM range and bearing by one step
  of the precision they are printed with (1 mm, 1 mrad).
- ``drop-first``: the first frame (image pair, scan, landmark measurement) is left out.
- ``drop-every-10th``: frames 10, 20, 30, ... (counted from 1) are left out.

Files that a variant does not change are symbolic links to the originals; list files (TUM's
``rgb.txt``, ASL ``data.csv``, MRCLAM measurement tables) are rewritten without the dropped
frames' lines, every other line kept as it was. The copies keep the originals' folder names,
since a TUM folder's name chooses its camera preset.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry.planar import se3_to_planar

VARIANTS = ("noise", "drop-first", "drop-every-10th")
NOISE_SEED = 0

LASER_STEP_M = 0.01
"""The range step of the Radish CARMEN logs (ranges are printed in centimetres)."""
MRCLAM_STEP = 0.001
"""MRCLAM prints ranges (m) and bearings (rad) with three decimals."""


def kept(n: int, variant: str) -> NDArray[np.bool_]:
    """(n,) bool: the frames a variant keeps."""
    keep = np.ones(n, dtype=bool)
    if variant == "drop-first":
        keep[:1] = False
    elif variant == "drop-every-10th":
        keep[9::10] = False
    elif variant != "noise":
        raise ValueError(f"unknown variant {variant!r}; known: {', '.join(VARIANTS)}")
    return keep


def grey_noise(image: NDArray[np.uint8], rng: np.random.Generator) -> NDArray[np.uint8]:
    """``image`` with -1, 0 or +1 added to every value, clipped to 0..255."""
    if image.dtype != np.uint8:
        raise TypeError(f"grey-level noise is for 8-bit images, got {image.dtype}")
    step = rng.integers(-1, 2, size=image.shape, dtype=np.int16)
    return np.clip(image.astype(np.int16) + step, 0, 255).astype(np.uint8)


def _link(src: Path, dst: Path) -> None:
    dst.symlink_to(src.resolve())


def _noisy_png(src: Path, dst: Path, rng: np.random.Generator) -> None:
    import cv2

    image = cv2.imread(str(src), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise OSError(f"cannot read {src}")
    if not cv2.imwrite(str(dst), grey_noise(image, rng)):
        raise OSError(f"cannot write {dst}")


def _images(
    src: Path, dst: Path, drop: Callable[[Path], bool], rng: np.random.Generator | None
) -> None:
    """The files of folder ``src`` in ``dst``: dropped ones left out, the others noisy (with
    ``rng``) or linked. Files are taken in name order, so the noise is the same every time."""
    dst.mkdir(parents=True)
    for f in sorted(src.iterdir()):
        if drop(f):
            continue
        if rng is not None and f.suffix.lower() == ".png":
            _noisy_png(f, dst / f.name, rng)
        else:
            _link(f, dst / f.name)


def _filter_lines(src: Path, dst: Path, dropped: Callable[[list[str]], bool]) -> None:
    """``src`` without the data lines (not comments, not blank) for which ``dropped(fields)``
    holds; fields are split on whitespace and commas."""
    out = []
    for line in src.read_text().splitlines(keepends=True):
        text = line.strip()
        if text and not text.startswith("#") and dropped(text.replace(",", " ").split()):
            continue
        out.append(line)
    dst.write_text("".join(out))


def _link_rest(src: Path, dst: Path, made: Iterable[str]) -> None:
    """Links in ``dst`` to every entry of ``src`` not named in ``made``."""
    skip = set(made)
    for entry in sorted(src.iterdir()):
        if entry.name not in skip:
            _link(entry, dst / entry.name)


def _rng(variant: str) -> np.random.Generator | None:
    return np.random.default_rng(NOISE_SEED) if variant == "noise" else None


# -- image folders ---------------------------------------------------------------------------------


def tum_variant(src: Path, out: Path, variant: str) -> Path:
    """A TUM RGB-D folder as ``out/<its name>``: frames are the associated colour-depth pairs;
    noise goes on the colour images only."""
    from slamcli.formats.tum_rgbd import TumRgbdSource

    pairs = TumRgbdSource(src).associations()
    keep = kept(len(pairs), variant)
    dropped = {name for p, k in zip(pairs, keep, strict=True) if not k for name in (p[1], p[3])}
    dest = out / src.name
    dest.mkdir(parents=True)
    lists = [n for n in ("rgb.txt", "depth.txt", "associations.txt") if (src / n).is_file()]
    for name in lists:
        _filter_lines(src / name, dest / name, lambda fields: bool(dropped & set(fields)))
    rng = _rng(variant)
    for sub in ("rgb", "depth"):
        colour = sub == "rgb"
        _images(
            src / sub,
            dest / sub,
            lambda f, sub=sub: f"{sub}/{f.name}" in dropped,
            rng if colour else None,
        )
    _link_rest(src, dest, [*lists, "rgb", "depth"])
    return dest


def kitti_variant(src: Path, out: Path, variant: str) -> Path:
    """A KITTI excerpt (``image_l/``, ``image_r/``, ``calib.txt``, ``poses.txt``) as
    ``out/<its name>``; an image ``NNNNNN.png`` keeps its number, hence its stamp."""
    pair = ("image_l", "image_r")
    numbers = sorted(f.name for f in (src / pair[0]).iterdir() if f.suffix == ".png")
    keep = kept(len(numbers), variant)
    dropped = {n for n, k in zip(numbers, keep, strict=True) if not k}
    dest = out / src.name
    dest.mkdir(parents=True)
    rng = _rng(variant)
    for sub in pair:
        _images(src / sub, dest / sub, lambda f: f.name in dropped, rng)
    _link_rest(src, dest, pair)
    return dest


def euroc_variant(src: Path, out: Path, variant: str) -> Path:
    """A EuRoC / ASL stereo folder as ``out/<its name>``: frames are the stereo pairs; both
    cameras' ``data.csv`` lose the dropped pairs' lines, and both images get noise."""
    from slamcli.formats.euroc import EurocSource

    source = EurocSource(src)
    keep = kept(len(source), variant)
    dropped = {
        "cam0": set(source.pair_stamps_ns[~keep].tolist()),
        "cam1": set(source.pair_right_stamps_ns[~keep].tolist()),
    }
    dest = out / src.name
    (dest / "mav0").mkdir(parents=True)
    rng = _rng(variant)
    for cam, stamps in dropped.items():
        a, b = src / "mav0" / cam, dest / "mav0" / cam
        b.mkdir()
        _filter_lines(a / "data.csv", b / "data.csv", lambda fields, s=stamps: int(fields[0]) in s)
        _images(a / "data", b / "data", lambda f, s=stamps: int(f.stem) in s, rng)
        _link_rest(a, b, ["data.csv", "data"])
    _link_rest(src / "mav0", dest / "mav0", list(dropped))
    _link_rest(src, dest, ["mav0"])
    return dest


# -- laser logs and landmark tables ----------------------------------------------------------------


def carmen_variant(log: Path, folder: Path, variant: str) -> tuple[Path, Path]:
    """``lidar_data.drifted_log`` of a corrected CARMEN log (drifted over every scan, so a kept
    scan has the odometry pose the main test's run reads), then perturbed into
    ``folder/drifted.log``; the log's own poses are the reference ``folder/reference.tum``.
    Noise moves each reading by -1, 0 or +1 range step, never below the scanner's minimum."""
    from lidar_data import drifted_log

    from slamcli.formats.carmen import CarmenSource, write_carmen
    from slamcli.types import ScanFrame

    (folder / "whole").mkdir(parents=True)
    whole, reference = drifted_log(log, folder / "whole")
    with CarmenSource.open(whole, groundtruth="log") as source:
        scans = [f for f in source.frames(("scan",)) if isinstance(f, ScanFrame)]
        odometry = source.groundtruth()
    assert odometry is not None and len(odometry) == len(scans)
    poses = se3_to_planar(odometry.world_from_body)
    rng = _rng(variant)
    if rng is not None:
        noisy = []
        for scan in scans:
            ranges = scan.ranges_m.astype(np.float64)
            on = scan.readings()
            ranges[on] += LASER_STEP_M * rng.integers(-1, 2, size=int(on.sum()))
            ranges[on] = np.maximum(ranges[on], scan.range_min_m)
            noisy.append(replace(scan, ranges_m=ranges.astype(np.float32)))
        scans = noisy
    keep = kept(len(scans), variant)
    out = folder / "drifted.log"
    write_carmen(out, ((s, p) for s, p, k in zip(scans, poses, keep, strict=True) if k))
    return out, reference


def mrclam_variant(src: Path, out: Path, variant: str) -> Path:
    """An MRCLAM folder as ``out/<its name>`` whose ``RobotN_Measurement.dat`` tables are
    perturbed: a frame is all of one robot's measurements at one time (as the reader groups
    them). Odometry and ground truth are the originals."""
    dest = out / src.name
    dest.mkdir(parents=True)
    rng = _rng(variant)
    tables = sorted(src.glob("Robot*_Measurement.dat"))
    for table in tables:
        lines = table.read_text().splitlines(keepends=True)
        data = [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]
        stamps = [lines[i].split()[0] for i in data]
        frame_of = np.cumsum([k == 0 or stamps[k] != stamps[k - 1] for k in range(len(stamps))])
        keep = kept(int(frame_of[-1]), variant)[frame_of - 1]
        for i, k in zip(data, keep, strict=True):
            if not k:
                lines[i] = ""
            elif rng is not None:
                t, subject, rng_m, bearing = lines[i].split()
                dr, db = MRCLAM_STEP * rng.integers(-1, 2, size=2)
                end = lines[i][len(lines[i].rstrip("\r\n")) :]
                r, b = float(rng_m) + dr, float(bearing) + db
                lines[i] = f"{t} \t  {subject} \t  {r:.3f} \t {b:.3f}{end}"
        (dest / table.name).write_text("".join(lines))
    _link_rest(src, dest, [t.name for t in tables])
    return dest
